"""Replay of `bench warning --trace` output: which runs would fire `GateNegativeDamping` earlier, or
newly, if a window the spectrum classified as one of REGIMES (default SelfExcited), standing at
least BAR times above the gate's ambient level, fired at once (docs/alerts.md, "A growing
oscillation far above the ambient level"; docs/benchmarks.md, "Stop 76").

    python3 benches/python/regime_at_once_replay.py [--bar 3.5] [--regimes SelfExcited,LimitCycle] TRACE...

Standard library only."""
import argparse
import re

from bench_trace import HEADER, WINDOW

# the window's regime and its ambient ratio, from the trace's tuple
REGIME_RATIO = re.compile(
    r"ssi common\) Some\(\(Some\((\w+)\), (?:None|Some\(\d+\)), (?:None|Some\(\([-\d.]+, [-\d.]+, [-\d.]+\)\)), "
    r"(?:None|Some\(([-\d.]+)\))"
)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bar", type=float, default=3.5)
    ap.add_argument("--regimes", default="SelfExcited")
    ap.add_argument("traces", nargs="+")
    a = ap.parse_args()
    regimes = set(a.regimes.split(","))
    for path in a.traces:
        runs, run = [], None
        with open(path, encoding="utf-8") as f:
            for line in f:
                h = HEADER.search(line)
                if h:
                    run = {"name": (h.group(1), h.group(2), int(h.group(3))), "first": None, "new": None}
                    runs.append(run)
                    continue
                if not line.startswith("t ") or run is None:
                    continue
                w, r = WINDOW.search(line), REGIME_RATIO.search(line)
                if not (w and r):
                    continue
                t = float(w.group(1))
                if run["first"] is None and "GateNegativeDamping" in w.group(8):
                    run["first"] = t
                if run["new"] is None and r.group(1) in regimes and r.group(2) and float(r.group(2)) >= a.bar:
                    run["new"] = t
        earlier = [(r["name"], r["first"], r["new"]) for r in runs
                   if r["new"] is not None and r["first"] is not None and r["new"] < r["first"]]
        new = [(r["name"], r["new"]) for r in runs if r["new"] is not None and r["first"] is None]
        print(f"{path}: {len(runs)} runs; earlier {len(earlier)}: {earlier}")
        print(f"  new firings {len(new)}: {new}")


if __name__ == "__main__":
    main()
