//! A gate's ambient level, and how far a window stands above it (`docs/damping.md`, "The
//! gate's ambient level").
//!
//! # Why
//! One window cannot always tell a steady noise-driven response from a self-excited one: the
//! window's classifier (`spectral::classify`) calls a window a limit cycle when its envelope is
//! steady and SSI reads about zero damping, which happens by chance on a lightly damped gate
//! (4 % of the windows of a +0.5 % lock gate, whose envelope correlation time is 6 s), and there
//! a free-vibration model read -0.6 to -2.5 % with intervals 0.2 to 0.7 points wide about once an
//! hour. Such a window must not raise an alarm on its own. The gate's history tells the two
//! apart where it matters: a gate that self-excites quickly leaves the level the turbulence drove
//! it to (the first confident windows of the onset ramp stood 3.9 to 8.2 times above it), while
//! those chance windows have the gate's usual level (at most 2.46 times it in 895 windows).
//! [`AmbientLevel`] keeps the median signal RMS of the gate's last noise-driven windows and sets
//! each report's `ambient_ratio`; the alert rule lets one window fire at once only at 3 times the
//! level or more (`alert::AT_ONCE_MIN_AMBIENT_RATIO`).
//!
//! # Why the level does not reclassify windows, but overrules the model below it
//! Tried and measured (session 18): reading a limit-cycle window below 3 times the level as
//! noise-driven removed the chance windows, but a limit cycle reached by a slow drift grows out
//! of an ambient response that is itself large near zero damping (its RMS grows as
//! `1 / sqrt(zeta)`): on the slow drift the cycle stood only 1.5 to 3 times above the level
//! until `zeta0 = -1 %`, SSI read those windows as about zero, and the limit-cycle coverage fell
//! from 90 to 73 % (lab gate) and from 93 to 60 % (lock gate). So a limit-cycle window keeps its
//! regime and its envelope estimate whatever its level.
//!
//! The free-vibration model is another matter (session 19). It decides a window only when the
//! envelope grows significantly or a limit-cycle window has no envelope estimate, and its
//! interval counts the turbulent forcing as measurement error: the chance windows above were
//! all such model windows, -0.6 to -2.5 % with intervals 0.1 to 0.9 points wide, while SSI on
//! the same windows read about zero (e.g. -0.03 % (-0.73, +0.67) beside the model's
//! -2.15 % (-2.58, -1.72)). Below 3 times the level the turbulence is at least a ninth of the
//! window's power, so such a window is read by its ambient estimate instead
//! ([`read_model_window_as_noise_driven`]): the gauge shows what SSI can tell, usually "about
//! zero, cannot tell the sign", instead of a confident self-excitation. Above the level, where a
//! real onset's first confident windows stand (3.9 to 8.2 times), the model keeps deciding.
//!
//! Only windows the ambient estimate decided (regime damped or undecided, trusted) feed the
//! level, never a self-excited or limit-cycle one: the level is the gate's ambient state.

use std::collections::VecDeque;

use super::report::{DampingReport, Verdict, Zeta0Source};
use super::verdict::ambient_decision;
use crate::spectral::Regime;

/// Noise-driven windows the level is the median of: one minute at the daemon's 5 s cadence,
/// long enough for a robust median, short enough to follow a drifting damping (the ambient RMS
/// grows as `1 / sqrt(zeta)`) and to forget the decay after a recovery.
pub const AMBIENT_LEVEL_WINDOWS: usize = 12;

/// Fewest noise-driven windows before the level is used.
pub const AMBIENT_LEVEL_MIN_WINDOWS: usize = 4;

/// How far above its ambient level a window must stand to show that the gate has left its
/// ambient state. Why 3: over 895 windows of a +0.5 % lock gate (`bench warning --scenarios
/// stable-low --gates lock --hours 2`, 10 s windows, 1.5 envelope correlation times each) the
/// ratio's 99th percentile was 2.3 and its largest 2.46, and a gamma law fitted to the windows'
/// mean squares (shape 1.9) puts a ratio of 3 at 2.5e-5 per window, 0.4 windows a day; at 2 it is
/// 300 windows a day. In 24 hours of each gate at +0.5 % no window reached 3 (largest 2.79, lock
/// gate; 2.33, lab gate). The first confident windows of the onset ramp stood 3.9 to 8.2 times above
/// the level, the held cycles 13 to 15 times. A gate with fewer cycles per window (a 2 Hz barrier
/// gate) has a wider ratio distribution: the margin is smaller there.
pub const DEPARTED_FROM_AMBIENT: f64 = 3.0;

