//! Unit tests of the linearisation, the energy balance and the biased population.

use super::*;
use crate::model::Model;
use approx::assert_relative_eq;

fn gate_model() -> Model {
    Model::parse(
        "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0",
        &[("k".to_string(), 81360.0)],
    )
    .unwrap()
}

#[test]
fn linearization_of_the_gate_model() {
    let m = gate_model();
    let lin = Linearization::of(&m, &[19.14, -12.18, 447.3], 0.0, 1e-3, 0.065);
    assert_relative_eq!(lin.m0, 19.14, max_relative = 1e-12);
    assert_relative_eq!(lin.c0, -12.18, max_relative = 1e-6);
    assert_relative_eq!(lin.k0, 81360.0, max_relative = 1e-6);
    let zeta = -12.18 / (2.0 * (81360.0f64 * 19.14).sqrt());
    assert_relative_eq!(lin.zeta0().unwrap(), zeta, max_relative = 1e-6);
    // A rest position without restoring force has no damping ratio.
    let flat = Linearization {
        m0: 1.0,
        c0: 0.1,
        k0: -1.0,
    };
    assert_eq!(flat.zeta0(), None);
}

#[test]
fn equivalent_damping_of_cubic_damping_matches_harmonic_balance() {
    // c_eq(a) = c1 + (3/4) c3 (a w)^2 for (c1 + c3 yd^2) yd.
    let m = gate_model();
    let c = [19.14, -12.18, 447.3];
    let lin = Linearization::of(&m, &c, 0.0, 1e-3, 0.065);
    let w = lin.omega0().unwrap();
    for a in [1e-4, 1e-3, 3e-3] {
        let (z, energy) = equivalent_damping(&m, &c, &lin, a, 0.0).unwrap();
        let c_eq = -12.18 + 0.75 * 447.3 * (a * w).powi(2);
        assert_relative_eq!(z, c_eq / (2.0 * 19.14 * w), max_relative = 1e-6);
        // Energy fed in per cycle: -pi c_eq w a^2.
        assert_relative_eq!(
            energy,
            -std::f64::consts::PI * c_eq * w * a * a,
            max_relative = 1e-6
        );
    }
    let a_lc = limit_cycle(&m, &c, &lin, 1e-3, 0.0).unwrap();
    let expected = (4.0f64 * 12.18 / (3.0 * 447.3)).sqrt() / w;
    assert_relative_eq!(a_lc, expected, max_relative = 1e-6);
    // Below the limit cycle the amplitude grows towards it but never reaches a limit above it.
    assert_eq!(
        time_to_amplitude(&m, &c, &lin, 1e-3, 2.0 * expected, 0.0),
        None
    );
    // Without the cubic term it grows exponentially: t = ln(limit/now) / sigma.
    let linear = [19.14, -12.18, 0.0];
    let t = time_to_amplitude(&m, &linear, &lin, 1e-3, 1e-2, 0.0).unwrap();
    let sigma = 12.18 / (2.0 * 19.14);
    assert_relative_eq!(t, 10f64.ln() / sigma, max_relative = 1e-3);
    assert_eq!(limit_cycle(&m, &linear, &lin, 1e-3, 0.0), None);
}

#[test]
fn cycle_zeta0_is_the_law_a_growth_carries_to_any_amplitude() {
    // zeta_eq(a) = zeta0 + b a^2 for cubic damping, so the zeta0 that makes `a` a limit cycle is
    // -b a^2: the model's own zeta0 at its limit cycle, four times it at twice that amplitude,
    // and, as a function of the coefficients, it moves with the cubic term where zeta0 does not.
    let m = gate_model();
    let c = [19.14, -12.18, 447.3];
    let lin = Linearization::of(&m, &c, 0.0, 1e-3, 0.065);
    let zeta0 = lin.zeta0().unwrap();
    let a_lc = limit_cycle(&m, &c, &lin, 1e-3, 0.0).unwrap();
    assert_relative_eq!(
        cycle_zeta0(&m, &c, &lin, a_lc, 0.0).unwrap(),
        zeta0,
        max_relative = 1e-6
    );
    assert_relative_eq!(
        cycle_zeta0(&m, &c, &lin, 2.0 * a_lc, 0.0).unwrap(),
        4.0 * zeta0,
        max_relative = 1e-6
    );
    let stronger_cubic = [19.14, -12.18, 2.0 * 447.3];
    let lin2 = Linearization::of(&m, &stronger_cubic, 0.0, 1e-3, 0.065);
    assert_relative_eq!(lin2.zeta0().unwrap(), zeta0, max_relative = 1e-9);
    assert_relative_eq!(
        cycle_zeta0(&m, &stronger_cubic, &lin2, a_lc, 0.0).unwrap(),
        2.0 * zeta0,
        max_relative = 1e-6
    );
    // no restoring force at rest: no damping ratio, no law
    let flat = Linearization {
        m0: 1.0,
        c0: 0.1,
        k0: -1.0,
    };
    assert_eq!(cycle_zeta0(&m, &c, &flat, a_lc, 0.0), None);
}

