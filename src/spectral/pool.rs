//! Pooling a gate's consecutive ambient estimates so the record behind its damping follows the
//! gate's period, not the window's seconds.
//!
//! # Why
//! What limits an ambient damping estimate is the number of cycles it sees (Au's uncertainty law:
//! `sd(zeta) ~ sqrt(zeta / (2 pi N_c))`), not seconds: a 10 s window holds 100 cycles of a 10 Hz
//! gate but 20 of a 2 Hz one. A single window of SSI-COV is unbiased but often too wide to
//! exclude zero (issue 8). [`DampingPool`] keeps the last windows' estimates of one gate and
//! combines them until they hold [`PoolOptions::min_cycles`] distinct cycles, bounded in
//! seconds and windows.
//!
//! # Combination
//! Each window's estimate is weighted by its record length in cycles (equal weights for equal
//! windows). Inverse-variance weights are not used on purpose: Au's floor makes the variance
//! grow with `zeta`, so `1/se^2` weights would favour low estimates and bias the pool down.
//! The location is the weighted mean or, for the ambient (SSI-COV) estimates, a robust location
//! ([`PoolLocation`]): one window's SSI-COV estimate is median-unbiased but skewed to the
//! right, the more so the fewer cycles it holds (a 2 Hz gate's 10 s window at +0.5 %: median
//! error +0.01 points, mean +0.36; a 10.4 Hz gate's: +0.04 and +0.13), so a mean of such windows
//! reads high by about half the spread of one (the pooled figure on the 2 Hz gate: +0.33 points
//! with the mean, +0.08 with the median). The median wastes a third of the information where
//! the windows are nearly symmetric (a 5 Hz gate at +2 %: spread 0.68 against the mean's 0.66);
//! the daemon's ambient pool takes the Hodges-Lehmann estimate in the square-root scale, which
//! keeps the median's low bias and is narrower than both (0.62 there;
//! `tests/ambient_pooling.rs`, docs/damping.md, "Pooling windows").
//! Consecutive windows overlap (the daemon's default: 10 s windows every 5 s), so their
//! estimates are correlated; the pool's variance takes the correlation of two estimates as the
//! fraction of their records they share, `rho_ij = overlap_ij / sqrt(T_i T_j)`:
//! `Var = sum_ij w_i w_j rho_ij se_i se_j / (sum w)^2`. For 50 % overlap this is about twice the
//! variance of independent windows, as it should be (half the samples are new per window).
//!
//! # Regime changes flush the pool, once a second window confirms them
//! A pooled estimate averages the record, so a gate whose damping changes must not carry its
//! old windows: a window whose estimate differs from the pool by more than
//! [`PoolOptions::flush_sigmas`] combined standard errors, or whose frequency moved by more than
//! [`PoolOptions::max_frequency_shift`], signals a change. One such window alone is more often a
//! spurious pole than a new state of the gate, so it is held back ([`PooledEstimate::held`]: the
//! pool's figure stands for it) and flushes the pool only when the next window signals a change
//! too; the two then start the new pool. A next window that agrees with the pool drops it. Why:
//! on a steady +0.5 % lock gate (5 Hz, `bench warning --scenarios stable-low`, 24 h, sessions
//! 43 and 44) the lone windows that flushed the pool read 3.9 to 4.2 points off the truth
//! (median; the windows before them 0.2), 10 to 12 times a day, each shown as the gate's damping
//! (+12.5 % (+6.1, +18.9) at a true +0.5 %); on the 2 Hz barrier gate 300 times a day. The
//! price is one window (5 s) on a real change of the ambient state; a gate that leaves its
//! ambient level is not pooled at all (`analysis::pooling`), so an onset is not delayed by it.
//! A pool of one window has no figure to defend and flushes at once, as does a window that
//! starts after a gap longer than [`PoolOptions::max_seconds`] (or before the last one ends:
//! a replay restarted). The report then rests on the new window alone (wide, honest) until the
//! pool fills again.

use super::SpectralError;
use std::collections::VecDeque;

