//! zeta0 on a limit cycle from the cycle's amplitude and the damping law the gate's last growth
//! identified (`docs/damping.md`, "The cycle's amplitude").
//!
//! # Why
//! On a limit cycle the equivalent damping is zero at the cycle's amplitude:
//! `zeta_eq(A) = zeta0 + b A^p = 0`. Everything that reads "the damping now" reads about zero
//! there, and the envelope's relaxation, which still sees zeta0, reads ten seconds of it with a
//! spread of half a point and a compression towards -1.5 % (-3 % read as -2.3 %, `docs/damping.md`,
//! "What it reads away from -2 %"). The window that grew into the cycle is where a free-vibration
//! fit is at its best (the growth dominates the forcing), and its model holds `b`, the damping's
//! amplitude dependence: `b = -zeta0_g / A*^p`, with `A*` its own limit-cycle amplitude. The cycle
//! then reads `zeta0 = -b A^p = zeta0_g (A / A*)^p` from its amplitude, which ten seconds
//! measure to a percent or so. Measured (`explore_cycle_amplitude` in `tests/damping_regimes.rs`,
//! 12 seeds, three held windows each): at -3 % the lab gate's held cycle is read within a median
//! 0.15 points (envelope 0.66), the lock gate's within 0.21 (0.58).
//!
//! What it assumes, and the guards:
//! - `b` is the gate's own: it is carried from the last growth, in sample time at most
//!   [`LAW_MAX_AGE_SECONDS`], and a reading that disagrees with the envelope's (their difference
//!   beyond 1.96 standard errors of it) is not used: the envelope decides alone, as before;
//! - the growth window's model decided it and reached its cycle
//!   (`DampingReport::growth_law_zeta`, set by the window's analysis:
//!   `analysis::GROWTH_MIN_REACH`), so its fit saw the non-linear damping it carries. Its interval
//!   is that of `b` itself (`linearisation::cycle_zeta0` at the model's cycle, under the forcing:
//!   the Newey-West one covered 3 of 8 growths at -3 %, `docs/benchmarks.md`), not zeta0's: a
//!   law carried with zeta0's interval covered 62 of 192 windows of the lock gate's onset (stop
//!   72), its non-linear term as uncertain as the rest;
//! - the growth window read one damping: it grew, or the regime read it as a cycle whose envelope
//!   did not still rise over it (`saw_one_damping`; a cycle still pushed out across a window is an
//!   onset's ramp, whose model reads the ramp's average, and such a window drops the gate's
//!   earlier law, read earlier on the same ramp);
//! - the cycle is where that model said it would settle (within [`LAW_AMPLITUDE_TOLERANCE`]),
//!   and no later window read by its prediction errors contradicts the law (`contradicted`): the
//!   damping has not moved since (`docs/damping.md`, "A law from one damping");
//! - the exponent `p` is the envelope estimators' (2: cubic velocity damping, Van der Pol).
//!
//! The carried interval is widened by [`LAW_INTERVAL_INFLATION`] (the forcing interval's measured
//! coverage on growths), and the two readings are combined by their inverse variances. The carried one is shared by every
//! window of a cycle, so it is combined after the envelope's pool, never pooled itself.

use super::falling_cycle::HeldCycle;
use super::report::{AmbientZeta, DampingReport, Verdict, Zeta0Source};
use crate::spectral::{normal_quantile, Regime};

/// Sample seconds a growth's damping law is carried: half an hour. The law is the gate's
/// non-linearity, which changes with the flow; a burst every few minutes renews it.
pub const LAW_MAX_AGE_SECONDS: f64 = 1800.0;

/// How far the cycle's amplitude may lie from the limit-cycle amplitude the growth's model
/// predicted, as a fraction of it, for the law to be used: the cycle settled where the growth
/// said it would, so the damping has not moved since (on an onset's ramp the cycle keeps
/// growing past the amplitude of a window's model, whose constant coefficients read the moving
/// cycle too close to zero).
pub const LAW_AMPLITUDE_TOLERANCE: f64 = 0.1;

