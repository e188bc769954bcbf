//! Damping estimates per regime, judged against the simulator's truth: median error over
//! seeded windows and the coverage of the 95 % intervals, on the lab gate (19 kg, 10.4 Hz,
//! 200 Hz) and on a 2000 kg, 5 Hz lock gate sampled at 100 Hz, both with an absolute sensor
//! noise floor. Nothing here is tuned per gate: the same options serve both.

use gatewatch::analysis::{relaxation_detrend_degree, BEND_DEGREE};
use gatewatch::simulate::{
    GateParams, GatePreset, GateSimulator, NoiseLevel, ScenarioName, ZetaSchedule,
};
use gatewatch::spectral::{RelaxationOptions, SpectralAnalyzer};

/// The lab gate with the turbulent forcing (about 5.6 N RMS response at +2 %) and a load
/// cell's noise floor of 0.7 N RMS.
fn lab_gate() -> GateParams {
    GateParams {
        forcing_std: 2.8,
        noise_std: 0.7,
        ..GateParams::default()
    }
}

/// A 2000 kg, 5 Hz lock gate at 100 Hz, scaled so that its ambient response at +2 % and its
/// sensor noise stand to its limit cycle (at -2 %) as the lab gate's do.
fn lock_gate() -> GateParams {
    let lab = lab_gate();
    let mass = 2000.0;
    let stiffness = mass * (2.0 * std::f64::consts::PI * 5.0f64).powi(2);
    let mut p = GateParams {
        mass,
        stiffness,
        rate_hz: 100.0,
        c3: 3.0e6,
        forcing_std: 1.0,
        noise_std: 0.0,
        ..GateParams::default()
    };
    let ratio = lab.stationary_force_std(0.02) / lab.limit_cycle_force_amplitude(-0.02).unwrap();
    let target = ratio * p.limit_cycle_force_amplitude(-0.02).unwrap();
    p.forcing_std *= target / p.stationary_force_std(0.02);
    p.noise_std = lab.noise_std / lab.stationary_force_std(0.02) * target;
    p
}

/// The crate's median (`identify::median`).
fn median(mut v: Vec<f64>) -> f64 {
    gatewatch::identify::median(&mut v).unwrap_or(f64::NAN)
}

/// Consecutive `secs`-second windows of a gate held at `zeta` on its limit cycle (started on
/// the cycle, 20 s settling discarded).
fn limit_cycle_windows(
    p: GateParams,
    zeta: f64,
    windows: usize,
    secs: f64,
    seed: u64,
) -> Vec<Vec<f64>> {
    let y_lc = p.limit_cycle_force_amplitude(zeta).unwrap() / p.stiffness;
    let p = GateParams { y0: y_lc, ..p };
    let rate = p.rate_hz;
    let mut sim = GateSimulator::new(p, ZetaSchedule::Constant(zeta), seed);
    let mut burn = vec![0.0; (20.0 * rate) as usize];
    sim.fill(&mut burn);
    (0..windows)
        .map(|_| {
            let mut x = vec![0.0; (secs * rate) as usize];
            sim.fill(&mut x);
            x
        })
        .collect()
}

/// (median |error|, coverage, median estimate) of the envelope estimator over the windows.
fn envelope_scores(
    p: GateParams,
    zeta: f64,
    windows: usize,
    secs: f64,
    seed: u64,
) -> (f64, f64, f64) {
    let f = p.natural_frequency_hz();
    let rate = p.rate_hz;
    let ws = limit_cycle_windows(p, zeta, windows, secs, seed);
    let mut sa = SpectralAnalyzer::new(ws[0].len(), rate).unwrap();
    let opts = RelaxationOptions::default();
    let mut errs = Vec::new();
    let mut est = Vec::new();
    let mut covered = 0;
    for (i, x) in ws.iter().enumerate() {
        let peak = sa.dominant_frequency(x, 1.0).unwrap().frequency_hz;
        let e = sa
            .envelope_relaxation(x, peak, &opts)
            .unwrap_or_else(|e| panic!("window {i} (f {f:.2} Hz): {e}"));
        errs.push((e.zeta0 - zeta).abs());
        est.push(e.zeta0);
        if e.zeta0_interval.0 <= zeta && zeta <= e.zeta0_interval.1 {
            covered += 1;
        }
        eprintln!(
            "window {i}: zeta0 {:+.3} % [{:+.3}, {:+.3}] cv {:.3} T|lambda| {:.1}",
            100.0 * e.zeta0,
            100.0 * e.zeta0_interval.0,
            100.0 * e.zeta0_interval.1,
            e.cv,
            e.correlation_times
        );
    }
    (median(errs), covered as f64 / ws.len() as f64, median(est))
}

#[test]
fn limit_cycle_envelope_lab_gate() {
    // 26 envelope correlation times per 10 s window: one window is enough.
    let (err, cov, med) = envelope_scores(lab_gate(), -0.02, 20, 10.0, 1);
    eprintln!(
        "lab gate: median |error| {:.3} points, coverage {:.2}, median {:+.3} %",
        100.0 * err,
        cov,
        100.0 * med
    );
    assert!(err <= 0.005, "median |error| {:.3} points", 100.0 * err);
    assert!(cov >= 0.9, "coverage {cov}");
}

/// Near-normal noise of unit variance (a sum of 12 xorshift uniforms), seeded: the sensor noise
/// of the steady-sine records.
fn seeded_normal(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        (0..12)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64
            })
            .sum::<f64>()
            - 6.0
    }
}

/// A steady sine with sensor noise (a forced vibration, or a cycle no turbulence kicks) is not
/// a limit cycle whose relaxation can be read: its envelope moves only by the band-pass's
/// ripple and the noise, which decorrelate within about a period, and the fit read that as
/// -4 to -11 % with a confident interval (session 49). The estimate is refused, on 100-cycle
/// records at the three bench gates' frequencies and rates, from no noise to 5 % of the
/// amplitude; the -2 % cycles of `limit_cycle_envelope_*` are read, so the refusal is not
/// a blanket one.
#[test]
fn a_steady_sine_with_sensor_noise_has_no_relaxation_to_read() {
    for (rate, f) in [(200.0, 10.38), (100.0, 5.03), (50.0, 2.01)] {
        let n = (100.0 / f * rate) as usize;
        let mut sa = SpectralAnalyzer::new(n, rate).unwrap();
        let mut read_without = 0;
        for noise in [0.0, 0.2, 2.0, 10.0] {
            let mut normal = seeded_normal(0x9e37_79b9_7f4a_7c15);
            let x: Vec<f64> = (0..n)
                .map(|i| {
                    let t = i as f64 / rate;
                    200.0 * (2.0 * std::f64::consts::PI * f * t).sin() + noise * normal()
                })
                .collect();
            let got = sa.envelope_relaxation(&x, f, &RelaxationOptions::default());
            match got {
                Err(e) => assert!(e.to_string().contains("no relaxation"), "{e}"),
                Ok(r) => panic!(
                    "{f} Hz, noise {noise}: read zeta0 {:+.2} % [{:+.2}, {:+.2}]",
                    100.0 * r.zeta0,
                    100.0 * r.zeta0_interval.0,
                    100.0 * r.zeta0_interval.1
                ),
            }
            // without the test, the same record is read as a violent relaxation
            let off = RelaxationOptions {
                floor_factor: 0.0,
                ..RelaxationOptions::default()
            };
            if let Ok(r) = sa.envelope_relaxation(&x, f, &off) {
                assert!(r.zeta0 < -0.02, "{f} Hz, noise {noise}: {}", r.zeta0);
                read_without += 1;
            }
        }
        // the control has something to say: it is the floor test that refuses these records
        assert!(
            read_without >= 1,
            "{f} Hz: refused even without the floor test"
        );
    }
}

