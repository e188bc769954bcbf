"""Replays `GateDampingDeclining` over the windows of `gatewatch bench warning --trace`, with the
shipped trend fit or a variant of its confident crossing, to try a rule on recorded streams
without re-streaming them.

The fit is a transcription of `analysis::trend::fit` (IRLS with Huber weights on the windows'
interval-derived sds, the scale `max(1, chi2 / (n - 2))`, the overlap factor of the figures'
shared records, Student's t on `n / overlap - 2`), the alert's readings and streaks those of
`alert::engine::trend_alert` with the defaults (horizon 600 s, minimum span 300 s, lead 600 s,
two windows to fire and to resolve; the confident crossing within the lead and the trend's
span). Each window is read as the daemon's trend reads it (`analysis::trend_reading`): a rising
window's pool where the trace prints one (`pool (...)`, since stop 79), else its own figure,
kept by its window's end and fitted at its figure's instant (`lag` in the trace, as the daemon
since stop 91; the replay fitted at the windows' ends until stop 95). The trace prints zeta0 to 0.01 points, so the replay's slope matches the traced one to about
1e-4 points a minute; `base` must reproduce the traced first firings to a window (it prints
both; on a trace recorded before stop 67, `lead` must).

Variants (`--variants`, comma-separated; each a `+`-joined set of changes to the shipped rule,
`base` for none):
- `ar1`: the slope's error inflated by the AR(1) factor of the residuals' lag-1
  autocorrelation, the rule until stop 96 (shipped since: the figures' shared records,
  `records_overlap`); replay a trace of an earlier build with `ar1` to reproduce its warnings;
- `lead`: the rule before stop 67, a confident crossing within the lead whatever the trend's
  span (shipped: within the lead and within the span, no further ahead than the trend reaches
  back; stop 66's figures are `lead` and `lead+band`);
- `band`: the confident crossing is the first time the line's one-sided 95 % upper confidence
  band (the level's error, the slope's and their covariance) falls below `fire_below`, not the
  level extrapolated at the slope's bound;
- `young`, `taper`: session 45's small-sample correction of the residuals' lag-1
  autocorrelation, `r + (1 + 7.5 r) / n`, applied while the trend spans under 0.9 of its horizon
  (`young`), or in full up to half the horizon and less and less until it is full (`taper`).
- `sF` (e.g. `s0.6`): the slope's and the level's standard errors multiplied by `F`, for a
  calibration study (stop 74: on 20 lock days at +0.5 % the standardized slope had a standard
  deviation of 0.6, not 1).
- `csdF` (e.g. `csd0.5`, stop 81; traces that print each window's RMS): a predicting window
  is vetoed when the windows' RMS did not rise with the decline as a gate under steady forcing
  would (its variance goes as `1 / zeta`): the 95 % upper bound of the rise of `ln RMS` over the
  trend's span (least squares, the same AR(1) overlap factor) below `F` times the rise the line
  implies, `0.5 ln(zeta_old / zeta_now)` (the line's ends, the newer one at least 0.05 %).
- `nwL` (e.g. `nw12`, stop 84): the overlap factor from the residuals' autocorrelations up to
  `L` lags with Bartlett's weights (Newey-West) instead of the AR(1) factor of the lag-1;
  `nwL+max`: the larger of the two.
- `floorF` (e.g. `floor1`, stop 84): the scale's floor `F` instead of the shipped one (1 since
  stop 84; 0.5 from session 20 to stop 83: replay a trace of those builds with `floor0.5` to see
  what they did, and mind that `base` now means 1).
- `medF` (e.g. `med1`, stop 95): each window's sd floored at `F` times the horizon's median sd
  instead of half of it (`med1`: no window weighs more than the median one; near zero the
  windows' intervals narrow with the damping, so they weigh most where they read high).
`--min-span` sets `trend_min_span_seconds` (300, the default since stop 68).

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install numpy scipy
    target/release/gatewatch bench warning --seeds 20 --gates lab,lock --scenarios slow-drift --trace 2> sd.trace
    /tmp/venv/bin/python benches/python/trend_replay.py sd.trace --variants base,lead,lead+band

docs/benchmarks.md, "The confident crossing from the line's band (stop 66)" and "No further
ahead than the trend reaches back (stop 67)".
"""
import argparse
import math
import os
import re
import sys