/// The median RMS of a gate's last noise-driven windows (bounded: [`AMBIENT_LEVEL_WINDOWS`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AmbientLevel {
    recent: VecDeque<f64>,
    /// Where the previous window's `zeta0` came from (after this memory's own reading).
    previous_source: Option<Zeta0Source>,
    /// The previous window's model-free regime.
    previous_regime: Option<Regime>,
    /// The previous window's `zeta0` interval (after this memory's own reading, before a
    /// widening by [`span_the_change`]: a hull is never taken of a hull).
    previous_interval: Option<(f64, f64)>,
    /// Sample time of the previous window's last sample (`None`: not known).
    previous_end: Option<f64>,
}

impl AmbientLevel {
    /// The level, once [`AMBIENT_LEVEL_MIN_WINDOWS`] noise-driven windows were seen.
    pub fn level(&self) -> Option<f64> {
        if self.recent.len() < AMBIENT_LEVEL_MIN_WINDOWS {
            return None;
        }
        let mut v: Vec<f64> = self.recent.iter().copied().collect();
        crate::identify::median(&mut v)
    }

    /// Sets the report's `ambient_ratio` against the level before this window, then lets a
    /// window the ambient estimate decided (damped or undecided regime, trusted) feed the level.
    /// Call in window order, after the window's verdict and before pooling. Without the
    /// window's span ([`AmbientLevel::observe_span`]) consecutive windows count as overlapping.
    pub fn observe(&mut self, d: &mut DampingReport) {
        self.observe_inner(d, None);
    }

    /// [`AmbientLevel::observe`] for the window covering `[t_start, t_end]` (sample time): the
    /// previous window's reading is spanned by a window that holds two states only when the
    /// two windows overlap (not after a gap, replaced jobs or a long restart).
    pub fn observe_span(&mut self, d: &mut DampingReport, t_start: f64, t_end: f64) {
        self.observe_inner(d, Some((t_start, t_end)));
    }

    fn observe_inner(&mut self, d: &mut DampingReport, span: Option<(f64, f64)>) {
        let previous = self.previous_source.take();
        let overlaps = match (self.previous_end.take(), span) {
            (Some(end), Some((start, _))) => start <= end,
            _ => true,
        };
        self.previous_end = span.map(|(_, end)| end);
        let previous_interval = self.previous_interval.take().filter(|_| overlaps);
        let first_cycle = self
            .previous_regime
            .replace(d.regime.unwrap_or(Regime::Undecided))
            != Some(Regime::LimitCycle)
            && d.regime == Some(Regime::LimitCycle);
        let Some(rms) = d.signal_rms.filter(|r| r.is_finite() && *r > 0.0) else {
            d.ambient_ratio = None;
            self.previous_source = d.zeta0_source;
            self.previous_interval = d.zeta0_interval;
            return;
        };
        d.ambient_ratio = self.level().map(|level| rms / level);
        match d.ambient_ratio {
            Some(r) if r < DEPARTED_FROM_AMBIENT => {
                read_model_window_as_noise_driven(d, first_cycle)
            }
            Some(_) => {
                read_departed_window_by_the_model(d, previous, first_cycle);
                self.previous_interval = d.zeta0_interval;
                span_the_change(d, previous_interval);
                self.previous_source = d.zeta0_source;
                self.record(d);
                return;
            }
            None => {}
        }
        self.previous_source = d.zeta0_source;
        self.previous_interval = d.zeta0_interval;
        self.record(d);
    }

    /// The memory as windows `reports` (oldest first, each with the sample time of its last
    /// sample, as [`AmbientLevel::observe_span`] and the pooling left them, e.g. the stored
    /// history) leave it: what a restart rebuilds. Where it differs from the live memory: the
    /// previous window's interval is the pooled one (the live memory keeps it before pooling),
    /// and none after a window whose interval was widened ([`span_the_change`]; its own is not
    /// stored). Only [`span_the_change`] reads it, for the first window after the restart.
    pub fn resume<'a>(reports: impl IntoIterator<Item = (&'a DampingReport, f64)>) -> AmbientLevel {
        let mut level = AmbientLevel::default();
        for (d, end) in reports {
            level.record(d);
            level.previous_source = d.zeta0_source;
            level.previous_regime = Some(d.regime.unwrap_or(Regime::Undecided));
            level.previous_interval = d.zeta0_interval.filter(|_| !d.spans_change);
            level.previous_end = Some(end);
        }
        level
    }

    /// Lets window `d` feed the level when it is noise-driven ([`decided_by_ambient`]) and its
    /// RMS was measured; nothing else. [`AmbientLevel::observe`] calls it after its own reading;
    /// the tracking memory (`analysis::tracking::Previous`) calls it alone, on the analysis's
    /// report.
    pub fn record(&mut self, d: &DampingReport) {
        let Some(rms) = d.signal_rms.filter(|r| r.is_finite() && *r > 0.0) else {
            return;
        };
        if decided_by_ambient(d) {
            if self.recent.len() == AMBIENT_LEVEL_WINDOWS {
                self.recent.pop_front();
            }
            self.recent.push_back(rms);
        }
    }
}