#[test]
fn biased_population_satisfies_the_spectral_constraints() {
    let m = gate_model();
    let scales = [19.0, 40.0, 1000.0];
    let w = 2.0 * std::f64::consts::PI * 10.38;
    let target = SpectralTarget {
        omega: w,
        sigma: Some(0.3),
    };
    let pop = biased_population(&m, &scales, target, 20, 7, 0.0, 1e-3, 0.065);
    assert_eq!(pop.len(), 20);
    for x in &pop {
        let c: Vec<f64> = x.iter().zip(&scales).map(|(x, s)| x * s).collect();
        let lin = Linearization::of(&m, &c, 0.0, 1e-3, 0.065);
        assert_relative_eq!(lin.k0 / lin.m0, w * w, max_relative = 1e-6);
        assert_relative_eq!(lin.c0 / lin.m0, -0.6, epsilon = 1e-6);
    }
    // The coordinates the constraints leave free stay spread out.
    let c3: Vec<f64> = pop.iter().map(|x| x[2]).collect();
    let spread =
        c3.iter().cloned().fold(f64::MIN, f64::max) - c3.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 0.5, "{c3:?}");
}

#[test]
fn zeta0_source_and_ambient_zeta_serialise_as_before() {
    // The API and `identify --json` showed `zeta0_source` as a string (or null) and
    // `ambient_zeta` as an array `[zeta, low, high]` when they were `Option<String>` and a tuple.
    let report = DampingReport {
        zeta0: Some(0.01),
        zeta0_source: Some(Zeta0Source::Ambient),
        ambient_zeta: Some(AmbientZeta {
            zeta: 0.01,
            low: 0.005,
            high: 0.015,
        }),
        // `unknown()`'s infinite NMAE serialises as null, which does not read back as an f64.
        fit_nmae: 0.5,
        ..DampingReport::unknown()
    };
    let json = serde_json::to_value(&report).unwrap();
    assert_eq!(json["zeta0_source"], serde_json::json!("ambient"));
    assert_eq!(
        json["ambient_zeta"],
        serde_json::json!([0.01, 0.005, 0.015])
    );
    assert_eq!(json["verdict"], serde_json::json!("unknown"));
    let back: DampingReport = serde_json::from_value(json).unwrap();
    assert_eq!(back.ambient_zeta, report.ambient_zeta);
    assert_eq!(back.zeta0_source, report.zeta0_source);

    for (source, name) in [
        (Zeta0Source::Model, "model"),
        (Zeta0Source::Ambient, "ambient"),
    ] {
        assert_eq!(
            serde_json::to_value(source).unwrap(),
            serde_json::json!(name)
        );
        assert_eq!(source.as_str(), name);
        assert_eq!(source.to_string(), name);
    }
    let none = serde_json::to_value(DampingReport::unknown()).unwrap();
    assert!(none["zeta0_source"].is_null());
    assert!(none["ambient_zeta"].is_null());
}

/// 3000 samples at `fs` of a sine at `f`: amplitude `before` up to sample `step`, 1 after.
fn stepped_sine(fs: f64, f: f64, step: usize, before: f64) -> Vec<f64> {
    (0..3000)
        .map(|i| {
            let amp = if i < step { before } else { 1.0 };
            amp * (2.0 * std::f64::consts::PI * f * i as f64 / fs).sin()
        })
        .collect()
}

/// A displacement signal's options: no moving average before the relaxation.
fn displacement() -> series::SeriesOptions {
    series::SeriesOptions {
        signal: Signal::Displacement,
        ..series::SeriesOptions::default()
    }
}

