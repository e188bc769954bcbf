//! How many samples a gate's identification reads: at least its `window_seconds`, and once its
//! frequency is known, enough to hold `window_cycles` cycles of it, up to the history the gate
//! keeps (docs/operations.md, "A slow gate"; docs/damping.md, "A window of too few cycles").
//!
//! # Why in cycles
//! What limits a damping estimate is the number of cycles it reads, not seconds (Au's law,
//! `sd ~ zeta^(1/2) (2 pi N_c)^(-1/2)`). A 10 s window holds 104 cycles of the 10.4 Hz lab gate,
//! 50 of a 5 Hz lock gate, 20 of a 2 Hz barrier gate and 10 of a 1 Hz surge-barrier leaf. Below
//! 16 the ambient estimator reads nothing (`analysis::MIN_WINDOW_CYCLES`), and at 10 the 1 Hz
//! gate paged 91 times a day at a true +1 % (docs/benchmarks.md, "Stop 85"). A default in
//! seconds cannot serve every gate; one in cycles can.
//!
//! # How
//! The gate's windows stay due on the cadence, each `window_seconds` long ([`super::window`]).
//! The identification reads the last [`CycleSpan::samples`] of the contiguous history handed
//! out with the window, where the history holds that many (after the start and after a gap the
//! window grows, one cadence at a time, as the history fills). The span follows the median of
//! the last [`FREQUENCY_MEMORY`] windows' dominant frequencies, so one window whose peak is a
//! spike or a fault does not change it, and a change of less than [`SPAN_DEADBAND`] is not made,
//! so a frequency that wanders by a bin does not change the window from one report to the next.
//!
//! The history follows the same median: it holds at least the
//! [`RELAXATION_CYCLES`](crate::analysis::RELAXATION_CYCLES) a limit cycle's envelope
//! relaxation reads and a tenth more ([`HISTORY_CYCLES`]), where six windows hold fewer. Why: at
//! 10 s windows six windows are 60 cycles of a 1 Hz gate, each envelope reading then reads 60
//! cycles instead of 100, and its pools fall short of the 140 cycles of record a held cycle
//! needs on a gate without an ambient level (`analysis::MIN_CYCLE_POOL_CYCLES`): with the record
//! alone lengthened, 9 of 10 held cycles never fired (docs/benchmarks.md, "Stop 86").
//!
//! # Bounds
//! The span is never shorter than `window_seconds` and never longer than six of them
//! (`service::window::history_samples`), so an identification costs at most six times what the
//! configured window does whatever a faulty sensor's peak says. The history is never shorter
//! than six windows and never longer than the window plus `MAX_HISTORY_EXTRA` samples (800 KB),
//! the bound `service::window` documents. A gate whose six windows hold fewer than 16 cycles is
//! still refused, and its warning says to lengthen `window_seconds`.

use std::collections::VecDeque;

use super::window::{history_samples, MAX_HISTORY_EXTRA};

/// Windows whose dominant frequency the span follows (their median).
pub const FREQUENCY_MEMORY: usize = 5;

/// A new span within this fraction of the current one is not taken.
pub const SPAN_DEADBAND: f64 = 0.1;

/// Cycles of history kept at least: the envelope's
/// [`RELAXATION_CYCLES`](crate::analysis::RELAXATION_CYCLES) and the deadband's
/// tenth more (a unit test ties them).
pub const HISTORY_CYCLES: f64 = 110.0;

/// The identification span of one gate.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleSpan {
    rate_hz: f64,
    /// `window_seconds` in samples: the shortest span.
    base: usize,
    /// The history's capacity in samples: the longest span.
    max: usize,
    /// Cycles aimed for (`window_cycles`; 0: the span and the history stay as configured).
    cycles: f64,
    current: usize,
    /// Samples of history kept now, from six windows up to `base + MAX_HISTORY_EXTRA`.
    history: usize,
    frequencies: VecDeque<f64>,
}

impl CycleSpan {
    /// A span of a window of `base` samples at `rate_hz` that lengthens to hold `cycles` cycles
    /// (0: never), up to six windows (`history_samples(base)`).
    pub fn new(rate_hz: f64, base: usize, cycles: f64) -> CycleSpan {
        let base = base.max(1);
        let max = history_samples(base);
        CycleSpan {
            rate_hz,
            base,
            max,
            cycles,
            current: base,
            history: max,
            frequencies: VecDeque::with_capacity(FREQUENCY_MEMORY),
        }
    }

    /// Samples of contiguous history the gate keeps now.
    pub fn history_samples(&self) -> usize {
        self.history
    }

    /// Samples the identification reads now.
    pub fn samples(&self) -> usize {
        self.current
    }

    /// Seconds of sample time the identification reads now.
    pub fn seconds(&self) -> f64 {
        self.current as f64 / self.rate_hz
    }

    /// Takes a window's dominant frequency (ignored unless finite and positive); returns whether
    /// the span or the history changed.
    pub fn observe(&mut self, frequency_hz: Option<f64>) -> bool {
        let Some(f) = frequency_hz.filter(|f| f.is_finite() && *f > 0.0) else {
            return false;
        };
        if self.cycles.is_nan() || self.cycles <= 0.0 {
            return false;
        }
        if self.frequencies.len() == FREQUENCY_MEMORY {
            self.frequencies.pop_front();
        }
        self.frequencies.push_back(f);
        let mut sorted: Vec<f64> = self.frequencies.iter().copied().collect();
        // never empty: `f` was just pushed
        let median = crate::identify::median(&mut sorted).unwrap_or(f);
        let samples = |cycles: f64, low: usize, high: usize| {
            let wanted = (cycles * self.rate_hz / median).ceil();
            if wanted >= high as f64 {
                high
            } else {
                (wanted as usize).clamp(low, high)
            }
        };
        let span = samples(self.cycles, self.base, self.max);
        let history = samples(HISTORY_CYCLES, self.max, self.base + MAX_HISTORY_EXTRA);
        let moves = |to: usize, from: usize| {
            to != from && (to as f64 - from as f64).abs() > SPAN_DEADBAND * from as f64
        };
        let changed = moves(span, self.current) || moves(history, self.history);
        if changed {
            self.current = span;
            self.history = history.max(span);
        }
        changed
    }

