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

/// `n` samples of `sim` from the scenario's `t = 0` (the warm-up dropped), with the clean output.
fn run_scenario(sim: &mut GateSimulator, n: usize) -> (Vec<f64>, Vec<f64>) {
    while sim.time() < -1e-9 {
        sim.next_sample();
    }
    let mut measured = Vec::with_capacity(n);
    let mut clean = Vec::with_capacity(n);
    for _ in 0..n {
        measured.push(sim.next_sample());
        clean.push(sim.last_clean());
    }
    (measured, clean)
}

#[test]
fn every_scenario_true_zeta_matches_its_definition() {
    let p = GatePreset::Lab.params();
    let z = |n: ScenarioName, t: f64| n.def(&p).true_zeta(t);
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    assert!(
        close(z(ScenarioName::Stable, 0.0), 0.01) && close(z(ScenarioName::Stable, 599.0), 0.01)
    );
    assert!(close(z(ScenarioName::StableLow, 300.0), 0.005));
    // slow drift: +2 % until 120 s, zero at 720 s, -1 % at 1020 s, -2 % from 1320 s
    let d = ScenarioName::SlowDrift.def(&p);
    assert!(close(d.true_zeta(120.0), 0.02) && close(d.true_zeta(720.0), 0.0));
    assert!(close(d.true_zeta(1020.0), -0.01) && close(d.true_zeta(1380.0), -0.02));
    let t0 = d
        .zeta
        .first_time_at_or_below(0.0, 0.0, d.duration_s, 1.0)
        .unwrap();
    assert!((t0 - 720.0).abs() < 1e-6, "slow drift crosses zero at {t0}");
    // onset: +2 % to -2 % in 60 s from 120 s: zero at 150 s, -1 % at 165 s
    let o = ScenarioName::Onset.def(&p);
    let t1 = o
        .zeta
        .first_time_at_or_below(-0.01, 0.0, o.duration_s, 1.0)
        .unwrap();
    assert!((t1 - 165.0).abs() < 1e-6, "onset reaches -1 % at {t1}");
    assert!(close(o.true_zeta(150.0), 0.0) && close(o.true_zeta(200.0), -0.02));
    assert!(
        close(z(ScenarioName::LimitCycle, 0.0), -0.02)
            && close(z(ScenarioName::LimitCycle, 299.0), -0.02)
    );
    let r = ScenarioName::Recovery.def(&p);
    assert!(
        close(r.true_zeta(100.0), -0.02)
            && close(r.true_zeta(150.0), 0.0)
            && close(r.true_zeta(200.0), 0.02)
    );
    let s = ScenarioName::Step.def(&p);
    assert!(close(s.true_zeta(119.9), 0.02) && close(s.true_zeta(120.1), -0.02));
    let b = ScenarioName::Bursting.def(&p);
    for (t, want) in [
        (30.0, 0.01),
        (61.0, -0.03),
        (74.0, -0.03),
        (76.0, 0.01),
        (151.0, -0.03),
        (170.0, 0.01),
    ] {
        assert!(
            close(b.true_zeta(t), want),
            "bursting at {t}: {}",
            b.true_zeta(t)
        );
    }
    let w = ScenarioName::WaterLevel.def(&p);
    assert!(close(w.true_zeta(300.0), 0.01));
    let k = w.stiffness_factor.as_ref().unwrap();
    assert!(close(k.at(0.0), 1.0) && close(k.at(300.0), 0.85) && close(k.at(600.0), 0.7));
    // window-average truth of a ramp is its value at the centre
    assert!((d.mean_zeta(700.0, 740.0) - 0.0).abs() < 1e-9);
    for n in ScenarioName::ALL {
        assert_eq!(ScenarioName::parse(n.as_str()), Ok(n));
        assert_eq!(
            n.is_stable(),
            n.def(&p)
                .zeta
                .first_time_at_or_below(0.0, 0.0, 2000.0, 0.5)
                .is_none(),
            "{n:?}"
        );
    }
    assert!(ScenarioName::parse("nope")
        .unwrap_err()
        .contains("slow-drift"));
}

#[test]
fn every_scenario_same_seed_same_signal() {
    for g in GatePreset::ALL {
        let p = g.params();
        for n in ScenarioName::ALL {
            let d = n.def(&p);
            let samples = (2.0 * p.rate_hz) as usize;
            let mut a = d.simulator(&p, NoiseLevel::Absolute(0.1), 5).unwrap();
            let mut b = d.simulator(&p, NoiseLevel::Absolute(0.1), 5).unwrap();
            let mut c = d.simulator(&p, NoiseLevel::Absolute(0.1), 6).unwrap();
            let (xa, _) = run_scenario(&mut a, samples);
            let (xb, _) = run_scenario(&mut b, samples);
            let (xc, _) = run_scenario(&mut c, samples);
            assert_eq!(xa, xb, "{n:?} on {g:?}: same seed, different signal");
            assert_ne!(xa, xc, "{n:?} on {g:?}: different seeds, same signal");
            assert!(xa.iter().all(|v| v.is_finite()));
        }
    }
}