/// The relaxation's record: the last 100 cycles of the history when they are longer than the
/// window and the cycle's level held; else the window alone (`None`).
#[test]
fn the_relaxation_reads_the_history_only_over_a_steady_cycle() {
    let (fs, f, n) = (100.0, 5.0, 1000);
    let opts = displacement();
    let wave = |amp_before: f64| stepped_sine(fs, f, 2000, amp_before);
    // steady: the last 100 cycles (2000 samples at 20 per cycle) of the 3000 held
    let (record, rate) = model_free::relaxation_record(&wave(1.1), fs, f, n, &opts).unwrap();
    assert_eq!((record.len(), rate), (2000, fs));
    // the cycle grew by half within the history: the window alone
    assert!(model_free::relaxation_record(&wave(0.6), fs, f, n, &opts).is_none());
    assert!(model_free::relaxation_record(&wave(1.5), fs, f, n, &opts).is_none());
    // no history beyond the window, or a gate fast enough for its window: the window alone
    assert!(model_free::relaxation_record(&wave(1.0)[2000..], fs, f, n, &opts).is_none());
    assert!(model_free::relaxation_record(&wave(1.0), fs, 10.4, 2000, &opts).is_none());
    // a non-finite sample in the history: the window alone
    let mut bad = wave(1.0);
    bad[10] = f64::NAN;
    assert!(model_free::relaxation_record(&bad, fs, f, n, &opts).is_none());
}

/// Where the 100 cycles hold several windows (a 2 Hz gate: 50 s, five 10 s windows), the record
/// ends at the first window-long block, going back, whose level differs from the window's: a
/// cycle that grew from 0.6 of its level 30 s ago is read over its last 30 s, not its last
/// 50 s, though the mean level of the 40 s before the window is within 25 % of the window's.
#[test]
fn the_relaxation_reads_the_history_back_to_where_the_level_moved() {
    let (fs, f, n) = (50.0, 2.0, 500);
    let opts = displacement();
    // 60 s of history (six windows); the cycle at `old` until 30 s ago, at 1 since
    let wave = |old: f64| stepped_sine(fs, f, 1500, old);
    let steady = model_free::relaxation_record(&wave(1.1), fs, f, n, &opts).unwrap();
    assert_eq!((steady.0.len(), steady.1), (2500, fs), "100 cycles");
    let grown = wave(0.6);
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let before = rms(&grown[500..2500]) / rms(&grown[2500..]);
    assert!(
        before > 1.0 / 1.25,
        "the mean level before the window passes: {before}"
    );
    let (record, _) = model_free::relaxation_record(&grown, fs, f, n, &opts).unwrap();
    assert_eq!(record.len(), 1500, "back to where the level moved");
    // the block just before the window moved: the window alone
    let mut late = wave(1.0);
    late[1900..2500].iter_mut().for_each(|v| *v *= 0.5);
    assert!(model_free::relaxation_record(&late, fs, f, n, &opts).is_none());
}

/// `rms_swing`: about 1 on a steady oscillation, the ratio of the amplitudes where the third
/// with the largest and the one with the smallest differ; none without three usable thirds.
#[test]
fn rms_swing_is_the_largest_over_the_smallest_third() {
    let wave = |a: f64, i: usize| a * (i as f64 * 0.7).sin();
    let steady: Vec<f64> = (0..600).map(|i| wave(2.0, i)).collect();
    assert_relative_eq!(rms_swing(&steady).unwrap(), 1.0, max_relative = 0.02);
    // a burst that ends: 10 times the amplitude in the first third
    let ending: Vec<f64> = (0..600)
        .map(|i| wave(if i < 200 { 10.0 } else { 1.0 }, i))
        .collect();
    assert_relative_eq!(rms_swing(&ending).unwrap(), 10.0, max_relative = 0.05);
    assert_eq!(rms_swing(&[1.0, 2.0, 3.0, 4.0, 5.0]), None);
    let mut flat_start = steady.clone();
    flat_start[..200].fill(3.0);
    assert_eq!(rms_swing(&flat_start), None, "a constant third");
}