/// Factor on the growth window's interval (about its reading) before it is carried: the interval
/// under the forcing covered 80 of 92 growths into a cycle (`explore_model_interval_calibration`,
/// docs/benchmarks.md, "The forcing through the model"), 87 %, the coverage of `+- 1.51 sd`;
/// `1.96 / 1.51 = 1.3` makes it the nominal 95 %. The carried reading is shared by every window
/// of the cycle, so its error is not averaged away by the pool: without the factor the step
/// scenario's held cycles were covered 89 to 90 % (6 seeds), their errors unchanged.
pub const LAW_INTERVAL_INFLATION: f64 = 1.3;

/// The damping law of the gate's last growth.
#[derive(Debug, Clone, Copy, PartialEq)]
struct GrowthLaw {
    /// The growth window's model zeta0 with its 95 % interval.
    zeta0: AmbientZeta,
    /// Its model's limit-cycle amplitude, in the signal's unit.
    limit_cycle: f64,
    /// Sample time of the growth window's end.
    t_end: f64,
}

impl GrowthLaw {
    /// The carried reading at the scale `(A / A*)^p`: the growth's reading with its interval
    /// widened about it by [`LAW_INTERVAL_INFLATION`], then scaled.
    fn carried(&self, scale: f64) -> AmbientZeta {
        let z = self.zeta0;
        AmbientZeta {
            zeta: z.zeta * scale,
            low: (z.zeta - LAW_INTERVAL_INFLATION * (z.zeta - z.low)) * scale,
            high: (z.zeta + LAW_INTERVAL_INFLATION * (z.high - z.zeta)) * scale,
        }
    }
}

/// A gate's memory of the damping law its last growth identified (bounded: one law).
#[derive(Debug, Clone, PartialEq)]
pub struct CycleAmplitude {
    law: Option<GrowthLaw>,
    /// The gate's last steady cycle, whose law reads a fall ([`Self::read_fall`]).
    held: Option<HeldCycle>,
    exponent: f64,
}

impl Default for CycleAmplitude {
    fn default() -> Self {
        CycleAmplitude {
            law: None,
            held: None,
            exponent: crate::spectral::RelaxationOptions::default().exponent,
        }
    }
}

