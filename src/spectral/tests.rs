use super::ambient::ar_roots;
use super::*;
use crate::simulate::{GateParams, GateSimulator, Scenario, ZetaSchedule};
use rustfft::num_complex::Complex;
use std::f64::consts::PI;

const FS: f64 = 200.0;

/// `secs` of a gate at constant `zeta` after a 20 s burn-in (stationary response).
fn simulate(zeta: f64, secs: f64, seed: u64, p: GateParams) -> Vec<f64> {
    let n = (secs * p.rate_hz) as usize;
    let mut sim = GateSimulator::new(p, ZetaSchedule::Constant(zeta), seed);
    let mut burn = vec![0.0; (20.0 * sim.params().rate_hz) as usize];
    sim.fill(&mut burn);
    let mut x = vec![0.0; n];
    sim.fill(&mut x);
    x
}

fn sine(n: usize, f: f64, amp: f64, phase: f64, sigma: f64) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let t = i as f64 / FS;
            amp * (sigma * t).exp() * (2.0 * PI * f * t + phase).sin()
        })
        .collect()
}

#[test]
fn moving_average_matches_brute_force_and_removes_offset() {
    let n = 1000;
    let x: Vec<f64> = (0..n)
        .map(|i| 3.0 + (i as f64 * 0.37).sin() + 0.001 * i as f64)
        .collect();
    let w = 41;
    let mut out = vec![0.0; n];
    remove_moving_average(&x, w, &mut out);
    for i in 0..n {
        let lo = i.saturating_sub(w / 2);
        let hi = (i + w / 2).min(n - 1);
        let m = x[lo..=hi].iter().sum::<f64>() / (hi - lo + 1) as f64;
        assert!((out[i] - (x[i] - m)).abs() < 1e-12, "sample {i}");
    }
    // A window of exactly 10 periods removes the offset and leaves the sine in the interior.
    let f = 10.0;
    let y: Vec<f64> = sine(n, f, 1.0, 0.3, 0.0).iter().map(|v| v + 5.0).collect();
    remove_moving_average(&y, 201, &mut out);
    let clean = sine(n, f, 1.0, 0.3, 0.0);
    for i in 100..n - 100 {
        assert!((out[i] - clean[i]).abs() < 0.01, "sample {i}: {}", out[i]);
    }
}

#[test]
fn detrend_removes_a_line_exactly() {
    let mut x: Vec<f64> = (0..500)
        .map(|i| 2.0 - 0.01 * i as f64 + (i as f64).sin() * 0.0)
        .collect();
    let (a, b) = detrend_linear(&mut x);
    assert!((a - 2.0).abs() < 1e-10 && (b + 0.01).abs() < 1e-12);
    assert!(x.iter().all(|v| v.abs() < 1e-10));
}

#[test]
fn hann_is_periodic_with_half_sum() {
    let w = hann(64);
    assert_eq!(w[0], 0.0);
    assert!((w[32] - 1.0).abs() < 1e-15);
    assert!((w[1] - w[63]).abs() < 1e-15);
    assert!((w.iter().sum::<f64>() - 32.0).abs() < 1e-12);
}

#[test]
fn dominant_frequency_is_sub_bin_accurate() {
    let n = 2000; // bin 0.1 Hz
    let mut sa = SpectralAnalyzer::new(n, FS).unwrap();
    let bin = sa.bin_hz();
    for (k, &f) in [10.37, 10.4, 10.45, 3.333, 47.91].iter().enumerate() {
        let amp = 2.5;
        let x: Vec<f64> = sine(n, f, amp, 0.7 * k as f64, 0.0)
            .iter()
            .map(|v| v + 1.0)
            .collect();
        let p = sa.dominant_frequency(&x, 1.0).unwrap();
        let err_bins = (p.frequency_hz - f).abs() / bin;
        assert!(
            err_bins < 0.01,
            "f {f}: {} ({err_bins} bins)",
            p.frequency_hz
        );
        assert!(
            (p.amplitude / amp - 1.0).abs() < 0.01,
            "amplitude {}",
            p.amplitude
        );
    }
}

