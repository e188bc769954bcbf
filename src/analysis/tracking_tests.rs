use super::*;
use crate::analysis::Zeta0Source;
use crate::spectral::Regime;

fn previous() -> Previous {
    Previous {
        coefficients: vec![19.0, -5.0, 1.0],
        full_fit_nmae: 0.02,
        since_full: 0,
        verdict: Verdict::Damped,
        trusted: true,
        agrees: true,
        t_start: 100.0,
        t_end: 109.995,
        signal_rms: Some(1.0),
        level: level_of(1.0),
    }
}

/// A gate's level after enough noise-driven windows of RMS `rms`.
fn level_of(rms: f64) -> AmbientLevel {
    let mut level = AmbientLevel::default();
    for _ in 0..crate::analysis::AMBIENT_LEVEL_MIN_WINDOWS {
        level.record(&noise_window(rms));
    }
    assert_eq!(level.level(), Some(rms));
    level
}

/// A trusted model's zeta0 with its interval (`DampingReport::model_zeta`).
fn fitted_model() -> Option<crate::analysis::AmbientZeta> {
    Some(crate::analysis::AmbientZeta {
        zeta: -0.02,
        low: -0.025,
        high: -0.015,
    })
}

fn report() -> DampingReport {
    DampingReport {
        fit_nmae: 0.025,
        agrees: Some(true),
        trusted: true,
        verdict: Verdict::Damped,
        frequency_hz: Some(10.4),
        model_frequency_hz: Some(10.5),
        ..DampingReport::unknown()
    }
}

#[test]
fn plan_tracks_an_overlapping_window_of_a_trusted_gate() {
    let p = previous();
    assert_eq!(plan(&TrackingPolicy::default(), Some(&p), 105.0), Ok(&p));
}

#[test]
fn plan_tracks_across_a_gap_of_up_to_max_gap_windows() {
    let p = previous();
    let policy = TrackingPolicy::default();
    // the previous window is 9.995 s long and ends at 109.995: 5 jobs replaced at a 5 s
    // cadence (the next window starts at 130) is 2.0 window lengths after its end
    for t in [110.0, 115.0, 125.0, 129.9] {
        assert_eq!(plan(&policy, Some(&p), t), Ok(&p), "{t}");
    }
    let one = TrackingPolicy {
        max_gap_windows: 1.0,
        ..TrackingPolicy::default()
    };
    assert_eq!(plan(&one, Some(&p), 119.9), Ok(&p));
    assert_eq!(plan(&one, Some(&p), 120.1), Err(FullReason::Gap));
}

#[test]
fn plan_runs_the_full_search_when_disabled_new_untrusted_gap_or_due() {
    let policy = TrackingPolicy::default();
    let off = TrackingPolicy {
        enabled: false,
        ..TrackingPolicy::default()
    };
    let p = previous();
    assert_eq!(plan(&off, Some(&p), 105.0), Err(FullReason::Disabled));
    assert_eq!(plan(&policy, None, 105.0), Err(FullReason::NewGate));
    let untrusted = Previous {
        trusted: false,
        ..previous()
    };
    assert_eq!(
        plan(&policy, Some(&untrusted), 105.0),
        Err(FullReason::Untrusted)
    );
    // more than max_gap_windows (2) window lengths after the previous window's end, and
    // before its start (time reset)
    assert_eq!(plan(&policy, Some(&p), 130.5), Err(FullReason::Gap));
    assert_eq!(plan(&policy, Some(&p), 90.0), Err(FullReason::Gap));
    // with no gap allowed, just after the previous window's end
    let overlap_only = TrackingPolicy {
        max_gap_windows: 0.0,
        ..TrackingPolicy::default()
    };
    assert_eq!(plan(&overlap_only, Some(&p), 110.5), Err(FullReason::Gap));
    let due = Previous {
        since_full: policy.full_every - 1,
        ..previous()
    };
    assert_eq!(plan(&policy, Some(&due), 105.0), Err(FullReason::Schedule));
    let always = TrackingPolicy {
        full_every: 1,
        ..TrackingPolicy::default()
    };
    assert_eq!(plan(&always, Some(&p), 105.0), Err(FullReason::Schedule));
}