/// Options of [`DampingPool`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoolOptions {
    /// Distinct cycles of the gate's frequency the pool aims for (older windows are dropped
    /// once the newer ones hold this many). Default 250: Au's law gives `sd ~ 0.11 zeta^(1/2)`
    /// there, about +-0.3 points (95 %) at +2 %.
    pub min_cycles: f64,
    /// The pool never spans more sample time than this, s (bounds the lag of a pooled estimate
    /// behind a slow drift).
    pub max_seconds: f64,
    /// The pool never holds more windows than this (bounds memory and work per window).
    pub max_windows: usize,
    /// A new estimate this many combined standard errors from the pool flushes it.
    pub flush_sigmas: f64,
    /// A relative frequency change larger than this flushes the pool (another mode, a new
    /// water level).
    pub max_frequency_shift: f64,
    /// Two-sided confidence of the pooled interval (normal quantile).
    pub confidence: f64,
    /// How the windows' estimates are combined (default [`PoolLocation::Mean`]).
    pub location: PoolLocation,
    /// Count each estimate by the record it read ([`WindowEstimate::record_seconds`]), not its
    /// window: its weight, the distinct cycles [`Self::min_cycles`] asks for, and the span
    /// [`Self::max_seconds`] bounds. Default `false` (the windows). Why: an estimate that read
    /// 100 cycles of history where its window holds 50 already holds two windows' worth, and a
    /// pool counted by windows would keep as many windows as before on top of it, reaching
    /// further back and lagging a drift more (the daemon's ambient pool,
    /// `analysis::ZetaPools`; docs/damping.md, "One ambient reading of 100 cycles").
    pub count_records: bool,
    /// The pool holds only estimates whose window's RMS ([`WindowEstimate::rms`]) lies within
    /// this factor of the newest's: an older one outside it, and every estimate before it, is
    /// dropped. `None` (the default): no such bound. Why: under the same forcing a response's
    /// variance goes as `1 / zeta`, so an RMS that moved by a factor `k` is a damping moved by
    /// `k^2`, or another state (a decay after a limit cycle), and a pool that reaches back
    /// across it reports the state before. The daemon's ambient pool uses 3, the bar at which a
    /// window has left its gate's ambient level (`analysis::ZetaPools`; docs/damping.md, "A pool
    /// holds one level").
    pub max_level_change: Option<f64>,
}

/// The pooled figure's location: the windows' cycle-weighted mean, or their cycle-weighted
/// median (for an estimator whose distribution is skewed, see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PoolLocation {
    /// Cycle-weighted mean: unbiased when each window's estimate is.
    #[default]
    Mean,
    /// Cycle-weighted median: unbiased when each window's estimate is median-unbiased, as
    /// SSI-COV's is, where its mean is not.
    Median,
    /// The Hodges-Lehmann estimate (the weighted median of the pairwise means) of the windows'
    /// signed square roots, squared back: for an estimator whose variance grows with `zeta`
    /// (Au's law, `sd ~ sqrt(zeta / (2 pi N_c))`), the square root makes the windows' spread
    /// equal and their distribution nearly symmetric, where Hodges-Lehmann is as efficient as
    /// the mean (95 % for normal windows, against the median's 64 %) and still ignores a
    /// spurious pole (it breaks down at 29 % of the windows). On SSI-COV's windows it keeps the
    /// median's low bias and the mean's spread (`tests/ambient_pooling.rs`).
    SqrtHodgesLehmann,
}

impl Default for PoolOptions {
    fn default() -> Self {
        PoolOptions {
            min_cycles: 250.0,
            max_seconds: 120.0,
            max_windows: 16,
            flush_sigmas: 3.0,
            max_frequency_shift: 0.05,
            confidence: 0.95,
            location: PoolLocation::Mean,
            count_records: false,
            max_level_change: None,
        }
    }
}

/// One window's ambient estimate, as pooled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowEstimate {
    /// Start of the window's record, s (any clock, the same for all windows of a gate).
    pub t_start: f64,
    /// End of the window's record, s.
    pub t_end: f64,
    /// Damping ratio.
    pub zeta: f64,
    /// Its standard error.
    pub stderr: f64,
    /// Frequency of the mode, Hz.
    pub frequency_hz: f64,
    /// Seconds of record the estimate read, ending at `t_end`: the window's, or more where it
    /// read the gate's history (a limit cycle's relaxation). Two estimates are correlated by the
    /// overlap of their records, not of their windows; a value below the window's length counts
    /// as the window's.
    pub record_seconds: f64,
    /// The window's signal RMS ([`PoolOptions::max_level_change`]); `None` (or not a positive
    /// number): not measured, and such an estimate is never dropped for its level, nor drops
    /// others.
    pub rms: Option<f64>,
}

impl WindowEstimate {
    /// Start of the record the estimate read.
    fn record_start(&self) -> f64 {
        self.t_start.min(self.t_end - self.record_seconds)
    }
}

/// The pooled estimate after a window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PooledEstimate {
    /// Pooled damping ratio.
    pub zeta: f64,
    /// Its interval.
    pub interval: (f64, f64),
    /// Its standard error.
    pub stderr: f64,
    /// Windows pooled.
    pub windows: usize,
    /// Distinct cycles of the windows behind it.
    pub cycles: f64,
    /// Distinct cycles of the records the estimates read (each [`WindowEstimate::record_seconds`]
    /// ending at its window's end, the window where that is longer): more than
    /// [`PooledEstimate::cycles`] where an estimate read the gate's history.
    pub record_cycles: f64,
    /// The sample time the figure stands for: the middle of the records its estimates read
    /// (each from its [`WindowEstimate::record_seconds`] start to its window's end), averaged
    /// with the weights the pool gives them. Three windows 5 s apart, each reading 20 s, stand
    /// for the instant 15 s before the newest window ends, and a drifting damping
    /// was there then, not at the window's end (`analysis::DampingTrend` places it there;
    /// docs/damping.md, "Trend").
    pub record_middle: f64,
    /// Whether this window flushed the pool (a regime change).
    pub flushed: bool,
    /// Whether this window signalled a change alone and was held back: the estimate is the
    /// pool's before it, and the next window decides (see the module documentation).
    pub held: bool,
}

