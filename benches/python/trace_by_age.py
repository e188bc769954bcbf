"""The error and interval coverage of `zeta0` by the age of the stream, over the windows of
`gatewatch bench warning --trace`: whether a stream's first minutes read differently from its
later ones (a cold start's bias), per scenario and gate.

Ages (s of sample time at the window's end): up to 60, 60 to 120, 120 to 240, beyond 240.
For each: the windows with an estimate, the median and mean error (estimate minus truth, in
percentage points), the share whose 95 % interval holds the truth, and the 95th percentile of
the error (the tail that a trend reads as a decline when a high run is followed by ordinary
windows).

    /tmp/venv/bin/python benches/python/trace_by_age.py cold_lab.trace cold_lock.trace

docs/benchmarks.md, "A cold start waits five minutes (stop 68)". Needs numpy and scipy (the
trace reader is `trend_replay.read_trace`; `trend_replay.py`'s docstring sets up the venv).
"""
import argparse
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402

AGES = ((0.0, 60.0), (60.0, 120.0), (120.0, 240.0), (240.0, float("inf")))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("traces", nargs="+", help="stderr of `gatewatch bench warning --trace`")
    args = p.parse_args()
    rows = {}
    for path in args.traces:
        for run in read_trace(path):
            for w in run["windows"]:
                if w["zeta0"] is None:
                    continue
                age = next(i for i, (_, b) in enumerate(AGES) if w["t"] <= b)
                key = (run["scenario"], run["gate"], age)
                covered = w["low"] <= w["true"] <= w["high"]
                rows.setdefault(key, []).append((w["zeta0"] - w["true"], covered))
    print("| scenario | gate | age (s) | windows | median err | mean err | coverage | 95th pct err |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for (scenario, gate, age), xs in sorted(rows.items()):
        err = sorted(e for e, _ in xs)
        a, b = AGES[age]
        span = f"{a:.0f}-{b:.0f}" if b < float("inf") else f"> {a:.0f}"
        print(
            f"| {scenario} | {gate} | {span} | {len(err)} | {statistics.median(err):.2f} | "
            f"{statistics.fmean(err):.2f} | {100 * sum(c for _, c in xs) / len(xs):.1f} % | "
            f"{err[int(0.95 * (len(err) - 1))]:.2f} |"
        )


if __name__ == "__main__":
    main()