import numpy as np
from scipy.stats import t as student

Z95_TWO_SIDED = 1.959963984540054
HUBER_K = 1.345

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402

LAG = re.compile(r"  lag ([\d.]+)")

def huber(r):
    a = np.abs(r)
    return np.where(a <= HUBER_K, 1.0, HUBER_K / np.maximum(a, 1e-300))


def lag1(r):
    """The residuals' lag-1 autocorrelation as the daemon clamps it (0 to 0.9)."""
    c0, c1 = (r * r).sum(), (r[1:] * r[:-1]).sum()
    return min(max(c1 / c0, 0.0), 0.9) if c0 > 1e-6 * len(r) else 0.0


def records_overlap(x, lag, sd, w):
    """`analysis::trend::overlap_factor` (since stop 96): the weighted slope's variance with each
    pair of figures correlated by the share of record they have in common (figure i read
    `[x_i - lag_i, x_i + lag_i]`), over its variance were they independent; at least 1.
    Shared with trend_reach_replay.py."""
    lag = np.zeros(len(x)) if lag is None else np.asarray(lag, dtype=float)
    u = w * (w.sum() * x - (w * x).sum()) * sd
    lo, hi = x - lag, x + lag
    common = np.clip(np.minimum(hi[:, None], hi[None, :]) - np.maximum(lo[:, None], lo[None, :]),
                     0.0, None)
    length = np.sqrt(np.outer(2 * lag, 2 * lag))
    corr = np.divide(common, length, out=np.zeros_like(common), where=length > 0)
    np.fill_diagonal(corr, 1.0)
    independent = (u * u).sum()
    return max(float(u @ corr @ u) / independent, 1.0) if independent > 0 else 1.0