/// Whether the ambient estimate decided window `d` as noise-driven: a damped or undecided
/// model-free regime, trusted, `zeta0` from the ambient estimate. Only such windows feed a
/// gate's level: the level is the gate's ambient state.
pub fn decided_by_ambient(d: &DampingReport) -> bool {
    matches!(d.regime, Some(Regime::Damped | Regime::Undecided))
        && d.trusted
        && d.zeta0_source == Some(Zeta0Source::Ambient)
}

/// A window the free-vibration model decided (a growing or a limit-cycle window without an
/// envelope estimate), on a gate that has not left its ambient level, takes its `zeta0` from
/// its ambient (SSI-COV) estimate instead, when there is one; the verdict and `trusted` follow
/// that estimate ([`ambient_decision`], row 2 of `analysis::decide`). Other windows are left
/// as they are. See the module's "why": at the ambient level the turbulence is most of the
/// response, which the model's interval counts as measurement error.
///
/// The same holds for the first limit-cycle window after other windows (`first_cycle`) when its
/// envelope decided: on a +0.5 % lock gate 637 of the 685 envelope readings below -0.5 % in a
/// day were such lone windows (a chance limit cycle lasts one window), untrusted but shown on
/// the gauge; a limit cycle the gate stays in keeps its envelope from its second window on.
fn read_model_window_as_noise_driven(d: &mut DampingReport, first_cycle: bool) {
    let source_ok = match d.zeta0_source {
        Some(Zeta0Source::Model) => true,
        Some(Zeta0Source::Envelope) => first_cycle,
        _ => false,
    };
    let (true, Some(a)) = (source_ok, d.ambient_zeta) else {
        return;
    };
    let decision = ambient_decision(a, d.regime);
    d.zeta0 = Some(a.zeta);
    d.zeta0_interval = Some((a.low, a.high));
    d.zeta0_source = Some(decision.source);
    d.verdict = decision.verdict;
    d.trusted = decision.trusted;
}

/// A window the ambient estimate decided, on a gate that has left its ambient level, where the
/// trusted model reads `zeta0 < 0` (with an interval), takes its `zeta0` from the model:
/// `SelfExcited`, trusted, as a growing window does (row 1 of `analysis::decide`). At 3 times
/// the level the gate's own vibration is at least eight ninths of the window's power, so the
/// free-vibration fit is at its best, while SSI-COV on such a fast-growing, non-stationary
/// window is wide and, pooled with the ambient windows before it, lags (the lock gate's onset
/// ramp: pooled +1.28 % (-0.17, +2.73) at a true -0.67 %, `docs/benchmarks.md`).
///
/// A limit-cycle window keeps its envelope estimate, but for the first one after an
/// ambient-decided window (`previous`) or after a window that was no limit cycle
/// (`first_cycle`, e.g. a growing window the model read), when the gate grew onto the cycle
/// inside it (`rms_swing` at least [`GREW_INSIDE_SWING`]): the growth is where the model is at
/// its best, while the envelope's relaxation, fitted across a growth it assumes away, reads too
/// close to zero (the bursts of `bench warning --scenarios bursting`: model -2.78 % (-2.85,
/// -2.72), relaxation -0.92 %, at a true -3 %).
fn read_departed_window_by_the_model(
    d: &mut DampingReport,
    previous: Option<Zeta0Source>,
    first_cycle: bool,
) {
    let Some(m) = d.model_zeta.filter(|m| m.zeta < 0.0) else {
        return;
    };
    let eligible = match d.zeta0_source {
        Some(Zeta0Source::Ambient) => d.regime != Some(Regime::LimitCycle),
        Some(Zeta0Source::Envelope) => {
            (previous == Some(Zeta0Source::Ambient) || first_cycle)
                && d.rms_swing.is_some_and(|s| s >= GREW_INSIDE_SWING)
        }
        _ => false,
    };
    if !eligible {
        return;
    }
    d.zeta0 = Some(m.zeta);
    d.zeta0_interval = Some((m.low, m.high));
    d.zeta0_source = Some(Zeta0Source::Model);
    d.verdict = Verdict::SelfExcited;
    d.trusted = true;
}