/// The measurement behind `RelaxationOptions::floor_factor`: on 100-cycle records (the daemon's
/// relaxation record), the envelope's variance over the floor a steady sine shows, on steady
/// sines with noise and on the three bench gates' -2 % cycles at 0.1, 1 and 4 times the issue's
/// noise floor (session 49: sines 0.6 to 1.5, cycles 12.1 or more at the noise, 4.8 or
/// more at four times it).
#[test]
#[ignore = "exploration: cargo test --release --test integration damping_regimes::explore_relaxation_floor -- --ignored --nocapture"]
fn explore_relaxation_floor() {
    let off = RelaxationOptions {
        floor_factor: 0.0,
        ..RelaxationOptions::default()
    };
    let floor_of = |x: &[f64], rate: f64, f: f64| -> String {
        let mut sa = SpectralAnalyzer::new(x.len(), rate).unwrap();
        let mut w = x.to_vec();
        gatewatch::spectral::detrend_linear(&mut w);
        let Ok(r) = sa.envelope_relaxation(&w, f, &off) else {
            return "refused without the test".into();
        };
        // the ratio is where the test passes: the largest floor_factor that keeps the record
        let mut lo = 0.0;
        let mut hi = 1e6;
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            let opts = RelaxationOptions {
                floor_factor: mid,
                ..RelaxationOptions::default()
            };
            if sa.envelope_relaxation(&w, f, &opts).is_ok() {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        format!(
            "zeta0 {:+.2} % cv {:.4} variance / floor {:.2}",
            100.0 * r.zeta0,
            r.cv,
            lo
        )
    };
    for (rate, f) in [(200.0, 10.38), (100.0, 5.03), (50.0, 2.01)] {
        let n = (100.0 / f * rate) as usize;
        for noise in [0.0, 0.2, 2.0, 10.0] {
            let mut normal = seeded_normal(0x2545_f491_4f6c_dd1d);
            let x: Vec<f64> = (0..n)
                .map(|i| {
                    200.0 * (2.0 * std::f64::consts::PI * f * i as f64 / rate).sin()
                        + noise * normal()
                })
                .collect();
            eprintln!("sine {f} Hz, noise {noise}: {}", floor_of(&x, rate, f));
        }
    }
    for preset in [GatePreset::Lab, GatePreset::Lock, GatePreset::Barrier] {
        let p = preset.params();
        let f = p.natural_frequency_hz();
        let def = ScenarioName::LimitCycle.def(&p);
        for noise in [0.0125, 0.125, 0.5] {
            for seed in 1..=4u64 {
                let mut sim = def
                    .simulator(&p, NoiseLevel::Relative(noise), seed)
                    .unwrap();
                let mut x = vec![0.0; (100.0 / f * p.rate_hz) as usize];
                let mut burn = vec![0.0; (30.0 * p.rate_hz) as usize];
                sim.fill(&mut burn);
                sim.fill(&mut x);
                eprintln!(
                    "{} -2 % cycle, noise {noise} x, seed {seed}: {}",
                    preset.as_str(),
                    floor_of(&x, p.rate_hz, f)
                );
            }
        }
    }
}

/// The lock gate's 10 s window holds only about 13 envelope correlation times, so one window's
/// spread (about 0.75 points) is at the physical limit and its median |error| is about 0.5 to 0.6
/// points. Its intervals still cover; pooling consecutive windows' estimates with
/// [`DampingPool`] (cycles, not seconds: five 50-cycle windows) brings the error under the
/// target.
#[test]
fn limit_cycle_envelope_lock_gate_pooled() {
    use gatewatch::spectral::{DampingPool, PoolOptions, WindowEstimate};
    let p = lock_gate();
    let rate = p.rate_hz;
    let ws = limit_cycle_windows(p, -0.02, 24, 10.0, 2);
    let mut sa = SpectralAnalyzer::new(ws[0].len(), rate).unwrap();
    let mut pool = DampingPool::new(PoolOptions::default()).unwrap();
    let (mut single_cov, mut pooled_cov, mut pooled_errs) = (0, 0, Vec::new());
    for (i, x) in ws.iter().enumerate() {
        let f = sa.dominant_frequency(x, 1.0).unwrap().frequency_hz;
        let e = sa
            .envelope_relaxation(x, f, &RelaxationOptions::default())
            .unwrap_or_else(|e| panic!("window {i}: {e}"));
        if e.zeta0_interval.0 <= -0.02 && -0.02 <= e.zeta0_interval.1 {
            single_cov += 1;
        }
        let t = 10.0 * i as f64;
        let pooled = pool
            .push(WindowEstimate {
                t_start: t,
                t_end: t + 10.0,
                zeta: e.zeta0,
                stderr: e.zeta0_stderr,
                frequency_hz: f,
                record_seconds: 0.0,
                rms: None,
            })
            .unwrap();
        eprintln!(
            "window {i}: {:+.3} %, pooled {:+.3} % [{:+.3}, {:+.3}] over {} windows{}",
            100.0 * e.zeta0,
            100.0 * pooled.zeta,
            100.0 * pooled.interval.0,
            100.0 * pooled.interval.1,
            pooled.windows,
            if pooled.flushed { " (flushed)" } else { "" }
        );
        if i >= 4 {
            pooled_errs.push((pooled.zeta + 0.02).abs());
            if pooled.interval.0 <= -0.02 && -0.02 <= pooled.interval.1 {
                pooled_cov += 1;
            }
        }
    }
    let n = pooled_errs.len() as f64;
    let err = median(pooled_errs);
    eprintln!(
        "lock gate pooled: median |error| {:.3} points, coverage {:.2}; single windows' coverage {:.2}",
        100.0 * err,
        pooled_cov as f64 / n,
        single_cov as f64 / ws.len() as f64
    );
    assert!(
        single_cov as f64 >= 0.9 * ws.len() as f64,
        "single coverage {single_cov}"
    );
    assert!(
        err <= 0.005,
        "pooled median |error| {:.3} points",
        100.0 * err
    );
    assert!(
        pooled_cov as f64 >= 0.9 * n,
        "pooled coverage {pooled_cov} of {n}"
    );
}

/// The daemon's analyzer for gate `p` with the default force model and search.
fn force_analyzer(p: &GateParams) -> gatewatch::analysis::Analyzer {
    use gatewatch::analysis::{AnalysisSettings, Analyzer, Signal};
    Analyzer::new(AnalysisSettings {
        signal: Signal::Force,
        force_terms: Default::default(),
        stiffness: Some(p.stiffness),
        model: "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0".into(),
        params: vec![("k".into(), p.stiffness)],
        population: 20,
        generations: 40,
        amplitude_limit: None,
        max_fit_nmae: 0.2,
        polish_rtol: gatewatch::analysis::DEFAULT_POLISH_RTOL,
        polish_solver: gatewatch::analysis::PolishSolver::default(),
        model_interval: gatewatch::analysis::ModelInterval::default(),
        ssi_reference: gatewatch::analysis::SsiReference::default(),
    })
    .unwrap()
}

/// The daemon's analyzer on the lab and lock gates held on their limit cycle at -2 %: the report's
/// `zeta0` comes from the envelope and is right (issue 8: it read about -0.3 %, the demo +0.41 %).
/// Six windows per gate keep it CI-sized; `limit_cycle_envelope_*` above cover the statistics.
#[test]
fn analyzer_reports_the_limit_cycle_from_the_envelope() {
    use gatewatch::analysis::{WindowInput, Zeta0Source};
    for (name, p, seed) in [("lab gate", lab_gate(), 5), ("lock gate", lock_gate(), 6)] {
        let analyzer = force_analyzer(&p);
        let mut zetas = Vec::new();
        let mut covered = 0;
        let mut warm: Option<Vec<f64>> = None;
        for (i, x) in limit_cycle_windows(p.clone(), -0.02, 6, 10.0, seed)
            .iter()
            .enumerate()
        {
            let a = analyzer
                .analyze(
                    WindowInput {
                        t0: 10.0 * i as f64,
                        rate_hz: p.rate_hz,
                        values: x,
                        history: &[],
                    },
                    warm.as_deref(),
                    seed + i as u64,
                )
                .unwrap();
            let d = &a.damping;
            eprintln!(
                "{name} window {i}: zeta0 {:?} {:?} from {:?}, verdict {:?}, curve {} points",
                d.zeta0,
                d.zeta0_interval,
                d.zeta0_source,
                d.verdict,
                d.zeta_eq_curve.len()
            );
            // Never a trusted all-clear or a confident number near zero on a limit cycle.
            if d.trusted {
                assert!(d.zeta0.unwrap() < 0.0, "{name} window {i}: {d:?}");
            }
            if d.zeta0_source == Some(Zeta0Source::Envelope) {
                let (lo, hi) = d.zeta0_interval.unwrap();
                if (lo..=hi).contains(&-0.02) {
                    covered += 1;
                }
                zetas.push(d.zeta0.unwrap());
            }
            warm = Some(a.warm_start);
        }
        // Most windows are classified as a limit cycle and read from the envelope (the rest fall
        // back to the model as before: a window whose envelope the classifier does not call
        // saturated).
        assert!(zetas.len() >= 4, "{name}: {} envelope windows", zetas.len());
        assert!(
            covered + 1 >= zetas.len(),
            "{name}: {covered} of {} covered",
            zetas.len()
        );
        let m = median(zetas);
        // One window's physical spread is 0.5 (lab) to 0.75 points (lock gate). The lab gate's
        // median of six windows is checked at 0.75 points (the 0.5-point target over 20 windows
        // is `limit_cycle_envelope_lab_gate`). On the lock gate the daemon's windows read about
        // -1.2 % (seed 6), nearer zero than the envelope test's windows (-2.0 %, pooled): not
        // yet explained (the force mode's 1 s moving-average removal is the first suspect), so
        // only "clearly self-excited, not nearly stable" is asserted there.
        if name == "lab gate" {
            assert!((m + 0.02).abs() <= 0.0075, "{name}: median zeta0 {m}");
        } else {
            assert!(m < -0.005, "{name}: median zeta0 {m}");
        }
    }
}

#[test]
#[ignore]
fn explore_relaxation_options() {
    for (name, p) in [("lab", lab_gate()), ("lock", lock_gate())] {
        let rate = p.rate_hz;
        let ws = limit_cycle_windows(p.clone(), -0.02, 30, 10.0, 7);
        let mut sa = SpectralAnalyzer::new(ws[0].len(), rate).unwrap();
        for decay in [0.25, 0.35, 0.5, 0.7] {
            for lag in [0.25, 0.5, 0.75] {
                let opts = RelaxationOptions {
                    fit_decay: decay,
                    min_lag_periods: lag,
                    min_correlation_times: 0.0,
                    ..RelaxationOptions::default()
                };
                let mut est = Vec::new();
                let mut cov = 0;
                for x in &ws {
                    let peak = sa.dominant_frequency(x, 1.0).unwrap().frequency_hz;
                    if let Ok(e) = sa.envelope_relaxation(x, peak, &opts) {
                        est.push(e.zeta0);
                        if e.zeta0_interval.0 <= -0.02 && -0.02 <= e.zeta0_interval.1 {
                            cov += 1;
                        }
                    }
                }
                let errs: Vec<f64> = est.iter().map(|z| (z + 0.02).abs()).collect();
                let n = est.len();
                let mean = est.iter().sum::<f64>() / n as f64;
                let sd = (est.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
                eprintln!(
                    "{name} decay {decay} lag {lag}: n {n} median {:+.3} mean {:+.3} sd {:.3} med|err| {:.3} cov {}/{n}",
                    100.0 * median(est.clone()),
                    100.0 * mean,
                    100.0 * sd,
                    100.0 * median(errs),
                    cov
                );
            }
        }
    }
}

/// A 5 Hz gate's 10 s window holds 50 cycles, and its limit cycle's envelope relaxation read
/// -1 % as about -1.6 %; the daemon hands the analyzer the gate's recent samples
/// (`WindowInput::history`) and the relaxation reads its last 100 cycles
/// (`analysis::RELAXATION_CYCLES`): the error is then the lab gate's (docs/benchmarks.md).
/// Windows of 10 s every 5 s over one stream, 30 s of history each, as the daemon has them.
#[test]
fn analyzer_reads_a_slow_gates_limit_cycle_over_its_history() {
    use gatewatch::analysis::WindowInput;
    let p = lock_gate();
    let zeta = -0.01;
    let analyzer = force_analyzer(&p);
    let rate = p.rate_hz;
    let (w, step, hist) = (
        (10.0 * rate) as usize,
        (5.0 * rate) as usize,
        (30.0 * rate) as usize,
    );
    let (mut with, mut without) = (Vec::new(), Vec::new());
    for seed in [3u64, 4, 5] {
        let stream = limit_cycle_windows(p.clone(), zeta, 16, 5.0, seed).concat();
        let mut end = hist;
        while end <= stream.len() {
            let values = &stream[end - w..end];
            for (history, out) in [
                (&stream[end - hist..end], &mut with),
                (&[][..], &mut without),
            ] {
                let a = analyzer
                    .analyze(
                        WindowInput {
                            t0: (end - w) as f64 / rate,
                            rate_hz: rate,
                            values,
                            history,
                        },
                        None,
                        end as u64,
                    )
                    .unwrap();
                if let Some(e) = a.damping.envelope_zeta {
                    out.push(e.zeta);
                }
            }
            end += 2 * step;
        }
    }
    let err = |v: &[f64]| median(v.iter().map(|z| (z - zeta).abs()).collect());
    eprintln!(
        "lock gate at -1 %: with history {} windows, median {:+.2} %, median |error| {:.2}; \
         without {} windows, median {:+.2} %, median |error| {:.2}",
        with.len(),
        100.0 * median(with.clone()),
        100.0 * err(&with),
        without.len(),
        100.0 * median(without.clone()),
        100.0 * err(&without)
    );
    assert!(
        with.len() >= 6 && without.len() >= 6,
        "{} and {}",
        with.len(),
        without.len()
    );
    assert!(err(&with) < err(&without), "the history did not help");
    assert!(
        err(&with) <= 0.005,
        "median |error| {:.2} points",
        100.0 * err(&with)
    );
}

/// The envelope's relaxation across `zeta0` (the held limit cycle of the bench is only -2 %):
/// per gate and value, 60 ten-second windows (3 seeds), the single windows' median estimate,
/// median |error| and coverage, and the same for the estimates pooled as the daemon pools them
/// ([`DampingPool`], from the fifth window on). Options from the environment for experiments:
/// `BAND`, `FIT_DECAY`, `MIN_LAG`, `EDGE` (periods), `SE_INFLATION`, `WINDOW_CYCLES` (each gate's
/// window holds that many cycles instead of 10 s), and `ESTIMATOR=whittle` (the experimental
/// `envelope_relaxation_whittle` with `RelaxationOptions::whittle()` instead of the daemon's
/// estimator). Figures in docs/benchmarks.md ("The limit cycle across
/// zeta0").
///
/// `cargo test --release --test integration damping_regimes::explore_relaxation_across_zeta -- --ignored --nocapture`
#[test]
#[ignore]
fn explore_relaxation_across_zeta() {
    use gatewatch::spectral::{DampingPool, PoolOptions, WindowEstimate};
    let env = |k: &str, d: f64| std::env::var(k).map_or(d, |v| v.parse().expect(k));
    // ESTIMATOR=whittle: the experimental debiased Whittle fit (not the daemon's), with its
    // measured options
    let whittle = std::env::var("ESTIMATOR").is_ok_and(|v| v == "whittle");
    let d = if whittle {
        RelaxationOptions::whittle()
    } else {
        RelaxationOptions::default()
    };
    let opts = RelaxationOptions {
        edge_periods: env("EDGE", d.edge_periods),
        band: env("BAND", d.band),
        fit_decay: env("FIT_DECAY", d.fit_decay),
        min_lag_periods: env("MIN_LAG", d.min_lag_periods),
        se_inflation: env("SE_INFLATION", d.se_inflation),
        // DETREND=inf: the mean alone removed (before session 23)
        detrend_significance: env("DETREND", d.detrend_significance),
        // DEGREE=1: a line at most (before session 30); the analyzer allows BEND_DEGREE where
        // the level moved
        detrend_max_degree: env("DEGREE", BEND_DEGREE as f64) as usize,
        ..d
    };
    println!("{opts:?}, whittle {whittle}");
    println!("| gate | zeta0 | windows | refused | median | median abs err | coverage | correlation times | pooled abs err | pooled coverage |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let cycles = std::env::var("WINDOW_CYCLES")
        .ok()
        .map(|v| v.parse::<f64>().expect("cycles"));
    for (name, p) in [("lab", lab_gate()), ("lock", lock_gate())] {
        let secs = cycles.map_or(10.0, |c| c / p.natural_frequency_hz());
        for zeta in [-0.005, -0.0075, -0.01, -0.015, -0.02, -0.03] {
            let (mut est, mut corr, mut pooled_err) = (Vec::new(), Vec::new(), Vec::new());
            let (mut refused, mut cov, mut pooled_cov) = (0, 0, 0);
            for seed in 1..=3u64 {
                let ws = limit_cycle_windows(p.clone(), zeta, 20, secs, seed);
                let mut sa = SpectralAnalyzer::new(ws[0].len(), p.rate_hz).unwrap();
                let mut pool = DampingPool::new(PoolOptions::default()).unwrap();
                for (i, x) in ws.iter().enumerate() {
                    let f = sa.dominant_frequency(x, 1.0).unwrap().frequency_hz;
                    let e = if whittle {
                        sa.envelope_relaxation_whittle(x, f, &opts)
                    } else {
                        // The analyzer's rule: a bend only where the level moved (the
                        // previous window is the record before this one).
                        let deg = if i > 0 {
                            let pair = [ws[i - 1].as_slice(), x.as_slice()].concat();
                            relaxation_detrend_degree(&pair, x.len()).min(opts.detrend_max_degree)
                        } else {
                            1
                        };
                        sa.envelope_relaxation(
                            x,
                            f,
                            &RelaxationOptions {
                                detrend_max_degree: deg,
                                ..opts
                            },
                        )
                    };
                    let Ok(e) = e else {
                        refused += 1;
                        continue;
                    };
                    est.push(e.zeta0);
                    corr.push(e.correlation_times);
                    cov += usize::from(e.zeta0_interval.0 <= zeta && zeta <= e.zeta0_interval.1);
                    let t = secs * i as f64;
                    let pe = pool
                        .push(WindowEstimate {
                            t_start: t,
                            t_end: t + secs,
                            zeta: e.zeta0,
                            stderr: e.zeta0_stderr,
                            frequency_hz: f,
                            record_seconds: 0.0,
                            rms: None,
                        })
                        .unwrap();
                    if i >= 4 {
                        pooled_err.push((pe.zeta - zeta).abs());
                        pooled_cov += usize::from(pe.interval.0 <= zeta && zeta <= pe.interval.1);
                    }
                }
            }
            let n = est.len();
            let errs = est.iter().map(|v| (v - zeta).abs()).collect();
            let np = pooled_err.len();
            println!(
                "| {name} | {:+.2} % | {n} | {refused} | {:+.2} % | {:.2} | {:.0} % | {:.1} | {:.2} | {:.0} % |",
                100.0 * zeta,
                100.0 * median(est),
                100.0 * median(errs),
                100.0 * cov as f64 / n as f64,
                median(corr),
                100.0 * median(pooled_err),
                100.0 * pooled_cov as f64 / np as f64,
            );
        }
    }
}

/// The envelope-drift estimator on the onset ramp (+2 % to -2 % in 60 s from 120 s), both
/// gates, three seeds: on the windows that reach zero damping and that the relaxation refuses
/// (the end of the growth: the envelope's CV is too large) it gives an estimate whose interval
/// covers the truth (at the window's centre or its mean over the window) in at least 90 % of
/// them, and on the held cycle (windows ending from 200 s) it agrees with the relaxation.
#[test]
fn envelope_drift_covers_the_end_of_the_growth() {
    use gatewatch::spectral::DriftOptions;
    let truth = |t: f64| 0.02 - 0.04 * ((t - 120.0) / 60.0).clamp(0.0, 1.0);
    let (mut refused, mut covered) = (0, 0);
    let mut held_gap = Vec::new();
    for (name, p) in [("lab", lab_gate()), ("lock", lock_gate())] {
        for seed in 1..=3u64 {
            let rate = p.rate_hz;
            let sched = ZetaSchedule::Ramp {
                start_s: 120.0,
                duration_s: 60.0,
                from: 0.02,
                to: -0.02,
            };
            let mut sim = GateSimulator::new(p.clone(), sched, seed);
            let n = (10.0 * rate) as usize;
            let mut all = vec![0.0; (240.0 * rate) as usize];
            sim.fill(&mut all);
            let mut sa = SpectralAnalyzer::new(n, rate).unwrap();
            for k in 0..=18 {
                let end = 150.0 + 5.0 * k as f64;
                let i1 = (end * rate) as usize;
                let x = &all[i1 - n..i1];
                let peak = sa.dominant_frequency(x, 1.0).unwrap().frequency_hz;
                let relax = sa.envelope_relaxation(x, peak, &RelaxationOptions::default());
                let d = sa.envelope_drift(x, peak, 0.25, &DriftOptions::default());
                let (centre, mean) = (truth(end - 5.0), 0.5 * (truth(end - 10.0) + truth(end)));
                eprintln!(
                    "{name} seed {seed} end {end}: truth {:+.2} %, drift {:?}, relaxation {}",
                    100.0 * centre,
                    d.as_ref().map(|d| d.zeta0_interval),
                    relax.is_ok()
                );
                if relax.is_err() && mean <= 0.0 {
                    refused += 1;
                    let d = d
                        .as_ref()
                        .unwrap_or_else(|e| panic!("{name} seed {seed} end {end}: {e}"));
                    let (lo, hi) = d.zeta0_interval;
                    if (lo <= centre && centre <= hi) || (lo <= mean && mean <= hi) {
                        covered += 1;
                    }
                }
                if let (Ok(r), Ok(d), true) = (&relax, &d, end >= 200.0) {
                    held_gap.push((d.zeta0 - r.zeta0).abs());
                }
            }
        }
    }
    eprintln!("refused by the relaxation: {refused}, covered by the drift: {covered}");
    assert!(
        refused >= 5,
        "only {refused} windows refused: the test says nothing"
    );
    assert!(
        covered as f64 >= 0.9 * refused as f64,
        "{covered} of {refused} covered"
    );
    let gap = median(held_gap);
    assert!(
        gap < 0.006,
        "median |drift - relaxation| on the held cycle {gap}"
    );
}

/// Consecutive 10 s windows of a gate on its limit cycle while its damping ramps from -1 % to
/// -3 % over 30 s (the onset's rate, 4 points a minute), started on the cycle at -1 %; with
/// each window's true `zeta0` at its centre.
fn ramping_limit_cycle_windows(p: GateParams, seed: u64) -> Vec<(Vec<f64>, f64)> {
    let (from, to, secs) = (-0.01, -0.03, 30.0);
    let y_lc = p.limit_cycle_force_amplitude(from).unwrap() / p.stiffness;
    let p = GateParams { y0: y_lc, ..p };
    let rate = p.rate_hz;
    let burn = 20.0;
    let schedule = ZetaSchedule::Ramp {
        start_s: burn,
        duration_s: secs,
        from,
        to,
    };
    let mut sim = GateSimulator::new(p, schedule, seed);
    let mut x = vec![0.0; (burn * rate) as usize];
    sim.fill(&mut x);
    (0..3)
        .map(|i| {
            let mut x = vec![0.0; (10.0 * rate) as usize];
            sim.fill(&mut x);
            let centre = 10.0 * i as f64 + 5.0;
            (x, from + (to - from) * centre / secs)
        })
        .collect()
}

/// (estimates, covered, median |error|) of the relaxation over ramping windows of `p`.
fn ramping_scores(p: &GateParams, seeds: u64, opts: &RelaxationOptions) -> (usize, usize, f64) {
    let (mut estimates, mut covered, mut errs) = (0, 0, Vec::new());
    for seed in 1..=seeds {
        let ws = ramping_limit_cycle_windows(p.clone(), seed);
        let mut sa = SpectralAnalyzer::new(ws[0].0.len(), p.rate_hz).unwrap();
        for (x, truth) in &ws {
            let f = sa.dominant_frequency(x, 1.0).unwrap().frequency_hz;
            let Ok(e) = sa.envelope_relaxation(x, f, opts) else {
                continue;
            };
            estimates += 1;
            covered += usize::from(e.zeta0_interval.0 <= *truth && *truth <= e.zeta0_interval.1);
            errs.push((e.zeta0 - truth).abs());
        }
    }
    (estimates, covered, median(errs))
}

/// A cycle whose damping still ramps (the onset after its growth): the amplitude follows
/// `sqrt(-zeta0)`, 20 to 40 % per 10 s window, and with only its mean removed that trend read as
/// a relaxation too slow (refused, or too close to zero). With the significant line removed
/// (`detrend_significance`) most windows are read and covered, on both gates. Measured (12
/// seeds, 3 windows each): lab 22 of 36 covered with the mean alone, 31 with the line; lock 29
/// and 30.
#[test]
fn ramping_limit_cycle_is_read_about_its_line() {
    let plain = RelaxationOptions {
        detrend_significance: f64::INFINITY,
        ..RelaxationOptions::default()
    };
    for (name, p, floor) in [("lab", lab_gate(), 29), ("lock", lock_gate(), 28)] {
        let (n0, c0, _) = ramping_scores(&p, 12, &plain);
        let (n, c, err) = ramping_scores(&p, 12, &RelaxationOptions::default());
        eprintln!("{name}: mean alone {n0} read, {c0} covered; line {n} read, {c} covered, median abs err {:.2}", 100.0 * err);
        assert!(
            c >= floor && c >= c0,
            "{name}: {c} of 36 covered (mean alone {c0})"
        );
        assert!(n >= n0, "{name}: {n} read, {n0} with the mean alone");
        assert!(
            err <= 0.007,
            "{name}: median abs err {:.2} points",
            100.0 * err
        );
    }
}

#[test]
#[ignore = "exploration: cargo test --release --test integration damping_regimes::explore_ramping -- --ignored --nocapture"]
fn explore_ramping_limit_cycle() {
    for (name, p) in [("lab", lab_gate()), ("lock", lock_gate())] {
        for sig in [f64::INFINITY, 3.0, 2.5, 2.0] {
            let opts = RelaxationOptions {
                detrend_significance: sig,
                ..RelaxationOptions::default()
            };
            let (n, c, e) = ramping_scores(&p, 12, &opts);
            println!(
                "{name} significance {sig}: {n} of 36 estimated, {c} covered, median abs err {:.2}",
                100.0 * e
            );
        }
    }
}

/// (estimates, covered) of the relaxation over the onset scenario's cycle windows (10 s windows
/// ending every 5 s from 160 to 195 s: the cycle reached while the damping still ramps, and the
/// window the ramp ends in) on a bench preset, scored against the window's mean truth.
fn ramp_end_scores(preset: &str, seeds: u64, opts: &RelaxationOptions) -> (usize, usize) {
    let p = GatePreset::parse(preset).unwrap().params();
    let def = ScenarioName::parse("onset").unwrap().def(&p);
    let rate = p.rate_hz;
    let n = (10.0 * rate) as usize;
    let mut sa = SpectralAnalyzer::new(n, rate).unwrap();
    let (mut estimates, mut covered) = (0, 0);
    for seed in 1..=seeds {
        let mut sim = def
            .simulator(&p, NoiseLevel::Relative(0.125), seed)
            .unwrap();
        let mut warm = vec![0.0; (def.warmup_s * rate).round() as usize];
        sim.fill(&mut warm);
        let mut all = vec![0.0; (195.0 * rate) as usize];
        sim.fill(&mut all);
        for end in (160..=195).step_by(5) {
            let e = (end as f64 * rate) as usize;
            let mut w = all[e - n..e].to_vec();
            gatewatch::spectral::detrend_linear(&mut w);
            let truth = def.mean_zeta(end as f64 - 10.0, end as f64);
            let f = sa.dominant_frequency(&w, 1.0).unwrap().frequency_hz;
            // The analyzer's rule: a bend only where the level moved against the 10 s before.
            let opts = RelaxationOptions {
                detrend_max_degree: relaxation_detrend_degree(&all[e - 2 * n..e], n)
                    .min(opts.detrend_max_degree),
                ..*opts
            };
            if let Ok(r) = sa.envelope_relaxation(&w, f, &opts) {
                estimates += 1;
                covered += usize::from(r.zeta0_interval.0 <= truth && truth <= r.zeta0_interval.1);
            }
        }
    }
    (estimates, covered)
}

/// The window an onset's ramp ends in: the envelope rises, then levels off, and the bend left
/// about a line read as a relaxation too slow (the lab gate at -1.9 % read -0.3 to -0.6 % in 7
/// of 12 seeds). With a polynomial up to `BEND_DEGREE` where the level moved (the analyzer's
/// rule) the bend is removed. Measured (12 seeds, 8 windows each): lab 71 of 82 read windows
/// covered with a line, 76 of 84 with the bend; lock 72 of 73 and 76 of 76.
#[test]
fn ramp_end_is_read_about_its_bend() {
    let bend = RelaxationOptions {
        detrend_max_degree: BEND_DEGREE,
        ..RelaxationOptions::default()
    };
    for (preset, gain) in [("lab", 4), ("lock", 2)] {
        let (n1, c1) = ramp_end_scores(preset, 12, &RelaxationOptions::default());
        let (n, c) = ramp_end_scores(preset, 12, &bend);
        eprintln!("{preset}: line {c1} of {n1} covered, cubic {c} of {n}");
        assert!(n >= n1, "{preset}: {n} read, {n1} with a line");
        assert!(c >= c1 + gain, "{preset}: {c} covered, {c1} with a line");
        assert!(10 * c >= 9 * n, "{preset}: {c} of {n} covered");
    }
}

/// The daemon's analyzer for a bench preset (its embedded configuration), its model's interval
/// by `method`.
fn daemon_analyzer(
    gate: GatePreset,
    method: gatewatch::analysis::ModelInterval,
) -> gatewatch::analysis::Analyzer {
    let config = gatewatch::service::bench_warning::run_config(gate, 1);
    let mut settings = config
        .gate(gate.as_str())
        .expect("preset gate")
        .analysis_settings();
    settings.model_interval = method;
    gatewatch::analysis::Analyzer::new(settings).expect("analyzer")
}

/// The daemon's analysis of the 10 s window of `xs` (sampled at `rate_hz` from `t = 0`) that ends
/// at `end` s, with the three windows of history the daemon hands its worker.
fn analyze_window_ending(
    analyzer: &gatewatch::analysis::Analyzer,
    xs: &[f64],
    rate_hz: f64,
    end: f64,
    seed: u64,
) -> gatewatch::analysis::WindowAnalysis {
    let nw = (10.0 * rate_hz).round() as usize;
    let ne = (end * rate_hz).round() as usize;
    let input = gatewatch::analysis::WindowInput {
        t0: end - 10.0,
        rate_hz,
        values: &xs[ne - nw..ne],
        history: &xs[ne - 3 * nw..ne],
    };
    analyzer.analyze(input, None, seed).expect("analysis")
}

/// `seconds` of a gate's samples, ambient at +1 % until 60 s and at `zeta` from then on, with
/// sensor noise of `noise` (signal units): the switch the explorations of the model's interval
/// and of the cycle's amplitude read.
fn switched_at_60_s(p: &GateParams, noise: f64, zeta: f64, seed: u64, seconds: f64) -> Vec<f64> {
    let schedule = ZetaSchedule::Table(vec![(59.999, 0.01), (60.0, zeta)]);
    let q = GateParams {
        noise_std: noise,
        ..p.clone()
    };
    let mut sim = GateSimulator::new(q, schedule, seed);
    let total = (seconds * p.rate_hz).round() as usize;
    (0..total).map(|_| sim.next_sample()).collect()
}

/// The onset's first negative windows, read by the daemon's model (the bench presets, their
/// noise, the daemon's analysis settings, a full search on each window): the model's own zeta0,
/// `c2 / (2 sqrt(k c1))`, and its cubic coefficient against the gate's, per window end, medians
/// over 20 seeds (docs/damping.md, "The onset's ramp read as a slow cycle"): by the window that
/// ends at -1 % the gate is near its moving limit cycle, and a fit of constant coefficients reads
/// the cycle's slow growth as a slow relaxation, the linear and the cubic damping both too small.
#[test]
#[ignore = "exploration: cargo test --release --test integration damping_regimes::explore_onset_model -- --ignored --nocapture"]
fn explore_onset_model_trade() {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for gate in [GatePreset::Lab, GatePreset::Lock] {
        let p = gate.params();
        let analyzer = daemon_analyzer(gate, Default::default());
        let def = ScenarioName::Onset.def(&p);
        let noise = NoiseLevel::Relative(0.125).rms(&p);
        let ends = [160.0, 165.0, 170.0];
        let mut rows = vec![(Vec::new(), Vec::new()); ends.len()];
        for seed in 1..=20u64 {
            let mut sim = def
                .simulator(&p, NoiseLevel::Absolute(noise), seed)
                .expect("simulator");
            while sim.time() < -1e-9 {
                sim.next_sample();
            }
            let n = (170.0 * p.rate_hz).round() as usize;
            let xs: Vec<f64> = (0..n).map(|_| sim.next_sample()).collect();
            for (k, e) in ends.iter().enumerate() {
                let a = analyze_window_ending(&analyzer, &xs, p.rate_hz, *e, seed);
                let c = |name: &str| a.coefficients.iter().find(|(n, _)| n == name).unwrap().1;
                let zeta = c("c2") / (2.0 * (p.stiffness * c("c1")).sqrt());
                rows[k].0.push(zeta);
                rows[k].1.push(c("c3") / p.c3);
            }
        }
        for (e, (z, r)) in ends.iter().zip(rows) {
            println!(
                "{} window ending {e} s: true mean {:+.2} %, end {:+.2} %; the model's zeta0 median {:+.2} %, its c3 median {:.2} of the gate's",
                gate.as_str(),
                100.0 * def.mean_zeta(e - 10.0, *e),
                100.0 * def.true_zeta(*e),
                100.0 * median(z),
                median(r)
            );
        }
    }
}

/// The model's interval (`model_zeta`) on windows where the model is right: a held limit cycle
/// and the window a constant negative damping grows from the ambient state into its cycle
/// (a burst's first window). Coverage and median half width per gate, method and case, 20 seeds.
#[test]
#[ignore = "exploration: cargo test --release --test integration damping_regimes::explore_model_interval -- --ignored --nocapture"]
fn explore_model_interval_calibration() {
    use gatewatch::analysis::ModelInterval;
    for (gate, method) in [GatePreset::Lab, GatePreset::Lock]
        .into_iter()
        .flat_map(|g| [(g, ModelInterval::NeweyWest), (g, ModelInterval::Forcing)])
    {
        let p = gate.params();
        let analyzer = daemon_analyzer(gate, method);
        let noise = NoiseLevel::Relative(0.125).rms(&p);
        // (case, zeta, switch time): ambient at +1 % until the switch, then zeta.
        for (case, zeta, ends) in [
            ("held -2 %", -0.02, vec![100.0, 110.0, 120.0]),
            ("held -3 %", -0.03, vec![100.0, 110.0, 120.0]),
            ("growth -3 %", -0.03, vec![62.0, 64.0, 66.0]),
            ("growth -2 %", -0.02, vec![64.0, 66.0, 68.0]),
        ] {
            let (mut n, mut covered, mut hw, mut err) = (0, 0, Vec::new(), Vec::new());
            for seed in 1..=20u64 {
                let last = ends.iter().cloned().fold(0.0, f64::max);
                let xs = switched_at_60_s(&p, noise, zeta, seed, last);
                for e in &ends {
                    let a = analyze_window_ending(&analyzer, &xs, p.rate_hz, *e, seed);
                    if let Some(m) = a.damping.model_zeta {
                        n += 1;
                        covered += usize::from(m.low <= zeta && zeta <= m.high);
                        hw.push((m.high - m.low) / 2.0 * 100.0);
                        err.push((m.zeta - zeta).abs() * 100.0);
                    }
                }
            }
            println!(
                "{} {method:?} {case}: {n} model windows, covered {covered}, median half width {:.3}, median abs err {:.3}",
                gate.as_str(),
                if hw.is_empty() { f64::NAN } else { median(hw) },
                if err.is_empty() { f64::NAN } else { median(err) },
            );
        }
    }
}

/// The limit cycle read from the growth that led to it: the growth window's model gives the
/// damping's amplitude dependence `zeta_eq(A) - zeta0 = b A^2` (`b = -zeta0 / A*^2` with `A*` its
/// limit-cycle amplitude), and the held cycle's amplitude `A` fixes `zeta_eq(A) = 0`, so
/// `zeta0 = -b A^2`. Per seed: the growth window's model, then the held windows' reading.
#[test]
#[ignore = "exploration: cargo test --release --test integration damping_regimes::explore_cycle_amplitude -- --ignored --nocapture"]
fn explore_cycle_amplitude() {
    use gatewatch::analysis::ModelInterval;
    let median = |mut v: Vec<f64>| {
        if v.is_empty() {
            return f64::NAN;
        }
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for gate in [GatePreset::Lab, GatePreset::Lock] {
        let p = gate.params();
        let analyzer = daemon_analyzer(gate, ModelInterval::NeweyWest);
        let noise = NoiseLevel::Relative(0.125).rms(&p);
        for zeta in [-0.02, -0.03, -0.01] {
            let (mut amp_err, mut env_err, mut growth_err) = (Vec::new(), Vec::new(), Vec::new());
            let mut covered = 0;
            for seed in 1..=12u64 {
                let xs = switched_at_60_s(&p, noise, zeta, seed, 120.0);
                // the first window the model reads a limit cycle in
                let mut carried = None;
                for end in [62.0, 64.0, 66.0, 68.0, 70.0, 72.0, 75.0, 80.0] {
                    let a = analyze_window_ending(&analyzer, &xs, p.rate_hz, end, seed);
                    let d = &a.damping;
                    if let (Some(m), Some(lc)) = (d.growth_law_zeta, d.limit_cycle_amplitude) {
                        carried = Some((end, m, lc));
                        growth_err.push((m.zeta - zeta).abs() * 100.0);
                        break;
                    }
                }
                let Some((gend, m, lcg)) = carried else {
                    println!("{} {zeta} seed {seed}: no growth model", gate.as_str());
                    continue;
                };
                let mut line = format!(
                    "{} {:+.1} % seed {seed}: growth {gend} s {:+.2} %, A* {:.4}; held:",
                    gate.as_str(),
                    zeta * 100.0,
                    m.zeta * 100.0,
                    lcg
                );
                for end in [100.0, 110.0, 120.0] {
                    let a = analyze_window_ending(&analyzer, &xs, p.rate_hz, end, seed);
                    let d = &a.damping;
                    let Some(rms) = d.signal_rms else { continue };
                    let amp = rms * std::f64::consts::SQRT_2;
                    let scale = (amp / lcg).powi(2);
                    let z = m.zeta * scale;
                    amp_err.push((z - zeta).abs() * 100.0);
                    // the interval the daemon carries: widened about its reading, then scaled
                    let k = gatewatch::analysis::LAW_INTERVAL_INFLATION;
                    let (lo, hi) = (
                        m.zeta - k * (m.zeta - m.low),
                        m.zeta + k * (m.high - m.zeta),
                    );
                    covered += usize::from(lo * scale <= zeta && zeta <= hi * scale);
                    let env = d.envelope_zeta.map(|e| e.zeta);
                    if let Some(e) = env {
                        env_err.push((e - zeta).abs() * 100.0);
                    }
                    line += &format!(
                        " [{:+.2} % env {:+.2} %]",
                        z * 100.0,
                        env.unwrap_or(f64::NAN) * 100.0
                    );
                }
                println!("{line}");
            }
            println!(
                "== {} {:+.1} %: growth err {:.2}, amplitude err {:.2} ({}, {covered} covered), envelope err {:.2} ({})",
                gate.as_str(),
                zeta * 100.0,
                median(growth_err),
                median(amp_err.clone()),
                amp_err.len(),
                median(env_err.clone()),
                env_err.len()
            );
        }
    }
}

/// The 2 Hz barrier gate's `scenario` for `seed`, at the bench's sensor noise, streamed through
/// the daemon's state and analysis (the real analyzer) as `bench warning` streams it.
async fn barrier_stream(
    scenario: ScenarioName,
    seed: u64,
) -> gatewatch::service::bench_warning::RunRecord {
    preset_stream(GatePreset::Barrier, scenario, seed).await
}

/// One scenario of a bench gate, streamed through the daemon's state and analysis as `bench
/// warning` streams it (one worker, the bench's relative sensor noise).
async fn preset_stream(
    gate: GatePreset,
    scenario: ScenarioName,
    seed: u64,
) -> gatewatch::service::bench_warning::RunRecord {
    use gatewatch::service::bench_warning::{run_config, run_stream, RunSpec};
    use gatewatch::service::worker::{AnalyzerMap, WindowAnalyzer};
    use std::sync::Arc;
    let p = gate.params();
    let config = run_config(gate, 1);
    let analyzer: Arc<dyn WindowAnalyzer> =
        Arc::new(AnalyzerMap::from_config(&config).expect("analyzer"));
    let spec = RunSpec {
        scenario,
        gate,
        seed,
        noise_rms: NoiseLevel::Relative(0.125).rms(&p),
        duration_s: scenario.def(&p).duration_s,
        trace: false,
    };
    run_stream(&spec, config, analyzer).await.expect("stream")
}

/// Asserts that the window's reported interval holds its true mean `zeta0`.
fn assert_covers(seed: u64, w: &gatewatch::service::bench_warning::WindowRecord) {
    assert!(
        w.interval
            .is_some_and(|(low, high)| low <= w.truth_mean && w.truth_mean <= high),
        "seed {seed}, window ending at {:.0} s ({:?}): {:?} {:?} at a true {:+.2} %",
        w.end,
        w.source,
        w.zeta0,
        w.interval,
        100.0 * w.truth_mean
    );
}

/// The 2 Hz barrier gate's recovery (on the -2 % cycle for 2 min, back to +2 % over 60 s)
/// streamed through the daemon's state and analysis as `bench warning` streams it: a window of
/// the shrinking cycle read as a cycle never claims a confident negative once the true `zeta0`
/// is back at zero or above. Before stop 89 the relaxation read seed 101's window ending at 165 s
/// -1.72 % (-3.22, -0.23) at a true +0.33 %, and seed 103's at 160 s -1.53 % (-2.87, -0.20) at
/// a true 0; the fall is now read through the cycle the gate held (`CycleAmplitude::read_fall`)
/// or, without one, spans the envelope's drift (`analysis::span_the_fall`; docs/damping.md, "A
/// falling cycle read through the cycle it held"). The held cycle before the ramp is still read
/// confidently negative.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shrinking_cycle_is_never_read_confidently_negative() {
    for seed in [101, 103] {
        let run = barrier_stream(ScenarioName::Recovery, seed).await;
        let as_cycle = |w: &&gatewatch::service::bench_warning::WindowRecord| {
            matches!(w.source.as_deref(), Some("envelope" | "amplitude"))
        };
        let shrunk: Vec<_> = run
            .windows
            .iter()
            .filter(as_cycle)
            .filter(|w| w.truth_mean >= -1e-6)
            .collect();
        assert!(
            !shrunk.is_empty(),
            "seed {seed}: no window of the shrinking cycle was read as a cycle at a true zeta0 of zero or above: the test says nothing"
        );
        for w in shrunk {
            let (z, iv) = (w.zeta0, w.interval);
            assert!(
                iv.is_some_and(|(_, high)| high >= 0.0),
                "seed {seed}, window ending at {:.0} s: {z:?} {iv:?} at a true {:+.2} %",
                w.end,
                100.0 * w.truth_mean
            );
        }
        assert!(
            run.windows
                .iter()
                .filter(as_cycle)
                .any(|w| w.end <= 120.0 && w.interval.is_some_and(|(_, high)| high < 0.0)),
            "seed {seed}: the held cycle was never read confidently negative"
        );
        // the ramp's falling windows read through the held cycle cover the truth
        let read_fall: Vec<_> = run
            .windows
            .iter()
            .filter(|w| w.end > 120.0 && w.source.as_deref() == Some("amplitude"))
            .collect();
        assert!(
            read_fall.len() >= 3,
            "seed {seed}: {} windows of the ramp read through the held cycle",
            read_fall.len()
        );
        for w in read_fall {
            assert_covers(seed, w);
        }
    }
}

/// The 2 Hz barrier gate's onset (+2 % to -2 % over 60 s, then the -2 % cycle) streamed through
/// the daemon's state and analysis as `bench warning` streams it: every window of the held cycle
/// read as a cycle covers the truth. Before stop 90 the cycle was read through a damping law from
/// a window of the ramp, whose constant-coefficient model read the ramp's average: seed 107's
/// law (-1.0 %, from a growing window) decided 19 windows at -1.0 % (-1.65, -0.3), none covering
/// -2 %; seed 119's (-0.82 %, from a window read as a cycle whose envelope still rose by five
/// standard errors) 20 of 22. Now a window read by its prediction errors that contradicts a law
/// drops it (seed 107), and a window read as a cycle still pushed out carries none (seed 119):
/// `CycleAmplitude`, docs/damping.md, "A law from one damping". The cycle is still read
/// confidently negative.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_onsets_cycle_is_not_read_through_the_ramps_average() {
    for seed in [107, 119] {
        let run = barrier_stream(ScenarioName::Onset, seed).await;
        let held: Vec<_> = run
            .windows
            .iter()
            .filter(|w| w.truth_mean <= -0.0199)
            .filter(|w| matches!(w.source.as_deref(), Some("envelope" | "amplitude")))
            .collect();
        assert!(
            held.len() >= 10,
            "seed {seed}: {} windows of the held cycle read as a cycle",
            held.len()
        );
        for w in &held {
            assert_covers(seed, w);
        }
        assert!(
            held.iter()
                .any(|w| w.interval.is_some_and(|(_, high)| high < 0.0)),
            "seed {seed}: the held cycle was never read confidently negative"
        );
    }
}

/// The lab gate's onset streamed through the daemon as `bench warning` streams it: the window
/// that ends at 160 s (150 to 160 s, true mean -0.33 %) rose to 1.6 to 3 times the gate's
/// ambient level, below the departure ratio, and is reported by its own SSI-COV reading, which
/// assumes a stationary response and still carries the seconds of positive damping before. On
/// seeds 127 and 145 its interval ended above the truth (+0.45 % (-0.25, +1.15) and +0.39 %
/// (-0.20, +0.98)). Since stop 91 it spans the prediction-error reading of the window too
/// (`analysis::ZetaPools::apply`; docs/damping.md, "A rising window's interval spans its
/// prediction errors"), and covers; its figure is still SSI-COV's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rising_windows_interval_spans_its_prediction_errors() {
    for seed in [127, 145] {
        let run = preset_stream(GatePreset::Lab, ScenarioName::Onset, seed).await;
        let w = run
            .windows
            .iter()
            .find(|w| (w.end - 160.0).abs() < 0.5)
            .expect("a window ending at 160 s");
        assert_eq!(w.source.as_deref(), Some("ambient"), "seed {seed}: {w:?}");
        assert!(
            w.zeta0.is_some_and(|z| z > 0.0),
            "seed {seed}: SSI-COV's figure stays: {w:?}"
        );
        assert_covers(seed, w);
    }
}