    /// The tail of `history` the identification reads, with the time of its first sample, given
    /// the window `(t0, values)`: the window itself where the history holds no more.
    pub fn slice<'a>(&self, t0: f64, values: &'a [f64], history: &'a [f64]) -> (f64, &'a [f64]) {
        let n = self.current.min(history.len());
        if n <= values.len() {
            return (t0, values);
        }
        let extra = (n - values.len()) as f64 / self.rate_hz;
        (t0 - extra, &history[history.len() - n..])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::RELAXATION_CYCLES;

    /// A 1 Hz gate at 20 Hz with 10 s windows (200 samples) and 60 s of history: 40 cycles are
    /// 800 samples.
    fn surge() -> CycleSpan {
        CycleSpan::new(20.0, 200, 40.0)
    }

    #[test]
    fn the_history_holds_the_relaxations_cycles_and_the_deadband() {
        assert!((HISTORY_CYCLES - RELAXATION_CYCLES * (1.0 + SPAN_DEADBAND)).abs() < 1e-9);
    }

    #[test]
    fn a_slow_gate_reads_its_cycles_and_a_fast_one_its_seconds() {
        let mut s = surge();
        assert_eq!(s.samples(), 200);
        assert_eq!(s.history_samples(), 1200);
        assert!(s.observe(Some(1.0)));
        assert_eq!(s.samples(), 800);
        assert_eq!(s.seconds(), 40.0);
        // the envelope's 100 cycles and the deadband's tenth: 110 s
        assert_eq!(s.history_samples(), 2200);
        // the lab gate's 10.4 Hz at 200 Hz: 40 cycles are 770 samples, below the window's 2000,
        // and six windows hold 624 cycles
        let mut lab = CycleSpan::new(200.0, 2000, 40.0);
        assert!(!lab.observe(Some(10.4)));
        assert_eq!((lab.samples(), lab.history_samples()), (2000, 12_000));
        // a 2 Hz gate at 50 Hz: 20 s of record, and its six windows hold the 110 cycles
        let mut barrier = CycleSpan::new(50.0, 500, 40.0);
        assert!(barrier.observe(Some(2.0)));
        assert_eq!((barrier.samples(), barrier.history_samples()), (1000, 3000));
    }

    #[test]
    fn the_span_never_passes_the_history_and_zero_cycles_turns_it_off() {
        let mut s = surge();
        s.observe(Some(0.2)); // 200 s wanted, six windows (60 s) at most
        assert_eq!(s.samples(), 1200);
        assert_eq!(s.history_samples(), 11_000); // the envelope's 550 s
                                                 // a spike train's peak near 0 Hz: the history stops at MAX_HISTORY_EXTRA beyond
        let mut s = surge();
        s.observe(Some(1e-6));
        assert_eq!(
            (s.samples(), s.history_samples()),
            (1200, 200 + MAX_HISTORY_EXTRA)
        );
        let mut off = CycleSpan::new(20.0, 200, 0.0);
        assert!(!off.observe(Some(0.2)));
        assert_eq!((off.samples(), off.history_samples()), (200, 1200));
        for bad in [
            None,
            Some(f64::NAN),
            Some(0.0),
            Some(-1.0),
            Some(f64::INFINITY),
        ] {
            let mut s = surge();
            assert!(!s.observe(bad), "{bad:?}");
            assert_eq!(s.samples(), 200);
        }
    }

    #[test]
    fn one_stray_peak_does_not_move_it_nor_does_a_bin_of_wander() {
        let mut s = surge();
        for _ in 0..4 {
            s.observe(Some(1.0));
        }
        assert_eq!(s.samples(), 800);
        // a spike's peak at 0.25 Hz: the median of five is still 1 Hz
        assert!(!s.observe(Some(0.25)));
        assert_eq!(s.samples(), 800);
        // 0.95 Hz wants 843 samples: 5 % more, inside the deadband
        let mut w = surge();
        w.observe(Some(1.0));
        assert!(!w.observe(Some(0.95)) && !w.observe(Some(0.95)));
        assert_eq!(w.samples(), 800);
        // 0.8 Hz for good: 1000 samples, taken once the median moves
        for _ in 0..3 {
            w.observe(Some(0.8));
        }
        assert_eq!(w.samples(), 1000);
    }

    #[test]
    fn the_slice_is_the_history_tail_with_its_start_time() {
        let mut s = CycleSpan::new(10.0, 4, 16.0);
        s.observe(Some(1.6)); // 100 samples wanted, six windows (24) at most
        assert_eq!(s.samples(), 24);
        let history: Vec<f64> = (0..8).map(f64::from).collect();
        let values = &history[4..];
        // the history holds 8: the identification reads all of it, from 0.4 s earlier
        let (t0, read) = s.slice(100.0, values, &history);
        assert_eq!(read, &history[..]);
        assert!((t0 - 99.6).abs() < 1e-12);
        let long: Vec<f64> = (0..30).map(f64::from).collect();
        let (t0, read) = s.slice(100.0, &long[26..], &long);
        assert_eq!(read, &long[6..]);
        assert!((t0 - 98.0).abs() < 1e-12);
        // off: the window
        let off = CycleSpan::new(10.0, 4, 0.0);
        assert_eq!(off.slice(100.0, values, &history), (100.0, values));
    }
}