/// The last windows' ambient estimates of one gate (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct DampingPool {
    opts: PoolOptions,
    entries: VecDeque<WindowEstimate>,
    /// The last window, when it signalled a change alone (held back, not pooled).
    pending: Option<WindowEstimate>,
}

impl DampingPool {
    /// An empty pool; checks the options.
    pub fn new(opts: PoolOptions) -> Result<DampingPool, SpectralError> {
        let ok = opts.min_cycles > 0.0
            && opts.max_seconds > 0.0
            && opts.max_windows >= 1
            && opts.flush_sigmas > 0.0
            && opts.max_frequency_shift > 0.0
            && opts.confidence > 0.0
            && opts.confidence < 1.0
            && opts
                .max_level_change
                .is_none_or(|k| k.is_finite() && k > 1.0);
        if !ok {
            return Err(SpectralError::Invalid(format!("pool options {opts:?}")));
        }
        Ok(DampingPool {
            opts,
            entries: VecDeque::with_capacity(opts.max_windows),
            pending: None,
        })
    }

    /// Windows held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the pool is empty.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Sets [`PoolOptions::max_seconds`] (ignored unless positive and finite): the daemon
    /// lengthens a slow gate's pools with its windows (`analysis::ZetaPools::follow_window`).
    pub fn set_max_seconds(&mut self, max_seconds: f64) {
        if max_seconds.is_finite() && max_seconds > 0.0 {
            self.opts.max_seconds = max_seconds;
        }
    }

    /// [`PoolOptions::max_seconds`] now.
    pub fn max_seconds(&self) -> f64 {
        self.opts.max_seconds
    }

    /// Empties the pool (and forgets a held window).
    pub fn clear(&mut self) {
        self.entries.clear();
        self.pending = None;
    }