#[test]
fn absolute_noise_has_the_requested_rms() {
    for (g, level) in [(GatePreset::Lab, 0.7), (GatePreset::Lock, 50.0)] {
        let p = g.params();
        let d = ScenarioName::Stable.def(&p);
        let mut sim = d.simulator(&p, NoiseLevel::Absolute(level), 9).unwrap();
        let (x, clean) = run_scenario(&mut sim, 40_000);
        let noise: Vec<f64> = x.iter().zip(&clean).map(|(a, b)| a - b).collect();
        // 40 000 draws: the sample RMS of Gaussian noise scatters by 1/sqrt(2n) = 0.35 %
        let r = rms(&noise);
        assert!(
            (r / level - 1.0).abs() < 0.02,
            "{g:?}: noise rms {r} vs {level}"
        );
    }
    // relative noise: a fraction of the preset's ambient std at +1 %
    let p = GatePreset::Lock.params();
    assert!((NoiseLevel::Relative(0.1).rms(&p) - 0.1 * p.stationary_force_std(0.01)).abs() < 1e-12);
}

#[test]
fn presets_have_their_frequency_rate_and_limit_cycle_ratio() {
    let lab = GatePreset::Lab.params();
    assert!((lab.natural_frequency_hz() - 10.4).abs() < 0.05);
    let lock = GatePreset::Lock.params();
    assert!((lock.natural_frequency_hz() - 5.0).abs() < 1e-9);
    assert!((lock.mass - 2000.0).abs() < 1e-12 && (lock.rate_hz - 100.0).abs() < 1e-12);
    let barrier = GatePreset::Barrier.params();
    assert!((barrier.natural_frequency_hz() - 2.0).abs() < 1e-9);
    for p in [&lock, &barrier] {
        let ratio = p.limit_cycle_force_amplitude(-0.02).unwrap() / p.stationary_force_std(0.01);
        assert!((ratio - 17.0).abs() < 1e-9, "limit cycle / ambient {ratio}");
    }
    assert_eq!(GatePreset::parse("lock"), Ok(GatePreset::Lock));
    assert!(GatePreset::parse("weir").is_err());
}

#[test]
fn held_limit_cycle_starts_on_the_cycle_of_the_lock_gate() {
    let p = GatePreset::Lock.params();
    let d = ScenarioName::LimitCycle.def(&p);
    let mut sim = d.simulator(&p, NoiseLevel::Absolute(0.0), 2).unwrap();
    let (_, clean) = run_scenario(&mut sim, 1000);
    let amp = rms(&clean) * std::f64::consts::SQRT_2;
    let lc = p.limit_cycle_force_amplitude(-0.02).unwrap();
    assert!(
        (amp / lc - 1.0).abs() < 0.1,
        "first 10 s at {amp}, cycle {lc}"
    );
}

#[test]
fn water_level_lowers_the_frequency() {
    let p = GatePreset::Lab.params();
    let d = ScenarioName::WaterLevel.def(&p);
    let mut sim = d.simulator(&p, NoiseLevel::Absolute(0.0), 4).unwrap();
    let (_, clean) = run_scenario(&mut sim, 200 * 600);
    // zero crossings per second ~ 2 f: over the first and the last 60 s
    let rate = |x: &[f64]| x.windows(2).filter(|w| w[0] * w[1] < 0.0).count() as f64 / 2.0 / 60.0;
    let f_start = rate(&clean[..200 * 60]);
    let f_end = rate(&clean[200 * 540..]);
    let want = p.natural_frequency_hz() * 0.7f64.sqrt();
    assert!(
        (f_start / p.natural_frequency_hz() - 1.0).abs() < 0.03,
        "start {f_start} Hz"
    );
    assert!(
        (f_end / want - 1.0).abs() < 0.04,
        "end {f_end} Hz vs {want}"
    );
}

