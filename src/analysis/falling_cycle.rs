//! A limit-cycle window whose envelope fell: its interval spans the envelope's drift
//! (`docs/damping.md`, "A falling cycle's interval spans its drift").
//!
//! The envelope's relaxation (`spectral::envelope_relaxation`) reads `zeta0` from how the
//! forcing's kicks to the amplitude relax back to a saturated cycle. A cycle that shrinks (the
//! damping climbing back through zero on a recovery) is none, and there the relaxation, read over
//! 100 cycles of history and pooled, reads the cycle that was. The drift of the envelope over the
//! window alone (`spectral::envelope_drift`) assumes no saturation, but reads a damping that
//! changes within the window high. Neither reading is the gate's alone, so the window says what
//! both allow ([`span_the_fall`]).
//!
//! Where the gate held its cycle before the fall, the cycle it held gives the damping's
//! amplitude law, and the fall is read through it ([`HeldCycle::read_fall`]): by first-order
//! stochastic averaging `d ln A = -w zeta_eq(A) dt + noise`, so the envelope's mean growth rate
//! `g` over the window gives the window's mean `zeta_eq = -g / w`; on the held cycle
//! `zeta_eq(A_c) = zeta0_c + b A_c^p = 0`, so `b A^p = -zeta0_c (A / A_c)^p`, and
//!
//! ```text
//! zeta0 = zeta_eq - b A^p = -g / w + zeta0_c (A / A_c)^p
//! ```
//!
//! with `A / A_c` the ratio of the window's RMS to the held cycle's (the mean of `A^2` over a
//! window is twice its mean square). On a saturated cycle (`g = 0`, `A = A_c`) it reads the held
//! cycle's own figure. Its interval carries the growth rate's standard error and the held
//! reading's interval scaled by `(A / A_c)^p`, which shrinks as the cycle does.

use super::pooling::falling;
use super::report::{AmbientZeta, DampingReport, Verdict, Zeta0Source};
use super::verdict::falls;
use crate::spectral::Regime;

/// Whether `d` is a limit-cycle window read as a cycle: by its envelope, or through the cycle's
/// amplitude.
fn read_as_cycle(d: &DampingReport) -> bool {
    matches!(
        d.zeta0_source,
        Some(Zeta0Source::Envelope | Zeta0Source::Amplitude)
    ) && d.regime == Some(Regime::LimitCycle)
}

/// The gate's last steady cycle: a trusted, confidently negative reading of a limit-cycle window
/// read as a cycle whose envelope neither fell nor rose by more than two standard errors, with
/// the window's RMS and end (sample time). What [`HeldCycle::read_fall`] reads a fall through.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeldCycle {
    /// The cycle's `zeta0` with its 95 % interval, as reported (pooled).
    pub zeta0: AmbientZeta,
    /// The window's RMS, in the signal's unit.
    pub rms: f64,
    /// Sample time of the window's end.
    pub t_end: f64,
}

impl HeldCycle {
    /// The held cycle a final report of the window ending at `t_end` shows, if it shows one.
    pub fn of(t_end: f64, d: &DampingReport) -> Option<HeldCycle> {
        let (g, se) = (d.growth_rate?, d.growth_rate_stderr?);
        let steady = !falls(g, se) && !falls(-g, se);
        let (zeta, (low, high)) = (d.zeta0?, d.zeta0_interval?);
        let rms = d.signal_rms.filter(|r| r.is_finite() && *r > 0.0)?;
        let confident = d.trusted && d.verdict == Verdict::SelfExcited && high < 0.0;
        (read_as_cycle(d) && steady && confident).then_some(HeldCycle {
            zeta0: AmbientZeta { zeta, low, high },
            rms,
            t_end,
        })
    }