/// The relaxation may remove a bend only where the window's level moved by more than
/// `BEND_LEVEL_CHANGE` against the record before it, either way; without that record, or with a
/// flat one, a line at most.
#[test]
fn a_bend_is_removed_only_where_the_level_moved() {
    let n = 400;
    let sine = |amp: f64, from: usize| -> Vec<f64> {
        (from..from + n)
            .map(|i| amp * (0.3 * i as f64).sin())
            .collect()
    };
    let history = |a0: f64, a1: f64| [sine(a0, 0), sine(a1, n)].concat();
    assert_eq!(relaxation_detrend_degree(&history(1.0, 1.0), n), 1);
    assert_eq!(relaxation_detrend_degree(&history(1.0, 1.15), n), 1);
    assert_eq!(
        relaxation_detrend_degree(&history(1.0, 1.3), n),
        BEND_DEGREE
    );
    assert_eq!(
        relaxation_detrend_degree(&history(1.3, 1.0), n),
        BEND_DEGREE
    );
    // Only the `n` samples before the window count: an older level is not looked at.
    let older = [sine(5.0, 0), history(1.0, 1.0)].concat();
    assert_eq!(relaxation_detrend_degree(&older, n), 1);
    // No record before the window, or a flat one: no evidence that the level moved.
    assert_eq!(relaxation_detrend_degree(&sine(1.0, 0), n), 1);
    assert_eq!(relaxation_detrend_degree(&history(0.0, 1.0), n), 1);
}

/// The polish's RK4 steps per sample give every cycle of the measured frequency at least
/// `MIN_RK4_STEPS_PER_CYCLE` steps: two per sample on the lab gate (200 Hz, 10.4 Hz) and the
/// lock gate (100 Hz, 5 Hz), more where the sampling is coarser, none for a bad frequency.
#[test]
fn polish_substeps_give_each_cycle_thirty_two_steps() {
    let w = |hz: f64| 2.0 * std::f64::consts::PI * hz;
    assert_eq!(polish_substeps(w(10.4), 1.0 / 200.0), Some(2));
    assert_eq!(polish_substeps(w(5.0), 1.0 / 100.0), Some(2));
    // 32 samples per cycle: one step per sample.
    assert_eq!(polish_substeps(w(5.0), 1.0 / 160.0), Some(1));
    // 8 samples per cycle: four steps per sample.
    assert_eq!(polish_substeps(w(5.0), 1.0 / 40.0), Some(4));
    // 5 samples per cycle: 6.4, so 7 steps per sample.
    assert_eq!(polish_substeps(w(5.0), 1.0 / 25.0), Some(7));
    for (s, dt) in [(10.0, 1.0 / 25.0), (7.3, 1.0 / 91.0), (0.3, 0.5)] {
        let steps_per_cycle = polish_substeps(w(s), dt).unwrap() as f64 / (s * dt);
        assert!(
            steps_per_cycle >= MIN_RK4_STEPS_PER_CYCLE,
            "{s} Hz, dt {dt}"
        );
    }
    assert_eq!(polish_substeps(w(1e9), 1.0), Some(1000));
    assert_eq!(polish_substeps(f64::NAN, 0.01), None);
    assert_eq!(polish_substeps(w(5.0), 0.0), None);
    assert_eq!(polish_substeps(-1.0, 0.01), None);
}

/// A model-decided window says `self_excited` or `damped` only when its interval lies on that
/// side of zero; across zero it is `unknown` and stays trusted. Other sources keep their row.
#[test]
fn a_model_windows_verdict_follows_its_interval() {
    use super::report::{DampingReport, Verdict, Zeta0Source};
    let report = |source, verdict, interval: (f64, f64)| DampingReport {
        zeta0: Some(0.5 * (interval.0 + interval.1)),
        zeta0_interval: Some(interval),
        zeta0_source: Some(source),
        verdict,
        trusted: true,
        ..DampingReport::default()
    };
    let read = |mut d: DampingReport| {
        series::read_the_models_sign_from_its_interval(&mut d);
        (d.verdict, d.trusted)
    };
    let m = Zeta0Source::Model;
    // the steady sine of session 49: -0.03 % (-0.11, +0.05)
    let sine = report(m, Verdict::SelfExcited, (-0.0011, 0.0005));
    assert_eq!(read(sine), (Verdict::Unknown, true));
    let below = report(m, Verdict::SelfExcited, (-0.03, -0.01));
    assert_eq!(read(below), (Verdict::SelfExcited, true));
    let across = report(m, Verdict::Damped, (-0.002, 0.02));
    assert_eq!(read(across), (Verdict::Unknown, true));
    let above = report(m, Verdict::Damped, (0.002, 0.02));
    assert_eq!(read(above), (Verdict::Damped, true));
    // an envelope row decides by its own rule (decide), untouched here
    let envelope = report(Zeta0Source::Envelope, Verdict::SelfExcited, (-0.02, 0.01));
    assert_eq!(read(envelope), (Verdict::SelfExcited, true));
    // no interval: no evidence against the row
    let mut bare = report(m, Verdict::SelfExcited, (-0.02, -0.01));
    bare.zeta0_interval = None;
    assert_eq!(read(bare), (Verdict::SelfExcited, true));
}