#[test]
fn a_full_search_that_did_not_fit_is_no_reference() {
    let policy = TrackingPolicy::default(); // fit_tolerance 1.5: limit 1.505 at the ceiling
    for full in [f64::NAN, f64::INFINITY, 75.0] {
        let p = Previous {
            full_fit_nmae: full,
            ..previous()
        };
        let with_fit = |fit_nmae| DampingReport {
            fit_nmae,
            ..report()
        };
        assert_eq!(
            accept(&policy, &p, &with_fit(0.9)),
            Ok(Acceptance::Fitted),
            "{full}"
        );
        for bad in [1.6, 80.0, f64::INFINITY, f64::NAN] {
            assert!(
                matches!(
                    accept(&policy, &p, &with_fit(bad)),
                    Err(Rejection::Fit { limit, .. }) if (limit - 1.505).abs() < 1e-12
                ),
                "reference {full}, refined {bad}"
            );
        }
    }
}

#[test]
fn gate_hash_is_the_daemon_s_window_seed_of_before() {
    // values of the hash as `service::worker::window_seed` computed it before it moved here
    // (FNV-1a, splitmix64), from an independent implementation: every window's seed, and so
    // every daemon result, is unchanged
    assert_eq!(gate_hash("g1", 100), 13_601_181_542_038_338_142);
    assert_eq!(gate_hash("weir-north", 0), 9_865_485_673_146_758_496);
}

#[test]
fn gates_started_together_are_scheduled_apart() {
    let policy = TrackingPolicy::default(); // full_every 12
    let mut first_full = std::collections::BTreeMap::new();
    for g in 0..64 {
        let gate = format!("g{g}");
        let mut p = Some(previous().first_of(&gate, &policy));
        // the same name, the same phase
        assert_eq!(p, Some(previous().first_of(&gate, &policy)));
        // windows until the schedule asks for the full search: never more than full_every
        let mut n = 1;
        while plan(&policy, p.as_ref(), 100.0 + 5.0 * n as f64).is_ok() {
            let q = p.take().unwrap();
            p = Some(Previous {
                since_full: q.since_full + 1,
                t_start: q.t_start + 5.0,
                t_end: q.t_end + 5.0,
                ..q
            });
            n += 1;
        }
        assert!(n <= policy.full_every, "{gate}: {n}");
        *first_full.entry(n).or_insert(0) += 1;
    }
    // 64 gates over 12 phases: each phase has some, none has a quarter of them
    assert_eq!(first_full.len(), policy.full_every, "{first_full:?}");
    assert!(first_full.values().all(|&k| k < 16), "{first_full:?}");
}

#[test]
fn accept_takes_a_refined_model_that_still_fits() {
    assert_eq!(
        accept(&TrackingPolicy::default(), &previous(), &report()),
        Ok(Acceptance::Fitted)
    );
}

