"""What one 10 s window of the onset holds about zeta0 (stop 73; docs/damping.md, "What the window
that ends at -1 % holds"): the exact likelihood of the window (an extended Kalman filter of the
simulator's own model, the force held per sample as process noise, the sensor's white noise),
zeta0 constant in the window, its 95 % interval by the likelihood ratio (3.84). The cubic
damping coefficient and the forcing's intensity are profiled over grids (0 to 10 times and 0.4
to 2.5 times the truth) or held at the truth ("known"); the frequency and the noise level are
the simulator's. An oracle: no estimator of the window that knows less reads it better.

Usage (after sim.py): python profile_oracle.py GATE END[,END...] [--c3 known|grid] [--q known|grid] [--zstep Z]
Prints per window: the true mean, the median estimate, the median half width, coverage, and how
many of the seeds' intervals lie below zero. Writes o3_GATE_TAG_END.npy (estimate, low, high).
Both grids: ~7 min per gate for two windows on the lock gate (100 seeds), twice that on the lab gate."""
import sys
import numpy as np
from scipy.linalg import expm

gate = sys.argv[1]
ends = [float(x) for x in sys.argv[2].split(",")]
arg = lambda name, dflt: sys.argv[sys.argv.index(name) + 1] if name in sys.argv else dflt
d = np.load(f"sim_{gate}.npz")
m, w, k, dt, sF, noise, c3 = (float(d[x]) for x in ("m", "w", "k", "dt", "sF", "noise", "c3"))
meas = d["meas"].astype(np.float64)
t = d["t"]
zstep = float(arg("--zstep", "0.001"))
zg = np.arange(-0.04, 0.04 + 1e-12, zstep)
cg = np.array([1.0]) if arg("--c3", "grid") == "known" else np.array([0, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 3.0, 5.0, 10.0])
qg = np.array([1.0]) if arg("--q", "grid") == "known" else np.exp(np.linspace(np.log(0.4), np.log(2.5), 7))
ZZ, CC, QQ = np.meshgrid(zg, cg, qg, indexing="ij")
zl, cl, ql = ZZ.ravel(), CC.ravel(), QQ.ravel()
L = len(zl)
M = np.zeros((3, 3)); M[:2, :2] = [[0, 1], [-w * w, 0]]; M[:2, 2] = [0, 1 / m]
E_ = expm(M * dt); Ga = E_[:2, 2]
Q0 = sF**2 * np.outer(Ga, Ga)
R = noise**2
c2 = 2 * 0.02 * m * w
vy = sF**2 * dt / (2 * c2 * k)
P0 = np.diag([100 * vy, 100 * vy * w * w])


def loglik(seg):
    S_ = seg.shape[0]
    zc = (2 * zl * w)[:, None]
    c3m = (cl * c3 / m)[:, None]
    q00, q01, q11 = (ql * Q0[0, 0])[:, None], (ql * Q0[0, 1])[:, None], (ql * Q0[1, 1])[:, None]
    x0 = np.zeros((L, S_)); x1 = np.zeros((L, S_))
    p00 = np.full((L, S_), P0[0, 0]); p01 = np.zeros((L, S_)); p11 = np.full((L, S_), P0[1, 1])
    ll = np.zeros((L, S_))
    h = dt / 4
    rhs = lambda y, v: (v, -w * w * y - zc * v - c3m * v * v * v)
    for i in range(seg.shape[1]):
        e = seg[:, i][None, :] - k * x0
        S = k * k * p00 + R
        K0 = k * p00 / S; K1 = k * p01 / S
        if i > 10:
            ll -= 0.5 * (np.log(S) + e * e / S)
        x0 = x0 + K0 * e; x1 = x1 + K1 * e
        p00, p01, p11 = p00 - K0 * K0 * S, p01 - K0 * K1 * S, p11 - K1 * K1 * S
        a21 = -w * w * dt
        a22 = (-zc - 3 * c3m * x1 * x1) * dt
        f00, f01, f10, f11 = 1.0, dt, a21, 1.0 + a22
        t00, t01, t10, t11 = 0.0, dt, a21, a22
        for n in range(2, 9):
            t00, t01, t10, t11 = (t01 * a21 / n, (t00 * dt + t01 * a22) / n, t11 * a21 / n, (t10 * dt + t11 * a22) / n)
            f00 = f00 + t00; f01 = f01 + t01; f10 = f10 + t10; f11 = f11 + t11
        y, v = x0, x1
        for _ in range(4):
            k1y, k1v = rhs(y, v)
            k2y, k2v = rhs(y + 0.5 * h * k1y, v + 0.5 * h * k1v)
            k3y, k3v = rhs(y + 0.5 * h * k2y, v + 0.5 * h * k2v)
            k4y, k4v = rhs(y + h * k3y, v + h * k3v)
            y = y + h / 6 * (k1y + 2 * k2y + 2 * k3y + k4y)
            v = v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        x0, x1 = y, v
        n00 = f00 * f00 * p00 + 2 * f00 * f01 * p01 + f01 * f01 * p11 + q00
        n01 = f00 * f10 * p00 + (f00 * f11 + f01 * f10) * p01 + f01 * f11 * p11 + q01
        n11 = f10 * f10 * p00 + 2 * f10 * f11 * p01 + f11 * f11 * p11 + q11
        p00, p01, p11 = n00, n01, n11
    return ll


def zeta_true(tt):
    return np.where(tt < 120, 0.02, np.where(tt < 180, 0.02 - 0.04 * (tt - 120) / 60, -0.02))


tag = f"c3{arg('--c3','grid')}_q{arg('--q','grid')}"
for end in ends:
    sel = (t >= end - 10.0) & (t < end)
    seg = meas[:, sel]
    ll = loglik(seg).reshape(len(zg), len(cg), len(qg), -1)
    prof = ll.max(axis=(1, 2))  # (zg, seeds)
    inside = 2 * (prof.max(0)[None, :] - prof) < 3.841
    zhat = zg[prof.argmax(0)]
    lo = np.array([zg[inside[:, s]].min() for s in range(seg.shape[0])])
    hi = np.array([zg[inside[:, s]].max() for s in range(seg.shape[0])])
    tm = zeta_true(t[sel]).mean()
    cov = np.mean((lo <= tm) & (tm <= hi))
    print(f"[{tag}] window ending {end:.0f} s: true mean {100*tm:+.2f} %  median est {100*np.median(zhat):+.2f}  "
          f"median half-width {50*np.median(hi-lo):.2f} pts  median |error| {100*np.median(abs(zhat-tm)):.2f} pts  "
          f"coverage {100*cov:.0f} %  below zero {(hi<0).sum()} of {len(hi)}  "
          f"at grid edge {((lo<=zg[0])|(hi>=zg[-1])).sum()}", flush=True)
    np.save(f"o3_{gate}_{tag}_{end:.0f}.npy", np.stack([zhat, lo, hi]))