    /// `zeta0` of a falling cycle read through this held cycle's law (module documentation),
    /// with `exponent` the damping's amplitude exponent `p`: `None` where `d` is not a limit-cycle
    /// window read as a cycle whose envelope fell ([`falling`]), or lacks its frequency, growth
    /// or RMS.
    pub fn read_fall(&self, d: &DampingReport, exponent: f64) -> Option<AmbientZeta> {
        if !(read_as_cycle(d) && falling(d)) {
            return None;
        }
        let w = 2.0 * std::f64::consts::PI * d.frequency_hz.filter(|f| *f > 0.0)?;
        let (g, se) = (d.growth_rate?, d.growth_rate_stderr?);
        let rms = d.signal_rms.filter(|r| *r > 0.0)?;
        let scale = (rms / self.rms).powf(exponent);
        let c = self.zeta0;
        let zeta = -g / w + c.zeta * scale;
        let from_growth = crate::spectral::normal_quantile(0.975) * se / w;
        let low = zeta - from_growth.hypot((c.zeta - c.low) * scale);
        let high = zeta + from_growth.hypot((c.high - c.zeta) * scale);
        [zeta, low, high]
            .iter()
            .all(|v| v.is_finite())
            .then_some(AmbientZeta { zeta, low, high })
    }
}