#[test]
fn accept_refuses_untrusted_disagreeing_changed_or_worse_fits() {
    let (policy, p) = (TrackingPolicy::default(), previous());
    let untrusted = DampingReport {
        trusted: false,
        ..report()
    };
    assert_eq!(accept(&policy, &p, &untrusted), Err(Rejection::Untrusted));
    let disagrees = DampingReport {
        agrees: Some(false),
        ..report()
    };
    assert_eq!(accept(&policy, &p, &disagrees), Err(Rejection::Disagrees));
    // ... unless the previous model disagreed too (an ambient-only gate)
    let p_disagreed = Previous {
        agrees: false,
        ..previous()
    };
    assert_eq!(
        accept(&policy, &p_disagreed, &disagrees),
        Ok(Acceptance::Fitted)
    );
    // a 20 % frequency shift, and a model that is no oscillator at rest
    let shifted = DampingReport {
        frequency_hz: Some(12.5),
        ..report()
    };
    assert!(matches!(
        accept(&policy, &p, &shifted),
        Err(Rejection::Frequency { .. })
    ));
    let no_oscillator = DampingReport {
        model_frequency_hz: None,
        ..report()
    };
    assert!(matches!(
        accept(&policy, &p, &no_oscillator),
        Err(Rejection::Frequency { model_hz: None, .. })
    ));
    let onset = DampingReport {
        verdict: Verdict::SelfExcited,
        ..report()
    };
    assert_eq!(accept(&policy, &p, &onset), Err(Rejection::VerdictChanged));
    // the gate leaves its ambient level (1.0): risen 2.5 times, or 3 times above the level
    let risen = DampingReport {
        signal_rms: Some(2.5),
        ..report()
    };
    assert_eq!(accept(&policy, &p, &risen), Err(Rejection::LeavesAmbient));
    let rising = Previous {
        signal_rms: Some(1.6),
        ..previous()
    };
    let departed = DampingReport {
        signal_rms: Some(3.1),
        ..report()
    };
    assert_eq!(
        accept(&policy, &rising, &departed),
        Err(Rejection::LeavesAmbient)
    );
    // ... but a window that stays above it (a held cycle) may be tracked, when its model
    // fits (it has a `model_zeta`)
    let held = Previous {
        signal_rms: Some(3.0),
        ..previous()
    };
    assert_eq!(
        accept(&policy, &held, &departed),
        Err(Rejection::UnfittedAboveAmbient)
    );
    let fitted = DampingReport {
        model_zeta: fitted_model(),
        ..departed.clone()
    };
    assert_eq!(accept(&policy, &held, &fitted), Ok(Acceptance::Fitted));
    // limit = 1.5 * 0.02 + 0.005 = 0.035
    let worse = DampingReport {
        fit_nmae: 0.04,
        ..report()
    };
    assert!(matches!(
        accept(&policy, &p, &worse),
        Err(Rejection::Fit { limit, .. }) if (limit - 0.035).abs() < 1e-12
    ));
    let nan = DampingReport {
        fit_nmae: f64::NAN,
        ..report()
    };
    assert!(matches!(
        accept(&policy, &p, &nan),
        Err(Rejection::Fit { .. })
    ));
}

fn waiving() -> TrackingPolicy {
    TrackingPolicy {
        waive_fit_on_noise: true,
        ..TrackingPolicy::default()
    }
}

/// A window of the turbulence's response as the refinement reports it: SSI decides, the
/// free-vibration model fits loosely and its growth disagrees with the envelope's.
fn noise_window(rms: f64) -> DampingReport {
    DampingReport {
        fit_nmae: 1.2,
        agrees: Some(false),
        verdict: Verdict::Unknown,
        regime: Some(Regime::Undecided),
        zeta0_source: Some(Zeta0Source::Ambient),
        signal_rms: Some(rms),
        ..report()
    }
}

#[test]
fn a_noise_driven_window_is_not_refused_for_its_fit_or_agreement() {
    let (policy, p) = (waiving(), previous()); // rms 1.0, fit limit 0.035
    assert!(noise_driven(&p, &noise_window(1.5)));
    // a noise-driven window that passes the fit tests is simply fitted
    let fits = DampingReport {
        agrees: Some(true),
        fit_nmae: 0.02,
        ..noise_window(1.5)
    };
    assert_eq!(accept(&policy, &p, &fits), Ok(Acceptance::Fitted));
    // off by default: the fit tests decide as for any window
    assert_eq!(
        accept(&TrackingPolicy::default(), &p, &noise_window(1.5)),
        Err(Rejection::Disagrees)
    );
    assert_eq!(
        accept(&policy, &p, &noise_window(1.5)),
        Ok(Acceptance::Waived)
    );
    assert_eq!(
        accept(&policy, &p, &noise_window(2.0)),
        Ok(Acceptance::Waived)
    );
    let damped = DampingReport {
        regime: Some(Regime::Damped),
        verdict: Verdict::Damped,
        ..noise_window(0.5)
    };
    assert_eq!(accept(&policy, &p, &damped), Ok(Acceptance::Waived));
    // what tells a change of the gate is still tested: a frequency shift, trust
    let shifted = DampingReport {
        frequency_hz: Some(12.5),
        ..noise_window(1.0)
    };
    assert!(matches!(
        accept(&policy, &p, &shifted),
        Err(Rejection::Frequency { .. })
    ));
    let untrusted = DampingReport {
        trusted: false,
        ..noise_window(1.0)
    };
    assert_eq!(accept(&policy, &p, &untrusted), Err(Rejection::Untrusted));
}

