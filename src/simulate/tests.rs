//! Unit tests of the simulator, the scenarios and the worked example.

use super::*;

fn rms(x: &[f64]) -> f64 {
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

#[test]
fn same_seed_same_samples_whatever_the_chunks() {
    let p = GateParams {
        noise_std: 0.1,
        drift_amplitude: 0.5,
        drift_per_s: 0.01,
        ..GateParams::default()
    };
    let mut a = GateSimulator::scenario(p.clone(), Scenario::ONSET_DEFAULT, 42);
    let mut whole = vec![0.0; 2000];
    a.fill(&mut whole);
    let mut b = GateSimulator::scenario(p.clone(), Scenario::ONSET_DEFAULT, 42);
    let mut pieces = Vec::new();
    let sizes = [1usize, 7, 200, 13, 999, 1, 779];
    for &s in &sizes {
        let mut buf = vec![0.0; s];
        b.fill(&mut buf);
        pieces.extend_from_slice(&buf);
    }
    assert_eq!(pieces.len(), 2000);
    assert_eq!(whole, pieces, "chunking changed the samples");
    let mut c = GateSimulator::scenario(p, Scenario::ONSET_DEFAULT, 43);
    let mut other = vec![0.0; 2000];
    c.fill(&mut other);
    assert_ne!(whole, other, "different seeds gave the same samples");
}

#[test]
fn stable_force_std_matches_prediction() {
    let p = GateParams::default();
    let predicted = p.stationary_force_std(0.01);
    let mut sim = GateSimulator::scenario(p, Scenario::Stable, 7);
    let mut x = vec![0.0; 200 * 300];
    sim.fill(&mut x);
    let s = rms(&x[200 * 20..]);
    // Within 20 %: 280 s holds ~170 correlation times (1/(zeta*omega) = 1.5 s) of the
    // response, so the sample std has a relative scatter of ~5 %; the remainder allows for
    // the interpolated forcing not being exactly white at 10 Hz.
    assert!(
        (s / predicted - 1.0).abs() < 0.2,
        "std {s} vs predicted {predicted}"
    );
    assert!(s > 1.0 && s < 10.0, "stable force std {s} N");
}

#[test]
fn stable_scenario_ar_damping_is_near_one_percent() {
    use crate::spectral::{ambient_damping, ArOptions};
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 11);
    let mut x = vec![0.0; 200 * 140];
    sim.fill(&mut x);
    // Two 60 s windows after a 20 s burn-in.
    for w in x[200 * 20..].chunks(200 * 60) {
        let a = ambient_damping(w, 200.0, &ArOptions::default()).unwrap();
        assert!((a.zeta - 0.01).abs() < 0.003, "zeta {a:?}");
        assert!(a.zeta_low > 0.0);
    }
}

#[test]
fn onset_true_zeta_crosses_minus_one_percent_when_expected() {
    let sim = GateSimulator::scenario(GateParams::default(), Scenario::ONSET_DEFAULT, 1);
    // From +2 % at 60 s to -2 % at 360 s: -1 % is three quarters of the way, at 285 s.
    let t = sim
        .schedule()
        .first_time_at_or_below(-0.01, 0.0, 1000.0, 1.0)
        .unwrap();
    assert!((t - 285.0).abs() < 1e-6, "crossed at {t}");
    assert!((sim.true_zeta(0.0) - 0.02).abs() < 1e-12);
    assert!((sim.true_zeta(210.0) - 0.0).abs() < 1e-12);
    assert!((sim.true_zeta(1e4) + 0.02).abs() < 1e-12);
}

#[test]
fn onset_grows_into_a_clearly_larger_limit_cycle() {
    let p = GateParams::default();
    let lc = p.limit_cycle_force_amplitude(-0.02).unwrap();
    let stable = p.stationary_force_std(0.02);
    let scenario = Scenario::Onset {
        hold_s: 20.0,
        ramp_s: 60.0,
    };
    let mut sim = GateSimulator::scenario(p, scenario, 21);
    let mut x = vec![0.0; 200 * 110];
    sim.fill(&mut x);
    // Stable phase (10-20 s): the response std of the +2 % gate, within 35 % (a 10 s
    // window holds only ~13 correlation times).
    let s = rms(&x[200 * 10..200 * 20]);
    assert!(
        (s / stable - 1.0).abs() < 0.35,
        "stable std {s} vs {stable}"
    );
    // 20 s after the ramp ended: the -2 % limit cycle.
    let amp = rms(&x[200 * 100..]) * std::f64::consts::SQRT_2;
    assert!((amp / lc - 1.0).abs() < 0.1, "amplitude {amp} vs {lc}");
    assert!(amp > 10.0 * s);
}