    /// Adds a window's estimate (flushing first on a confirmed regime change, holding it back
    /// when it signals a change alone) and returns the pooled estimate. A window that is not
    /// finite, has a non-positive standard error or ends before it starts is refused with the
    /// reason.
    pub fn push(&mut self, e: WindowEstimate) -> Result<PooledEstimate, SpectralError> {
        let finite = [
            e.t_start,
            e.t_end,
            e.zeta,
            e.stderr,
            e.frequency_hz,
            e.record_seconds,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !(finite && e.stderr > 0.0 && e.t_end > e.t_start && e.frequency_hz > 0.0) {
            return Err(SpectralError::Invalid(format!("window estimate {e:?}")));
        }
        let mut flushed = false;
        let pending = self.pending.take();
        if let (Some(last), Some(pooled)) = (self.entries.back().copied(), self.combine()) {
            let gap = e.t_start - last.t_end;
            let shift = (e.frequency_hz / last.frequency_hz - 1.0).abs();
            let far = (e.zeta - pooled.zeta).abs()
                > self.opts.flush_sigmas * e.stderr.hypot(pooled.stderr);
            // Out of order (a replay restarted) counts as a gap too.
            let gap_or_replay = gap > self.opts.max_seconds || e.t_end <= last.t_end;
            let change = shift > self.opts.max_frequency_shift || far;
            if gap_or_replay {
                self.entries.clear();
                flushed = true;
            } else if change {
                match pending.filter(|p| p.t_end < e.t_end) {
                    // confirmed: the held window is the new state's first
                    Some(first) => {
                        self.entries.clear();
                        self.entries.push_back(first);
                        flushed = true;
                    }
                    // alone: held back until the next window says whether it was a change
                    None if self.entries.len() >= 2 => {
                        self.pending = Some(e);
                        return Ok(PooledEstimate {
                            held: true,
                            ..pooled
                        });
                    }
                    // a pool of one window has no figure to defend
                    None => {
                        self.entries.clear();
                        flushed = true;
                    }
                }
            }
            // otherwise a held window was a lone outlier, and is dropped
        }
        self.entries.push_back(e);
        self.trim();
        let mut p = self
            .combine()
            .expect("the pool holds the window just pushed");
        p.flushed = flushed;
        Ok(p)
    }

    /// Where an estimate counts from ([`PoolOptions::count_records`]): its record's start, or
    /// its window's.
    fn counted_start(&self, e: &WindowEstimate) -> f64 {
        if self.opts.count_records {
            e.record_start()
        } else {
            e.t_start
        }
    }

    /// Drops the oldest windows beyond the bounds, or not needed for `min_cycles`, and those
    /// from before the newest one whose level is not the newest's
    /// ([`PoolOptions::max_level_change`]).
    fn trim(&mut self) {
        let newest = match self.entries.back() {
            Some(e) => *e,
            None => return,
        };
        let level = |e: &WindowEstimate| e.rms.filter(|r| r.is_finite() && *r > 0.0);
        if let (Some(k), Some(now)) = (self.opts.max_level_change, level(&newest)) {
            let other_level =
                |e: &WindowEstimate| level(e).is_some_and(|r| r * k < now || r > now * k);
            if let Some(i) = self.entries.iter().rposition(other_level) {
                self.entries.drain(..=i);
            }
        }
        while self.entries.len() > 1 {
            let oldest = self.entries[0];
            let too_many = self.entries.len() > self.opts.max_windows;
            let too_long = newest.t_end - self.counted_start(&oldest) > self.opts.max_seconds;
            let newer = self
                .entries
                .iter()
                .skip(1)
                .map(|e| (self.counted_start(e), e));
            let not_needed = covered_cycles(newer) >= self.opts.min_cycles;
            if too_many || too_long || not_needed {
                self.entries.pop_front();
            } else {
                break;
            }
        }
    }

    /// The cycle-weighted mean with the overlap-correlated variance.
    fn combine(&self) -> Option<PooledEstimate> {
        if self.entries.is_empty() {
            return None;
        }
        let w: Vec<f64> = self
            .entries
            .iter()
            .map(|e| (e.t_end - self.counted_start(e)) * e.frequency_hz)
            .collect();
        let sw: f64 = w.iter().sum();
        let zeta = match self.opts.location {
            PoolLocation::Mean => {
                self.entries
                    .iter()
                    .zip(&w)
                    .map(|(e, w)| w * e.zeta)
                    .sum::<f64>()
                    / sw
            }
            PoolLocation::Median => {
                weighted_median(self.entries.iter().map(|e| e.zeta).zip(w.iter().copied()))
            }
            PoolLocation::SqrtHodgesLehmann => {
                sqrt_hodges_lehmann(self.entries.iter().map(|e| e.zeta).zip(w.iter().copied()))
            }
        };
        let mut var = 0.0;
        for (i, a) in self.entries.iter().enumerate() {
            for (j, b) in self.entries.iter().enumerate() {
                let (sa, sb) = (a.record_start(), b.record_start());
                let shared = (a.t_end.min(b.t_end) - sa.max(sb)).max(0.0);
                let rho = shared / ((a.t_end - sa) * (b.t_end - sb)).sqrt();
                var += w[i] * w[j] * rho * a.stderr * b.stderr;
            }
        }
        let stderr = var.sqrt() / sw;
        let record_middle = self
            .entries
            .iter()
            .zip(&w)
            .map(|(e, w)| w * 0.5 * (e.record_start() + e.t_end))
            .sum::<f64>()
            / sw;
        let q = super::normal_quantile(0.5 + self.opts.confidence / 2.0);
        Some(PooledEstimate {
            zeta,
            interval: (zeta - q * stderr, zeta + q * stderr),
            stderr,
            windows: self.entries.len(),
            cycles: span_cycles(self.entries.iter()),
            record_cycles: record_span_cycles(self.entries.iter()),
            record_middle,
            flushed: false,
            held: false,
        })
    }
}

/// The weighted median of `(value, weight)` pairs (positive weights), continuous in the
/// weights: in value order each value stands at the centre of its share of the cumulative
/// weight, and the median is read by linear interpolation at half the total. Equal weights give
/// the ordinary median (the middle value, or the midpoint of the middle two); two windows whose
/// cycle weights differ by a rounding (their frequencies differ slightly) give nearly their
/// midpoint, not one of them. At most [`PoolOptions::max_windows`] pairs: the sort's allocation
/// is bounded and once per window, outside any inner loop.
fn weighted_median(pairs: impl Iterator<Item = (f64, f64)>) -> f64 {
    let mut v: Vec<(f64, f64)> = pairs.collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = v.iter().map(|p| p.1).sum::<f64>() / 2.0;
    let mut cum = 0.0;
    let mut prev: Option<(f64, f64)> = None; // (centre, value)
    for &(z, w) in &v {
        let centre = cum + w / 2.0;
        cum += w;
        if centre >= half {
            return match prev {
                Some((c0, z0)) if centre > c0 => z0 + (z - z0) * (half - c0) / (centre - c0),
                _ => z,
            };
        }
        prev = Some((centre, z));
    }
    v.last().map_or(f64::NAN, |p| p.0)
}

/// The weighted Hodges-Lehmann location of `(value, weight)` pairs in the signed square-root
/// scale, returned in the values' scale: the pairwise means `(u_i + u_j) / 2` for `i <= j` of
/// `u = sign(z) sqrt(|z|)`, weighted `w_i w_j` (equal weights give the textbook estimate), their
/// [`weighted_median`], squared back with its sign. The signed root is monotone, so the estimate
/// lies between the smallest and the largest value; near zero (a gate drifting through it) it
/// stays continuous. At most [`PoolOptions::max_windows`] pairs in, so at most 136 pairwise
/// means: one bounded allocation per window, outside any inner loop.
fn sqrt_hodges_lehmann(pairs: impl Iterator<Item = (f64, f64)>) -> f64 {
    let v: Vec<(f64, f64)> = pairs
        .map(|(z, w)| (z.signum() * z.abs().sqrt(), w))
        .collect();
    let mut walsh = Vec::with_capacity(v.len() * (v.len() + 1) / 2);
    for (i, &(ui, wi)) in v.iter().enumerate() {
        for &(uj, wj) in &v[i..] {
            walsh.push((0.5 * (ui + uj), wi * wj));
        }
    }
    let u = weighted_median(walsh.into_iter());
    u.signum() * u * u
}

/// Distinct cycles covered by windows in time order (overlaps counted once).
fn span_cycles<'a>(entries: impl Iterator<Item = &'a WindowEstimate>) -> f64 {
    covered_cycles(entries.map(|e| (e.t_start, e)))
}

