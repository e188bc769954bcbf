"""Three readings of `gatewatch bench warning --trace` output that stop 97 used to test two leads
and to split the slow drift's shallow slope (docs/benchmarks.md, "Stop 97: two leads measured
and dropped"):

- `acf TRACE...`: the autocorrelation of each run's trusted figures at lags of 1 to 40 windows
  (5 s each), averaged over the runs of each gate, beside the median `lag` (half the record the
  figures read). On steady days: does the correlation reach past the records?
- `early TRACE`: per gate, scenario and window time (10 s to 360 s), the trusted windows'
  median and mean error against the truth, their claimed sd (half the 95 % interval over 1.96),
  the error's sd in claimed sds, and the coverage. On cold starts: do the first windows read high?
- `slopes TRACE...`: the trend's median slope over the seeds at 600 s and 700 s of a slow drift
  (points a minute), fitted as the daemon does (`trend_replay.irls` on `trend_replay.trend_reading`,
  each figure at its instant), with equal weights (Huber kept), by ordinary least squares, and
  the shipped fit through the true window means.

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install numpy scipy
    /tmp/venv/bin/python benches/python/trend_sources.py acf days.trace
    /tmp/venv/bin/python benches/python/trend_sources.py early cold.trace
    /tmp/venv/bin/python benches/python/trend_sources.py slopes sd_lock.trace sd_lab.trace
"""
import os
import re
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402
from trend_replay import irls, trend_reading  # noqa: E402

LAG = re.compile(r"  lag ([\d.]+)")
ACF_LAGS = [1, 2, 4, 6, 8, 10, 12, 14, 16, 20, 24, 30, 40]
EARLY_TIMES = [10, 15, 20, 25, 30, 35, 40, 50, 60, 80, 100, 150, 200, 300, 360]


def lag_of(w):
    m = LAG.search(w["line"])
    return float(m.group(1)) if m else None


def acf(paths):
    for path in paths:
        by_gate = {}
        for r in read_trace(path):
            ws = [w for w in r["windows"] if w["trusted"] and w["zeta0"] is not None and w["low"] is not None]
            if len(ws) < 2 * max(ACF_LAGS):
                continue
            z = np.array([w["zeta0"] for w in ws])
            zs = (z - z.mean()) / z.std()
            ac = [float(np.mean(zs[:-k] * zs[k:])) for k in ACF_LAGS]
            lags = [l for l in map(lag_of, ws) if l is not None]
            share = len(ws) / len(r["windows"])
            by_gate.setdefault(r["gate"], []).append((ac, np.median(lags) if lags else float("nan"), share))
        for gate, runs in by_gate.items():
            mean = np.mean([a for a, _, _ in runs], axis=0)
            print(f"{path} {gate}: {len(runs)} runs, median lag {np.median([l for _, l, _ in runs]):.1f} s, "
                  f"trusted share {np.mean([s for _, _, s in runs]):.3f}")
            print("  lag (windows): " + "  ".join(f"{k}:{a:+.2f}" for k, a in zip(ACF_LAGS, mean)))


def early(path):
    by = {}
    for r in read_trace(path):
        for w in r["windows"]:
            if w["zeta0"] is None or w["truth"] is None or not w["trusted"] or w["low"] is None:
                continue
            by.setdefault((r["gate"], r["scenario"], w["t"]), []).append(
                (w["zeta0"] - w["truth"], (w["high"] - w["low"]) / 3.92, w["low"] <= w["truth"] <= w["high"]))
    for gate, scenario in sorted({(g, s) for g, s, _ in by}):
        print(f"{gate} {scenario}")
        for t in EARLY_TIMES:
            v = by.get((gate, scenario, float(t)))
            if not v:
                continue
            e = np.array([x[0] for x in v])
            sd = np.array([x[1] for x in v])
            print(f"  t {t:4d} n {len(v):3d}  median error {np.median(e):+.2f}  mean {e.mean():+.2f}  "
                  f"claimed sd {np.median(sd):.2f}  error/sd sd {np.std(e / sd):.2f}  "
                  f"coverage {np.mean([x[2] for x in v]):.2f}")


def slopes(paths):
    for path in paths:
        runs = read_trace(path)
        for end in (600.0, 700.0):
            rows = []
            for r in runs:
                pts = []
                for w in r["windows"]:
                    if not end - 600.0 < w["t"] <= end:
                        continue
                    z, low, high, trusted = trend_reading(w)
                    if not trusted or z is None or low is None:
                        continue
                    truth = w["truth"] if w["truth"] is not None else w["true"]
                    pts.append((w["t"], lag_of(w) or 0.0, z, low, high, truth))
                if len(pts) < 6:
                    continue
                t, lag, z, low, high, truth = np.array(pts).T
                x = t - lag - t[-1]
                ones = np.ones_like(z)
                rows.append((
                    irls(x, z, low, high)[1],
                    irls(x, z, -ones, ones)[1],
                    np.polyfit(x, z, 1)[0],
                    irls(x, truth, low - z + truth, high - z + truth)[1],
                ))
            med = np.median(np.array(rows) * 60.0, axis=0)
            print(f"{path} {runs[0]['gate']} at {end:.0f} s ({len(rows)} runs), median slope in points a minute: "
                  f"shipped {med[0]:.3f}, equal weights {med[1]:.3f}, least squares {med[2]:.3f}, "
                  f"shipped through the truth {med[3]:.3f}")


def main():
    if len(sys.argv) < 3 or sys.argv[1] not in ("acf", "early", "slopes"):
        raise SystemExit(__doc__)
    what, paths = sys.argv[1], sys.argv[2:]
    if what == "acf":
        acf(paths)
    elif what == "early":
        for p in paths:
            early(p)
    else:
        slopes(paths)


if __name__ == "__main__":
    main()
