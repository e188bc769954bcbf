"""How a window's own amplitude goes with its ambient reading's error, in `gatewatch bench
warning --trace` outputs (stop 92).

Two tables:

- steady gates (`stable`, `stable-low`): the ambient windows after the first minute, ranked by
  their RMS, in four bands (the lowest 2 %, 2-10 %, 10-90 %, the top 10 %): median error against
  the truth and the interval's coverage. A noise-driven response's amplitude wanders, and a
  window at the bottom of a wander follows a fall of its envelope.
- steady gates again, by the window's `ambient_ratio` (its RMS over the gate's ambient level,
  the median of its last two minutes of noise-driven windows, as the daemon reports it): median
  error, median error in units of the interval's standard error (half width / 1.96), coverage,
  and the least-squares slope of that standardised error against `ln ambient_ratio` with its
  correlation (stop 93: a window's reading and its own RMS come from the same record, so a
  window low in its wander reads high whatever the sensor noise).
- near zero (every scenario): the windows the bench scored with a true mean in [-0.35, 0) %,
  by the regime the bench gave them (`score::Regime::classify`: growth below half the cycle's
  amplitude at that zeta0, limit cycle above) and by `zeta0_source`: count, median RMS, median
  `ambient_ratio` (since stop 93), median error, coverage.

Usage: python by_amplitude.py TRACE...

Standard library only. Used in docs/benchmarks.md ("Stop 92")."""
import math
import os
import re
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402

BANDS = [(0.0, 0.02, "lowest 2 %"), (0.02, 0.10, "2-10 %"), (0.10, 0.90, "10-90 %"), (0.90, 1.0, "top 10 %")]
NEAR_ZERO = (-0.35, 0.0)


def covered(w, truth):
    return w["low"] is not None and w["low"] <= truth <= w["high"]


def steady(runs):
    rows = []
    keys = sorted({(r["scenario"], r["gate"]) for r in runs if r["scenario"] in ("stable", "stable-low")})
    for scenario, gate in keys:
        ws = [
            w
            for r in runs
            if (r["scenario"], r["gate"]) == (scenario, gate)
            for w in r["windows"]
            if w["source"] == "ambient" and w["zeta0"] is not None and w["rms"] and w["t"] > 60.0
        ]
        ws.sort(key=lambda w: w["rms"])
        for lo, hi, name in BANDS:
            band = ws[int(lo * len(ws)) : int(hi * len(ws))]
            if not band:
                continue
            err = statistics.median(w["zeta0"] - w["true"] for w in band)
            cov = sum(covered(w, w["true"]) for w in band) / len(band)
            rows.append(f"| {scenario} | {gate} | {name} | {len(band)} | {err:+.2f} | {cov:.0%} |")
    return rows


# the `ambient ratio` of a window line's tuple (regime, pooled, ssi, ambient ratio, ...)
RATIO = re.compile(
    r"ssi common\) Some\(\(Some\(\w+\), (?:Some\(\d+\)|None), (?:Some\(\([^)]*\)\)|None), Some\(([-\d.e+]+)\)"
)
RATIO_BANDS = [0.0, 0.6, 0.75, 0.9, 1.1, 1.3, 1.6, 2.0, float("inf")]


def by_ratio(runs):
    rows = []
    keys = sorted({(r["scenario"], r["gate"]) for r in runs if r["scenario"] in ("stable", "stable-low")})
    for scenario, gate in keys:
        ws = []
        for r in runs:
            if (r["scenario"], r["gate"]) != (scenario, gate):
                continue
            for w in r["windows"]:
                m = RATIO.search(w["line"])
                ok = w["source"] == "ambient" and w["zeta0"] is not None and w["low"] is not None
                if m is None or not ok or w["t"] <= 60.0 or w["high"] <= w["low"]:
                    continue
                sd = (w["high"] - w["low"]) / (2 * 1.959964)
                ws.append((float(m.group(1)), w["zeta0"] - w["true"], sd, covered(w, w["true"])))
        for lo, hi in zip(RATIO_BANDS, RATIO_BANDS[1:]):
            band = [x for x in ws if lo <= x[0] < hi]
            if len(band) < 5:
                continue
            err = statistics.median(x[1] for x in band)
            z = statistics.median(x[1] / x[2] for x in band)
            cov = sum(x[3] for x in band) / len(band)
            rows.append(f"| {scenario} | {gate} | {lo:g} to {hi:g} | {len(band)} | {err:+.2f} | {z:+.2f} | {cov:.0%} |")
        xs = [math.log(x[0]) for x in ws if x[0] > 0]
        zs = [x[1] / x[2] for x in ws if x[0] > 0]
        if len(xs) > 20:
            mx, mz = statistics.fmean(xs), statistics.fmean(zs)
            slope = sum((a - mx) * (b - mz) for a, b in zip(xs, zs)) / sum((a - mx) ** 2 for a in xs)
            rows.append(f"| {scenario} | {gate} | all: slope {slope:+.2f}, correlation {statistics.correlation(xs, zs):+.2f} | {len(xs)} | | | |")
    return rows


def near_zero(runs):
    table = {}
    for r in runs:
        for w in r["windows"]:
            truth = w["truth"]
            if w["scored"] is None or w["zeta0"] is None:
                continue
            if not NEAR_ZERO[0] <= truth < NEAR_ZERO[1]:
                continue
            key = (r["scenario"], r["gate"], w["scored"], w["source"])
            table.setdefault(key, []).append((w, truth))
    rows = []
    for (scenario, gate, regime, source), ws in sorted(table.items()):
        rms = statistics.median(w["rms"] or 0.0 for w, _ in ws)
        err = statistics.median(w["zeta0"] - t for w, t in ws)
        cov = sum(covered(w, t) for w, t in ws) / len(ws)
        ratios = [float(m.group(1)) for m in (RATIO.search(w["line"]) for w, _ in ws) if m]
        ratio = f"{statistics.median(ratios):.2f}" if ratios else "-"
        rows.append(
            f"| {scenario} | {gate} | {regime} | {source} | {len(ws)} | {rms:.3g} | {ratio} | {err:+.2f} | {cov:.0%} |"
        )
    return rows


def table(header, rows):
    """A markdown table: `header` the column names (a leading ">" right-aligns a column)."""
    names = [h.lstrip(">") for h in header]
    rule = ["---:" if h.startswith(">") else "---" for h in header]
    return "\n".join(["| " + " | ".join(names) + " |", "|" + "|".join(rule) + "|", *rows])


def main():
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    runs = [run for path in sys.argv[1:] for run in read_trace(path)]
    out = []
    rows = steady(runs)
    if rows:
        out.append(table(["scenario", "gate", "windows by RMS", ">windows", ">median error", ">coverage"], rows))
    rows = by_ratio(runs)
    if rows:
        out.append(table(["scenario", "gate", "ambient_ratio", ">windows", ">median error", ">in sds", ">coverage"], rows))
    rows = near_zero(runs)
    if rows:
        header = ["scenario", "gate", "scored", "zeta0_source", ">windows", ">median RMS", ">median ambient_ratio",
                  ">median error", ">coverage"]
        out.append(f"true mean in [{NEAR_ZERO[0]}, {NEAR_ZERO[1]}) %:\n\n" + table(header, rows))
    print("\n\n".join(out))


if __name__ == "__main__":
    main()
