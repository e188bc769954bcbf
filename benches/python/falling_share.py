"""How many ambient windows of `gatewatch bench warning --trace` outputs fell: their envelope's
growth rate lies more than FALLING_SIGMAS (2) standard errors below zero, so the daemon reports
them alone by their own reading (`analysis::falling`, stop 88). Prints the count per gate and
scenario and in all, and the same of the limit-cycle windows read as a cycle (`envelope` or
`amplitude`), whose interval then spans the envelope's drift (`analysis::span_the_fall`, stop 89).

Usage: python falling_share.py TRACE...

Standard library only. Used in docs/benchmarks.md ("Stop 88", "Stop 89")."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402

FALLING_SIGMAS = 2.0


def main():
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    counts = {"ambient": {}, "cycle": {}}
    for path in sys.argv[1:]:
        for run in read_trace(path):
            key = (run["scenario"], run["gate"])
            for w in run["windows"]:
                g = w["growth"]
                if w["source"] == "ambient":
                    kind = "ambient"
                elif w["source"] in ("envelope", "amplitude") and w["regime"] == "LimitCycle":
                    kind = "cycle"
                else:
                    continue
                c = counts[kind].setdefault(key, [0, 0])
                if g is None:
                    continue
                c[0] += 1
                c[1] += g[0] < -FALLING_SIGMAS * g[1]
    for kind, what in (("ambient", "ambient windows"), ("cycle", "windows read as a cycle")):
        table = counts[kind]
        total = [sum(c[0] for c in table.values()), sum(c[1] for c in table.values())]
        for (scenario, gate), (n, f) in sorted(table.items()) + [(("all", ""), total)]:
            share = 100.0 * f / n if n else 0.0
            print(f"{scenario} {gate}: {n} {what}, {f} falling ({share:.1f} %)")


if __name__ == "__main__":
    main()
