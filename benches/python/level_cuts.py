"""How often a level bound would cut a gate's ambient pool by chance, and what the recovery's
windows read, in `gatewatch bench warning --trace` outputs (stop 93, "A pool holds one level").

Two tables:

- steady gates (`stable`, `stable-low`): for each factor `k`, the share of windows one of whose
  `--back` windows before (3 by default: the lock gate's pool holds three or four readings,
  the barrier gate's two or three) has an RMS more than `k` times the window's or less than a
  `k`-th of it. That is how often the daemon's ambient pool would end at such a window by
  chance (`spectral::PoolOptions::max_level_change`). The trace's `rms` is the report's
  `signal_rms`, the very figure the pool compares; which windows a pool holds depends on its
  other bounds, so the share is of windows, not of the pool's cuts.
- recovery: the windows the bench scored as ambient in 20 s bins of sample time, with their
  median error against the true mean and their coverage: the minute after the ramp back to
  +2 % is where a pool that reaches back into the decay read low.

Usage: python level_cuts.py [--back N] [--factors 2,2.5,3,4] TRACE...

Standard library only. Used in docs/benchmarks.md ("Stop 93")."""
import argparse
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402


def cut_rates(runs, back, factors):
    rows = []
    keys = sorted({(r["scenario"], r["gate"]) for r in runs if r["scenario"] in ("stable", "stable-low")})
    for scenario, gate in keys:
        series = [
            [w["rms"] for w in r["windows"] if w["rms"]]
            for r in runs
            if (r["scenario"], r["gate"]) == (scenario, gate)
        ]
        n = sum(max(len(s) - back, 0) for s in series)
        if n == 0:
            continue
        for k in factors:
            hits = sum(
                any(not s[i] / k <= s[j] <= s[i] * k for j in range(i - back, i))
                for s in series
                for i in range(back, len(s))
            )
            rows.append(f"| {scenario} | {gate} | {k:g} | {n} | {hits / n:.2%} |")
    return rows


def recovery(runs):
    bins = {}
    for r in runs:
        if r["scenario"] != "recovery":
            continue
        for w in r["windows"]:
            if w["scored"] != "ambient" or w["zeta0"] is None:
                continue
            key = (r["gate"], int(w["t"] // 20) * 20)
            covered = w["low"] is not None and w["low"] <= w["truth"] <= w["high"]
            bins.setdefault(key, []).append((w["zeta0"] - w["truth"], covered))
    rows = []
    for (gate, t), v in sorted(bins.items()):
        err = statistics.median(e for e, _ in v)
        cov = sum(c for _, c in v) / len(v)
        rows.append(f"| {gate} | {t}-{t + 20} | {len(v)} | {err:+.2f} | {cov:.0%} |")
    return rows


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("traces", nargs="+")
    p.add_argument("--back", type=int, default=3, help="windows before each window compared")
    p.add_argument("--factors", default="2,2.5,3,4")
    args = p.parse_args()
    try:
        factors = [float(f) for f in args.factors.split(",")]
    except ValueError:
        raise SystemExit(f"--factors: not a comma-separated list of numbers: {args.factors!r}") from None
    if args.back < 1 or any(not k > 1 for k in factors):
        raise SystemExit("--back must be at least 1 and every factor above 1")
    runs = [run for path in args.traces for run in read_trace(path)]
    rows = cut_rates(runs, args.back, factors)
    if rows:
        print("| scenario | gate | factor | windows | cut by chance |")
        print("|---|---|---:|---:|---:|")
        print("\n".join(rows))
    rows = recovery(runs)
    if rows:
        print("\n| gate | sample time, s | ambient windows | median err | coverage |")
        print("|---|---|---:|---:|---:|")
        print("\n".join(rows))


if __name__ == "__main__":
    main()