#[test]
fn a_window_that_rose_grows_or_is_read_by_the_model_keeps_the_fit_tests() {
    let (policy, p) = (waiving(), previous());
    let refused = |r: &DampingReport| {
        assert!(!noise_driven(&p, r), "{r:?}");
        assert_eq!(accept(&policy, &p, r), Err(Rejection::Disagrees), "{r:?}");
    };
    // the level rose more than twofold: the first sign of an onset, which the search
    // confirms before any fit test
    assert!(!noise_driven(&p, &noise_window(2.01)));
    assert_eq!(
        accept(&policy, &p, &noise_window(2.01)),
        Err(Rejection::LeavesAmbient)
    );
    // a growing or limit-cycle window is not the turbulence's response
    for regime in [Regime::SelfExcited, Regime::LimitCycle] {
        refused(&DampingReport {
            regime: Some(regime),
            ..noise_window(1.0)
        });
    }
    refused(&DampingReport {
        regime: None,
        ..noise_window(1.0)
    });
    // a window the model or the envelope decides
    for source in [Zeta0Source::Model, Zeta0Source::Envelope] {
        refused(&DampingReport {
            zeta0_source: Some(source),
            ..noise_window(1.0)
        });
    }
    // self-excited after self-excited (the verdict test passes): still tested
    let p_excited = Previous {
        verdict: Verdict::SelfExcited,
        ..previous()
    };
    let excited = DampingReport {
        verdict: Verdict::SelfExcited,
        ..noise_window(1.0)
    };
    assert!(!noise_driven(&p_excited, &excited));
    assert_eq!(
        accept(&policy, &p_excited, &excited),
        Err(Rejection::Disagrees)
    );
    // departed from the gate's ambient level (1.0) though risen less than twofold since the
    // last window: the start of a burst that took two windows to grow
    let rising = Previous {
        signal_rms: Some(1.6),
        ..previous()
    };
    assert!(noise_driven(&rising, &noise_window(2.9)));
    assert!(!noise_driven(&rising, &noise_window(3.0)));
    assert_eq!(
        accept(&policy, &rising, &noise_window(3.0)),
        Err(Rejection::LeavesAmbient)
    );
    // no level yet (fewer noise-driven windows than the level needs), or nothing to compare
    let new_gate = Previous {
        level: AmbientLevel::default(),
        ..previous()
    };
    assert!(!noise_driven(&new_gate, &noise_window(1.0)));
    let unmeasured = Previous {
        signal_rms: None,
        ..previous()
    };
    assert!(!noise_driven(&unmeasured, &noise_window(1.0)));
    assert!(!noise_driven(
        &previous(),
        &DampingReport {
            signal_rms: None,
            ..noise_window(1.0)
        }
    ));
    // with agreement, the fit test is what refuses (a window above the level with a fitted
    // model, as the previous one was: a held cycle)
    let held = Previous {
        signal_rms: Some(3.0),
        ..previous()
    };
    let agreeing = DampingReport {
        agrees: Some(true),
        model_zeta: fitted_model(),
        ..noise_window(3.0)
    };
    assert!(matches!(
        accept(&policy, &held, &agreeing),
        Err(Rejection::Fit { .. })
    ));
}

