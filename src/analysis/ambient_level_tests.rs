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
        agrees: Some(true),
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
    // (the buffer itself is compared: three windows at 50 among the windows at 2 would leave the
    // median at 2 even if they had entered)
    let before = level.recent.clone();
    for mut d in [untrusted, model, growing, limit_cycle_window(50.0)] {
        level.observe(&mut d);
        assert_eq!(d.ambient_ratio, Some(25.0));
        assert_eq!(level.recent, before);
    }
    assert_eq!(level.level(), Some(2.0));
}

/// A gate whose response grows by 15 % a window (5 s), as the lock gate's did on the onset ramp
/// from +1 % towards zero, leaves the level it grew from: two minutes of level still hold the
/// ambient state when the growth has tripled the RMS. A one-minute level (12 windows) chased it:
/// each growing window stood below the bar and fed the level, and the ratio settled at 2.47, so
/// the gate never departed (this test with `AMBIENT_LEVEL_WINDOWS` set back to 12 fails so;
/// stop 78).
#[test]
fn a_level_of_two_minutes_is_left_by_a_growth_of_a_minute() {
    let hold = |k: usize| if k % 2 == 0 { 0.9 } else { 1.1 };
    let growth: Vec<f64> = (1..=10).map(|k| 1.15f64.powi(k)).collect();
    let mut level = AmbientLevel::default();
    for k in 0..AMBIENT_LEVEL_WINDOWS {
        level.observe(&mut ambient_window(hold(k)));
    }
    let now: Vec<f64> = growth
        .iter()
        .map(|rms| {
            let mut d = ambient_window(*rms);
            level.observe(&mut d);
            d.ambient_ratio.unwrap()
        })
        .collect();
    let first = now.iter().position(|r| *r >= DEPARTED_FROM_AMBIENT);
    // the level rises from 1.0 to 1.1 (the median of the hold once the growth pushes its lowest
    // window out) and the ninth window, 1.15^9 = 3.52, stands 3.2 times above it: 45 s in
    assert_eq!(first, Some(8), "ratios over the level: {now:?}");
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
        d.departure_ratio = None;
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
        d.departure_ratio = None;
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
        d.departure_ratio = None;
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

/// A window that left the level with a prediction-error reading reports it, in place of
/// SSI-COV's reading or of a model whose interval reaches zero; a confident negative model, a
/// limit cycle, a window below the departure ratio or one without the reading keep theirs.
#[test]
fn a_departed_window_is_read_by_its_prediction_errors() {
    let pem = AmbientZeta {
        zeta: -0.006,
        low: -0.009,
        high: -0.003,
    };
    let window = |rms: f64, model: Option<AmbientZeta>| DampingReport {
        model_zeta: model,
        prediction_error_zeta: Some(pem),
        ..ambient_window(rms)
    };
    let read = |mut d: DampingReport| {
        primed_at_5().observe(&mut d);
        d
    };
    // SSI-COV decided, 3 times above: the filter's reading, negative and trusted
    let d = read(window(3.0 * 5.0, None));
    assert_eq!(d.zeta0, Some(pem.zeta));
    assert_eq!(d.zeta0_interval, Some((pem.low, pem.high)));
    assert_eq!(d.zeta0_source, Some(Zeta0Source::PredictionError));
    assert_eq!((d.verdict, d.trusted), (Verdict::SelfExcited, true));
    // a model whose interval reaches zero gives way to it ...
    let vague = AmbientZeta {
        zeta: -0.002,
        low: -0.005,
        high: 0.001,
    };
    let d = read(window(4.0 * 5.0, Some(vague)));
    assert_eq!(d.zeta0_source, Some(Zeta0Source::PredictionError));
    // ... a confident one keeps the window where the filter cannot tell the sign ...
    let sure = AmbientZeta {
        zeta: -0.0187,
        low: -0.0351,
        high: -0.0022,
    };
    let d = read(DampingReport {
        prediction_error_zeta: Some(vague),
        ..window(4.0 * 5.0, Some(sure))
    });
    assert_eq!(d.zeta0_source, Some(Zeta0Source::Model));
    assert_eq!(d.zeta0, Some(sure.zeta));
    // ... and gives way where the filter reads the sign as well: the same verdict, the filter's
    // figure and interval
    let d = read(window(4.0 * 5.0, Some(sure)));
    assert_eq!(d.zeta0_source, Some(Zeta0Source::PredictionError));
    assert_eq!(d.zeta0_interval, Some((pem.low, pem.high)));
    assert_eq!((d.verdict, d.trusted), (Verdict::SelfExcited, true));
    // an interval of the filter across zero: read, undecided
    let d = read(DampingReport {
        prediction_error_zeta: Some(vague),
        ..window(3.5 * 5.0, None)
    });
    assert_eq!(d.zeta0_source, Some(Zeta0Source::PredictionError));
    assert_eq!((d.verdict, d.trusted), (Verdict::Unknown, true));
    // below the departure ratio, a held cycle, or without the reading: as before
    for d in [
        window(2.9 * 5.0, None),
        DampingReport {
            regime: Some(Regime::LimitCycle),
            ..window(4.0 * 5.0, None)
        },
        DampingReport {
            prediction_error_zeta: None,
            ..window(4.0 * 5.0, None)
        },
    ] {
        assert_ne!(read(d).zeta0_source, Some(Zeta0Source::PredictionError));
    }
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
    // the growth in the window's first seconds only (the lab gate's first burst, seed 17,
    // swung 1.18), against a held cycle's largest swing (1.07)
    for (swing, source) in [(1.18, Zeta0Source::Model), (1.08, Zeta0Source::Envelope)] {
        let mut w = DampingReport {
            rms_swing: Some(swing),
            ..envelope()
        };
        primed_at_5().observe(&mut w);
        assert_eq!(w.zeta0_source, Some(source), "swing {swing}");
    }
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

#[test]
fn departure_ratio_is_three_from_fifty_cycles_and_rises_below() {
    // the calibrated gates keep 3: the lock gate (5 Hz, 50 cycles a 10 s window), the lab gate
    assert_eq!(departure_ratio(50.0), DEPARTED_FROM_AMBIENT);
    assert_eq!(departure_ratio(104.0), DEPARTED_FROM_AMBIENT);
    // the table's rows, and between them in ln(cycles)
    assert!((departure_ratio(20.0) - 3.84).abs() < 1e-12);
    let mid = departure_ratio((20.0f64 * 30.0).sqrt());
    assert!((mid - (3.84 + 3.49) / 2.0).abs() < 1e-12, "{mid}");
    // falls with the cycles, never below 3, at most the plateau; NaN is the conservative end
    let mut last = f64::INFINITY;
    for c in [0.5, 2.0, 5.0, 7.0, 10.0, 15.0, 25.0, 40.0, 49.0, 50.0, 1e4] {
        let r = departure_ratio(c);
        assert!((DEPARTED_FROM_AMBIENT..=4.65).contains(&r), "{c}: {r}");
        assert!(r <= last, "{c}: {r} > {last}");
        last = r;
    }
    assert_eq!(departure_ratio(f64::NAN), 4.65);
}

#[test]
fn a_slow_gates_level_carries_its_departure_ratio() {
    // a 2 Hz gate: 20 cycles a 10 s window
    let mut level = AmbientLevel::default();
    for _ in 0..6 {
        let mut w = ambient_window(1.0);
        w.window_cycles = Some(20.0);
        level.observe(&mut w);
    }
    assert!((level.departure_ratio() - 3.84).abs() < 1e-12);
    // 3.3 times its level (a chance window of the +0.5 % barrier gate): not departed, so the
    // model's confident -2 % gives way to the ambient estimate
    let mut w = limit_cycle_window(3.3);
    w.window_cycles = Some(20.0);
    level.observe(&mut w);
    assert_eq!(w.ambient_ratio, Some(3.3));
    assert_eq!(w.departure_ratio, Some(level.departure_ratio()));
    assert!(!departed(&w));
    assert!(!level.departs(3.3));
    assert!(level.departs(3.9));
    // windows that say nothing of their cycles keep 3
    let mut old = AmbientLevel::default();
    for _ in 0..6 {
        old.observe(&mut ambient_window(1.0));
    }
    assert_eq!(old.departure_ratio(), DEPARTED_FROM_AMBIENT);
}

/// Ratios of windows of a stable gate at `zeta = 0.5 %` whose windows hold `cycles` cycles,
/// each over the median of the `AMBIENT_LEVEL_WINDOWS` before it: the squared envelope of a
/// lightly damped response to white forcing is an exponential variable decorrelating at
/// `2 zeta omega` (`|z|^2`, `z` a complex Ornstein-Uhlenbeck process), averaged over 10 s
/// windows every 5 s.
fn simulated_ratios(cycles: f64, chains: usize, hours: f64, seed: u64) -> Vec<f64> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    const STEPS_PER_WINDOW: usize = 100;
    let lambda_t = 4.0 * std::f64::consts::PI * 0.005 * cycles;
    let a = (-0.5 * lambda_t / STEPS_PER_WINDOW as f64).exp();
    let s = (1.0 - a * a).sqrt();
    let steps = (hours * 3600.0 / 10.0 * STEPS_PER_WINDOW as f64) as usize;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut normal = || -> f64 { StandardNormal.sample(&mut rng) };
    let mut out = Vec::new();
    for _ in 0..chains {
        let (mut re, mut im) = (normal() / 2f64.sqrt(), normal() / 2f64.sqrt());
        let mut cum = Vec::with_capacity(steps + 1);
        cum.push(0.0);
        for _ in 0..steps {
            re = a * re + s * normal() / 2f64.sqrt();
            im = a * im + s * normal() / 2f64.sqrt();
            cum.push(cum.last().unwrap() + re * re + im * im);
        }
        let rms: Vec<f64> = (0..steps - STEPS_PER_WINDOW)
            .step_by(STEPS_PER_WINDOW / 2)
            .map(|i| ((cum[i + STEPS_PER_WINDOW] - cum[i]) / STEPS_PER_WINDOW as f64).sqrt())
            .collect();
        for i in AMBIENT_LEVEL_WINDOWS..rms.len() {
            let mut before = rms[i - AMBIENT_LEVEL_WINDOWS..i].to_vec();
            out.push(rms[i] / crate::identify::median(&mut before).unwrap());
        }
    }
    out
}

fn upper_quantile(mut v: Vec<f64>, p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((1.0 - p) * v.len() as f64) as usize]
}