/// The settings enums read their configuration spelling from the command line too, and an
/// unknown word names what it is and the words expected.
#[test]
fn settings_words_parse_as_the_configuration_spells_them() {
    use super::{ForceTerms, ModelInterval, SsiReference};
    assert_eq!("all".parse(), Ok(ForceTerms::All));
    assert_eq!("stiffness".parse(), Ok(ForceTerms::Stiffness));
    assert_eq!("lagged".parse(), Ok(SsiReference::Lagged));
    assert_eq!("common".parse(), Ok(SsiReference::Common));
    assert_eq!("newey-west".parse(), Ok(ModelInterval::NeweyWest));
    assert_eq!("forcing".parse(), Ok(ModelInterval::Forcing));
    assert_eq!(
        "Forcing".parse::<ModelInterval>(),
        Err("unknown model interval `Forcing`: expected newey-west or forcing".to_string())
    );
    assert_eq!(
        "".parse::<SsiReference>(),
        Err("unknown SSI reference ``: expected lagged or common".to_string())
    );
    assert_eq!(
        "newey_west".parse::<ForceTerms>(),
        Err("unknown force terms `newey_west`: expected all or stiffness".to_string())
    );
}

/// A displacement record's scales follow its unit, a power of ten: none for a record of order
/// one (the chapter's search box), `u^p` for the coefficients and `u` for fitted initial
/// conditions otherwise, none for an equation that fixes its solutions' size.
#[test]
fn displacement_scales_follow_the_records_unit() {
    let vdp = Model::parse("ydd + (c1 + c2*y^2)*yd + y = 0", &[]).unwrap();
    let known = crate::identify::Initial::FromData;
    assert!(displacement_scales(&vdp, 2.0, &known).is_empty());
    assert!(displacement_scales(&vdp, 0.4, &known).is_empty());
    let s = displacement_scales(&vdp, 2.6e4, &known);
    assert_eq!(s.len(), 2);
    assert_relative_eq!(s[0], 1.0);
    assert_relative_eq!(s[1], 1e-8, max_relative = 1e-12);
    let s = displacement_scales(&vdp, 8e-4, &crate::identify::Initial::Fit);
    assert_eq!(s.len(), 4);
    assert_relative_eq!(s[1], 1e6, max_relative = 1e-12);
    assert_relative_eq!(s[2], 1e-3, max_relative = 1e-12);
    assert_relative_eq!(s[3], 1e-3, max_relative = 1e-12);
    let fixed = Model::parse("ydd + c1*yd + y + y^3 = 0", &[]).unwrap();
    assert!(displacement_scales(&fixed, 1e4, &known).is_empty());
}

/// A 5 Hz gate's 10 s window holds 50 cycles, over which a stable gate's envelope often looks as
/// steady as a cycle's; over the last 100 cycles of its history it does less often, and a held
/// cycle's still does (`model_free::steady_over_cycles`). Streams of the lock preset at +0.5 %
/// (four seeds of 30 min) and on its -2 % cycle, windows of 10 s every 5 s with 30 s of history,
/// as the daemon hands them over: the limit-cycle windows with the history against the window
/// alone (measured: 65 and 22 of 1,420 at +0.5 %).
#[test]
fn a_limit_cycle_window_must_be_steady_over_a_hundred_cycles() {
    use crate::simulate::{GatePreset, NoiseLevel, ScenarioName};
    let p = GatePreset::Lock.params();
    let fs = p.rate_hz;
    let opts = series::SeriesOptions {
        signal: Signal::Force,
        stiffness: Some(p.stiffness),
        ..series::SeriesOptions::default()
    };
    let (w, step, hist) = (
        (10.0 * fs) as usize,
        (5.0 * fs) as usize,
        (30.0 * fs) as usize,
    );
    let count = |scenario: ScenarioName, seconds: f64, seed: u64| -> (usize, usize, usize) {
        let mut sim = scenario
            .def(&p)
            .simulator(&p, NoiseLevel::Relative(0.125), seed)
            .unwrap();
        let mut y = vec![0.0; (seconds * fs) as usize];
        sim.fill(&mut y);
        let mut spectral = None;
        let (mut windows, mut alone, mut with) = (0, 0, 0);
        let mut end = hist;
        while end <= y.len() {
            let t: Vec<f64> = (0..w).map(|i| i as f64 / fs).collect();
            let series = crate::data::TimeSeries::new(t, y[end - w..end].to_vec()).unwrap();
            let data = model_free::preprocess(&series, &opts);
            let mut lc = |history: &[f64]| {
                model_free::model_free(&data, history, &opts, &mut spectral)
                    .spec
                    .is_some_and(|s| s.regime == crate::spectral::Regime::LimitCycle)
            };
            alone += usize::from(lc(&[]));
            with += usize::from(lc(&y[end - hist..end]));
            windows += 1;
            end += step;
        }
        (windows, alone, with)
    };
    let (mut n, mut alone, mut with) = (0, 0, 0);
    for seed in 1..=4 {
        let c = count(ScenarioName::StableLow, 1800.0, seed);
        (n, alone, with) = (n + c.0, alone + c.1, with + c.2);
    }
    assert!(
        alone >= 20 && with * 2 <= alone,
        "+0.5 %: {alone} of {n} windows classed limit cycles alone, {with} with the history"
    );
    let (n, alone, with) = count(ScenarioName::LimitCycle, 120.0, 24);
    assert!(
        alone * 10 >= n * 9 && with == alone,
        "-2 % cycle: {alone} of {n} windows classed limit cycles alone, {with} with the history"
    );
}