/// The level after a tracked window the model decided, at the gate's level and undecided, so
/// that only its source keeps it out (at 9 times the level it was left out as departed, and
/// the source was never consulted: a review, stop 67).
fn fitted_level(p: &Previous) -> AmbientLevel {
    let a = WindowAnalysis {
        equation: String::new(),
        coefficients: Vec::new(),
        damping: DampingReport {
            zeta0_source: Some(Zeta0Source::Model),
            regime: Some(Regime::Undecided),
            signal_rms: Some(1.0),
            ..report()
        },
        evaluations: 0,
        seconds: 0.0,
        warm_start: vec![1.0],
        path: Path::Tracked,
    };
    Previous::after(Some(p), &a, 105.0, 115.0).level
}

#[test]
fn the_level_follows_noise_driven_windows_at_the_level_only() {
    let window = |path, damping| WindowAnalysis {
        equation: String::new(),
        coefficients: Vec::new(),
        damping,
        evaluations: 0,
        seconds: 0.0,
        warm_start: vec![20.0, -4.0, 1.1],
        path,
    };
    let p = previous(); // level 1.0
    let noise = Previous::after(
        Some(&p),
        &window(Path::Tracked, noise_window(1.2)),
        105.0,
        115.0,
    );
    assert_eq!(noise.coefficients, vec![20.0, -4.0, 1.1]);
    assert_eq!((noise.since_full, noise.signal_rms), (1, Some(1.2)));
    // a noise-driven window feeds the level, a model-decided one does not
    let mut fed = p.level.clone();
    fed.record(&noise_window(1.2));
    assert_eq!(noise.level, fed);
    assert_eq!(fitted_level(&p), p.level);
    // nor does a departed one, whatever read it
    let departed = Previous::after(
        Some(&p),
        &window(Path::Tracked, noise_window(3.5)),
        105.0,
        115.0,
    );
    assert_eq!(departed.level, p.level);
}

#[test]
fn previous_counts_tracked_windows_and_keeps_the_full_fit() {
    let mut a = WindowAnalysis {
        equation: String::new(),
        coefficients: Vec::new(),
        damping: report(),
        evaluations: 0,
        seconds: 0.0,
        warm_start: vec![1.0, 2.0, 3.0],
        path: Path::Full,
    };
    let full = Previous::after(None, &a, 0.0, 10.0);
    assert_eq!((full.since_full, full.full_fit_nmae), (0, 0.025));
    a.path = Path::Tracked;
    a.damping.fit_nmae = 0.03;
    a.damping.signal_rms = Some(2.5);
    let tracked = Previous::after(Some(&full), &a, 5.0, 15.0);
    assert_eq!((tracked.since_full, tracked.full_fit_nmae), (1, 0.025));
    assert_eq!(tracked.coefficients, vec![1.0, 2.0, 3.0]);
    assert_eq!((tracked.t_start, tracked.t_end), (5.0, 15.0));
    assert_eq!(tracked.signal_rms, Some(2.5));
}

#[test]
fn policy_validation_names_the_key() {
    let bad = TrackingPolicy {
        full_every: 0,
        ..TrackingPolicy::default()
    };
    assert!(bad.validate().unwrap_err().starts_with("full_every"));
    let bad = TrackingPolicy {
        fit_tolerance: 0.5,
        ..TrackingPolicy::default()
    };
    assert!(bad.validate().unwrap_err().starts_with("fit_tolerance"));
    for refine_rtol in [0.0, 1.0, f64::NAN] {
        let bad = TrackingPolicy {
            refine_rtol,
            ..TrackingPolicy::default()
        };
        assert!(bad.validate().unwrap_err().starts_with("refine_rtol"));
    }
    for max_gap_windows in [-1.0, MAX_GAP_WINDOWS + 1.0, f64::NAN, f64::INFINITY] {
        let bad = TrackingPolicy {
            max_gap_windows,
            ..TrackingPolicy::default()
        };
        assert!(bad.validate().unwrap_err().starts_with("max_gap_windows"));
    }
    assert_eq!(TrackingPolicy::default().validate(), Ok(()));
}
