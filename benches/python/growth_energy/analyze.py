"""Score log-envelope slope vs energy-balance (stochastic averaging) zeta estimators.

Usage: python analyze.py            (needs sim_lab.npz, sim_lock.npz from sim.py)
Windows 10 s, hop 5 s.  Classes: ambient (zeta(centre)>=0), growth (zeta<0 and clean
sqrt2*RMS < 0.5*LC amplitude), lc1 (first two windows per seed at/above that threshold).
"""
import sys
import numpy as np
from scipy import signal, stats
import sim

WIN, HOP = 10.0, 5.0
BASE = (10.0, 110.0)  # ambient baseline used to learn D (before the ramp starts at 120 s)


def envelope(g, x):
    sos = signal.butter(4, [0.75 * g["f"], 1.25 * g["f"]], btype="band", fs=g["fs"], output="sos")
    xb = signal.sosfiltfilt(sos, x, axis=-1)
    A = np.abs(signal.hilbert(xb, axis=-1))
    return A


def chunks(E, t, i0, i1, h_n, want2=False):
    """increments / integrals over consecutive chunks of h_n samples in [i0,i1]"""
    i1 = min(i1, len(t) - 1)
    idx = np.arange(i0, i1 + 1, h_n)
    dt = t[1] - t[0]
    tc = 0.5 * (t[i0] + t[i1])
    dE, I0, I1, Eb, I2 = [], [], [], [], []
    for a, b in zip(idx[:-1], idx[1:]):
        seg = E[:, a:b + 1]
        tt = t[a:b + 1] - tc
        dE.append(seg[:, -1] - seg[:, 0])
        I0.append(np.trapezoid(seg, dx=dt, axis=1))
        I1.append(np.trapezoid(seg * tt, dx=dt, axis=1))
        Eb.append(seg.mean(axis=1))
        if want2:
            I2.append(np.trapezoid(seg * seg, dx=dt, axis=1))
    hsec = h_n * dt
    out = np.array(dE).T, np.array(I0).T, np.array(I1).T, np.array(Eb).T, hsec
    return out + (np.array(I2).T,) if want2 else out


def wls(y, X, wts):
    """per-seed WLS. y (S,n), X (S,n,p), wts (S,n). returns beta (S,p), se (S,p), dof"""
    S, n, p = X.shape
    beta = np.empty((S, p)); se = np.empty((S, p))
    for s in range(S):
        sw = np.sqrt(wts[s])
        Xw = X[s] * sw[:, None]; yw = y[s] * sw
        b, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
        r = yw - Xw @ b
        s2 = r @ r / (n - p)
        cov = s2 * np.linalg.inv(Xw.T @ Xw)
        beta[s] = b; se[s] = np.sqrt(np.diag(cov))
    return beta, se, n - p


def eb_window(E, t, i0, i1, g, D, h_sec, linear, gamma=None):
    """energy balance dE/dt = D - 2 w (zeta0(t) + gamma E) E, zeta0(t) = a + b (t - tc).
    gamma=None: no amplitude term; gamma='fit': fitted; number: known (cubic damping, harmonic balance)."""
    h_n = int(round(h_sec * g["fs"]))
    dE, I0, I1, Eb, hs, I2 = chunks(E, t, i0, i1, h_n, want2=True)
    w = g["w"]
    D = np.broadcast_to(np.asarray(D, float).reshape(-1, 1), dE.shape)
    y = dE - D * hs
    X = [-2 * w * I0] + ([-2 * w * I1] if linear else [])
    if gamma == "fit":
        X.append(-2 * w * I2)
    elif gamma is not None:
        y = y + 2 * w * gamma * I2
    X = np.stack(X, axis=-1)
    beta, se, dof = wls(y, X, 1.0 / Eb)
    return beta[:, 0], se[:, 0], dof


def gamma_true(g):
    """cubic damping as equivalent zeta per unit envelope^2 (force amplitude^2): 3 c3 w / (8 m k^2)"""
    return 3 * g["c3"] * g["w"] / (8 * g["m"] * g["k"] ** 2)