#[test]
fn table_schedule_interpolates() {
    let s = ZetaSchedule::Table(vec![(0.0, 0.01), (10.0, -0.01), (20.0, -0.01)]);
    assert!((s.at(-1.0) - 0.01).abs() < 1e-15);
    assert!((s.at(5.0) - 0.0).abs() < 1e-15);
    assert!((s.at(15.0) + 0.01).abs() < 1e-15);
    assert!((s.at(99.0) + 0.01).abs() < 1e-15);
    let c = ZetaSchedule::Custom(Box::new(|t| 0.01 - 0.001 * t));
    let t = c.first_time_at_or_below(-0.01, 0.0, 100.0, 1.0).unwrap();
    assert!((t - 20.0).abs() < 1e-9);
}

#[test]
fn limit_cycle_settles_at_harmonic_balance_amplitude() {
    let p = GateParams::default();
    let predicted = p.limit_cycle_force_amplitude(-0.02).unwrap();
    let stable = p.stationary_force_std(0.01) * std::f64::consts::SQRT_2;
    let mut sim = GateSimulator::scenario(p, Scenario::LimitCycle, 3);
    let mut x = vec![0.0; 200 * 40];
    sim.fill(&mut x);
    // Amplitude of a sinusoid = sqrt(2) * rms, over 5 s blocks of the last 20 s.
    let blocks: Vec<f64> = x[200 * 20..]
        .chunks(1000)
        .map(|b| rms(b) * std::f64::consts::SQRT_2)
        .collect();
    let (lo, hi) = blocks
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(hi / lo < 1.1, "envelope not settled: {blocks:?}");
    let mean = blocks.iter().sum::<f64>() / blocks.len() as f64;
    assert!(
        (mean / predicted - 1.0).abs() < 0.1,
        "limit cycle {mean} vs harmonic balance {predicted}"
    );
    assert!(
        mean > 5.0 * stable,
        "limit cycle {mean} not clearly above {stable}"
    );
}

#[test]
fn worked_example_converged_in_substeps() {
    let base = WorkedExampleOptions {
        noise_fraction: 0.0,
        ..WorkedExampleOptions::default()
    };
    let a = worked_example(&base);
    let b = worked_example(&WorkedExampleOptions {
        substeps: 40,
        ..base.clone()
    });
    assert_eq!(a.force.len(), 2000);
    let scale = a.clean.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = a
        .clean
        .iter()
        .zip(&b.clean)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    assert!(
        err < 1e-6 * scale,
        "20 vs 40 substeps differ by {err} (scale {scale})"
    );
    assert!((a.clean[0] - EX_K * EX_Y0).abs() < 1e-9);
}

#[test]
fn worked_example_noise_is_one_percent() {
    let ex = worked_example(&WorkedExampleOptions::default());
    let n = ex.clean.len() as f64;
    let mean = ex.clean.iter().sum::<f64>() / n;
    let std = (ex.clean.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
    let noise: Vec<f64> = ex.force.iter().zip(&ex.clean).map(|(a, b)| a - b).collect();
    let r = rms(&noise) / std;
    assert!((r - 0.01).abs() < 0.001, "noise fraction {r}");
}

#[test]
fn worked_example_settles_on_its_limit_cycle() {
    let ex = worked_example(&WorkedExampleOptions {
        noise_fraction: 0.0,
        ..WorkedExampleOptions::default()
    });
    let p = GateParams {
        mass: EX_MASS,
        stiffness: EX_K,
        c3: EX_C3,
        ..GateParams::default()
    };
    let predicted = p
        .limit_cycle_force_amplitude(EX_C1 / p.critical_damping())
        .unwrap();
    // A growth phase: ~27 N at the start, growing towards the ~240 N limit cycle.
    assert!(ex.clean[0] > 25.0 && ex.clean[0] < 30.0);
    let head = rms(&ex.clean[..200]) * std::f64::consts::SQRT_2;
    let tail = &ex.clean[ex.clean.len() - 400..];
    assert!(rms(tail) * std::f64::consts::SQRT_2 > 5.0 * head);
    let amp = rms(tail) * std::f64::consts::SQRT_2;
    assert!(
        (amp / predicted - 1.0).abs() < 0.1,
        "tail amplitude {amp} vs harmonic balance {predicted}"
    );
}