#[test]
fn dominant_frequency_ignores_the_low_frequency_floor() {
    let n = 4000;
    let mut sa = SpectralAnalyzer::new(n, FS).unwrap();
    let x: Vec<f64> = (0..n)
        .map(|i| {
            let t = i as f64 / FS;
            10.0 * (2.0 * PI * 0.2 * t).sin() + (2.0 * PI * 10.43 * t).sin()
        })
        .collect();
    let p = sa.dominant_frequency(&x, 2.0).unwrap();
    assert!((p.frequency_hz - 10.43).abs() < 0.05 * sa.bin_hz());
    // Without the floor the drift wins.
    let q = sa.dominant_frequency(&x, 0.0).unwrap();
    assert!(q.frequency_hz < 1.0);
}

#[test]
fn analyzer_rejects_wrong_length_and_nan() {
    let mut sa = SpectralAnalyzer::new(100, FS).unwrap();
    assert_eq!(
        sa.dominant_frequency(&[0.0; 99], 0.0),
        Err(SpectralError::Length {
            expected: 100,
            got: 99
        })
    );
    let mut x = vec![1.0; 100];
    x[5] = f64::NAN;
    assert_eq!(sa.envelope(&x, None).err(), Some(SpectralError::NonFinite));
    assert!(SpectralAnalyzer::new(8, FS).is_err());
}

#[test]
fn envelope_of_a_sine_is_its_amplitude() {
    let n = 2000;
    let mut sa = SpectralAnalyzer::new(n, FS).unwrap();
    let x = sine(n, 10.37, 3.0, 0.2, 0.0);
    // Without a band the truncation error decays like 1/(omega t): ~1 % after 2 s.
    let env = sa.envelope(&x, None).unwrap();
    for (i, e) in env.iter().enumerate().take(n - 400).skip(400) {
        assert!((e - 3.0).abs() < 0.03, "no band, sample {i}: {e}");
    }
    // The tapered band confines the end effects to well under 1 s.
    let env = sa.envelope(&x, Some((5.0, 15.0))).unwrap();
    for (i, e) in env.iter().enumerate().take(n - 200).skip(200) {
        assert!((e - 3.0).abs() < 0.003, "band, sample {i}: {e}");
    }
}

#[test]
fn growth_rate_of_growing_and_decaying_sines() {
    let n = 2000; // 10 s
    let mut sa = SpectralAnalyzer::new(n, FS).unwrap();
    for &sigma in &[0.3, -0.3, 0.05, -0.05] {
        let x = sine(n, 10.37, 1.0, 0.4, sigma);
        let g = sa
            .growth_rate(&x, 10.37, &GrowthOptions::default())
            .unwrap();
        assert!(
            (g.sigma / sigma - 1.0).abs() < 0.01,
            "sigma {sigma}: got {} +- {}",
            g.sigma,
            g.stderr
        );
        let zeta = damping_from_growth(sigma, 10.37);
        assert!((g.zeta - zeta).abs() < 0.01 * zeta.abs());
        // The residuals are deterministic (end effects), so the serial-correlation correction
        // inflates the error; it still stays small.
        assert!(g.stderr < 0.05 * sigma.abs(), "stderr {}", g.stderr);
    }
}

#[test]
fn growth_rate_of_a_free_decay() {
    // Linear oscillator (no cubic damping, no forcing), zeta = 2 %, from 10 N.
    let zeta = 0.02;
    let p = GateParams {
        c3: 0.0,
        forcing_std: 0.0,
        y0: 10.0 / 81360.0,
        ..GateParams::default()
    };
    let wn = 2.0 * PI * p.natural_frequency_hz();
    let mut sim = GateSimulator::new(p, ZetaSchedule::Constant(zeta), 0);
    let n = 1000; // 5 s: the amplitude falls by e^-6.5
    let mut x = vec![0.0; n];
    sim.fill(&mut x);
    let mut sa = SpectralAnalyzer::new(n, FS).unwrap();
    let peak = sa.dominant_frequency(&x, 1.0).unwrap();
    let fd = wn * (1.0 - zeta * zeta).sqrt() / (2.0 * PI);
    // A decaying signal broadens the peak; still within 2 % of a bin spacing of 0.2 Hz.
    assert!(
        (peak.frequency_hz - fd).abs() < 0.02,
        "{}",
        peak.frequency_hz
    );
    let g = sa
        .growth_rate(&x, peak.frequency_hz, &GrowthOptions::default())
        .unwrap();
    let sigma = -zeta * wn;
    assert!(
        (g.sigma / sigma - 1.0).abs() < 0.01,
        "{} vs {sigma}",
        g.sigma
    );
    assert!((g.zeta / zeta - 1.0).abs() < 0.01, "zeta {}", g.zeta);
    // The AR fit of a noise-free decay is exact as well.
    let a = ambient_damping(&x, FS, &ArOptions::default()).unwrap();
    assert!((a.zeta / zeta - 1.0).abs() < 0.01, "AR zeta {}", a.zeta);
}