/// Widens the reported interval of a limit-cycle window whose envelope fell ([`falling`]) and
/// which its envelope's relaxation (or the cycle's amplitude) read: the interval becomes the
/// hull of its own and that of the envelope's drift over the window
/// (`DampingReport::envelope_drift_zeta`); `zeta0` stays. Where the hull no longer lies below
/// zero the window cannot tell (verdict `Unknown`, untrusted: it neither fires nor clears an
/// alert). Returns whether the interval widened. The daemon calls it after the pools and the
/// cycle's amplitude (`service::state`).
///
/// Why: the relaxation assumes a saturated cycle, and a falling envelope is none. On the 2 Hz
/// barrier gate's recovery the cycle shrinks while `zeta0` climbs back through zero, and the
/// relaxation (100 cycles of history, pooled over a minute) read -1.72 % (-3.22, -0.23) at a
/// true +0.33 %: confident and wrong, like every window of the shrinking cycle. The drift over the
/// window assumes no saturation but reads a `zeta0` that changes within the window high (its
/// intercept extrapolates to the smallest amplitudes, the latest): +0.68 % (-0.15, +1.50) there,
/// +0.78 % at a true -1.33 % earlier. Neither reading is the gate's alone; their hull covered 14
/// of 14 decay windows and 97 % of the limit-cycle ones on 20 recoveries (64 % and 94 % before;
/// `docs/damping.md`, "A falling cycle's interval spans its drift").
pub fn span_the_fall(d: &mut DampingReport) -> bool {
    if !(read_as_cycle(d) && falling(d)) {
        return false;
    }
    let (Some((low, high)), Some(e)) = (d.zeta0_interval, d.envelope_drift_zeta) else {
        return false;
    };
    let (l, h) = (low.min(e.low), high.max(e.high));
    if !(l.is_finite() && h.is_finite()) || (l, h) == (low, high) {
        return false;
    }
    d.zeta0_interval = Some((l, h));
    if h >= 0.0 {
        d.verdict = Verdict::Unknown;
        d.trusted = false;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::AmbientZeta;

    /// A limit-cycle window read by its envelope, confidently negative, whose envelope fell by
    /// `falls` standard errors, with the drift's reading `drift`.
    fn cycle(falls: f64, drift: Option<(f64, f64, f64)>) -> DampingReport {
        DampingReport {
            zeta0: Some(-0.0172),
            zeta0_interval: Some((-0.0322, -0.0023)),
            zeta0_source: Some(Zeta0Source::Envelope),
            regime: Some(Regime::LimitCycle),
            growth_rate: Some(-0.01 * falls),
            growth_rate_stderr: Some(0.01),
            envelope_drift_zeta: drift.map(|(zeta, low, high)| AmbientZeta { zeta, low, high }),
            verdict: Verdict::SelfExcited,
            trusted: true,
            ..DampingReport::unknown()
        }
    }

    /// The interval becomes the hull of both readings, the figure stays, and a hull that
    /// reaches zero cannot tell: untrusted, no verdict. A hull still below zero keeps the
    /// verdict; a drift inside the interval changes nothing.
    #[test]
    fn a_falling_cycle_spans_its_drift() {
        let mut d = cycle(5.0, Some((0.0068, -0.0015, 0.0150)));
        assert!(span_the_fall(&mut d));
        assert_eq!(d.zeta0, Some(-0.0172), "the figure stays");
        assert_eq!(d.zeta0_interval, Some((-0.0322, 0.0150)));
        assert_eq!((d.verdict, d.trusted), (Verdict::Unknown, false));

        let mut lower = cycle(5.0, Some((-0.030, -0.040, -0.020)));
        assert!(span_the_fall(&mut lower));
        assert_eq!(lower.zeta0_interval, Some((-0.040, -0.0023)));
        assert_eq!((lower.verdict, lower.trusted), (Verdict::SelfExcited, true));

        let mut inside = cycle(5.0, Some((-0.020, -0.030, -0.010)));
        let before = inside.clone();
        assert!(!span_the_fall(&mut inside));
        assert_eq!(inside, before);
    }

    /// Only a limit-cycle window read as a cycle whose envelope fell by more than two standard
    /// errors, and only with a drift reading, is widened.
    #[test]
    fn only_a_falling_cycle_with_a_drift_is_widened() {
        let drift = Some((0.0068, -0.0015, 0.0150));
        let mut cases = vec![
            ("fell by 1.5 standard errors", cycle(1.5, drift)),
            ("rose", cycle(-5.0, drift)),
            ("no drift reading", cycle(5.0, None)),
        ];
        let mut ambient = cycle(5.0, drift);
        ambient.zeta0_source = Some(Zeta0Source::Ambient);
        cases.push(("read by SSI-COV", ambient));
        let mut undecided = cycle(5.0, drift);
        undecided.regime = Some(Regime::Undecided);
        cases.push(("no limit cycle", undecided));
        let mut no_interval = cycle(5.0, drift);
        no_interval.zeta0_interval = None;
        cases.push(("no interval", no_interval));
        for (what, mut d) in cases {
            let before = d.clone();
            assert!(!span_the_fall(&mut d), "{what}");
            assert_eq!(d, before, "{what}");
        }
        let mut amplitude = cycle(5.0, drift);
        amplitude.zeta0_source = Some(Zeta0Source::Amplitude);
        assert!(
            span_the_fall(&mut amplitude),
            "read through the cycle's amplitude"
        );
    }

    /// A steady 2 Hz cycle at -2 % (-2.6, -1.4), RMS 500, read by its envelope and trusted.
    fn held() -> DampingReport {
        DampingReport {
            zeta0: Some(-0.02),
            zeta0_interval: Some((-0.026, -0.014)),
            zeta0_source: Some(Zeta0Source::Envelope),
            zeta0_windows: Some(9),
            regime: Some(Regime::LimitCycle),
            frequency_hz: Some(2.0),
            growth_rate: Some(0.001),
            growth_rate_stderr: Some(0.005),
            signal_rms: Some(500.0),
            verdict: Verdict::SelfExcited,
            trusted: true,
            ..DampingReport::unknown()
        }
    }

    /// The same cycle shrunk to RMS 250 while its envelope falls at 0.05/s (standard error
    /// 0.005), still read by the relaxation at -1.7 %.
    fn shrinking() -> DampingReport {
        DampingReport {
            zeta0: Some(-0.017),
            growth_rate: Some(-0.05),
            signal_rms: Some(250.0),
            ..held()
        }
    }

    /// `zeta0 = -g / w + zeta0_c (A / A_c)^2`: 0.05 / (4 pi) - 2 % x 1/4 = -0.10 %, its
    /// interval the growth's standard error and the held cycle's interval at a quarter.
    #[test]
    fn a_fall_is_read_through_the_cycle_held_before_it() {
        let h = HeldCycle::of(100.0, &held()).expect("a held cycle");
        assert_eq!(h.rms, 500.0);
        let z = h.read_fall(&shrinking(), 2.0).expect("a falling cycle");
        let w = 4.0 * std::f64::consts::PI;
        let want = 0.05 / w - 0.02 * 0.25;
        assert!((z.zeta - want).abs() < 1e-12, "{z:?}");
        let half = (1.959_963_984_540_054 * 0.005 / w).hypot(0.006 * 0.25);
        assert!((z.zeta - z.low - half).abs() < 1e-9, "{z:?}");
        assert!((z.high - z.zeta - half).abs() < 1e-9, "{z:?}");
        // a steady window is no fall, and a window read by SSI-COV no cycle
        assert_eq!(h.read_fall(&held(), 2.0), None);
        let mut ambient = shrinking();
        ambient.zeta0_source = Some(Zeta0Source::Ambient);
        assert_eq!(h.read_fall(&ambient, 2.0), None);
    }

    /// Only a steady, trusted, confidently negative cycle read as a cycle is held.
    #[test]
    fn only_a_steady_confident_cycle_is_held() {
        type Edit = fn(&mut DampingReport);
        let edits: [(&str, Edit); 7] = [
            ("fell", |d| d.growth_rate = Some(-0.02)),
            ("rose", |d| d.growth_rate = Some(0.02)),
            ("untrusted", |d| d.trusted = false),
            ("across zero", |d| d.zeta0_interval = Some((-0.026, 0.001))),
            ("read by SSI-COV", |d| {
                d.zeta0_source = Some(Zeta0Source::Ambient)
            }),
            ("no cycle", |d| d.regime = Some(Regime::Undecided)),
            ("no RMS", |d| d.signal_rms = None),
        ];
        for (what, edit) in edits {
            let mut d = held();
            edit(&mut d);
            assert_eq!(HeldCycle::of(0.0, &d), None, "{what}");
        }
    }

    /// The gate's memory: a held cycle is remembered (and found again after a restart, from the
    /// stored reports), a fall read through it stands alone with its verdict by its interval, and
    /// a held cycle older than the law's age reads nothing.
    #[test]
    fn the_memory_reads_a_fall_through_its_last_held_cycle() {
        use crate::analysis::{CycleAmplitude, LAW_MAX_AGE_SECONDS};
        let mut live = CycleAmplitude::default();
        let mut h = held();
        assert!(!live.read_fall(100.0, &mut h), "a held cycle is not a fall");
        assert_eq!(h, held(), "and is not changed");
        let resumed = CycleAmplitude::resume([(&held(), 100.0)]);
        for mut memory in [live, resumed] {
            let mut d = shrinking();
            d.pooled_zeta = Some(AmbientZeta {
                zeta: -0.017,
                low: -0.026,
                high: -0.014,
            });
            assert!(memory.read_fall(130.0, &mut d));
            let z = d.amplitude_zeta.expect("the reading");
            assert_eq!(d.zeta0, Some(z.zeta));
            assert_eq!(d.zeta0_interval, Some((z.low, z.high)));
            assert_eq!(d.zeta0_source, Some(Zeta0Source::Amplitude));
            assert_eq!((d.zeta0_windows, d.pooled_zeta), (Some(1), None));
            assert!(z.low < 0.0 && z.high > 0.0, "{z:?}");
            assert_eq!((d.verdict, d.trusted), (Verdict::Unknown, false));
            // a slower fall of a larger cycle reads confidently negative
            let mut early = DampingReport {
                growth_rate: Some(-0.02),
                growth_rate_stderr: Some(0.002),
                signal_rms: Some(450.0),
                ..shrinking()
            };
            assert!(memory.read_fall(135.0, &mut early));
            assert!(early.zeta0_interval.unwrap().1 < 0.0, "{early:?}");
            assert_eq!((early.verdict, early.trusted), (Verdict::SelfExcited, true));
            let mut late = shrinking();
            assert!(!memory.read_fall(100.0 + LAW_MAX_AGE_SECONDS + 1.0, &mut late));
            assert_eq!(late, shrinking());
        }
    }
}
