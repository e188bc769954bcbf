"""Replays GateNegativeDamping on `gatewatch bench warning --trace` output with and without the
growth reading (`fire_on_growth`, stop 73; docs/alerts.md, "A growing oscillation far above the
ambient level"): a window the spectrum classified self-excited (`regime = SelfExcited`)
standing at least RATIO times above the gate's ambient level reads negative whatever its
interval, like a limit-cycle window there (`fire_on_limit_cycle`, which both sides keep).

Usage: python growth_replay.py RATIO [--at-once] TRACE...   (RATIO: the at-once bar, 3.5 on the
bench's lab and lock gates; --at-once: such a window fires alone, the variant not shipped)

Re-derives every window's reading from its trace line with negative_replay.py's parser, checks
that the rule without growth reproduces the traced firings ("base mismatches": the known
limits of a replay from printed figures, docs/benchmarks.md "Stop 71"), and prints the runs
whose first four events change."""
import collections
import sys

import negative_replay as nr


def reading(r, growth, ratio, at_once):
    far = (r.get('ratio') or 0) >= ratio
    cycle = r.get('regime') == 'Some(LimitCycle)' and far
    grows = growth and r.get('regime') == 'Some(SelfExcited)' and far
    rd = nr.base_reading(r)
    if grows and at_once:
        return ('neg', True)
    if (cycle or grows) and rd[0] != 'neg':
        return ('neg', False)
    return rd


def run(ws, growth, ratio, at_once):
    neg = good = 0
    firing = False
    events = []
    for r in ws:
        rd = reading(r, growth, ratio, at_once)
        if not firing:
            if rd[0] == 'neg':
                neg += 1
                if rd[1] or neg >= 2:
                    firing = True
                    good = 0
                    events.append(('fire', r['t'], r['truth']))
            else:
                neg = 0
        else:
            if rd[0] == 'good':
                good += 1
                if good >= 2:
                    firing = False
                    neg = 0
                    events.append(('resolve', r['t'], r['truth']))
            else:
                good = 0
    return events


if __name__ == '__main__':
    ratio = float(sys.argv[1])
    at_once = '--at-once' in sys.argv
    files = [f for f in sys.argv[2:] if f != '--at-once']
    runs = collections.defaultdict(list)
    for f in files:
        for r in nr.parse(f):
            runs[(r['scen'], r['gate'], r['seed'])].append(r)
    mism = 0
    diffs = []
    for k, ws in sorted(runs.items()):
        ws.sort(key=lambda r: r['t'])
        tr = nr.traced(ws)
        b = run(ws, False, ratio, False)
        n = run(ws, True, ratio, at_once)
        if [e[:2] for e in tr] != [e[:2] for e in b]:
            mism += 1
            print('MISMATCH', k, tr[:4], b[:4])
        if [e[:2] for e in b] != [e[:2] for e in n]:
            diffs.append((k, b[:4], n[:4]))
    print('runs', len(runs), 'base mismatches', mism, 'changed', len(diffs))
    for d in diffs:
        print(d)
