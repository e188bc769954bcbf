"""How many ambient windows of `gatewatch bench warning --trace` outputs fell: their envelope's
growth rate lies more than FALLING_SIGMAS (2) standard errors below zero, so the daemon reports
them alone by their own reading (`analysis::falling`, stop 88). Prints the count per gate and
scenario and in all.

Usage: python falling_share.py TRACE...

Standard library only. Used in docs/benchmarks.md ("Stop 88")."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402

FALLING_SIGMAS = 2.0


def main():
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    counts = {}
    for path in sys.argv[1:]:
        for run in read_trace(path):
            key = (run["scenario"], run["gate"])
            c = counts.setdefault(key, [0, 0])
            for w in run["windows"]:
                g = w["growth"]
                if w["source"] != "ambient" or g is None:
                    continue
                c[0] += 1
                c[1] += g[0] < -FALLING_SIGMAS * g[1]
    total = [sum(c[0] for c in counts.values()), sum(c[1] for c in counts.values())]
    for (scenario, gate), (n, f) in sorted(counts.items()) + [(("all", ""), total)]:
        share = 100.0 * f / n if n else 0.0
        print(f"{scenario} {gate}: {n} ambient windows, {f} falling ({share:.1f} %)")


if __name__ == "__main__":
    main()