/// A noise-driven window of a 2 Hz gate (20 cycles) is read again with its history, 100 cycles
/// (`model_free::AMBIENT_RECORD_CYCLES`), back to where the response's level moved; a window
/// that holds 100 cycles, or has no history, is read alone.
#[test]
fn a_slow_gates_ambient_reading_reads_100_cycles_of_its_history() {
    use crate::simulate::{GatePreset, NoiseLevel, ScenarioName};
    let read = |preset: GatePreset, before: f64| {
        let p = preset.params();
        let fs = p.rate_hz;
        let opts = series::SeriesOptions {
            signal: Signal::Force,
            stiffness: Some(p.stiffness),
            ..series::SeriesOptions::default()
        };
        let mut sim = ScenarioName::Stable
            .def(&p)
            .simulator(&p, NoiseLevel::Relative(0.125), 3)
            .unwrap();
        let mut y = vec![0.0; (300.0 * fs) as usize];
        sim.fill(&mut y);
        // the history keeps the last 70 s, the window the last 10 s; `before` scales what came
        // more than 20 s before the end (a burst: the response at another level)
        let (w, hist) = ((10.0 * fs) as usize, (70.0 * fs) as usize);
        let start = y.len() - hist;
        let y = &mut y[start..];
        let cut = y.len() - 2 * w;
        y[..cut].iter_mut().for_each(|v| *v *= before);
        let t: Vec<f64> = (0..w).map(|i| i as f64 / fs).collect();
        let series = crate::data::TimeSeries::new(t, y[hist - w..].to_vec()).unwrap();
        let data = model_free::preprocess(&series, &opts);
        let mut spectral = None;
        let with = model_free::model_free(&data, y, &opts, &mut spectral);
        let alone = model_free::model_free(&data, &y[hist - w..], &opts, &mut spectral);
        assert!(alone.ambient_record.is_none());
        let own = with
            .spec
            .and_then(|s| s.ambient)
            .expect("an SSI-COV reading");
        (with.ambient_record, own.zeta_high - own.zeta_low)
    };
    let (record, own_width) = read(GatePreset::Barrier, 1.0);
    let (a, seconds) = record.expect("the 2 Hz gate's window is read with its history");
    assert!((48.0..=51.0).contains(&seconds), "{seconds} s: 100 cycles");
    assert!(
        a.high - a.low < 0.6 * own_width,
        "the record's interval {a:?} against the window's width {own_width}"
    );
    // five times the level more than 20 s back: the record stops at the window before
    let (record, _) = read(GatePreset::Barrier, 5.0);
    let seconds = record.expect("one window of history still holds").1;
    assert!((19.0..=20.0).contains(&seconds), "{seconds} s");
    // a 5 Hz gate's 100 cycles are 20 s; the 10.4 Hz lab gate's window holds them
    assert!(read(GatePreset::Lock, 1.0)
        .0
        .is_some_and(|r| (19.0..=20.5).contains(&r.1)));
    assert!(read(GatePreset::Lab, 1.0).0.is_none());
}