/// Smallest [`DampingReport::rms_swing`] of the first limit-cycle window (after an
/// ambient-decided one, or one that was no cycle) for the model to read it
/// ([`read_departed_window_by_the_model`]): the gate grew onto its cycle inside that window. Why 1.25: a held cycle's thirds differ by at most
/// 7 % (swing 1.07 at most, `docs/damping.md`), while the first cycle windows of the bursts and
/// onsets of `bench warning`, which held the growth, swung 1.5 to 4. Below it the growth was
/// in the window before (read by SSI-COV, which missed it), the window is a saturated cycle,
/// and a model fitted to a saturated cycle reads zeta0 near zero with a narrow interval (-0.35 %
/// (-0.80, +0.09) and -0.10 % (-0.32, +0.13) at a true -3 %, swings 1.01 and 1.02, on the lock
/// gate's bursts): the envelope's estimate stands.
pub const GREW_INSIDE_SWING: f64 = 1.25;

/// Smallest [`DampingReport::rms_swing`] of a window that holds two states of the gate. Why 4:
/// on 2 hours of each bench gate at +1 % and +0.5 % the swing's 99th percentile was 3.0 to 3.8
/// (largest 6.6), on a held limit cycle at most 1.07, and on the windows a burst of
/// `bench warning --scenarios bursting` began or ended in 3.9 to 18.6 (`docs/damping.md`, "A
/// window that holds two states"). The noise-driven windows that reach it stay below
/// [`DEPARTED_FROM_AMBIENT`], and only windows above it are tested.
pub const STATE_CHANGE_SWING: f64 = 4.0;

/// A window that left the ambient level, whose response changed abruptly inside it
/// ([`STATE_CHANGE_SWING`]) and whose trusted ambient (SSI-COV) estimate cannot tell the sign
/// (its interval crosses zero), holds two states of the gate: the end of a burst (the limit
/// cycle, then the decay) or its start (the ambient response, then the growth). SSI-COV assumes
/// one stationary state and reads such a window as about zero with a narrow interval
/// (0.04 % (-0.47, +0.55) where the truth went from -3 % to +1 %): a confident reading of a
/// state the gate was never in. The window overlaps the previous one (`previous` is `None`
/// when it does not), which saw the first state; the interval becomes the hull of both
/// (`spans_change`), so it says "somewhere across these" instead. The point and the verdict
/// stay (the widened interval still crosses zero), so the window neither fires nor resolves an
/// alert it would not have; the trend weighs it less.
fn span_the_change(d: &mut DampingReport, previous: Option<(f64, f64)>) {
    let two_states = d.zeta0_source == Some(Zeta0Source::Ambient)
        && d.trusted
        && d.verdict == Verdict::Unknown
        && d.regime != Some(Regime::LimitCycle)
        && d.rms_swing.is_some_and(|s| s >= STATE_CHANGE_SWING);
    let (true, Some((lo, hi)), Some((plo, phi))) = (two_states, d.zeta0_interval, previous) else {
        return;
    };
    if !(lo <= 0.0 && 0.0 <= hi) {
        return; // decided after all (an alarm regime's untrusted Unknown is excluded above)
    }
    d.zeta0_interval = Some((lo.min(plo), hi.max(phi)));
    d.spans_change = true;
}