impl CycleAmplitude {
    /// The memory after a gate's stored reports (oldest first, with their windows' ends in
    /// sample time), as the daemon left them: the law of the last growth among them (the
    /// stored reports are the final ones, after this memory's own reading).
    pub fn resume<'a>(reports: impl IntoIterator<Item = (&'a DampingReport, f64)>) -> Self {
        let mut memory = CycleAmplitude::default();
        for (d, t_end) in reports {
            memory.follow_law(t_end, d);
            if let Some(held) = HeldCycle::of(t_end, d) {
                memory.held = Some(held);
            }
        }
        memory
    }

    /// The law after the window ending at `t_end`: a growth window that read one damping brings
    /// its law; one whose cycle was still pushed out ([`saw_one_damping`]), or a reading that
    /// contradicts the law ([`contradicted`]), drops it, since the damping is still moving (an
    /// earlier window of the same ramp read an older damping still). Returns whether the window
    /// was a growth window or dropped the law (then it is not read through a law).
    fn follow_law(&mut self, t_end: f64, d: &DampingReport) -> bool {
        if let Some(law) = growth_law(t_end, d) {
            self.law = saw_one_damping(d).then_some(law);
            return true;
        }
        if self.law.is_some_and(|l| contradicted(l, d)) {
            self.law = None;
            return true;
        }
        false
    }

    /// Reads the final report of the window ending at `t_end` (sample time), after
    /// [`Self::observe`]: a steady cycle is remembered ([`HeldCycle`]); a limit-cycle window read
    /// as a cycle whose envelope fell is read through the last held cycle's law, in sample time at
    /// most [`LAW_MAX_AGE_SECONDS`] back (`zeta0_source = "amplitude"`, its own reading: one
    /// window, the verdict by its interval as the envelope's rows of `decide` read it, and the
    /// trend reads it). Returns whether it read the fall; where it did not, the daemon spans the
    /// fall's two readings instead ([`super::span_the_fall`]). `docs/damping.md`, "A falling
    /// cycle read through the cycle it held".
    pub fn read_fall(&mut self, t_end: f64, d: &mut DampingReport) -> bool {
        if let Some(held) = HeldCycle::of(t_end, d) {
            self.held = Some(held);
            return false;
        }
        let Some(held) = self.held.filter(|h| t_end - h.t_end <= LAW_MAX_AGE_SECONDS) else {
            return false;
        };
        let Some(z) = held.read_fall(d, self.exponent) else {
            return false;
        };
        d.zeta0 = Some(z.zeta);
        d.zeta0_interval = Some((z.low, z.high));
        d.zeta0_source = Some(Zeta0Source::Amplitude);
        d.amplitude_zeta = Some(z);
        d.zeta0_windows = Some(1);
        d.pooled_zeta = None;
        // read through this window's amplitude: it stands for the window
        (d.zeta0_lag_seconds, d.pooled_lag_seconds) = (None, None);
        (d.verdict, d.trusted) = if z.high < 0.0 {
            (Verdict::SelfExcited, true)
        } else {
            (Verdict::Unknown, false)
        };
        true
    }

    /// Reads the report of the window ending at `t_end` (sample time), after the envelope's
    /// pool: a growth window's model is remembered; on a limit-cycle window read by its envelope
    /// the cycle's amplitude gives a second reading (`amplitude_zeta`), and where the two agree
    /// `zeta0`, its interval, the verdict and `trusted` become their combination
    /// (`zeta0_source = "amplitude"`).
    pub fn observe(&mut self, t_end: f64, d: &mut DampingReport) {
        if self.follow_law(t_end, d) {
            return;
        }
        let Some(law) = self.law.filter(|l| t_end - l.t_end <= LAW_MAX_AGE_SECONDS) else {
            return;
        };
        if d.zeta0_source != Some(Zeta0Source::Envelope) || d.regime != Some(Regime::LimitCycle) {
            return;
        }
        let Some(rms) = d.signal_rms.filter(|r| r.is_finite() && *r > 0.0) else {
            return;
        };
        // A sine of amplitude A has the RMS A / sqrt(2); the sensor's noise adds a fraction of a
        // percent at a cycle's level.
        let ratio = rms * std::f64::consts::SQRT_2 / law.limit_cycle;
        if (ratio - 1.0).abs() > LAW_AMPLITUDE_TOLERANCE {
            return;
        }
        let carried = law.carried(ratio.powf(self.exponent));
        if !(carried.zeta.is_finite() && carried.low.is_finite() && carried.high.is_finite()) {
            return;
        }
        d.amplitude_zeta = Some(carried);
        let (Some(z), Some((lo, hi))) = (d.zeta0, d.zeta0_interval) else {
            return;
        };
        let Some((zeta, interval)) = combine((z, lo, hi), carried) else {
            return;
        };
        d.zeta0 = Some(zeta);
        d.zeta0_interval = Some(interval);
        d.zeta0_source = Some(Zeta0Source::Amplitude);
        // read through this window's amplitude: it stands for the window
        d.zeta0_lag_seconds = None;
        // a lone limit-cycle window stays no evidence on its own (`ZetaPools::apply`); a pooled
        // one is read as the envelope's rows of `decide` read it
        if d.zeta0_windows != Some(1) {
            (d.verdict, d.trusted) = if interval.1 < 0.0 {
                (Verdict::SelfExcited, true)
            } else {
                (Verdict::Unknown, false)
            };
        }
    }
}

