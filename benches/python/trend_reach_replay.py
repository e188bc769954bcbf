"""Replays `analysis::reach_down_to_trend` over the windows of `gatewatch bench warning --trace`
and prints, per scenario, gate and the regime the bench scored, how often the window's own 95 %
interval and the interval reached down to the trend cover the true mean (stop 94), how often a
window reached down, and the intervals' median width.

Each window is read as the daemon's trend reads it (`trend_replay.trend_reading`: a rising
window's pool, else the window's own interval, `own (...)` where the trace prints it), kept by its
window's end and fitted at its figure's instant (`lag` in the trace, since stop 91). Where the
trend after the window spans at least `--min-span` seconds and `--gate` lets it (shipped since
stop 95, `recent`: the trend declines with confidence, its slope's one-sided 95 % bound below
zero, or its fitted slope is negative and it so declined within the horizon; stop 94's
`confident`: the first alone; see `decides` for the others), the window's lower end reaches down
to the lower end of the line's two-sided 95 % band at the figure's instant:

- `forecast` (shipped): the line through the windows that ended at or before the figure's
  record began (twice its lag before the window's end);
- `fit`: the line through every window kept, this one included.

On a trace of a build from stop 94 on, the shipped reach is already in the printed interval;
replay a trace of an earlier build (or compare the `own` column). The trace prints figures to
0.01 points, so the replay's bands match the daemon's to about that.

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install numpy scipy
    gatewatch bench warning --seeds 20 --first-seed 101 --gates lab --scenarios slow-drift --trace 2> sd.trace
    /tmp/venv/bin/python benches/python/trend_reach_replay.py sd.trace --variants forecast,fit
    /tmp/venv/bin/python benches/python/trend_reach_replay.py sd.trace --variants forecast --gate confident

docs/damping.md, "A declining gate's interval reaches down to its trend (stop 94)" and "... while
the line still falls (stop 95)".
"""
import argparse
import collections
import math
import os
import re
import sys

import numpy as np
from scipy.stats import t as student

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402
from trend_replay import huber, irls, lag1, records_overlap, trend_reading  # noqa: E402

LAG = re.compile(r"  lag ([\d.]+)")


def line(x, z, low, high, lag, ar1=False):
    """`analysis::trend::fit` at x = 0 (the newest window's end): level, slope, the slope's
    variance and the effective degrees of freedom its test reads, and the band's (`b...`);
    None as in the daemon. Since stop 96 the slope's test counts the figures' shared records
    (`lag`, half of each) and the band the larger of that and the residuals' AR(1) factor;
    with `ar1` both read the AR(1) factor (the rule before)."""
    n = len(x)
    if n < 6 or x.max() <= x.min():
        return None
    fitted = irls(x, z, low, high)
    if fitted is None:
        return None
    level, slope, sd, s0, s1, s2, det = fitted
    r = (z - level - slope * x) / sd
    scale = max((huber(r) * r * r).sum() / (n - 2), 1.0)
    rho = lag1(r)
    residual = (1 + rho) / (1 - rho)
    overlap = residual if ar1 else records_overlap(x, lag, sd, huber(r) / sd**2)
    band = max(overlap, residual)
    k, kb = scale * overlap / det, scale * band / det
    return {"level": level, "slope": slope, "vs": s0 * k, "dof": max(n / overlap - 2.0, 1.0),
            "bvs": s0 * kb, "bvl": s2 * kb, "bcov": -s1 * kb, "bdof": max(n / band - 2.0, 1.0)}


def band_low(e, x):
    """Lower end of the line's two-sided 95 % band at x (seconds from its newest window)."""
    var = e["bvl"] + x * x * e["bvs"] + 2 * x * e["bcov"]
    return e["level"] + e["slope"] * x - student.ppf(0.975, e["bdof"]) * math.sqrt(max(var, 0.0))


def confident(now):
    """Whether the trend declines with confidence: its slope's one-sided 95 % bound below zero."""
    return now["slope"] + student.ppf(0.95, now["dof"]) * math.sqrt(now["vs"]) < 0


def decides(now, gate, recent, floor):
    """Whether the trend after the window (over the minimum span) lets it reach down to `floor`:
    `recent` (shipped since stop 95), a confident decline, or a fitted slope below zero with a
    confident decline within the horizon (`recent`); `confident` (stop 94), a confident decline;
    `fitted`, a fitted slope below zero; `near`, a confident decline, or a fitted slope below zero
    with the forecast's lower end below zero; `span`, any trend."""
    if gate == "confident":
        return confident(now)
    if gate == "recent":
        return confident(now) or (now["slope"] < 0 and recent)
    if gate == "fitted":
        return now["slope"] < 0
    if gate == "near":
        return confident(now) or (now["slope"] < 0 and floor < 0)
    return True