#[test]
fn normal_quantile_values() {
    assert!((normal_quantile(0.975) - 1.959964).abs() < 1e-6);
    assert!((normal_quantile(0.5)).abs() < 1e-9);
    assert!((normal_quantile(0.001) + 3.090232).abs() < 1e-6);
}

#[test]
fn ar_roots_match_a_known_pole_pair() {
    // z = r e^{+-i theta}: z^2 - 2 r cos(theta) z + r^2.
    let (r, th) = (0.99f64, 0.3f64);
    let a = [2.0 * r * th.cos(), -r * r];
    let roots = ar_roots(&a);
    assert!(roots
        .iter()
        .any(|z| (z - Complex::from_polar(r, th)).norm() < 1e-12));
    // Same pole pair times a real pole at 0.5, through the companion matrix.
    let a3 = [a[0] + 0.5, a[1] - 0.5 * a[0], -0.5 * a[1]];
    let roots = ar_roots(&a3);
    assert!(roots
        .iter()
        .any(|z| (z - Complex::from_polar(r, th)).norm() < 1e-9));
    assert!(roots
        .iter()
        .any(|z| (z - Complex::new(0.5, 0.0)).norm() < 1e-9));
}

/// Coverage of the 95 % interval of the default AR(4) fit over seeds 0..30, for each damping and
/// window length. Measured (seeds 0..40 while developing): 85-95 % per cell.
#[test]
fn ambient_interval_covers_the_truth_in_most_seeds() {
    let seeds = 30u64;
    let mut total = 0;
    let mut covered_total = 0;
    for &zeta in &[0.01, 0.02, 0.05] {
        for &secs in &[10.0, 30.0, 60.0] {
            let mut covered = 0;
            let mut positive = 0;
            for seed in 0..seeds {
                let x = simulate(zeta, secs, 1000 + seed, GateParams::default());
                let a = ambient_damping(
                    &x,
                    FS,
                    &ArOptions {
                        frequency_hint_hz: Some(10.4),
                        ..ArOptions::default()
                    },
                )
                .unwrap();
                let fn_true = GateParams::default().natural_frequency_hz();
                // Within half the half-power bandwidth 2 zeta f_n (plus 0.1 Hz).
                let tol = 0.1 + zeta * fn_true;
                assert!((a.frequency_hz - fn_true).abs() < tol, "{}", a.frequency_hz);
                covered += usize::from(a.zeta_low <= zeta && zeta <= a.zeta_high);
                positive += usize::from(a.zeta_low > 0.0);
            }
            eprintln!(
                "zeta {zeta} T {secs}s: covered {covered}/{seeds}, positive {positive}/{seeds}"
            );
            assert!(
                covered as f64 >= 0.8 * seeds as f64,
                "zeta {zeta}, {secs} s: coverage {covered}/{seeds}"
            );
            let need = if secs < 20.0 && zeta < 0.015 {
                0.75
            } else {
                0.95
            };
            assert!(
                positive as f64 >= need * seeds as f64,
                "zeta {zeta}, {secs} s: positive {positive}/{seeds}"
            );
            total += seeds as usize;
            covered_total += covered;
        }
    }
    eprintln!("overall coverage {covered_total}/{total}");
    assert!(covered_total as f64 >= 0.85 * total as f64);
}