/// The law a report carries: its `growth_law_zeta` (set by the window's analysis on a window
/// that may have grown into its cycle: the model's zeta0 with the interval of its non-linear
/// damping at its limit cycle) with its model's limit-cycle amplitude, where the model decided
/// the window in the end (trusted), or read it below zero and gave way to the prediction-error
/// reading, below zero too. A report stored before that field existed carries no law.
fn growth_law(t_end: f64, d: &DampingReport) -> Option<GrowthLaw> {
    // a window whose confident model gave way to the prediction-error reading, both below zero
    // (`read_departed_window_by_prediction_errors`), was the model's growth all the same
    let model_read_it = d.zeta0_source == Some(Zeta0Source::Model)
        || (d.zeta0_source == Some(Zeta0Source::PredictionError)
            && d.model_zeta.is_some_and(|m| m.high < 0.0));
    if !(d.trusted && model_read_it) {
        return None;
    }
    let zeta0 = d.growth_law_zeta?;
    let limit_cycle = d
        .limit_cycle_amplitude
        .filter(|a| a.is_finite() && *a > 0.0)?;
    Some(GrowthLaw {
        zeta0,
        limit_cycle,
        t_end,
    })
}

/// Whether a growth window's model may have read one damping, the law's premise: a growing
/// window, or a window its regime reads as a cycle whose envelope did not still rise over it
/// (by [`super::FALLING_SIGMAS`] standard errors): a burst that grew in its first seconds and
/// then held its cycle. A window read as a cycle whose envelope still rose is a cycle still
/// pushed out across the window: on an onset's ramp the damping went on falling, and the
/// window's constant-coefficient model read its average, too close to zero (the 2 Hz barrier
/// gate's onset: 13 of 17 laws from such windows, reading -0.8 to -1.4 % of a -2 % cycle).
/// `docs/damping.md`, "A law from one damping".
fn saw_one_damping(d: &DampingReport) -> bool {
    match d.regime {
        Some(Regime::SelfExcited) => true,
        Some(Regime::LimitCycle) => match (d.growth_rate, d.growth_rate_stderr) {
            (Some(g), Some(se)) => !super::falls(-g, se),
            _ => true,
        },
        _ => false,
    }
}

/// Whether a later window's own reading of zeta0 contradicts the law: a trusted window read by
/// its prediction errors (a growth the model did not carry a law for, or the saturation after
/// it), whose reading and the law's carried one (widened by [`LAW_INTERVAL_INFLATION`]) differ
/// by more than 1.96 standard errors of their difference. The law holds the growth window's
/// damping at rest, and a window read by its prediction errors reads the damping at rest now;
/// where they differ the damping moved since the law's window (an onset's ramp whose window
/// the model read as one constant damping, too close to zero: `docs/damping.md`, "A law from
/// one damping").
fn contradicted(law: GrowthLaw, d: &DampingReport) -> bool {
    if !(d.trusted && d.zeta0_source == Some(Zeta0Source::PredictionError)) {
        return false;
    }
    let (Some(z), Some((lo, hi))) = (d.zeta0, d.zeta0_interval) else {
        return false;
    };
    standard_errors((z, lo, hi), law.carried(1.0)).is_some_and(|(_, _, differ)| differ)
}

/// The standard errors of a reading `(zeta, low, high)` and a carried one (each interval's half
/// width over 1.96), and whether the two differ: their difference beyond 1.96 standard errors of
/// it. `None` when an interval is empty.
fn standard_errors((z, lo, hi): (f64, f64, f64), c: AmbientZeta) -> Option<(f64, f64, bool)> {
    let q = normal_quantile(0.975);
    let se_e = (hi - lo) / (2.0 * q);
    let se_c = (c.high - c.low) / (2.0 * q);
    if !(se_e > 0.0 && se_c > 0.0) {
        return None;
    }
    let differ = (z - c.zeta).abs() > q * (se_e * se_e + se_c * se_c).sqrt();
    Some((se_e, se_c, differ))
}

