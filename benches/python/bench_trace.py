"""The windows of `gatewatch bench warning --trace` output, parsed once for the trace scripts
(trend_replay.py, trace_by_age.py, compare_firings.py, slope_calibration.py,
rising_replay.py, falling_share.py). Standard library only."""
import re

HEADER = re.compile(r"\[\d+/\d+\] (\S+) on (\w+) gate, seed (\d+)")
# zeta0, its interval and its source each print as `Some(..)` or `None`: an untrusted model
# window has a zeta0 without an interval (`Some(1.93) None Some("model")`), which the pattern
# refused until stop 75.
WINDOW = re.compile(
    r"^t\s+([\d.]+)\s+true ([+-][\d.]+) %\s+zeta0 "
    r"(?:Some\(([-\d.]+)\)|None) (?:Some\(\(([-\d.]+), ([-\d.]+)\)\)|None) (?:Some\(\"(\w+)\"\)|None) "
    r"trusted (\w+).*?firing \[([^\]]*)\]"
)
# a rising window's pool (`pooled_zeta`), which the daemon's trend reads instead of the window's
# own figure (stop 79, `analysis::trend_reading`)
POOL = re.compile(r"  pool \(([-\d.]+), ([-\d.]+), ([-\d.]+)\)")
# the spectrum's regime of the window (the first field of the facts' tuple)
REGIME = re.compile(r"ssi common\) Some\(\(Some\((\w+)\)")
# the window's own 95 % interval where the report's reaches down to the gate's declining trend
# (stop 94, `analysis::reach_down_to_trend`): what the trend and the alert read
OWN = re.compile(r"  own \(([-\d.]+), ([-\d.]+)\)")
# the window's RMS in the signal's unit, where the trace has it (since stop 81)
RMS = re.compile(r"  rms ([\d.]+e[+-]?\d+)")
# the trend's slope and its one-sided upper bound, %/min, where the window has a trend
TREND = re.compile(r"trend \(%/min, upper %/min, confident crossing s\) Some\(\((-?[\d.e+-]+), (-?[\d.e+-]+), ")
# the regime the bench scored the window in and the true mean over it, %, where it was scored
SCORED = re.compile(r"scored ([\w-]+) \(true mean ([+-]?[\d.]+) %\)")
# the window's envelope growth rate and its standard error, 1/s
GROWTH = re.compile(r"growth \(1/s, se\) Some\(\(Some\(([-\d.e+]+)\), Some\(([-\d.e+]+)\)\)\)")


def trend(line):
    """(slope, upper bound) of the window's trend in %/min, None where it has none."""
    m = TREND.search(line)
    return (float(m.group(1)), float(m.group(2))) if m else None


def pool(line):
    """(zeta0, low, high) of a rising window's pool, None where the trace shows none."""
    m = POOL.search(line)
    return tuple(float(g) for g in m.groups()) if m else None


def growth(line):
    """(growth rate, standard error) of the window's envelope in 1/s, None where it has none."""
    m = GROWTH.search(line)
    return (float(m.group(1)), float(m.group(2))) if m else None


def own(line):
    """(low, high) of the window's own interval where the report's was widened to the trend."""
    m = OWN.search(line)
    return (float(m.group(1)), float(m.group(2))) if m else None


def rms(line):
    """The window's RMS (signal units), None where the trace does not print it."""
    m = RMS.search(line)
    return float(m.group(1)) if m else None


def read_trace(path):
    """The runs of a `--trace` output: scenario, gate, seed and their windows."""
    runs, run = [], None
    try:
        f = open(path, encoding="utf-8")
    except OSError as e:
        raise SystemExit(f"{path}: cannot read the trace: {e.strerror}") from None
    with f:
        for number, line in enumerate(f, 1):
            h = HEADER.search(line)
            if h:
                run = {"scenario": h.group(1), "gate": h.group(2), "seed": int(h.group(3)), "windows": []}
                runs.append(run)
                continue
            if not line.startswith("t "):
                continue
            m = WINDOW.search(line)
            if m is None or run is None:
                raise SystemExit(f"{path}:{number}: not a window line of `bench warning --trace`")
            num = lambda g: float(m.group(g)) if m.group(g) is not None else None
            scored = SCORED.search(line)
            run["windows"].append({
                "t": num(1), "true": num(2), "zeta0": num(3), "low": num(4), "high": num(5),
                "source": m.group(6), "trusted": m.group(7) == "true", "firing": m.group(8),
                "trend": trend(line), "rms": rms(line), "growth": growth(line), "pool": pool(line),
                "own": own(line),
                "regime": (lambda r: r.group(1) if r else None)(REGIME.search(line)), "line": line,
                "scored": scored.group(1) if scored else None,
                "truth": float(scored.group(2)) if scored else None,
            })
    return runs
