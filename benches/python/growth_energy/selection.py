"""Is the +0.3..0.4 bias on 'growth' windows a selection effect? Compare the class as defined
(clean amplitude over the window < 0.5*LC) with selections that do not look at the window's
own outcome: amplitude over the 2 s BEFORE the window (predetermined).  Usage: python selection.py"""
import pickle, numpy as np
import sim, analyze
rows = pickle.load(open("rows_dense.pkl", "rb"))
EST = ["LS logenv", "EBP-lin+gam D=0", "EBP-lin+gam Dest", "EBP-lin+gam Dor", "EBP-lin+gam Dor*0.7", "EBP-lin+gam Dor*1.3", "EBP-c Dor"]
print(f"{'gate':5s} {'selection':34s} {'estimator':22s} {'N':>5s} {'med|err|':>8s} {'med err':>8s} {'cover':>6s}")
for gate in ["lab", "lock"]:
    g = sim.gate(gate)
    t, clean, meas = analyze.load(gate)
    pre = {}
    for s0 in np.arange(140, 176, 1.0):
        i0 = int(round(s0 * g["fs"]))
        pre[s0] = np.sqrt(2) * clean[:, i0 - int(2 * g["fs"]):i0].std(1)
    for k in EST:
        R = [r for r in rows if r[0] == gate and r[8] == k and r[5] < 0]
        sels = {
            "class growth (window amp<0.5LC)": [r for r in R if r[3] == "growth"],
            "pre-window amp < 0.5LC(zc)": [r for r in R if pre[r[2]][r[1]] < 0.5 * sim.lc_amp(g, r[5])],
            "pre-window amp < 0.25LC(zc)": [r for r in R if pre[r[2]][r[1]] < 0.25 * sim.lc_amp(g, r[5])],
            "all zc<0 windows, centre<=165": [r for r in R if r[2] + 5 <= 165],
        }
        for sn, rr in sels.items():
            e = np.array([r[9] - r[4] for r in rr]); cv = np.array([abs(r[9] - r[4]) <= r[11] * r[10] for r in rr])
            print(f"{gate:5s} {sn:34s} {k:22s} {len(rr):5d} {100*np.median(abs(e)):8.3f} {100*np.median(e):+8.3f} {100*cv.mean():5.0f}%")
        print()
