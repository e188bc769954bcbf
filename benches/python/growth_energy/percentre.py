"""Per-window-centre table (all seeds, no amplitude-based selection) + growth vs not at the same centre.
Usage: python percentre.py [rows.pkl]"""
import pickle, sys, numpy as np
rows = pickle.load(open(sys.argv[1] if len(sys.argv) > 1 else "rows.pkl", "rb"))
EST = ["LS logenv", "EBP-lin D=0", "EBP-lin Dor", "EBP-lin+gam D=0", "EBP-lin+gam Dest", "EBP-lin+gam Dor", "EBP-lin+gam Dor*0.7", "EBP-lin+gam Dor*1.3", "EBlin+gam Dor"]
by = {}
for r in rows:
    by.setdefault((r[0], r[2] + 5, r[8]), []).append(r)
for gate in ["lab", "lock"]:
    print(f"== {gate}: centre | truth | N(growth/all) | E/Ea | per estimator: med err (all) [med err growth-only] cover(all)")
    for c in [145, 150, 155, 160, 165, 170]:
        for k in EST:
            r = by.get((gate, c, k))
            if not r: continue
            e = np.array([x[9] - x[4] for x in r]); cov = np.array([abs(x[9] - x[4]) <= x[11] * x[10] for x in r])
            gm = np.array([x[3] == "growth" for x in r])
            eg = f"{100*np.median(e[gm]):+.3f}" if gm.any() else "  n/a "
            print(f"{gate} {c:4.0f} {100*r[0][4]:+.3f}  {gm.sum():3d}/{len(r):3d}  E/Ea={np.median([x[7] for x in r]):6.1f}  {k:22s} med err {100*np.median(e):+.3f} med|err| {100*np.median(abs(e)):.3f} [growth {eg}] cover {100*cov.mean():3.0f}%")
        print()
