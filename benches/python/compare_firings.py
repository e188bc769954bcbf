"""Compares the alerts of two `gatewatch bench warning --trace` outputs run by run: every change
of the firing set (`firing [...]` on the window lines), with its window's end time. Prints the
runs whose transitions differ, then how many are identical. The two traces must stream the same
scenarios, gates and seeds (e.g. one bench command run with two builds).

Usage: python compare_firings.py OLD_TRACE NEW_TRACE

Standard library only. Used in docs/benchmarks.md ("Stop 74") to compare a change's benches
with the previous stop's traces."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402


def transitions(path):
    """{(scenario, gate, seed): [(t, firing set as printed), ...]} at each change of the set."""
    runs = {}
    for run in read_trace(path):
        changes, prev = [], None
        for w in run["windows"]:
            if w["firing"] != prev:
                changes.append((w["t"], f"[{w['firing']}]"))
                prev = w["firing"]
        runs[(run["scenario"], run["gate"], run["seed"])] = changes
    return runs


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__.split("\n\n")[1])
    old, new = transitions(sys.argv[1]), transitions(sys.argv[2])
    same = 0
    for k in sorted(set(old) | set(new)):
        if old.get(k) == new.get(k):
            same += 1
            continue
        print(f"{k[0]} {k[1]} seed {k[2]}\n  old {old.get(k)}\n  new {new.get(k)}")
    print(f"identical runs: {same} of {len(set(old) | set(new))}")


if __name__ == "__main__":
    main()