#[test]
fn sensor_faults_spike_drop_clip_and_offset() {
    let p = GatePreset::Lab.params();
    let d = ScenarioName::SensorFaults.def(&p);
    let f = d.faults.clone();
    let mut sim = d.simulator(&p, NoiseLevel::Absolute(0.0), 8).unwrap();
    let (x, clean) = run_scenario(&mut sim, 200 * 600);
    assert!(x.iter().all(|v| v.abs() <= f.clip + 1e-12), "clipping");
    let zeros = x.iter().filter(|v| **v == 0.0).count();
    // 600 s at 1/150 per s: ~4 dropouts of 200 samples each
    assert!(zeros >= 200, "no dropout: {zeros} zero samples");
    // the offset after 300 s: the median of measured - clean moves by dc_offset
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let before: Vec<f64> = x[..200 * 300]
        .iter()
        .zip(&clean)
        .map(|(a, b)| a - b)
        .collect();
    let after: Vec<f64> = x[200 * 300..]
        .iter()
        .zip(&clean[200 * 300..])
        .map(|(a, b)| a - b)
        .collect();
    assert!(median(before).abs() < 1e-9);
    // clipping eats into the offset where the response is large; most samples keep it whole
    assert!((median(after) - f.dc_offset).abs() < 0.05 * f.dc_offset);
    // spikes (10 sigma) saturate the amplifier: a clipped reading where the gate is near rest
    // (|clean| < 0.5 sigma, 38 % of the time): 0.1 per s over 600 s is ~60 spikes, ~23 of them
    // counted here (Poisson, sd ~5)
    let s1 = p.stationary_force_std(0.01);
    let spikes = x
        .iter()
        .zip(&clean)
        .filter(|(a, b)| (a.abs() - f.clip).abs() < 1e-9 && b.abs() < 0.5 * s1)
        .count();
    assert!((10..=45).contains(&spikes), "{spikes} spikes");
}

/// The impacts scenario strikes the gate about once a minute with free vibrations 5 to 20 times
/// its ambient response, which decay at its positive damping; the forcing and the noise of a
/// seed are those of the same seed unstruck (their own streams), so the difference of the two
/// runs is the blows alone.
#[test]
fn impacts_strike_the_gate_and_decay() {
    for g in [GatePreset::Lab, GatePreset::Lock] {
        let p = g.params();
        let d = ScenarioName::Impacts.def(&p);
        assert!(d.impacts.is_active() && ScenarioName::Impacts.is_stable());
        let n = (600.0 * p.rate_hz) as usize;
        let mut struck = d.simulator(&p, NoiseLevel::Absolute(0.0), 4).unwrap();
        let mut calm = ScenarioDef {
            impacts: Impacts::default(),
            ..ScenarioName::Impacts.def(&p)
        }
        .simulator(&p, NoiseLevel::Absolute(0.0), 4)
        .unwrap();
        let (x, _) = run_scenario(&mut struck, n);
        let (y, _) = run_scenario(&mut calm, n);
        let s = p.stationary_force_std(0.01);
        // the blows' response in blocks of half a second, in ambient stds
        let block = (0.5 * p.rate_hz) as usize;
        let peaks: Vec<f64> = x
            .chunks(block)
            .zip(y.chunks(block))
            .map(|(a, b)| {
                a.iter()
                    .zip(b)
                    .map(|(u, v)| (u - v).abs())
                    .fold(0.0, f64::max)
                    / s
            })
            .collect();
        // a blow: a block at least 4 stds whose predecessor held under half of it
        let blows: Vec<usize> = (1..peaks.len())
            .filter(|&i| peaks[i] >= 4.0 && peaks[i - 1] < 0.5 * peaks[i])
            .collect();
        // intervals of 30 to 90 s in 600 s: 6 to 20 blows
        assert!(
            (6..=20).contains(&blows.len()),
            "{g:?}: {} blows",
            blows.len()
        );
        let largest = blows.iter().map(|&i| peaks[i]).fold(0.0, f64::max);
        assert!(
            (8.0..=24.0).contains(&largest),
            "{g:?}: largest blow {largest:.1} stds"
        );
        for &i in &blows {
            // nothing before the first blow, and each one decays: 3 correlation times
            // 1/(zeta omega) later it is at most a fifth of its peak (e^-3 linear, faster with
            // the cubic damping at these amplitudes)
            let tau = 1.0 / (0.01 * 2.0 * std::f64::consts::PI * p.natural_frequency_hz());
            let later = i + (6.0 * tau).ceil() as usize;
            if later < peaks.len() {
                assert!(
                    peaks[later] < 0.2 * peaks[i] + 1.0,
                    "{g:?}: the blow at block {i} ({:.1} stds) still {:.1} stds {:.1} s later",
                    peaks[i],
                    peaks[later],
                    3.0 * tau
                );
            }
        }
        assert!(
            peaks[..blows[0]].iter().all(|v| *v == 0.0),
            "{g:?}: struck before the first blow"
        );
    }
}