/// The inverse-variance combination of the envelope's `(zeta, low, high)` and the carried
/// reading, with its 95 % interval; `None` when they disagree (difference beyond 1.96 standard
/// errors of it) or an interval is empty. Each interval's half width over 1.96 is its standard
/// error (the envelope's is normal; the model's may be a wider t interval, on the safe side).
fn combine((z, lo, hi): (f64, f64, f64), c: AmbientZeta) -> Option<(f64, (f64, f64))> {
    let (se_e, se_c, differ) = standard_errors((z, lo, hi), c)?;
    if differ {
        return None;
    }
    let q = normal_quantile(0.975);
    let (w_e, w_c) = (1.0 / (se_e * se_e), 1.0 / (se_c * se_c));
    let zeta = (w_e * z + w_c * c.zeta) / (w_e + w_c);
    let half = q / (w_e + w_c).sqrt();
    Some((zeta, (zeta - half, zeta + half)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const A_STAR: f64 = 50.0;

    /// A trusted growth window at `zeta` (+- `half` under the forcing), its model's cycle at
    /// [`A_STAR`].
    fn growth(zeta: f64, half: f64) -> DampingReport {
        DampingReport {
            zeta0: Some(zeta),
            zeta0_interval: Some((zeta - half / 2.0, zeta + half / 2.0)),
            zeta0_source: Some(Zeta0Source::Model),
            growth_zeta: Some(AmbientZeta {
                zeta,
                low: zeta - half / 2.0,
                high: zeta + half / 2.0,
            }),
            growth_law_zeta: Some(AmbientZeta {
                zeta,
                low: zeta - half,
                high: zeta + half,
            }),
            limit_cycle_amplitude: Some(A_STAR),
            amplitude: Some(0.9 * A_STAR),
            regime: Some(Regime::SelfExcited),
            trusted: true,
            verdict: Verdict::SelfExcited,
            ..DampingReport::unknown()
        }
    }

    /// A limit-cycle window of amplitude `amp` read by its envelope at `zeta` (+- `half`), pooled
    /// over `windows`.
    fn cycle(amp: f64, zeta: f64, half: f64, windows: usize) -> DampingReport {
        let trusted = windows > 1 && zeta + half < 0.0;
        DampingReport {
            zeta0: Some(zeta),
            zeta0_interval: Some((zeta - half, zeta + half)),
            zeta0_source: Some(Zeta0Source::Envelope),
            zeta0_windows: Some(windows),
            signal_rms: Some(amp / std::f64::consts::SQRT_2),
            regime: Some(Regime::LimitCycle),
            trusted,
            verdict: if trusted {
                Verdict::SelfExcited
            } else {
                Verdict::Unknown
            },
            ..DampingReport::unknown()
        }
    }

    #[test]
    fn a_cycle_is_read_from_its_amplitude_and_the_growth_before_it() {
        let mut memory = CycleAmplitude::default();
        let mut g = growth(-0.03, 0.004);
        memory.observe(70.0, &mut g);
        // the growth window itself is not changed
        assert_eq!(g, growth(-0.03, 0.004));
        // the carried reading is the growth's interval under the forcing (not the reported one),
        // widened by LAW_INTERVAL_INFLATION; the envelope reads -2.3 % +- 0.8 on the cycle at A*: the combination lies between, much
        // nearer the narrower carried reading, and is narrower than either
        let mut d = cycle(A_STAR, -0.023, 0.008, 3);
        memory.observe(90.0, &mut d);
        let c = d.amplitude_zeta.expect("carried reading");
        let width = 0.008 * LAW_INTERVAL_INFLATION;
        assert!((c.zeta + 0.03).abs() < 1e-12 && (c.high - c.low - width).abs() < 1e-12);
        assert_eq!(d.zeta0_source, Some(Zeta0Source::Amplitude));
        let z = d.zeta0.unwrap();
        let (lo, hi) = d.zeta0_interval.unwrap();
        assert!(
            -0.03 < z && z < -0.023 && (z + 0.03).abs() < (z + 0.023).abs(),
            "{z}"
        );
        assert!(hi - lo < width && lo < z && z < hi, "({lo}, {hi})");
        assert!(d.trusted && d.verdict == Verdict::SelfExcited);
        // 5 % more amplitude is 10 % more damping (p = 2): the cycle is larger because zeta0 is
        let mut d = cycle(1.05 * A_STAR, -0.03, 0.008, 3);
        memory.observe(95.0, &mut d);
        let c = d.amplitude_zeta.unwrap();
        assert!((c.zeta + 0.03 * 1.05 * 1.05).abs() < 1e-12, "{c:?}");
        assert_eq!(d.zeta0_source, Some(Zeta0Source::Amplitude));
        // a cycle far from where the growth said it would settle: the damping moved since
        for amp in [0.85 * A_STAR, 1.15 * A_STAR, 2.0 * A_STAR] {
            let before = cycle(amp, -0.03, 0.008, 3);
            let mut d = before.clone();
            memory.observe(100.0, &mut d);
            assert_eq!(d, before, "amplitude {amp}");
        }
    }

    #[test]
    fn a_reading_that_disagrees_leaves_the_envelope_alone() {
        let mut memory = CycleAmplitude::default();
        memory.observe(70.0, &mut growth(-0.03, 0.002));
        let before = cycle(A_STAR, -0.01, 0.004, 3);
        let mut d = before.clone();
        memory.observe(90.0, &mut d);
        assert!(d.amplitude_zeta.is_some());
        assert_eq!(
            DampingReport {
                amplitude_zeta: None,
                ..d
            },
            before
        );
    }

    #[test]
    fn only_a_window_with_a_growth_reading_is_carried() {
        // the window's analysis sets `growth_law_zeta` (`series::grew_into_cycle`); a model
        // window without it (a growth far below its cycle, a law whose interval reaches zero, a
        // report stored before the field) carries nothing
        for g in [
            DampingReport {
                growth_law_zeta: None,
                ..growth(-0.03, 0.004)
            },
            DampingReport {
                limit_cycle_amplitude: None,
                ..growth(-0.03, 0.004)
            },
        ] {
            let mut memory = CycleAmplitude::default();
            memory.observe(70.0, &mut g.clone());
            let mut d = cycle(A_STAR, -0.025, 0.008, 3);
            memory.observe(90.0, &mut d);
            assert_eq!(d.amplitude_zeta, None, "{g:?}");
            assert_eq!(d.zeta0_source, Some(Zeta0Source::Envelope));
        }
    }

    /// A growth window whose confident model gave way to the prediction-error reading (both
    /// below zero) carries the model's law all the same; one whose model did not read it below
    /// zero carries nothing.
    #[test]
    fn a_growth_shown_by_its_prediction_errors_carries_the_models_law() {
        let shown = |model_high: f64| {
            let g = growth(-0.03, 0.004);
            DampingReport {
                zeta0: Some(-0.01),
                zeta0_interval: Some((-0.02, -0.002)),
                zeta0_source: Some(Zeta0Source::PredictionError),
                model_zeta: Some(AmbientZeta {
                    zeta: -0.03,
                    low: -0.032,
                    high: model_high,
                }),
                ..g
            }
        };
        for (model_high, carried) in [(-0.028, true), (0.001, false)] {
            let mut memory = CycleAmplitude::default();
            memory.observe(70.0, &mut shown(model_high));
            let mut d = cycle(A_STAR, -0.023, 0.008, 3);
            memory.observe(90.0, &mut d);
            assert_eq!(
                d.amplitude_zeta.is_some(),
                carried,
                "model high {model_high}"
            );
            if carried {
                assert!((d.amplitude_zeta.unwrap().zeta + 0.03).abs() < 1e-12);
                assert_eq!(d.zeta0_source, Some(Zeta0Source::Amplitude));
            }
        }
    }

    /// A growing window carries its law; a window read as a cycle carries it only where its
    /// envelope did not still rise by two standard errors over it (a burst that grew in its first
    /// seconds and held its cycle), not where the cycle was still pushed out (an onset's ramp).
    #[test]
    fn a_law_comes_from_a_window_that_saw_one_damping() {
        let read_as = |regime: Regime, envelope: Option<(f64, f64)>| DampingReport {
            regime: Some(regime),
            growth_rate: envelope.map(|g| g.0),
            growth_rate_stderr: envelope.map(|g| g.1),
            ..growth(-0.02, 0.004)
        };
        for (window, carried) in [
            (read_as(Regime::SelfExcited, Some((0.1, 0.01))), true),
            (read_as(Regime::SelfExcited, None), true),
            // the lab gate's bursts: 1.1 to 2.0 standard errors
            (read_as(Regime::LimitCycle, Some((0.019, 0.01))), true),
            (read_as(Regime::LimitCycle, Some((-0.005, 0.01))), true),
            (read_as(Regime::LimitCycle, None), true),
            // the barrier gate's onset: 2 to 5
            (read_as(Regime::LimitCycle, Some((0.021, 0.01))), false),
            (read_as(Regime::LimitCycle, Some((0.05, 0.01))), false),
            (read_as(Regime::Undecided, Some((0.1, 0.01))), false),
        ] {
            let mut memory = CycleAmplitude::default();
            memory.observe(70.0, &mut window.clone());
            let mut d = cycle(A_STAR, -0.018, 0.008, 3);
            memory.observe(90.0, &mut d);
            assert_eq!(d.amplitude_zeta.is_some(), carried, "{window:?}");
            assert_eq!(CycleAmplitude::resume([(&window, 70.0)]), memory);
            // after an earlier growth's law: a window still pushed out drops it too (the damping
            // is still moving, and the earlier window read an older damping still)
            let earlier = growth(-0.012, 0.004);
            let mut memory = CycleAmplitude::default();
            memory.observe(60.0, &mut earlier.clone());
            memory.observe(70.0, &mut window.clone());
            let mut d = cycle(A_STAR, -0.018, 0.008, 3);
            memory.observe(90.0, &mut d);
            let read = d.amplitude_zeta.map(|c| c.zeta);
            assert_eq!(read.is_some(), carried, "{window:?}");
            assert!(read.is_none_or(|z| (z + 0.02).abs() < 1e-12), "{read:?}");
            let stored = [(&earlier, 60.0), (&window, 70.0)];
            assert_eq!(CycleAmplitude::resume(stored), memory);
        }
    }

    /// A window after the growth read by its prediction errors (not a law itself: its model
    /// did not read the growth).
    fn departed(zeta: f64, half: f64, trusted: bool) -> DampingReport {
        DampingReport {
            zeta0: Some(zeta),
            zeta0_interval: Some((zeta - half, zeta + half)),
            zeta0_source: Some(Zeta0Source::PredictionError),
            regime: Some(Regime::Undecided),
            trusted,
            verdict: Verdict::SelfExcited,
            ..DampingReport::unknown()
        }
    }

    /// The law of a window that read an onset's ramp as one damping, too close to zero, is
    /// dropped when a later window's prediction errors read the damping at rest elsewhere: the
    /// cycle is then read by its envelope alone. A reading that agrees, or one that is not
    /// trusted, leaves the law, and a restart drops it as the live gate did.
    #[test]
    fn a_law_the_next_reading_contradicts_is_dropped() {
        // the law -1 % +- 0.4 carries +- 0.52; the later reading -2 % +- 0.45: their difference
        // 1 point against 1.96 x 0.35 = 0.68
        for (later, kept) in [
            (departed(-0.02, 0.0045, true), false),
            (departed(-0.012, 0.0045, true), true),
            (departed(-0.02, 0.0045, false), true),
            // a model window is no such reading: on a cycle its model reads near zero
            (
                DampingReport {
                    zeta0_source: Some(Zeta0Source::Model),
                    ..departed(-0.02, 0.0045, true)
                },
                true,
            ),
        ] {
            let mut memory = CycleAmplitude::default();
            memory.observe(70.0, &mut growth(-0.01, 0.004));
            let mut seen = later.clone();
            memory.observe(80.0, &mut seen);
            assert_eq!(seen, later, "the reading itself is not changed");
            let mut d = cycle(A_STAR, -0.015, 0.02, 3);
            memory.observe(90.0, &mut d);
            assert_eq!(d.amplitude_zeta.is_some(), kept, "{later:?}");
            let source = if kept {
                Zeta0Source::Amplitude
            } else {
                Zeta0Source::Envelope
            };
            assert_eq!(d.zeta0_source, Some(source));
            let g = growth(-0.01, 0.004);
            let stored = [(&g, 70.0), (&later, 80.0)];
            assert_eq!(CycleAmplitude::resume(stored), memory);
        }
        // a later growth brings a law again
        let mut memory = CycleAmplitude::default();
        memory.observe(70.0, &mut growth(-0.01, 0.004));
        memory.observe(80.0, &mut departed(-0.02, 0.0045, true));
        memory.observe(85.0, &mut growth(-0.02, 0.004));
        let mut d = cycle(A_STAR, -0.018, 0.02, 3);
        memory.observe(90.0, &mut d);
        assert!((d.amplitude_zeta.unwrap().zeta + 0.02).abs() < 1e-12);
    }

    #[test]
    fn the_law_expires_and_is_never_applied_to_other_windows() {
        let mut memory = CycleAmplitude::default();
        memory.observe(70.0, &mut growth(-0.03, 0.004));
        let mut late = cycle(A_STAR, -0.025, 0.008, 3);
        memory.observe(70.0 + LAW_MAX_AGE_SECONDS + 1.0, &mut late);
        assert_eq!(late.zeta0_source, Some(Zeta0Source::Envelope));
        assert_eq!(late.amplitude_zeta, None);
        // an ambient window at the same amplitude is not a cycle
        let mut memory = CycleAmplitude::default();
        memory.observe(70.0, &mut growth(-0.03, 0.004));
        let mut ambient = DampingReport {
            zeta0_source: Some(Zeta0Source::Ambient),
            regime: Some(Regime::Undecided),
            ..cycle(A_STAR, 0.01, 0.005, 3)
        };
        let before = ambient.clone();
        memory.observe(90.0, &mut ambient);
        assert_eq!(ambient, before);
    }

    #[test]
    fn a_restart_remembers_the_last_growth_of_the_stored_reports() {
        let growth_a = growth(-0.02, 0.004);
        let growth_b = growth(-0.03, 0.004);
        let ambient = DampingReport {
            zeta0_source: Some(Zeta0Source::Ambient),
            regime: Some(Regime::Undecided),
            ..cycle(A_STAR, 0.01, 0.005, 3)
        };
        let stored = [(&growth_a, 70.0), (&growth_b, 160.0), (&ambient, 200.0)];
        let mut live = CycleAmplitude::default();
        for (d, end) in stored {
            live.observe(end, &mut d.clone());
        }
        let resumed = CycleAmplitude::resume(stored);
        assert_eq!(resumed, live);
        let mut d = cycle(A_STAR, -0.025, 0.008, 3);
        CycleAmplitude::resume(stored).observe(250.0, &mut d);
        assert!((d.amplitude_zeta.unwrap().zeta + 0.03).abs() < 1e-12);
        assert_eq!(CycleAmplitude::resume([]), CycleAmplitude::default());
    }

    #[test]
    fn a_lone_cycle_window_stays_no_evidence_on_its_own() {
        let mut memory = CycleAmplitude::default();
        memory.observe(70.0, &mut growth(-0.03, 0.004));
        let mut d = cycle(A_STAR, -0.025, 0.008, 1);
        memory.observe(80.0, &mut d);
        assert_eq!(d.zeta0_source, Some(Zeta0Source::Amplitude));
        assert!(!d.trusted && d.verdict == Verdict::Unknown);
    }
}
