//! A limit-cycle window whose envelope fell: its interval spans the envelope's drift
//! (`docs/damping.md`, "A falling cycle's interval spans its drift").
//!
//! The envelope's relaxation (`spectral::envelope_relaxation`) reads `zeta0` from how the
//! forcing's kicks to the amplitude relax back to a saturated cycle. A cycle that shrinks (the
//! damping climbing back through zero on a recovery) is none, and there the relaxation, read over
//! 100 cycles of history and pooled, reads the cycle that was. The drift of the envelope over the
//! window alone (`spectral::envelope_drift`) assumes no saturation, but reads a damping that
//! changes within the window high. Neither reading is the gate's alone, so the window says what
//! both allow.

use super::pooling::falling;
use super::report::{DampingReport, Verdict, Zeta0Source};
use crate::spectral::Regime;

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
    let read_as_cycle = matches!(
        d.zeta0_source,
        Some(Zeta0Source::Envelope | Zeta0Source::Amplitude)
    );
    if !(read_as_cycle && d.regime == Some(Regime::LimitCycle) && falling(d)) {
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
}