/// Distinct cycles covered by the records the estimates read, in time order.
fn record_span_cycles<'a>(entries: impl Iterator<Item = &'a WindowEstimate>) -> f64 {
    covered_cycles(entries.map(|e| (e.record_start(), e)))
}

/// Distinct cycles of the spans `(start, e.t_end)` in order of their ends (overlaps counted
/// once), each at its estimate's frequency.
fn covered_cycles<'a>(spans: impl Iterator<Item = (f64, &'a WindowEstimate)>) -> f64 {
    let mut cycles = 0.0;
    let mut covered_to = f64::NEG_INFINITY;
    for (start, e) in spans {
        let from = start.max(covered_to);
        if e.t_end > from {
            cycles += (e.t_end - from) * e.frequency_hz;
        }
        covered_to = covered_to.max(e.t_end);
    }
    cycles
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn est(t_start: f64, zeta: f64, stderr: f64) -> WindowEstimate {
        WindowEstimate {
            t_start,
            t_end: t_start + 10.0,
            zeta,
            stderr,
            frequency_hz: 10.0,
            record_seconds: 0.0,
            rms: None,
        }
    }

    /// The pooled figure stands for the middle of its records, weighted as the pool weighs
    /// them: four 10 s windows 5 s apart (ending at 10 to 25 s) stand for the mean of their
    /// middles, 12.5 s; a held window leaves the instant where the pool's figure was; records of
    /// 20, 20 and 40 s weigh by their length, and the longest reaches back furthest.
    #[test]
    fn a_pool_stands_at_the_middle_of_its_records() {
        let mut p = DampingPool::new(PoolOptions::default()).unwrap();
        for k in 0..3 {
            p.push(est(5.0 * k as f64, 0.01, 0.002)).unwrap();
        }
        let r = p.push(est(15.0, 0.01, 0.002)).unwrap();
        assert_eq!(r.windows, 4);
        assert_relative_eq!(r.record_middle, 12.5, epsilon = 1e-9);
        let held = p.push(est(20.0, 0.2, 0.002)).unwrap();
        assert!(held.held);
        assert_relative_eq!(held.record_middle, 12.5, epsilon = 1e-9);
        // a longer record weighs more and reaches further back
        let opts = PoolOptions {
            count_records: true,
            min_cycles: 1000.0,
            ..PoolOptions::default()
        };
        let mut p = DampingPool::new(opts).unwrap();
        let mut r = None;
        for (k, record) in [(0, 20.0), (1, 20.0), (2, 40.0)] {
            let e = WindowEstimate {
                record_seconds: record,
                ..est(100.0 + 5.0 * k as f64, 0.01, 0.002)
            };
            r = Some(p.push(e).unwrap());
        }
        let r = r.unwrap();
        assert_eq!(r.windows, 3);
        // middles 100, 105, 100 (ends 110, 115, 120), weights 20, 20, 40 s of record
        assert_relative_eq!(r.record_middle, 101.25, epsilon = 1e-9);
    }

    #[test]
    fn disjoint_equal_windows_average_with_sqrt_n_error() {
        let mut p = DampingPool::new(PoolOptions::default()).unwrap();
        let mut last = None;
        for (k, z) in [0.018, 0.022, 0.020].iter().enumerate() {
            last = Some(p.push(est(10.0 * k as f64, *z, 0.004)).unwrap());
        }
        let last = last.unwrap();
        assert_relative_eq!(last.zeta, 0.020, epsilon = 1e-12);
        assert_relative_eq!(last.stderr, 0.004 / 3f64.sqrt(), epsilon = 1e-12);
        assert_eq!(last.windows, 3);
        assert_relative_eq!(last.cycles, 300.0, epsilon = 1e-9);
    }

    /// 50 % overlap: half the samples are new per window, so the pooled variance is larger
    /// than for independent windows.
    #[test]
    fn overlapping_windows_count_their_shared_record() {
        let mut p = DampingPool::new(PoolOptions::default()).unwrap();
        let mut r = None;
        for k in 0..5 {
            r = Some(p.push(est(5.0 * k as f64, 0.02, 0.004)).unwrap());
        }
        let r = r.unwrap();
        // The newest four windows (5 s to 30 s) hold 250 cycles: the oldest is dropped.
        assert_eq!(r.windows, 4);
        assert_relative_eq!(r.cycles, 250.0, epsilon = 1e-9);
        // sum_ij rho_ij = 4 + 2 * 3 * 0.5 = 7, over 4^2.
        assert_relative_eq!(r.stderr, 0.004 * 7f64.sqrt() / 4.0, epsilon = 1e-12);
        assert!(r.stderr > 0.004 / 4f64.sqrt());
    }

    #[test]
    fn the_pool_keeps_only_what_min_cycles_needs_and_its_bounds() {
        let mut p = DampingPool::new(PoolOptions {
            min_cycles: 250.0,
            ..PoolOptions::default()
        })
        .unwrap();
        for k in 0..10 {
            p.push(est(10.0 * k as f64, 0.02, 0.004)).unwrap();
        }
        // 100 cycles per window: three windows hold 300 >= 250, two would hold 200.
        assert_eq!(p.len(), 3);
        // A 2 Hz gate (20 cycles per window) is bounded by max_seconds = 120 s.
        let mut slow = DampingPool::new(PoolOptions::default()).unwrap();
        for k in 0..30 {
            let e = WindowEstimate {
                frequency_hz: 2.0,
                ..est(10.0 * k as f64, 0.02, 0.01)
            };
            slow.push(e).unwrap();
        }
        assert_eq!(slow.len(), 12);
    }

    /// Counted by records (`count_records`): estimates that read 20 s of a 5 Hz gate (100
    /// cycles), 5 s apart, hold 150 distinct cycles in three windows, where counted by their
    /// 10 s windows the pool keeps five; `max_seconds` bounds the records' span; a window-only
    /// estimate among them weighs its window.
    #[test]
    fn a_pool_counted_by_records_holds_fewer_windows() {
        let push_all = |count_records: bool, max_seconds: f64| {
            let mut p = DampingPool::new(PoolOptions {
                min_cycles: 150.0,
                max_seconds,
                count_records,
                ..PoolOptions::default()
            })
            .unwrap();
            let mut last = None;
            for k in 0..10 {
                let e = WindowEstimate {
                    frequency_hz: 5.0,
                    record_seconds: 20.0,
                    ..est(5.0 * k as f64, 0.01, 0.004)
                };
                last = Some(p.push(e).unwrap());
            }
            last.unwrap()
        };
        let by_record = push_all(true, 60.0);
        assert_eq!(by_record.windows, 3);
        assert_relative_eq!(by_record.record_cycles, 150.0, epsilon = 1e-9);
        assert_eq!(push_all(false, 60.0).windows, 5);
        // 30 s of records at most: two windows (25 s), whatever the cycles ask
        assert_eq!(push_all(true, 28.0).windows, 2);
        // the weights: a 20 s record at 0.010 and a 10 s window at 0.016 pool to 0.012 by
        // records, to 0.013 by windows
        let mixed = |count_records: bool| {
            let mut p = DampingPool::new(PoolOptions {
                min_cycles: 1000.0,
                count_records,
                ..PoolOptions::default()
            })
            .unwrap();
            let record = WindowEstimate {
                record_seconds: 20.0,
                ..est(0.0, 0.01, 0.004)
            };
            p.push(record).unwrap();
            p.push(est(5.0, 0.016, 0.004)).unwrap().zeta
        };
        assert_relative_eq!(mixed(true), 0.012, epsilon = 1e-12);
        assert_relative_eq!(mixed(false), 0.013, epsilon = 1e-12);
    }

    #[test]
    fn the_weighted_median_is_the_middle_by_weight() {
        let wm = |v: &[(f64, f64)]| weighted_median(v.iter().copied());
        assert_eq!(wm(&[(3.0, 1.0), (1.0, 1.0), (2.0, 1.0)]), 2.0);
        // equal weights, even count: the midpoint of the middle two
        assert_eq!(wm(&[(4.0, 1.0), (1.0, 1.0), (2.0, 1.0), (3.0, 1.0)]), 2.5);
        // weights that do not sum exactly in binary still tie at the half
        assert_relative_eq!(wm(&[(1.0, 0.1), (2.0, 0.1), (3.0, 0.1), (4.0, 0.1)]), 2.5);
        // a heavy window pulls the median towards it: centres 0.5, 1.5, 3.5, half 2.5
        assert_relative_eq!(wm(&[(1.0, 1.0), (9.0, 3.0), (2.0, 1.0)]), 5.5);
        assert_eq!(wm(&[(5.0, 2.0)]), 5.0);
        // two windows whose weights differ by a rounding: their midpoint, not one of them
        assert_relative_eq!(wm(&[(1.0, 104.01), (2.0, 103.99)]), 1.5, epsilon = 1e-3);
    }

    /// The median pool: one high window among steady ones moves it to the middle of the others,
    /// where the mean moves by a share of the excess; the variance is the same (the overlap
    /// formula of the windows' errors), so the interval only moves.
    #[test]
    fn a_median_pool_is_not_pulled_by_one_high_window() {
        let pooled = |location: PoolLocation| {
            let mut p = DampingPool::new(PoolOptions {
                location,
                min_cycles: 1000.0,
                ..PoolOptions::default()
            })
            .unwrap();
            let mut last = None;
            for (k, z) in [0.010, 0.011, 0.009, 0.030].iter().enumerate() {
                last = Some(p.push(est(10.0 * k as f64, *z, 0.008)).unwrap());
            }
            last.unwrap()
        };
        let (mean, median) = (pooled(PoolLocation::Mean), pooled(PoolLocation::Median));
        assert_relative_eq!(mean.zeta, 0.015, epsilon = 1e-12);
        assert_relative_eq!(median.zeta, 0.0105, epsilon = 1e-12);
        assert_relative_eq!(median.stderr, mean.stderr, epsilon = 1e-15);
        assert_eq!((median.windows, mean.windows), (4, 4));
    }

    /// The square-root Hodges-Lehmann pool: the textbook estimate on equal weights, between the
    /// median and the mean on a skewed set, not pulled by one spurious window, continuous through
    /// zero.
    #[test]
    fn the_sqrt_hodges_lehmann_location() {
        let hl = |v: &[f64]| sqrt_hodges_lehmann(v.iter().map(|&z| (z, 1.0)));
        // one value, two values (the square of the mean root), symmetric in the root scale
        assert_relative_eq!(hl(&[0.02]), 0.02, epsilon = 1e-15);
        assert_relative_eq!(hl(&[0.01, 0.04]), 0.0225, epsilon = 1e-15);
        assert_relative_eq!(hl(&[0.04, 0.09, 0.16]), 0.09, epsilon = 1e-15);
        // roots 0.1, 0.2, 0.3, 0.4: pairwise means 0.1 .. 0.4, median 0.25
        assert_relative_eq!(hl(&[0.01, 0.04, 0.09, 0.16]), 0.0625, epsilon = 1e-12);
        // a spurious pole among five steady windows moves it less than the mean
        let v = [0.010, 0.011, 0.009, 0.0105, 0.0095, 0.30];
        let mean = v.iter().sum::<f64>() / 6.0;
        let z = hl(&v);
        assert!(z > 0.0095 && z < 0.0115, "{z}");
        assert!(z - 0.01 < 0.05 * (mean - 0.01));
        // through zero: sign-symmetric values give zero, and a small move gives a small change
        assert_relative_eq!(hl(&[-0.004, 0.004]), 0.0, epsilon = 1e-18);
        let a = hl(&[-0.004, 0.0001, 0.004]);
        let b = hl(&[-0.004, 0.0002, 0.004]);
        assert!(a.abs() < 2e-4 && (b - a).abs() < 2e-4, "{a} {b}");
        // a heavy window pulls it towards its value
        let heavy = sqrt_hodges_lehmann([(0.01, 1.0), (0.04, 3.0)].into_iter());
        assert!(heavy > 0.0225 && heavy < 0.04, "{heavy}");
    }

    /// Estimates that read longer records than their windows share more of them: two 10 s windows
    /// 5 s apart that each read 40 s share 35 s (rho 0.875), not 5 s (0.5), and the pooled error
    /// says so.
    #[test]
    fn overlapping_records_count_as_correlated() {
        let pooled = |record_seconds: f64| {
            let mut p = DampingPool::new(PoolOptions::default()).unwrap();
            p.push(WindowEstimate {
                record_seconds,
                ..est(0.0, 0.02, 0.004)
            })
            .unwrap();
            p.push(WindowEstimate {
                record_seconds,
                ..est(5.0, 0.02, 0.004)
            })
            .unwrap()
        };
        let (window, record) = (pooled(0.0), pooled(40.0));
        assert_relative_eq!(
            window.stderr,
            0.004 * (0.5f64 * 1.5).sqrt(),
            epsilon = 1e-12
        );
        assert_relative_eq!(
            record.stderr,
            0.004 * (0.5f64 * 1.875).sqrt(),
            epsilon = 1e-12
        );
        assert_eq!((window.windows, record.windows), (2, 2));
    }

    /// A regime change (the damping drops from +2 % to -1 %) flushes the pool once a second
    /// window confirms it, instead of averaging the old windows into the new state; the first
    /// window of the change is held back meanwhile (the pool's figure stands for it) and starts
    /// the new pool with the second.
    #[test]
    fn a_confirmed_regime_change_flushes_the_pool() {
        let mut p = DampingPool::new(PoolOptions::default()).unwrap();
        for k in 0..3 {
            assert!(!p.push(est(10.0 * k as f64, 0.02, 0.003)).unwrap().flushed);
        }
        let r = p.push(est(30.0, -0.01, 0.003)).unwrap();
        assert!(r.held && !r.flushed);
        assert_eq!(r.windows, 3);
        assert_relative_eq!(r.zeta, 0.02, epsilon = 1e-12);
        let r = p.push(est(40.0, -0.011, 0.003)).unwrap();
        assert!(r.flushed && !r.held);
        assert_eq!(r.windows, 2);
        assert_relative_eq!(r.zeta, -0.0105, epsilon = 1e-12);
        // a consistent window neither flushes nor is held
        let r = p.push(est(50.0, -0.0105, 0.003)).unwrap();
        assert!(!r.flushed && !r.held && r.windows == 3);
        // a frequency jump is a change too, confirmed by the next window's
        let moved = |t: f64| WindowEstimate {
            frequency_hz: 11.0,
            ..est(t, -0.011, 0.003)
        };
        assert!(p.push(moved(60.0)).unwrap().held);
        let r = p.push(moved(70.0)).unwrap();
        assert!(r.flushed && r.windows == 2);
        // a gap flushes at once
        let late = WindowEstimate {
            frequency_hz: 11.0,
            ..est(1000.0, -0.011, 0.003)
        };
        let r = p.push(late).unwrap();
        assert!(r.flushed && !r.held && r.windows == 1);
        // so does a change against a pool of one window: it has no figure to defend
        let r = p.push(est(1010.0, 0.03, 0.003)).unwrap();
        assert!(r.flushed && !r.held && r.windows == 1);
        assert_relative_eq!(r.zeta, 0.03, epsilon = 1e-12);
    }

    /// One spurious window (a pole at +12 % among +0.5 % windows, as SSI-COV reads now and then on
    /// a lightly damped gate) neither flushes the pool nor enters it: the pool's figure stands for
    /// it, and the next window, which agrees with the pool, drops it.
    #[test]
    fn a_lone_outlier_is_held_back_and_dropped() {
        let mut p = DampingPool::new(PoolOptions::default()).unwrap();
        for k in 0..4 {
            p.push(est(5.0 * k as f64, 0.005, 0.002)).unwrap();
        }
        let before = p.push(est(20.0, 0.005, 0.002)).unwrap();
        let r = p.push(est(25.0, 0.12, 0.03)).unwrap();
        assert!(r.held && !r.flushed);
        assert_eq!(
            r,
            PooledEstimate {
                held: true,
                ..before
            }
        );
        let r = p.push(est(30.0, 0.0052, 0.002)).unwrap();
        assert!(!r.held && !r.flushed);
        // the outlier never entered: with it (its error 15 times theirs) the pooled error
        // would be several times one steady window's
        assert!((r.zeta - 0.005).abs() < 1e-4, "{}", r.zeta);
        assert!(r.windows >= 2 && r.stderr < 0.002, "{r:?}");
        // a held window is forgotten when the pool is emptied
        p.push(est(35.0, 0.12, 0.03)).unwrap();
        p.clear();
        let r = p.push(est(40.0, 0.005, 0.002)).unwrap();
        assert!(!r.flushed && r.windows == 1);
    }

    #[test]
    fn bad_estimates_and_options_are_refused() {
        let mut p = DampingPool::new(PoolOptions::default()).unwrap();
        assert!(p.push(est(0.0, f64::NAN, 0.003)).is_err());
        assert!(p.push(est(0.0, 0.02, 0.0)).is_err());
        assert!(p.is_empty());
        assert!(DampingPool::new(PoolOptions {
            max_windows: 0,
            ..PoolOptions::default()
        })
        .is_err());
        for k in [1.0, 0.5, f64::NAN, f64::INFINITY] {
            let opts = PoolOptions {
                max_level_change: Some(k),
                ..PoolOptions::default()
            };
            assert!(DampingPool::new(opts).is_err(), "{k}");
        }
    }

    /// With `max_level_change`, a window whose RMS moved by more than the factor from an older
    /// one's drops that one and every one before it, whatever its figure: a decay after a
    /// limit cycle (each window a third below the one before, every figure near the pool's) is
    /// pooled only back to where the level was within twice the newest's. A window without a
    /// measured RMS neither drops nor is dropped, and without the option nothing moves.
    #[test]
    fn a_pool_holds_one_level() {
        let at = |t: f64, rms: Option<f64>| WindowEstimate {
            rms,
            ..est(t, 0.01, 0.004)
        };
        let levels = [300.0, 200.0, 133.0, 89.0, 59.0];
        let push_all = |opts: PoolOptions| {
            let mut p = DampingPool::new(opts).unwrap();
            let mut last = None;
            for (k, r) in levels.iter().enumerate() {
                last = Some(p.push(at(5.0 * k as f64, Some(*r))).unwrap());
            }
            (p, last.unwrap())
        };
        // enough cycles wanted that only the level drops a window
        let unbounded = PoolOptions {
            min_cycles: 1000.0,
            ..PoolOptions::default()
        };
        let (mut p, r) = push_all(PoolOptions {
            max_level_change: Some(2.0),
            ..unbounded
        });
        // 59 keeps 89 (1.5 times) and drops 133 (2.25 times) with everything older
        assert_eq!(r.windows, 2, "{r:?}");
        assert!(!r.flushed && !r.held);
        let (_, all) = push_all(unbounded);
        assert_eq!(all.windows, levels.len());
        // an unmeasured window joins and stays; the next measured one is read against the
        // measured ones
        assert_eq!(p.push(at(25.0, None)).unwrap().windows, 3);
        assert_eq!(p.push(at(30.0, Some(60.0))).unwrap().windows, 4);
        // a rise is another level as well: the pool restarts at the rising window
        let r = p.push(at(35.0, Some(130.0))).unwrap();
        assert_eq!(r.windows, 1, "{r:?}");
    }
}