#[test]
fn departure_ratio_table_matches_a_simulation() {
    // the lock gate's exceedance of 3 is the bar every gate is held to (the table's derivation:
    // 1,500 two-hour chains a row, over the 12-window level of the time; here 150 one-hour
    // chains over the level as it is, so a tolerance of 0.25)
    let lock = simulated_ratios(50.0, 150, 1.0, 1);
    let p = lock.iter().filter(|r| **r >= 3.0).count() as f64 / lock.len() as f64;
    assert!((5e-5..1e-3).contains(&p), "{p}");
    for (cycles, seed) in [(10.0, 2), (20.0, 3), (30.0, 4)] {
        let r = upper_quantile(simulated_ratios(cycles, 150, 1.0, seed), p);
        let table = departure_ratio(cycles);
        assert!(
            (r - table).abs() < 0.25,
            "{cycles} cycles: simulated {r}, table {table}"
        );
    }
    // and the barrier gate at 3 is what it was: exceeded about ten times as often
    let barrier = simulated_ratios(20.0, 150, 1.0, 5);
    let p20 = barrier.iter().filter(|r| **r >= 3.0).count() as f64 / barrier.len() as f64;
    assert!(p20 > 5.0 * p, "{p20} vs {p}");
}

/// The derivation of [`departure_ratio`]'s table at full size (1,500 two-hour chains a row):
/// `cargo test --release --lib departure_ratio_table -- --ignored --nocapture`. Prints, for each
/// row, the ratio a stable +0.5 % gate exceeds as rarely as the lock gate (50 cycles) exceeds 3,
/// beside the table's value.
#[test]
#[ignore = "a derivation: about a minute of simulation"]
fn departure_ratio_table() {
    let lock = simulated_ratios(50.0, 1500, 2.0, 11);
    let p = lock.iter().filter(|r| **r >= 3.0).count() as f64 / lock.len() as f64;
    println!("lock gate's P(ratio >= 3) = {p:.3e}");
    for (i, cycles) in [5.0, 10.0, 15.0, 20.0, 30.0, 40.0, 50.0]
        .into_iter()
        .enumerate()
    {
        let r = upper_quantile(simulated_ratios(cycles, 1500, 2.0, 12 + i as u64), p);
        println!(
            "{cycles:>4} cycles: simulated {r:.2}, table {:.2}",
            departure_ratio(cycles)
        );
    }
}
