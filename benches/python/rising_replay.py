"""Replays stop 79's rising-window rule on a `gatewatch bench warning --trace` output recorded
before it (stop 78's build), where every ambient window was pooled: a window that stood at least
RATIO times above its gate's ambient level shows its own SSI-COV reading (the trace's `ssi`
triple) instead of the pool's (docs/damping.md, "A rising window stands alone").

Usage: python rising_replay.py TRACE [--ratios 1.3,1.5,2] [--trend]

Prints, per scenario, gate and scored regime, the windows, the median |zeta0 error| and the
coverage of the 95 % interval as traced and with the rule at each ratio (the `bench warning`
rows, without the bootstrap, from the trace's two decimals: 0.01 points and 1 % from the
bench's own rows at most), and how many windows stood alone. With `--trend` (needs numpy
and scipy, as trend_replay.py) it also replays `GateDampingDeclining` fed the lone readings,
and prints the runs whose first firings move: the replay that made the trend read the pool's
figure instead (docs/benchmarks.md, "Stop 79").

    gatewatch bench warning --seeds 100 --gates lock --scenarios onset --trace 2> onset.trace
    python3 benches/python/rising_replay.py onset.trace --ratios 1.3,1.5,2
"""
import argparse
import re
import statistics

from bench_trace import read_trace

num = r"(-?[\d.]+)"
# (regime, pooled windows, own SSI-COV reading, ambient ratio, ...) as the trace prints them
FACTS = re.compile(
    r"ssi common\) Some\(\((?:Some\(\w+\)|None), (?:Some\((\d+)\)|None), "
    r"(?:Some\(\(" + num + ", " + num + ", " + num + r"\)\)|None), (?:Some\(" + num + r"\)|None),"
)


def read(path):
    """The runs of the trace (`bench_trace.read_trace`), each window with what the rule needs
    read off its line as well."""
    runs = read_trace(path)
    for run in runs:
        for w in run["windows"]:
            facts = FACTS.search(w["line"])
            if not (facts and w["scored"]):
                raise SystemExit(f"{path}: the window at t = {w['t']} of {run['scenario']} "
                                 f"{run['gate']} seed {run['seed']} has no pooling facts or score")
            w.update({
                "pooled": int(facts.group(1)) if facts.group(1) else None,
                "own": tuple(float(facts.group(i)) for i in (2, 3, 4)) if facts.group(2) else None,
                "ratio": float(facts.group(5)) if facts.group(5) else None,
            })
    return runs


def alone(w, ratio):
    """The window as the rule at `ratio` shows it: its own reading where it was pooled and stood
    at least `ratio` times above the level (below the departure ratio, which the trace's pooled
    windows always are), else as traced."""
    rising = (w["source"] == "ambient" and (w["pooled"] or 0) >= 2 and w["own"] is not None
              and w["ratio"] is not None and w["ratio"] >= ratio)
    if not rising:
        return w, False
    z, low, high = w["own"]
    return dict(w, zeta0=z, low=low, high=high), True


def rows(runs, ratios):
    table = {}
    for run in runs:
        for w in run["windows"]:
            for ratio in [None] + ratios:
                v, stood = (w, False) if ratio is None else alone(w, ratio)
                if v["zeta0"] is None:
                    continue
                r = table.setdefault((run["scenario"], run["gate"], w["scored"], ratio), [[], [], 0])
                r[0].append(abs(v["zeta0"] - w["truth"]))
                if v["low"] is not None:
                    r[1].append(v["low"] <= w["truth"] <= v["high"])
                r[2] += stood
    for key in sorted({k[:3] for k in table}):
        cells = []
        for ratio in [None] + ratios:
            err, cov, stood = table[key + (ratio,)]
            c = f"{100 * sum(cov) / len(cov):.0f} %" if cov else "-"
            cells.append(f"{'traced' if ratio is None else ratio}: {statistics.median(err):.2f}, {c}"
                         + ("" if ratio is None else f" ({stood} alone)"))
        print(f"{key[0]} {key[1]} {key[2]} ({len(table[key + (None,)][0])} windows)  " + "  ".join(cells))


def trend_moves(runs, ratios):
    import trend_replay  # numpy and scipy only here
    for run in runs:
        ws = run["windows"]
        base = trend_replay.replay(ws, "base")
        for ratio in ratios:
            lone = trend_replay.replay([alone(w, ratio)[0] for w in ws], "base")
            if lone != base:
                print(f"{run['scenario']} {run['gate']} seed {run['seed']}: trend fed lone readings from "
                      f"{ratio}: {lone}, traced rule {base}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("trace", help="stderr of `gatewatch bench warning --trace` (before stop 79)")
    p.add_argument("--ratios", default="1.5", help="comma-separated ratios to the ambient level")
    p.add_argument("--trend", action="store_true", help="replay GateDampingDeclining as well")
    args = p.parse_args()
    ratios = [float(r) for r in args.ratios.split(",")]
    runs = read(args.trace)
    rows(runs, ratios)
    if args.trend:
        trend_moves(runs, ratios)


if __name__ == "__main__":
    main()
