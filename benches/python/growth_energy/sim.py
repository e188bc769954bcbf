"""Simulate the 'onset' scenario for the lab and lock gates (vectorised over seeds).

m*ydd + c(t)*yd + c3*yd^3 + k*y = F,  c = 2*zeta(t)*m*omega, F white (held per sample).
Measured = k*y + white sensor noise (0.125 * ambient force std at zeta=+1%).
Usage: [SEED0=k] python sim.py [nseeds] [lab|lock]  -> writes sim_lab.npz, sim_lock.npz (sim_<gate>_s<k>.npz if SEED0>0)
"""
import sys
import numpy as np

WARM = 30.0
T_REC = 300.0


def zeta_of(t):
    """t = recorded time (warm-up is t<0). +2% until 120 s, ramp to -2% at 180 s."""
    return np.where(t < 120.0, 0.02, np.where(t < 180.0, 0.02 - 0.04 * (t - 120.0) / 60.0, -0.02))


def gate(name):
    if name == "lab":
        m, f, fs, sF = 19.14, 10.4, 200.0, 1.0
        w = 2 * np.pi * f
        k = 81360.0
        c3 = 4e4
    else:
        m, f, fs, sF = 2000.0, 5.0, 100.0, 100.0
        w = 2 * np.pi * f
        k = m * w * w
        c3 = None
    dt = 1.0 / fs
    # ambient force std (k*y) at zeta=+1% for white ZOH force: var = w^2 k/(m w^2) ... = k*q/(2c), q = sF^2 dt
    amb1 = np.sqrt(k * sF**2 * dt / (2 * 2 * 0.01 * m * w))
    if c3 is None:
        c = 2 * (-0.02) * m * w
        Y = 17 * amb1 / k
        c3 = -4 * c / (3 * Y**2 * w**2)
    return dict(name=name, m=m, f=f, w=w, k=k, fs=fs, dt=dt, sF=sF, c3=c3, amb1=amb1,
                noise=0.125 * amb1)


def lc_amp(g, zeta):
    """harmonic-balance limit-cycle force amplitude k*Y for zeta<0 (nan otherwise)"""
    c = 2 * zeta * g["m"] * g["w"]
    with np.errstate(invalid="ignore"):
        Y = np.sqrt(-4 * c / (3 * g["c3"] * g["w"] ** 2))
    return g["k"] * Y


def simulate(g, nseeds, seed0=0, nsub=4):
    rng = np.random.default_rng([seed0, 12345 if g["name"] == "lab" else 54321])
    dt, m, w, k, c3 = g["dt"], g["m"], g["w"], g["k"], g["c3"]
    nw = int(round(WARM / dt))
    n = int(round(T_REC / dt))
    ntot = nw + n
    F = rng.standard_normal((ntot, nseeds)) * g["sF"]
    y = np.zeros(nseeds)
    v = np.zeros(nseeds)
    h = dt / nsub
    Y = np.empty((n, nseeds))
    ts = (np.arange(ntot) - nw) * dt

    def zs(t):
        return 0.02 if t < 120.0 else (0.02 - 0.04 * (t - 120.0) / 60.0 if t < 180.0 else -0.02)

    def acc(cm, y, v, f):
        return f / m - v * (cm + c3m * v * v) - w2 * y
    c3m = c3 / m
    w2 = k / m

    for i in range(ntot):
        f = F[i]
        t = ts[i]
        if i >= nw:
            Y[i - nw] = y  # sample at start of interval
        for s in range(nsub):
            tt = t + s * h
            ca = 2 * zs(tt) * w; cb = 2 * zs(tt + 0.5 * h) * w; cc = 2 * zs(tt + h) * w
            k1y = v; k1v = acc(ca, y, v, f)
            k2y = v + 0.5 * h * k1v; k2v = acc(cb, y + 0.5 * h * k1y, k2y, f)
            k3y = v + 0.5 * h * k2v; k3v = acc(cb, y + 0.5 * h * k2y, k3y, f)
            k4y = v + h * k3v; k4v = acc(cc, y + h * k3y, k4y, f)
            y = y + h / 6 * (k1y + 2 * k2y + 2 * k3y + k4y)
            v = v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    clean = k * Y
    meas = clean + rng.standard_normal(clean.shape) * g["noise"]
    t = np.arange(n) * dt
    return t, clean.T, meas.T


if __name__ == "__main__":
    ns = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    names = sys.argv[2:] or ["lab", "lock"]
    seed0 = int(__import__("os").environ.get("SEED0", "0"))
    for name in names:
        g = gate(name)
        t, clean, meas = simulate(g, ns, seed0=seed0)
        np.savez_compressed(f"sim_{name}{'' if seed0 == 0 else '_s%d' % seed0}.npz", t=t, clean=clean.astype(np.float32),
                            meas=meas.astype(np.float32), **{k: v for k, v in g.items() if k != "name"})
        amb = clean[:, int(20 / g["dt"]):int(110 / g["dt"])].std()
        print(name, "c3=%.4g amb1(theory)=%.4g  ambient std at +2%% sim=%.4g (theory %.4g)  LC amp(-2%%)=%.4g"
              % (g["c3"], g["amb1"], amb, g["amb1"] / np.sqrt(2), lc_amp(g, -0.02)))
        end = clean[:, -int(60 / g["dt"]):]
        print("   sqrt2*rms last 60 s: median %.4g" % np.median(np.sqrt(2) * end.std(axis=1)))