/// Whether the window stands at least [`DEPARTED_FROM_AMBIENT`] times above the gate's ambient
/// level (set by [`AmbientLevel::observe`]): the gate has left its ambient state.
pub fn departed(d: &DampingReport) -> bool {
    d.ambient_ratio.is_some_and(|r| r >= DEPARTED_FROM_AMBIENT)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::{AmbientZeta, Verdict};

    /// A noise-driven window the ambient estimate decided (trusted, cannot tell the sign).
    fn ambient_window(rms: f64) -> DampingReport {
        let a = AmbientZeta {
            zeta: 0.004,
            low: -0.003,
            high: 0.011,
        };
        DampingReport {
            zeta0: Some(a.zeta),
            zeta0_interval: Some((a.low, a.high)),
            zeta0_source: Some(Zeta0Source::Ambient),
            ambient_zeta: Some(a),
            trusted: true,
            verdict: Verdict::Unknown,
            regime: Some(Regime::Undecided),
            signal_rms: Some(rms),
            fit_nmae: 0.6,
            ..DampingReport::unknown()
        }
    }

    /// A window classified as a limit cycle where a trusted model read -2 % with a narrow
    /// interval (what `bench warning` saw on a +0.5 % lock gate).
    fn limit_cycle_window(rms: f64) -> DampingReport {
        DampingReport {
            zeta0: Some(-0.02),
            zeta0_interval: Some((-0.024, -0.016)),
            zeta0_source: Some(Zeta0Source::Model),
            trusted: true,
            agrees: true,
            fit_nmae: 0.1,
            verdict: Verdict::SelfExcited,
            regime: Some(Regime::LimitCycle),
            signal_rms: Some(rms),
            ..DampingReport::unknown()
        }
    }

    /// The level is the median of the last noise-driven windows, bounded, and none before the
    /// fourth; other windows do not feed it.
    #[test]
    fn the_level_is_the_median_of_the_last_noise_driven_windows() {
        let mut level = AmbientLevel::default();
        for (k, rms) in [5.0, 7.0, 6.0].into_iter().enumerate() {
            let mut d = ambient_window(rms);
            level.observe(&mut d);
            assert_eq!(d.ambient_ratio, None, "no level before window {}", k + 1);
            assert_eq!(level.level(), None, "after {} windows", k + 1);
        }
        level.observe(&mut ambient_window(100.0));
        assert_eq!(level.level(), Some(6.5));
        for _ in 0..AMBIENT_LEVEL_WINDOWS {
            level.observe(&mut ambient_window(2.0));
        }
        assert_eq!(level.recent.len(), AMBIENT_LEVEL_WINDOWS);
        assert_eq!(level.level(), Some(2.0));
        // untrusted, model-decided, growing or limit-cycle windows do not feed it
        let mut untrusted = ambient_window(50.0);
        untrusted.trusted = false;
        let mut model = ambient_window(50.0);
        model.zeta0_source = Some(Zeta0Source::Model);
        let mut growing = ambient_window(50.0);
        growing.regime = Some(Regime::SelfExcited);
        for mut d in [untrusted, model, growing, limit_cycle_window(50.0)] {
            level.observe(&mut d);
            assert_eq!(d.ambient_ratio, Some(25.0));
        }
        assert_eq!(level.level(), Some(2.0));
    }

    /// The ratio is the window's RMS over the level before it, and a window without an ambient
    /// estimate is otherwise unchanged: a model-decided limit-cycle window at the ambient level
    /// has nothing to be read by instead.
    #[test]
    fn the_ratio_is_set_and_nothing_else_changes() {
        let mut level = AmbientLevel::default();
        for rms in [5.0, 6.0, 5.5, 6.5, 5.8] {
            level.observe(&mut ambient_window(rms));
        }
        assert_eq!(level.level(), Some(5.8));
        for ratio in [1.0, 4.0] {
            let mut d = limit_cycle_window(ratio * 5.8);
            level.observe(&mut d);
            assert!((d.ambient_ratio.unwrap() - ratio).abs() < 1e-12);
            d.ambient_ratio = None;
            assert_eq!(d, limit_cycle_window(ratio * 5.8));
        }
        let mut no_rms = limit_cycle_window(1.0);
        no_rms.signal_rms = None;
        level.observe(&mut no_rms);
        assert_eq!(no_rms.ambient_ratio, None);
    }

    /// A model-decided window (or the first limit-cycle window, envelope-decided) below
    /// `DEPARTED_FROM_AMBIENT` times the level is read by its ambient estimate (verdict by row 2: across zero `Unknown` trusted, above zero on an alarm
    /// regime `Unknown` untrusted, below zero `SelfExcited`); at or above it, without a level,
    /// or when the envelope decided, the window is unchanged.
    #[test]
    fn a_model_window_at_the_ambient_level_is_read_by_its_ambient_estimate() {
        let ssi = |zeta: f64, low: f64, high: f64| AmbientZeta { zeta, low, high };
        let with_ssi = |rms: f64, regime: Regime, a: AmbientZeta| DampingReport {
            ambient_zeta: Some(a),
            regime: Some(regime),
            ..limit_cycle_window(rms)
        };
        let cases = [
            // (ratio, regime, SSI, expected verdict, trusted)
            (
                1.5,
                Regime::LimitCycle,
                ssi(-0.0003, -0.0073, 0.0067),
                Verdict::Unknown,
                true,
            ),
            (
                2.9,
                Regime::SelfExcited,
                ssi(0.004, 0.001, 0.007),
                Verdict::Unknown,
                false,
            ),
            (
                1.2,
                Regime::SelfExcited,
                ssi(-0.01, -0.02, -0.002),
                Verdict::SelfExcited,
                true,
            ),
        ];
        for (ratio, regime, a, verdict, trusted) in cases {
            let mut d = with_ssi(ratio * 5.0, regime, a);
            primed_at_5().observe(&mut d);
            assert_eq!(d.zeta0, Some(a.zeta), "ratio {ratio}, {regime:?}");
            assert_eq!(d.zeta0_interval, Some((a.low, a.high)));
            assert_eq!(d.zeta0_source, Some(Zeta0Source::Ambient));
            assert_eq!((d.verdict, d.trusted), (verdict, trusted), "ratio {ratio}");
            assert_eq!(d.regime, Some(regime), "the regime is kept");
        }
        let unchanged = |mut d: DampingReport, level: &mut AmbientLevel| {
            let before = d.clone();
            level.observe(&mut d);
            d.ambient_ratio = None;
            assert_eq!(d, before);
        };
        let a = ssi(-0.0003, -0.0073, 0.0067);
        unchanged(
            with_ssi(3.0 * 5.0, Regime::LimitCycle, a),
            &mut primed_at_5(),
        );
        unchanged(
            with_ssi(1.0, Regime::LimitCycle, a),
            &mut AmbientLevel::default(),
        );
        // an envelope window: the first limit-cycle window after others is read by SSI, the
        // second one keeps its envelope estimate
        let envelope = || DampingReport {
            zeta0: Some(-0.02),
            zeta0_interval: Some((-0.045, 0.005)),
            zeta0_source: Some(Zeta0Source::Envelope),
            trusted: false,
            verdict: Verdict::Unknown,
            ..with_ssi(5.0, Regime::LimitCycle, a)
        };
        let mut level = primed_at_5();
        let mut first = envelope();
        level.observe(&mut first);
        assert_eq!(first.zeta0, Some(a.zeta));
        assert_eq!(first.zeta0_source, Some(Zeta0Source::Ambient));
        assert_eq!((first.verdict, first.trusted), (Verdict::Unknown, true));
        unchanged(envelope(), &mut level);
    }

    /// An ambient-decided window 3 or more times above the level, where the trusted model reads
    /// zeta0 < 0, takes the model's zeta0 and interval (self-excited, trusted); below the level,
    /// with a non-negative or no model, or on a limit-cycle window it is unchanged.
    #[test]
    fn a_window_that_left_the_ambient_level_is_read_by_a_trusted_negative_model() {
        let model = |zeta: f64| {
            Some(AmbientZeta {
                zeta,
                low: zeta - 0.001,
                high: zeta + 0.001,
            })
        };
        let window = |rms: f64, m: Option<AmbientZeta>| DampingReport {
            model_zeta: m,
            ..ambient_window(rms)
        };
        let m = model(-0.0127).unwrap();
        let mut d = window(3.0 * 5.0, Some(m));
        primed_at_5().observe(&mut d);
        assert_eq!(d.zeta0, Some(m.zeta));
        assert_eq!(d.zeta0_interval, Some((m.low, m.high)));
        assert_eq!(d.zeta0_source, Some(Zeta0Source::Model));
        assert_eq!((d.verdict, d.trusted), (Verdict::SelfExcited, true));
        assert_eq!(
            level_after(primed_at_5(), &mut d.clone()),
            4,
            "it does not feed the level"
        );
        let unchanged = |mut d: DampingReport| {
            let before = d.clone();
            primed_at_5().observe(&mut d);
            d.ambient_ratio = None;
            assert_eq!(d, before);
        };
        unchanged(window(2.9 * 5.0, model(-0.0127)));
        unchanged(window(4.0 * 5.0, model(0.004)));
        unchanged(window(4.0 * 5.0, None));
        unchanged(DampingReport {
            regime: Some(Regime::LimitCycle),
            ..window(4.0 * 5.0, model(-0.0127))
        });
    }

    /// The first limit-cycle window after an ambient-decided one, 3 or more times above the
    /// level, takes a trusted negative model's zeta0 when the growth is inside it (its thirds'
    /// RMS differ); a later one, one after a model window, or a saturated one keeps its
    /// envelope estimate.
    #[test]
    fn the_first_limit_cycle_window_after_the_ambient_state_is_read_by_the_model() {
        let m = AmbientZeta {
            zeta: -0.0278,
            low: -0.0285,
            high: -0.0272,
        };
        let envelope = || DampingReport {
            zeta0: Some(-0.0092),
            zeta0_interval: Some((-0.0205, 0.0022)),
            zeta0_source: Some(Zeta0Source::Envelope),
            regime: Some(Regime::LimitCycle),
            model_zeta: Some(m),
            signal_rms: Some(60.0),
            rms_swing: Some(2.7),
            ..DampingReport::unknown()
        };
        let mut level = primed_at_5();
        let mut first = envelope();
        level.observe(&mut first);
        assert_eq!(first.zeta0, Some(m.zeta));
        assert_eq!(first.zeta0_source, Some(Zeta0Source::Model));
        assert_eq!((first.verdict, first.trusted), (Verdict::SelfExcited, true));
        let mut second = envelope();
        level.observe(&mut second);
        assert_eq!(
            second.zeta0_source,
            Some(Zeta0Source::Envelope),
            "after a model window"
        );
        let mut third = envelope();
        level.observe(&mut third);
        assert_eq!(third.zeta0, Some(-0.0092), "after an envelope window");
        // a first cycle window that is already saturated (the growth was in the window before)
        let saturated = || DampingReport {
            rms_swing: Some(1.02),
            ..envelope()
        };
        let mut level = primed_at_5();
        let mut steady = saturated();
        level.observe(&mut steady);
        assert_eq!(
            (steady.zeta0, steady.zeta0_source),
            (Some(-0.0092), Some(Zeta0Source::Envelope)),
            "no growth inside it"
        );
        let mut no_swing = DampingReport {
            rms_swing: None,
            ..envelope()
        };
        primed_at_5().observe(&mut no_swing);
        assert_eq!(no_swing.zeta0_source, Some(Zeta0Source::Envelope));
    }

    /// A window 3 or more times above the level, whose thirds' RMS differ by
    /// `STATE_CHANGE_SWING` or more and whose ambient estimate cannot tell the sign, widens its
    /// interval to the hull with the previous window's (point and verdict kept); a steadier
    /// window, one below the level, a decided one, or one without a previous interval is
    /// unchanged.
    #[test]
    fn a_window_that_holds_two_states_spans_the_previous_reading() {
        // the end of a burst: the previous window read the limit cycle, this one SSI's ~0
        let previous = || DampingReport {
            zeta0: Some(-0.0207),
            zeta0_interval: Some((-0.0381, -0.0033)),
            zeta0_source: Some(Zeta0Source::Envelope),
            regime: Some(Regime::LimitCycle),
            signal_rms: Some(75.0),
            ..DampingReport::unknown()
        };
        let straddling = |rms: f64, swing: f64| DampingReport {
            rms_swing: Some(swing),
            ..ambient_window(rms)
        };
        let observed = |d: &mut DampingReport| {
            let mut level = primed_at_5();
            level.observe(&mut previous());
            level.observe(d);
        };
        let mut d = straddling(56.0, 12.4);
        observed(&mut d);
        assert_eq!(d.zeta0_interval, Some((-0.0381, 0.011)));
        assert!(d.spans_change);
        assert_eq!(
            (d.zeta0, d.verdict, d.trusted),
            (Some(0.004), Verdict::Unknown, true)
        );
        assert_eq!(d.zeta0_source, Some(Zeta0Source::Ambient));

        let unchanged = |mut d: DampingReport| {
            let before = d.clone();
            observed(&mut d);
            assert_eq!(d.zeta0_interval, before.zeta0_interval, "{before:?}");
            assert!(!d.spans_change);
        };
        unchanged(straddling(56.0, STATE_CHANGE_SWING - 0.01));
        unchanged(straddling(2.9 * 5.0, 12.4));
        unchanged(DampingReport {
            rms_swing: None,
            ..straddling(56.0, 12.4)
        });
        // a decided window (its interval above zero) keeps it: a decay read by SSI is right
        unchanged(DampingReport {
            zeta0_interval: Some((0.002, 0.02)),
            verdict: Verdict::Damped,
            ..straddling(56.0, 12.4)
        });
        unchanged(DampingReport {
            regime: Some(Regime::LimitCycle),
            ..straddling(56.0, 12.4)
        });
        // nothing to span without a previous window's interval
        let mut level = primed_at_5();
        let mut bare = previous();
        bare.zeta0_interval = None;
        level.observe(&mut bare);
        let mut d = straddling(56.0, 12.4);
        level.observe(&mut d);
        assert_eq!(d.zeta0_interval, Some((-0.003, 0.011)));
        assert!(!d.spans_change);
        // an untrusted Unknown (an alarm regime's interval above zero) is no two-state window
        unchanged(DampingReport {
            zeta0_interval: Some((0.002, 0.02)),
            trusted: false,
            ..straddling(56.0, 12.4)
        });
    }

    /// The previous reading is spanned only when the windows overlap, and a widened interval is
    /// not what the next window spans (no hull of a hull).
    #[test]
    fn only_an_overlapping_previous_window_is_spanned_and_never_a_hull() {
        let lc = DampingReport {
            zeta0_interval: Some((-0.038, -0.003)),
            zeta0_source: Some(Zeta0Source::Envelope),
            regime: Some(Regime::LimitCycle),
            signal_rms: Some(75.0),
            ..DampingReport::unknown()
        };
        let straddling = || DampingReport {
            rms_swing: Some(12.0),
            ..ambient_window(56.0)
        };
        // [0, 10] then [5, 15]: overlapping; [0, 10] then [11, 21]: a gap
        for (start, spanned) in [(5.0, true), (10.0, true), (11.0, false)] {
            let mut level = primed_at_5();
            level.observe_span(&mut lc.clone(), 0.0, 10.0);
            let mut d = straddling();
            level.observe_span(&mut d, start, start + 10.0);
            assert_eq!(d.spans_change, spanned, "start {start}");
        }
        let mut level = primed_at_5();
        level.observe_span(&mut lc.clone(), 0.0, 10.0);
        let mut first = straddling();
        level.observe_span(&mut first, 5.0, 15.0);
        assert_eq!(first.zeta0_interval, Some((-0.038, 0.011)));
        let mut second = straddling();
        level.observe_span(&mut second, 10.0, 20.0);
        assert_eq!(
            second.zeta0_interval,
            Some((-0.003, 0.011)),
            "the hull of its own and the first window's own interval"
        );
    }

    /// Resumed from the reports `observe` left, the memory is the one `observe` built: the same
    /// level, and the same reading of the next window (the first limit-cycle window after
    /// ambient ones is read by SSI; a departed window that holds two states spans the previous
    /// window's interval).
    #[test]
    fn resumed_from_the_reports_the_memory_reads_the_next_window_alike() {
        let mut live = AmbientLevel::default();
        let mut reports = Vec::new();
        for (k, rms) in [5.0, 6.0, 5.5, 6.5, 5.8, 50.0].into_iter().enumerate() {
            let mut d = ambient_window(rms);
            let start = 5.0 * k as f64;
            live.observe_span(&mut d, start, start + 10.0);
            reports.push((d, start + 10.0));
        }
        let mut resumed = AmbientLevel::resume(reports.iter().map(|(d, end)| (d, *end)));
        assert_eq!(resumed, live);
        // the median of the six (the departed one is ambient-decided: it feeds the level)
        assert_eq!(resumed.level(), Some(5.9));
        let next = || DampingReport {
            rms_swing: Some(10.0),
            ..ambient_window(40.0)
        };
        let (mut a, mut b) = (next(), next());
        live.observe_span(&mut a, 30.0, 40.0);
        resumed.observe_span(&mut b, 30.0, 40.0);
        assert_eq!(a, b);
        assert!(a.spans_change);
        assert_eq!(
            AmbientLevel::resume(std::iter::empty()),
            AmbientLevel::default()
        );
    }

    /// A level of 5.0 from the fewest ambient windows that set one.
    fn primed_at_5() -> AmbientLevel {
        let mut level = AmbientLevel::default();
        for _ in 0..AMBIENT_LEVEL_MIN_WINDOWS {
            level.observe(&mut ambient_window(5.0));
        }
        level
    }

    /// Windows feeding the level after `d` was observed.
    fn level_after(mut level: AmbientLevel, d: &mut DampingReport) -> usize {
        level.observe(d);
        level.recent.len()
    }
}