def eb_pre(E, t, i0, i1, g, D, h_sec, linear, gamma=None):
    """energy balance with a PREDETERMINED regressor (exact one-step solution of the mean ODE):
    E[j+1] = E[j] e^{-L h} + D (1 - e^{-L h}) / L,  L = 2 w (a + b (t_j - tc) + gamma E[j]).
    Noise = martingale increment, uncorrelated with E[j]; WLS with weights 1/E[j]. Gauss-Newton."""
    h_n = int(round(h_sec * g["fs"]))
    i1 = min(i1, len(t) - 1)
    idx = np.arange(i0, i1 + 1, h_n)
    tc = 0.5 * (t[i0] + t[i1])
    Ej, Ek = E[:, idx[:-1]], E[:, idx[1:]]
    tj = (t[idx[:-1]] - tc)[None, :]
    hs = h_n * (t[1] - t[0])
    w = g["w"]
    S, n = Ej.shape
    D = np.asarray(D, float).reshape(-1, 1) * np.ones((1, n))
    gam = 0.0 if gamma is None else gamma
    p = 2 if linear else 1
    beta = np.zeros((S, p))
    def model(beta):
        z = beta[:, :1] + (beta[:, 1:2] * tj if linear else 0) + gam * Ej
        L = 2 * w * z
        Lh = L * hs
        small = np.abs(Lh) < 1e-8
        ex = np.exp(-Lh)
        frac = np.where(small, hs, (1 - ex) / np.where(small, 1, L))   # (1-e^{-Lh})/L
        pred = Ej * ex + D * frac
        # d pred / d L
        dfrac = np.where(small, -hs * hs / 2, (hs * ex * L - (1 - ex)) / np.where(small, 1, L) ** 2)
        dL = -hs * Ej * ex + D * dfrac
        J = [dL * 2 * w] + ([dL * 2 * w * tj] if linear else [])
        return pred, np.stack(J, -1)
    Wt = 1.0 / np.maximum(Ej, 1e-12)
    for it in range(30):
        pred, J = model(beta)
        r = Ek - pred
        JW = J * Wt[..., None]
        A = np.einsum("snp,snq->spq", JW, J)
        bvec = np.einsum("snp,sn->sp", JW, r)
        step = np.linalg.solve(A, bvec[..., None])[..., 0]
        step = np.clip(step, -0.02, 0.02)
        beta = beta + step
        if np.abs(step).max() < 1e-7:
            break
    pred, J = model(beta)
    r = Ek - pred
    s2 = (Wt * r * r).sum(1) / (n - p)
    A = np.einsum("snp,snq->spq", J * Wt[..., None], J)
    cov = s2[:, None, None] * np.linalg.inv(A)
    return beta[:, 0], np.sqrt(cov[:, 0, 0]), n - p


def ls_window(A, t, i0, i1, g, lag_sec=1.0):
    """OLS slope of ln A; zeta=-slope/omega; Newey-West SE"""
    tt = t[i0:i1] - t[i0:i1].mean()
    la = np.log(A[:, i0:i1])
    b = (la * tt).sum(1) / (tt * tt).sum()
    r = la - la.mean(1, keepdims=True) - b[:, None] * tt
    L = int(lag_sec * g["fs"])
    u = r * tt  # score
    S0 = (u * u).sum(1)
    for l in range(1, L + 1):
        S0 = S0 + 2 * (1 - l / (L + 1)) * (u[:, l:] * u[:, :-l]).sum(1)
    se = np.sqrt(np.maximum(S0, 0)) / (tt * tt).sum()
    return -b / g["w"], se / g["w"]


def baseline_D(E, t, g, h_sec=0.5):
    """learn D (and zeta_a) from the ambient baseline alone: E sampled every h is an AR(1)
    E[j+1] = a + b E[j] (+ martingale noise), b = exp(-2 w zeta_a h), E_inf = a/(1-b), D = 2 zeta_a w E_inf.
    (Regressing increments on the integral over the same chunk is endogenous and gives D~0.)"""
    i0, i1 = int(BASE[0] * g["fs"]), int(BASE[1] * g["fs"])
    h_n = int(round(h_sec * g["fs"]))
    Es = E[:, i0:i1:h_n]
    x, y = Es[:, :-1], Es[:, 1:]
    xm, ym = x.mean(1, keepdims=True), y.mean(1, keepdims=True)
    b = ((x - xm) * (y - ym)).sum(1) / ((x - xm) ** 2).sum(1)
    a = ym[:, 0] - b * xm[:, 0]
    zeta_a = -np.log(np.clip(b, 1e-6, None)) / (2 * g["w"] * h_sec)
    Einf = a / (1 - b)
    Emean = E[:, i0:i1].mean(1)
    return dict(D_est=2 * zeta_a * g["w"] * Emean, zeta_a_est=zeta_a, Emean=Emean,
                D_oracle=2 * 0.02 * g["w"] * Emean,            # true zeta_a, measured E_a
                D_theory=np.full(E.shape[0], g["w"] ** 2 * g["sF"] ** 2 * g["dt"]))


def load(name):
    import glob
    fs = sorted(glob.glob(f"sim_{name}.npz")) + sorted(glob.glob(f"sim_{name}_s*.npz"))
    ds = [np.load(f) for f in fs]
    t = ds[0]["t"]
    clean = np.concatenate([d["clean"] for d in ds]).astype(float)
    meas = np.concatenate([d["meas"] for d in ds]).astype(float)
    return t, clean, meas