/// Documents why the default order is 4: OLS AR(2) of the sampled noise-forced oscillator
/// (an ARMA(2,1) process) underestimates the damping by about half.
#[test]
fn ar2_is_biased_on_a_noise_forced_oscillator() {
    let mut sum2 = 0.0;
    let mut sum4 = 0.0;
    for seed in 0..10 {
        let x = simulate(0.02, 60.0, seed, GateParams::default());
        let o = |order| ArOptions {
            order,
            frequency_hint_hz: Some(10.4),
            ..ArOptions::default()
        };
        sum2 += ambient_damping(&x, FS, &o(2)).unwrap().zeta / 10.0;
        sum4 += ambient_damping(&x, FS, &o(4)).unwrap().zeta / 10.0;
    }
    assert!(sum2 < 0.014, "AR(2) mean zeta {sum2}");
    assert!((sum4 / 0.02 - 1.0).abs() < 0.1, "AR(4) mean zeta {sum4}");
}

#[test]
fn ambient_with_measurement_noise_and_higher_order() {
    // 20 % measurement noise (of the ~2 N response std): AR(4) is then badly biased (mean zeta
    // ~0.12 for a true 0.02 while developing), order 8 stays near the truth.
    let p = GateParams {
        noise_std: 0.2 * GateParams::default().stationary_force_std(0.02),
        ..GateParams::default()
    };
    let mut covered = 0;
    for seed in 0..10 {
        let x = simulate(0.02, 30.0, seed, p.clone());
        let a = ambient_damping(
            &x,
            FS,
            &ArOptions {
                order: 8,
                frequency_hint_hz: Some(10.4),
                ..ArOptions::default()
            },
        )
        .unwrap();
        assert!(a.zeta_low > 0.0);
        covered += usize::from(a.zeta_low <= 0.02 && 0.02 <= a.zeta_high);
    }
    assert!(covered >= 8, "covered {covered}/10");
}

#[test]
fn self_excited_growth_gives_negative_zeta() {
    for (seed, forcing) in [(0u64, 0.0), (1, 1.0), (2, 1.0)] {
        let p = GateParams {
            c3: 0.0,
            forcing_std: forcing,
            y0: 5.0 / 81360.0,
            ..GateParams::default()
        };
        let mut sim = GateSimulator::new(p, ZetaSchedule::Constant(-0.01), seed);
        let mut x = vec![0.0; 2000];
        sim.fill(&mut x);
        let a = ambient_damping(&x, FS, &ArOptions::default()).unwrap();
        assert!(
            a.zeta_high < 0.0,
            "forcing {forcing}: zeta {} [{}, {}]",
            a.zeta,
            a.zeta_low,
            a.zeta_high
        );
        assert!((a.zeta + 0.01).abs() < 0.003, "zeta {}", a.zeta);
        let mut sa = SpectralAnalyzer::new(x.len(), FS).unwrap();
        let w = sa.analyze_window(&x, &WindowOptions::default()).unwrap();
        assert_eq!(w.regime, Regime::SelfExcited, "{w:?}");
        assert!((w.growth.zeta + 0.01).abs() < 0.002, "{:?}", w.growth);
    }
}

/// 10 s of the lab gate (200 Hz, the load-cell noise, cubic damping off) that grow:
/// ambient at +2 %, then `zeta` from 2 s before the record's start.
pub(super) fn growing_record(zeta: f64, seed: u64) -> Vec<f64> {
    let p = GateParams {
        c3: 0.0,
        forcing_std: 2.8,
        noise_std: 0.7,
        ..GateParams::default()
    };
    let schedule = ZetaSchedule::Table(vec![(19.99, 0.02), (20.0, zeta)]);
    let mut sim = GateSimulator::new(p, schedule, seed);
    let rate = sim.params().rate_hz;
    let mut x = vec![0.0; (32.0 * rate) as usize];
    sim.fill(&mut x);
    x.split_off((22.0 * rate) as usize)
}

/// With common reference instants (`SsiOptions::common_reference`) a window growing from the
/// ambient state reports the mode's negative damping, while its regime stays the one the
/// lagged reading gives (the classifier was calibrated on it). 12 seeds, lab gate, a 10 s
/// window 2 s into a growth at -0.5 % from +2 %, cubic damping off.
#[test]
fn common_reference_reports_the_growth_and_keeps_the_regime() {
    let lagged = WindowOptions::default();
    let common = WindowOptions {
        ambient: AmbientMethod::Ssi(SsiOptions {
            common_reference: true,
            ..SsiOptions::default()
        }),
        ..lagged
    };
    let (mut below, mut above) = (0, 0);
    for seed in 0..12 {
        let x = &growing_record(-0.005, seed);
        let mut sa = SpectralAnalyzer::new(x.len(), FS).unwrap();
        let l = sa.analyze_window(x, &lagged).unwrap();
        let c = sa.analyze_window(x, &common).unwrap();
        assert_eq!(l.regime, c.regime, "seed {seed}");
        let (Some(la), Some(ca)) = (l.ambient, c.ambient) else {
            continue;
        };
        above += usize::from(la.zeta > 0.0);
        below += usize::from(ca.zeta < 0.0);
    }
    assert!(above >= 9, "lagged readings above zero: {above} of 12");
    assert!(below >= 9, "common readings below zero: {below} of 12");
}

