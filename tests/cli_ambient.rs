//! An engineer's ambient record through `gatewatch identify`: a single channel of a structure
//! shaken by wind or flow, holding several modes near one another and a sensor's noise floor,
//! the case issue 8 met on a building's public recordings (its AR(4) estimate read 7 % where
//! SSI-COV read 1.2 to 2.4 %). The record is built here from exact discrete pole pairs driven by
//! white noise, so the truth of each mode's damping is known.
//!
//! docs/benchmarks.md, "Several modes in one channel", runs records made the same way through an
//! independent covariance-driven SSI (`strid`, from PyPI) beside this
//! (`benches/python/ambient_crosscheck.py`).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::f64::consts::PI;
use std::process::{Command, Stdio};

const RATE: f64 = 40.0;
/// The modes: frequency (Hz), damping ratio, RMS. The first is the one the spectrum's peak
/// names; the second lies 21 % above it, inside the band a single-mode fit would smear.
const MODES: [(f64, f64, f64); 3] = [(1.20, 0.015, 1.0), (1.45, 0.020, 0.6), (3.60, 0.010, 0.4)];
const FIRST_ZETA: f64 = 0.015;

/// `seconds` of the modes' response plus white noise of RMS `noise` (the signal's unit), after a
/// warm-up of 200 s that brings every mode to its stationary state.
fn record(seed: u64, seconds: f64, noise: f64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let warm = (200.0 * RATE) as usize;
    let n = (seconds * RATE) as usize;
    let dt = 1.0 / RATE;
    let mut y = vec![0.0; n];
    for &(f, z, rms) in &MODES {
        let w = 2.0 * PI * f;
        let r = (-z * w * dt).exp();
        let wd = w * (1.0 - z * z).sqrt();
        let (a1, a2) = (2.0 * r * (wd * dt).cos(), -r * r);
        let (mut x1, mut x2) = (0.0, 0.0);
        let mut x = Vec::with_capacity(n);
        for k in 0..warm + n {
            let v = a1 * x1 + a2 * x2 + normal.sample(&mut rng);
            x2 = x1;
            x1 = v;
            if k >= warm {
                x.push(v);
            }
        }
        let s = (x.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        for (yk, xk) in y.iter_mut().zip(&x) {
            *yk += rms * xk / s;
        }
    }
    for yk in &mut y {
        *yk += noise * normal.sample(&mut rng);
    }
    y
}

fn identify(path: &std::path::Path, json: bool) -> std::process::Output {
    let mut args = vec![
        "identify".to_string(),
        "--input".into(),
        path.display().to_string(),
        "--value-column".into(),
        "force".into(),
        "--signal".into(),
        "force".into(),
        "--stiffness".into(),
        "1000".into(),
        "--model".into(),
        "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0".into(),
    ];
    if json {
        args.push("--json".into());
    }
    Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(&args)
        .stdin(Stdio::null())
        .output()
        .expect("gatewatch runs")
}

fn write_csv(path: &std::path::Path, y: &[f64]) {
    let mut s = String::from("t,force\n");
    for (k, v) in y.iter().enumerate() {
        s.push_str(&format!("{:.4},{v:.6}\n", k as f64 / RATE));
    }
    std::fs::write(path, s).unwrap();
}

/// Eight 82 s records (about 100 cycles of the first mode, the windows) at a noise floor
/// of half the response's RMS: the reported `zeta0` is the ambient (SSI-COV) estimate of the
/// first mode, within 0.5 points of the truth in the median, and its 95 % interval holds the
/// truth in at least 7 of 8. The AR(4) fit gatewatch used before SSI-COV puts the first mode of
/// such records at 30 to 90 % (`benches/python/ambient_crosscheck.py`, docs/benchmarks.md).
#[test]
fn several_modes_and_a_noise_floor_read_the_first_mode() {
    let dir = tempfile::tempdir().unwrap();
    let mut errors = Vec::new();
    let mut covered = 0;
    for seed in 1..=8u64 {
        let path = dir.path().join(format!("ambient{seed}.csv"));
        write_csv(&path, &record(seed, 82.0, 0.5));
        let o = identify(&path, true);
        assert_eq!(
            o.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let d = &v["damping"];
        assert_eq!(d["zeta0_source"], "ambient", "seed {seed}: {d}");
        let z = d["zeta0"].as_f64().unwrap();
        let lo = d["zeta0_interval"][0].as_f64().unwrap();
        let hi = d["zeta0_interval"][1].as_f64().unwrap();
        assert!(lo <= z && z <= hi, "seed {seed}: {d}");
        let f = d["ambient_frequency_hz"].as_f64().unwrap();
        assert!(
            (f - 1.2).abs() < 0.03,
            "seed {seed}: the first mode, {f} Hz"
        );
        errors.push((z - FIRST_ZETA).abs());
        if lo <= FIRST_ZETA && FIRST_ZETA <= hi {
            covered += 1;
        }
    }
    errors.sort_by(f64::total_cmp);
    let median = 0.5 * (errors[3] + errors[4]);
    assert!(median <= 0.005, "median |error| {median}: {errors:?}");
    assert!(covered >= 7, "interval held the truth in {covered} of 8");
}

/// On such a record the free-vibration fit finds a limit cycle at the record's own amplitude
/// (a noise-driven response has a steady envelope), with a fit far above `--max-fit-nmae`. The
/// printout says the model is not trusted on each line that comes from it, and which estimate
/// the verdict rests on: before, it printed "limit-cycle amplitude: 1.17e0" and "trusted: yes"
/// beside a `damped` verdict, called the SSI-COV estimate "AR", and gave an ambient interval
/// across zero as "unknown (the model cannot be trusted)".
#[test]
fn the_printout_marks_the_untrusted_models_lines() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ambient.csv");
    write_csv(&path, &record(1, 82.0, 0.1));
    let o = identify(&path, false);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(0), "{out}");
    let line = |key: &str| {
        out.lines()
            .find(|l| l.trim_start().starts_with(key))
            .unwrap_or_else(|| panic!("no {key} line: {out}"))
            .to_string()
    };
    assert!(line("fit NMAE").contains("model trusted: no"), "{out}");
    assert!(
        line("report trusted").contains("zeta0 from ambient"),
        "{out}"
    );
    // the interval decides: above zero damped, across zero unknown for that reason, not the model's
    let interval = line("zeta0 (at rest)");
    let verdict = line("verdict");
    assert!(interval.ends_with("(ambient)"), "{out}");
    assert!(
        verdict.ends_with("damped") || verdict.contains("interval reaches zero"),
        "{out}"
    );
    for key in ["zeta_eq", "energy fed"] {
        assert!(line(key).ends_with("(model, not trusted)"), "{out}");
    }
    let cycle = line("limit-cycle amplitude");
    assert!(
        cycle.ends_with("n/a") || cycle.ends_with("(model, not trusted)"),
        "{out}"
    );
    assert!(line("ambient zeta (SSI-COV)").contains('%'), "{out}");
    assert!(!out.contains("(AR)"), "{out}");
}