def replay(runs, variants, horizon, min_span, gate="recent", ar1=False):
    rows = collections.defaultdict(
        lambda: {"n": 0, "own": 0, "width": [], **{v: [0, 0, []] for v in variants}})
    for run in runs:
        pts = []  # (window end, figure's instant, zeta0, low, high)
        declined = None  # the newest window kept when the trend last declined with confidence
        for w in run["windows"]:
            m = LAG.search(w["line"])
            lag = float(m.group(1)) if m else 5.0
            zeta0, low, high, trusted = trend_reading(w)
            if trusted and zeta0 is not None and low is not None:
                pts.append((w["t"], w["t"] - lag, zeta0, low, high))
                while w["t"] - pts[0][0] > horizon:
                    pts.pop(0)
            a = np.array(pts) if pts else None
            now = None
            if a is not None and len(a) >= 6 and a[-1, 0] - a[0, 0] >= min_span:
                now = line(a[:, 1] - w["t"], a[:, 2], a[:, 3], a[:, 4], a[:, 0] - a[:, 1], ar1)
                if now and confident(now):
                    declined = a[-1, 0]
            recent = declined is not None and w["t"] - declined <= horizon
            own = w.get("own") or (w["low"], w["high"])
            if w["scored"] is None or w["zeta0"] is None or own[0] is None:
                continue
            lows = {v: own[0] for v in variants}
            if now:
                for v in variants:
                    b = a if v == "fit" else a[a[:, 0] <= w["t"] - 2 * lag]
                    if len(b) < 6:
                        continue
                    newest = b[-1, 0]
                    e = line(b[:, 1] - newest, b[:, 2], b[:, 3], b[:, 4], b[:, 0] - b[:, 1], ar1)
                    if e:
                        floor = band_low(e, w["t"] - lag - newest)
                        if decides(now, gate, recent, floor):
                            lows[v] = min(own[0], floor)
            r = rows[(run["scenario"], run["gate"], w["scored"])]
            truth = w["truth"]
            r["n"] += 1
            r["own"] += own[0] <= truth <= own[1]
            r["width"].append(own[1] - own[0])
            for v in variants:
                r[v][0] += lows[v] <= truth <= own[1]
                r[v][1] += lows[v] < own[0]
                r[v][2].append(own[1] - lows[v])
    return rows


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("traces", nargs="+", help="stderr of `gatewatch bench warning --trace`")
    p.add_argument("--variants", default="forecast,fit")
    p.add_argument("--horizon", type=float, default=600.0, help="trend_horizon_seconds")
    p.add_argument("--min-span", type=float, default=300.0, help="trend_min_span_seconds")
    p.add_argument("--gate", choices=["recent", "confident", "fitted", "near", "span"],
                   default="recent",
                   help="which trend lets a window reach down (`decides`; shipped: recent)")
    p.add_argument("--overlap", choices=["records", "ar1"], default="records",
                   help="the trend's overlap factor: the slope's test from the figures' "
                        "records and the band the larger of that and the residuals' AR(1) "
                        "(shipped since stop 96), or the AR(1) for both (before)")
    args = p.parse_args()
    variants = args.variants.split(",")
    unknown = set(variants) - {"forecast", "fit"}
    if unknown:
        raise SystemExit(f"unknown variant {', '.join(sorted(unknown))}")
    runs = [r for path in args.traces for r in read_trace(path)]
    rows = replay(runs, variants, args.horizon, args.min_span, args.gate, args.overlap == "ar1")
    head = " | ".join(f"{v}: covered | {v}: reached | {v}: width" for v in variants)
    print(f"| scenario | gate | regime | windows | own: covered | own: width | {head} |")
    print("|---|---|---|---:|---:|---:|" + "---:|---:|---:|" * len(variants))
    for k in sorted(rows):
        r = rows[k]
        n = r["n"]
        cells = " | ".join(f"{100 * r[v][0] / n:.0f} % | {100 * r[v][1] / n:.0f} % | "
                           f"{np.median(r[v][2]):.2f}" for v in variants)
        print(f"| {k[0]} | {k[1]} | {k[2]} | {n} | {100 * r['own'] / n:.0f} % | "
              f"{np.median(r['width']):.2f} | {cells} |")


if __name__ == "__main__":
    main()