def irls(x, z, low, high, median_floor=0.5):
    """`analysis::trend::fit`'s weighted Huber line through `z` at `x` (seconds from the newest
    window): each point's sd from its interval (floored at 0.01 points and at `median_floor`
    times the median, half in the daemon), ten IRLS iterations. Returns (level, slope, sd, s0,
    s1, s2, det), None where the daemon has none. Shared with trend_reach_replay.py."""
    n = len(x)
    raw = np.maximum((high - low) / (2 * Z95_TWO_SIDED), 0.01)  # MIN_SD, 0.01 points
    sd = np.maximum(raw, median_floor * np.sort(raw)[(n - 1) // 2])
    level = slope = 0.0
    for it in range(10):
        w = (np.ones(n) if it == 0 else huber((z - level - slope * x) / sd)) / sd**2
        s0, s1, s2 = w.sum(), (w * x).sum(), (w * x * x).sum()
        sy, sxy = (w * z).sum(), (w * x * z).sum()
        det = s0 * s2 - s1 * s1
        if not det > 0:
            return None
        slope = (s0 * sxy - s1 * sy) / det
        level = (sy - s1 * slope) / s0
    return level, slope, sd, s0, s1, s2, det


def fit(t, z, low, high, flags, span_share, threshold=0.0, lag=None):
    """The trend at the newest point, in the trace's unit (percent); None as in the daemon.
    Points are kept by their windows' ends `t` and fitted at their figures' instants, `lag`
    seconds before (since stop 91; zero where the trace prints no lag)."""
    n = len(t)
    if n < 6 or t[-1] <= t[0]:
        return None
    x = t - (0.0 if lag is None else lag) - t[-1]
    median_floor = next((float(f[3:]) for f in flags if f.startswith("med")), 0.5)
    line = irls(x, z, low, high, median_floor)
    if line is None:
        return None
    level, slope, sd, s0, s1, s2, det = line
    r = (z - level - slope * x) / sd
    floor = next((float(f[5:]) for f in flags if f.startswith("floor")), 1.0)
    scale = max((huber(r) * r * r).sum() / (n - 2), floor)
    rho = lag1(r)
    overlap = (records_overlap(x, lag, sd, huber(r) / sd**2) if "ar1" not in flags
               else (1 + rho) / (1 - rho))
    if "young" in flags or "taper" in flags:
        # session 45's small-sample correction of the lag-1 estimate while the horizon fills
        # (`span_share`: the points' span over the horizon)
        if "young" in flags:
            share = 1.0 if span_share < 0.9 else 0.0
        else:
            share = min(max(2.0 * (1.0 - span_share), 0.0), 1.0)
        rho = min(rho + share * (1 + 7.5 * rho) / n, 0.9)
        overlap = (1 + rho) / (1 - rho)
    for f in flags:
        if f.startswith("nw"):
            # Bartlett (Newey-West) long-run variance over L lags instead of the AR(1) factor
            lags = int(f[2:])
            c0 = (r * r).sum()
            acc = 1.0
            for j in range(1, min(lags, n - 1) + 1):
                rj = (r[j:] * r[:-j]).sum() / c0 if c0 > 1e-6 * n else 0.0
                acc += 2.0 * (1.0 - j / (lags + 1.0)) * rj
            overlap = max(overlap, acc) if "max" in flags else max(acc, 1.0)
    k = scale * overlap / det
    for f in flags:
        if f.startswith("s"):
            k *= float(f[1:]) ** 2
    var_slope, var_level, cov = s0 * k, s2 * k, -s1 * k
    q = student.ppf(0.95, max(round(max(n / overlap - 2.0, 1.0)), 1))
    upper = slope + q * math.sqrt(var_slope)

    def crossing(s):
        if s >= 0:
            return None
        return 0.0 if level <= threshold else (level - threshold) / -s

    if upper >= 0:
        confident = None
    elif "band" in flags:
        # The band's upper edge, level + slope T + q sqrt(var_level + 2 T cov + T^2 var_slope),
        # is convex in T and falls without bound when `upper` < 0: one crossing, the larger
        # root of the squared equation.
        d = level - threshold
        if d + q * math.sqrt(var_level) <= 0:
            confident = 0.0
        else:
            a = slope * slope - q * q * var_slope
            b = slope * d - q * q * cov
            c = d * d - q * q * var_level
            confident = max((-b + math.sqrt(max(b * b - a * c, 0.0))) / a, 0.0)
    else:
        confident = crossing(upper)
    return {"span": t[-1] - t[0], "expected": crossing(slope), "confident": confident,
            "level": level, "slope": slope, "se": math.sqrt(var_slope), "q": q, "upper": upper}


def trend_reading(w):
    """What the daemon's trend reads of a window (`analysis::trend_reading`): a rising window's
    pool where the trace shows one (stop 79; its `trusted` by the ambient rows: an interval above
    zero on a window the spectrum calls growing or a limit cycle cannot tell), else the window's
    own figure and interval (`own (...)` where the report's reaches down to the trend)."""
    if w.get("pool") is not None:
        z, low, high = w["pool"]
        trusted = not (low > 0 and w.get("regime") in ("SelfExcited", "LimitCycle"))
        return z, low, high, trusted
    if w.get("own") is not None:
        # the window's own interval, where the report's reaches down to the trend (stop 94)
        return w["zeta0"], w["own"][0], w["own"][1], w["trusted"]
    return w["zeta0"], w["low"], w["high"], w["trusted"]


def rms_supports(a, e, fraction):
    """Whether the windows' RMS rose with the trend's decline (the `csdF` variant)."""
    t, lr = a[:, 0], np.log(a[:, 4])
    if not np.all(np.isfinite(lr)):
        raise SystemExit("the csd variant needs a trace that prints each window's RMS (stop 81 on)")
    x = t - t[-1]
    n = len(t)
    design = np.vstack([np.ones(n), x]).T
    coef, *_ = np.linalg.lstsq(design, lr, rcond=None)
    res = lr - design @ coef
    rho = lag1(res)
    overlap = (1 + rho) / (1 - rho)
    se = math.sqrt((res * res).sum() / (n - 2) * overlap / ((x - x.mean()) ** 2).sum())
    q = student.ppf(0.95, max(round(max(n / overlap - 2.0, 1.0)), 1))
    old = e["level"] - e["slope"] * e["span"]
    new = max(e["level"], 0.05)
    implied = 0.5 * math.log(max(old, new) / new)
    return (coef[1] + q * se) * e["span"] >= fraction * implied


def replay(windows, variant, min_span=300.0, horizon=600.0, lead=600.0, for_windows=2, resolve_windows=2):
    """The first firing times of `GateDampingDeclining` over one run's windows."""
    flags = set(variant.split("+")) - {"base"}
    unknown = {f for f in flags - {"lead", "band", "young", "taper", "max", "ar1"}
               if not re.fullmatch(r"(s|csd|nw|floor|med)\d+(\.\d+)?", f)}
    csd = next((float(f[3:]) for f in flags if f.startswith("csd")), None)
    if unknown:
        raise SystemExit(f"unknown variant {', '.join(sorted(unknown))} in {variant!r}")
    points, fired = [], []
    streak = calm = 0
    firing = False
    for w in windows:
        zeta0, low, high, trusted = trend_reading(w)
        if trusted and zeta0 is not None and low is not None:
            m = LAG.search(w["line"])
            points.append((w["t"], zeta0, low, high, w.get("rms") or math.nan,
                           float(m.group(1)) if m else 0.0))
            while w["t"] - points[0][0] > horizon:
                points.pop(0)
        reading = "unknown"
        if trusted and len(points) >= 6:
            a = np.array(points)
            e = fit(a[:, 0], a[:, 1], a[:, 2], a[:, 3], flags, (a[-1, 0] - a[0, 0]) / horizon,
                    lag=a[:, 5])
            if e is not None and e["span"] >= min_span:
                reach = lead if "lead" in flags else min(lead, e["span"])
                if e["confident"] is not None and e["confident"] <= reach:
                    reading = "predicts"
                    if csd is not None and not rms_supports(a, e, csd):
                        reading = "vetoed"
                elif e["expected"] is not None and e["expected"] <= lead:
                    reading = "holds"
                else:
                    reading = "calm"
        if firing:
            calm = calm + 1 if reading == "calm" else 0
            if calm >= resolve_windows:
                firing = False
        elif reading == "predicts":
            streak += 1
            if streak >= for_windows:
                firing, calm, streak = True, 0, 0
                fired.append(w["t"])
        else:
            streak = 0
    return fired


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("trace", help="stderr of `gatewatch bench warning --trace`")
    p.add_argument("--variants", default="base,lead")
    p.add_argument("--min-span", type=float, default=300.0, help="trend_min_span_seconds")
    args = p.parse_args()
    for run in read_trace(args.trace):
        ws = run["windows"]
        traced = [w["t"] for i, w in enumerate(ws)
                  if "GateDampingDeclining" in w["firing"]
                  and (i == 0 or "GateDampingDeclining" not in ws[i - 1]["firing"])]
        zero = next((w["t"] for w in ws if w["true"] <= 0), None)
        cols = "  ".join(f"{v} {replay(ws, v, args.min_span)}" for v in args.variants.split(","))
        print(f"{run['scenario']} {run['gate']} seed {run['seed']}: true zero at {zero}, traced {traced}  {cols}")


if __name__ == "__main__":
    main()
