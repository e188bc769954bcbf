"""How well the trend's slope interval is calibrated on `gatewatch bench warning --trace` output:
every window's traced slope and its one-sided 95 % upper bound give a standard error
`(upper - slope) / 1.66` (the Student quantile at the trend's usual degrees of freedom), and
`(slope - TRUE_SLOPE) / se` should then scatter with a standard deviation of about 1. Prints per
gate the windows, the median and the standard deviation of that ratio (also from its
interquartile range), and the fraction of windows whose upper bound lies below the true slope
(5 % if calibrated).

Usage: python slope_calibration.py TRUE_SLOPE T_MIN T_MAX TRACE...
  TRUE_SLOPE in percentage points a minute (0 on a stable stream, -0.2 on the slow drift);
  only windows ending in [T_MIN, T_MAX] s of sample time count.

Standard library only. docs/benchmarks.md, "Stop 74"."""
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import read_trace  # noqa: E402


def main():
    if len(sys.argv) < 5:
        raise SystemExit(__doc__.split("\n\n")[1])
    try:
        true_slope, t_min, t_max = (float(a) for a in sys.argv[1:4])
    except ValueError:
        raise SystemExit("TRUE_SLOPE, T_MIN and T_MAX must be numbers") from None
    ratios = {}
    for path in sys.argv[4:]:
        for run in read_trace(path):
            for w in run["windows"]:
                if w["trend"] is None or not t_min <= w["t"] <= t_max:
                    continue
                slope, upper = w["trend"]
                se = (upper - slope) / 1.66
                if se > 0:
                    ratios.setdefault(run["gate"], []).append((slope - true_slope) / se)
    for gate, z in sorted(ratios.items()):
        z.sort()
        q = lambda p: z[int(p * (len(z) - 1))]
        below = sum(v < -1.66 for v in z) / len(z)
        print(f"{gate}: {len(z)} windows, median {q(0.5):+.2f}, sd {statistics.pstdev(z):.2f} "
              f"(from the IQR {(q(0.75) - q(0.25)) / 1.349:.2f}), upper bound below the truth on {below:.1%}")


if __name__ == "__main__":
    main()