def run(name, hop=HOP, span=(0, 300)):
    g = sim.gate(name)
    t, clean, meas = load(name)
    A = envelope(g, meas)
    E = A ** 2
    S = meas.shape[0]
    bl = baseline_D(E, t, g)
    gam = gamma_true(g)
    zt = sim.zeta_of(t)
    rows = []
    lc_seen = np.zeros(S, int)
    starts = np.arange(span[0], span[1] - WIN + 1e-9, hop)
    for s0 in starts:
        i0 = int(round(s0 * g["fs"])); i1 = int(round((s0 + WIN) * g["fs"]))
        truth = zt[i0:i1].mean()
        zc = sim.zeta_of(np.array(s0 + WIN / 2))[()]
        amp = np.sqrt(2) * clean[:, i0:i1].std(1)
        if zc >= 0:
            cls = np.array(["ambient"] * S)
        else:
            lim = 0.5 * sim.lc_amp(g, zc)
            cls = np.where(amp < lim, "growth", "lc")
            for s in range(S):
                if cls[s] == "lc":
                    lc_seen[s] += 1
                    if lc_seen[s] <= 2:
                        cls[s] = "lc1"
        est = {}
        est["LS logenv"] = ls_window(A, t, i0, i1, g) + (np.inf,)
        Dk, Do = bl["D_est"], bl["D_oracle"]
        Ew = E[:, i0:i1].mean(1)
        h = 0.5
        for lin in (False, True):
            tag = f"EB{'lin' if lin else 'c'}"
            for Dname, Dv in [("Dest", Dk), ("Dor", Do), ("Dor*0.7", 0.7 * Do), ("Dor*1.3", 1.3 * Do), ("D=0", 0 * Do)]:
                est[f"{tag} {Dname}"] = eb_window(E, t, i0, i1, g, Dv, h, lin)
        for Dname, Dv in [("Dest", Dk), ("Dor", Do), ("Dor*0.7", 0.7 * Do), ("Dor*1.3", 1.3 * Do)]:
            est[f"EBlin+gam {Dname}"] = eb_window(E, t, i0, i1, g, Dv, h, True, gamma=gam)
        est["EBlin+gam*1.3 Dest"] = eb_window(E, t, i0, i1, g, Dk, h, True, gamma=1.3 * gam)
        est["EBlin+gam*0.7 Dest"] = eb_window(E, t, i0, i1, g, Dk, h, True, gamma=0.7 * gam)
        est["EBc+gamfit Dest"] = eb_window(E, t, i0, i1, g, Dk, h, False, gamma="fit")
        for Dname, Dv in [("Dest", Dk), ("Dor", Do), ("Dor*0.7", 0.7 * Do), ("Dor*1.3", 1.3 * Do), ("D=0", 0 * Do)]:
            est[f"EBP-lin {Dname}"] = eb_pre(E, t, i0, i1, g, Dv, h, True)
            est[f"EBP-c {Dname}"] = eb_pre(E, t, i0, i1, g, Dv, h, False)
            est[f"EBP-lin+gam {Dname}"] = eb_pre(E, t, i0, i1, g, Dv, h, True, gamma=gam)
        for k, (z, se, dof) in est.items():
            q = stats.t.ppf(0.975, dof) if np.isfinite(dof) else 1.96
            for s in range(S):
                rows.append((name, s, s0, cls[s], truth, zc, amp[s], Ew[s] / bl["Emean"][s], k, z[s], se[s], q))
    return rows, bl, g


def summarize(rows, out=sys.stdout):
    import collections
    agg = collections.defaultdict(list)
    for r in rows:
        name, s, s0, cls, truth, zc, amp, er, k, z, se, q = r
        agg[(name, cls, k)].append((z - truth, abs(z - truth) <= q * se, er, truth, q * se))
    keys = sorted(agg)
    print(f"{'gate':5s} {'class':8s} {'estimator':24s} {'N':>5s} {'med|err|':>9s} {'med err':>8s} {'cover':>6s} {'CIhalf':>7s} {'medE/Ea':>8s}", file=out)
    for key in keys:
        a = np.array(agg[key], float)
        print(f"{key[0]:5s} {key[1]:8s} {key[2]:24s} {len(a):5d} {100*np.median(abs(a[:,0])):9.3f} "
              f"{100*np.median(a[:,0]):8.3f} {100*a[:,1].mean():5.0f}% {100*np.median(a[:,4]):7.3f} {np.median(a[:,2]):8.1f}", file=out)


if __name__ == "__main__":
    import pickle
    dense = "--dense" in sys.argv
    names = [a for a in sys.argv[1:] if not a.startswith("--")] or ["lab", "lock"]
    allrows = []
    for name in names:
        rows, bl, g = run(name, hop=1.0 if dense else HOP, span=(140, 185) if dense else (0, 300))
        allrows += rows
        print(f"{name}: seeds={len(bl['D_est'])} D_theory={bl['D_theory'][0]:.4g}  D_oracle median={np.median(bl['D_oracle']):.4g} "
              f"D_est median={np.median(bl['D_est']):.4g} zeta_a_est median={100*np.median(bl['zeta_a_est']):.3f}% "
              f"sd={100*np.std(bl['zeta_a_est']):.3f}%  gamma={gamma_true(g):.3g}")
        rel = bl["D_est"] / bl["D_oracle"]
        print(f"   D_est/D_oracle: median {np.median(rel):.3f}, 5-95% {np.percentile(rel,5):.3f}-{np.percentile(rel,95):.3f}")
    pickle.dump(allrows, open("rows_dense.pkl" if dense else "rows.pkl", "wb"))
    summarize(allrows)
