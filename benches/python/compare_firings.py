"""Compares the alerts of two `gatewatch bench warning --trace` outputs run by run: every change
of the firing set (`firing [...]` on the window lines), with its window's end time. Prints the
runs whose transitions differ, then how many are identical. The two traces must stream the same
scenarios, gates and seeds (e.g. one bench command run with two builds).

Usage: python compare_firings.py OLD_TRACE NEW_TRACE

Standard library only. Used in docs/benchmarks.md ("Stop 74") to compare a change's benches
with the previous stop's traces."""
import re
import sys

HEADER = re.compile(r"\] (\S+) on (\S+) gate, seed (\d+)")
FIRING = re.compile(r"firing (\[[^\]]*\])")


def transitions(path):
    """{(scenario, gate, seed): [(t, firing set as printed), ...]} at each change of the set."""
    runs, key, prev = {}, None, None
    try:
        f = open(path, encoding="utf-8")
    except OSError as e:
        raise SystemExit(f"{path}: cannot read the trace: {e.strerror}") from None
    with f:
        for number, line in enumerate(f, 1):
            h = HEADER.search(line)
            if h and line.startswith("["):
                key = (h.group(1), h.group(2), int(h.group(3)))
                runs[key], prev = [], None
                continue
            if not line.startswith("t "):
                continue
            m = FIRING.search(line)
            if m is None or key is None:
                raise SystemExit(f"{path}:{number}: not a window line of `bench warning --trace`")
            t = float(line.split()[1])
            if m.group(1) != prev:
                runs[key].append((t, m.group(1)))
                prev = m.group(1)
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