#[test]
fn stable_windows_classify_as_damped() {
    let mut sa = SpectralAnalyzer::new(6000, FS).unwrap();
    let mut damped = 0;
    for seed in 0..10 {
        let x = simulate(0.01, 30.0, seed, GateParams::default());
        let w = sa.analyze_window(&x, &WindowOptions::default()).unwrap();
        assert_ne!(w.regime, Regime::SelfExcited, "seed {seed}: {w:?}");
        damped += usize::from(w.regime == Regime::Damped);
        assert!((w.peak.frequency_hz - 10.4).abs() < 0.2);
    }
    assert!(damped >= 9, "damped {damped}/10");
}

#[test]
fn onset_fires_after_true_zeta_turns_negative() {
    // 30 s windows stepped by 10 s through the onset scenario with a faster ramp (120 s).
    let scenario = Scenario::Onset {
        hold_s: 30.0,
        ramp_s: 120.0,
    };
    let mut sim = GateSimulator::scenario(GateParams::default(), scenario, 5);
    let t_cross = sim
        .schedule()
        .first_time_at_or_below(-0.01, 0.0, 1e3, 0.5)
        .unwrap();
    let t_zero = sim
        .schedule()
        .first_time_at_or_below(0.0, 0.0, 1e3, 0.5)
        .unwrap();
    let n = 6000;
    let step = 2000;
    let mut buf = vec![0.0; 40_000];
    sim.fill(&mut buf);
    let mut sa = SpectralAnalyzer::new(n, FS).unwrap();
    let mut first_fire = None;
    let mut start = 0;
    while start + n <= buf.len() {
        let w = sa
            .analyze_window(&buf[start..start + n], &WindowOptions::default())
            .unwrap();
        let t_end = (start + n) as f64 / FS;
        let fired = matches!(w.regime, Regime::SelfExcited | Regime::LimitCycle);
        if fired && first_fire.is_none() {
            first_fire = Some(t_end);
        }
        start += step;
    }
    let fire = first_fire.expect("never fired");
    eprintln!("onset: zeta 0 at {t_zero} s, -1 % at {t_cross} s, fired at {fire} s (window end)");
    assert!(fire > t_zero, "fired at {fire} before zeta turned negative");
    assert!(fire < t_cross + 30.0, "fired at {fire}, -1 % at {t_cross}");
}

#[test]
fn saturated_limit_cycle_is_recognised() {
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::LimitCycle, 9);
    let mut burn = vec![0.0; 20 * 200];
    sim.fill(&mut burn);
    let mut sa = SpectralAnalyzer::new(6000, FS).unwrap();
    for _ in 0..3 {
        let mut x = vec![0.0; 6000];
        sim.fill(&mut x);
        let w = sa.analyze_window(&x, &WindowOptions::default()).unwrap();
        assert_eq!(w.regime, Regime::LimitCycle, "{w:?}");
        assert!(w.growth.envelope_cv < 0.1, "{:?}", w.growth);
    }
}

#[test]
fn noise_driven_envelope_is_rayleigh_like() {
    let mut sa = SpectralAnalyzer::new(12_000, FS).unwrap();
    for seed in 0..5 {
        let x = simulate(0.01, 60.0, seed, GateParams::default());
        let w = sa.analyze_window(&x, &WindowOptions::default()).unwrap();
        let cv = w.growth.envelope_cv;
        assert!(cv > 0.35 && cv < 0.7, "seed {seed}: CV {cv}");
    }
}

#[test]
fn analyzer_is_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<SpectralAnalyzer>();
    check::<crate::simulate::GateSimulator>();
}
