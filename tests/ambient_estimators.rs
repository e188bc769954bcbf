//! Ambient damping estimators under sensor noise, judged on seeded simulations against the known
//! truth: SSI-COV ([`ssi_cov_damping`]) beside the AR(4) fit ([`ambient_damping`]).
//!
//! Run with `cargo test --release --test integration ambient_estimators:: -- --nocapture` to see the table.
//!
//! Cases: the lab gate (19.14 kg, 10.4 Hz, 200 Hz) at `zeta = 2 %` and `1 %` with a load cell's
//! noise floor of 0.7 N against a response of about 5.6 N RMS at 2 % (the user's report), and a
//! 2000 kg, 5 Hz lock gate sampled at 100 Hz with the same signal-to-noise ratio; records of 10 s
//! and 30 s after a burn-in. The cubic damping `c3` is set to zero: at these amplitudes the lab
//! gate's `c3 = 4e4` adds about +0.1 point of equivalent linear damping at 2 % (3 c3 sigma_v^2),
//! which would blur what "the truth" is for a linear estimator.
//!
//! Per case: median bias and median |error| in percentage points, coverage of the 95 % interval,
//! the spread of the SSI estimates next to Au's uncertainty law `sd ~ sqrt(zeta / (2 pi N_c))`.

use gatewatch::simulate::{GateParams, GateSimulator, ZetaSchedule};
use gatewatch::spectral::{
    ambient_damping, ssi_cov_damping, ArOptions, SpectralAnalyzer, SsiOptions,
};
use std::f64::consts::PI;

const SEEDS: u64 = 40;

/// Records a failed target instead of stopping, so the whole table is printed first.
macro_rules! check {
    ($failures:ident, $ok:expr, $($msg:tt)+) => {
        let ok: bool = $ok;
        if !ok {
            $failures.push(format!($($msg)+));
        }
    };
}

/// A simulated case.
struct Case {
    name: &'static str,
    params: GateParams,
    zeta: f64,
    secs: f64,
}

/// The lab gate with the forcing scaled to a 5.6 N RMS response at 2 % and a 0.7 N noise floor.
fn lab_gate() -> GateParams {
    let mut p = GateParams {
        c3: 0.0,
        noise_std: 0.7,
        ..GateParams::default()
    };
    p.forcing_std = 5.6 / p.stationary_force_std(0.02);
    p
}

/// A 2000 kg, 5 Hz lock gate at 100 Hz, same signal-to-noise ratio as the lab gate at 2 % (8:1
/// in RMS). The forcing level is arbitrary (the estimators are scale-free); 400 N per sample
/// gives a response of about 0.8 kN RMS.
fn lock_gate() -> GateParams {
    let mass = 2000.0;
    let f = 5.0;
    let mut p = GateParams {
        mass,
        stiffness: mass * (2.0 * PI * f).powi(2),
        c3: 0.0,
        forcing_std: 400.0,
        rate_hz: 100.0,
        ..GateParams::default()
    };
    p.noise_std = p.stationary_force_std(0.02) / 8.0;
    p
}

fn record(p: &GateParams, zeta: f64, secs: f64, seed: u64) -> Vec<f64> {
    let mut sim = GateSimulator::new(p.clone(), ZetaSchedule::Constant(zeta), seed);
    // Burn-in: many envelope time constants 1 / (zeta omega), whatever the gate.
    let burn_s = 10.0 / (zeta * 2.0 * PI * p.natural_frequency_hz());
    let mut burn = vec![0.0; (burn_s * p.rate_hz) as usize];
    sim.fill(&mut burn);
    let mut x = vec![0.0; (secs * p.rate_hz) as usize];
    sim.fill(&mut x);
    x
}

#[derive(Debug, Default)]
struct Stats {
    errors: Vec<f64>,
    covered: usize,
    failed: usize,
    stderr: Vec<f64>,
    cycles: Vec<f64>,
    orders: Vec<f64>,
}

impl Stats {
    fn push(&mut self, est: f64, lo: f64, hi: f64, truth: f64, se: f64) {
        self.errors.push(est - truth);
        self.covered += usize::from(lo <= truth && truth <= hi);
        self.stderr.push(se);
    }
    fn n(&self) -> usize {
        self.errors.len() + self.failed
    }
    /// Median bias, points.
    fn bias(&self) -> f64 {
        100.0 * median(&self.errors)
    }
    /// Median |error|, points.
    fn mae(&self) -> f64 {
        let abs: Vec<f64> = self.errors.iter().map(|e| e.abs()).collect();
        100.0 * median(&abs)
    }
    /// Coverage over all seeds (a failure counts as not covered).
    fn coverage(&self) -> f64 {
        self.covered as f64 / self.n() as f64
    }
    /// Sample standard deviation of the estimates, points.
    fn spread(&self) -> f64 {
        let m = self.errors.iter().sum::<f64>() / self.errors.len() as f64;
        let v = self.errors.iter().map(|e| (e - m).powi(2)).sum::<f64>()
            / (self.errors.len() as f64 - 1.0);
        100.0 * v.sqrt()
    }
}

/// The crate's median (`identify::median`) of a copy; NaN when empty.
fn median(v: &[f64]) -> f64 {
    gatewatch::identify::median(&mut v.to_vec()).unwrap_or(f64::NAN)
}

/// Runs both estimators over the seeds of one case.
fn run(case: &Case, opts: &SsiOptions) -> (Stats, Stats) {
    let (mut ssi, mut ar) = (Stats::default(), Stats::default());
    let rate = case.params.rate_hz;
    for seed in 0..SEEDS {
        let x = record(&case.params, case.zeta, case.secs, 1000 + seed);
        let mut an = SpectralAnalyzer::new(x.len(), rate).expect("analyzer");
        let f_peak = an.dominant_frequency(&x, 0.5).expect("a peak").frequency_hz;
        match ssi_cov_damping(&x, rate, f_peak, opts) {
            Ok(e) => {
                ssi.push(
                    e.zeta,
                    e.zeta_interval.0,
                    e.zeta_interval.1,
                    case.zeta,
                    e.zeta_stderr,
                );
                ssi.cycles.push(e.cycles);
                ssi.orders.push(e.order as f64);
            }
            Err(err) => {
                eprintln!("{} seed {seed}: SSI failed: {err}", case.name);
                ssi.failed += 1;
            }
        }
        let ar_opts = ArOptions {
            frequency_hint_hz: Some(f_peak),
            ..ArOptions::default()
        };
        match ambient_damping(&x, rate, &ar_opts) {
            Ok(a) => ar.push(a.zeta, a.zeta_low, a.zeta_high, case.zeta, a.zeta_stderr),
            Err(_) => ar.failed += 1,
        }
    }
    (ssi, ar)
}

fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    for &(zeta, secs, name) in &[
        (0.02, 10.0, "lab 10.4 Hz, 2 %, 10 s"),
        (0.02, 30.0, "lab 10.4 Hz, 2 %, 30 s"),
        (0.01, 10.0, "lab 10.4 Hz, 1 %, 10 s"),
        (0.01, 30.0, "lab 10.4 Hz, 1 %, 30 s"),
    ] {
        v.push(Case {
            name,
            params: lab_gate(),
            zeta,
            secs,
        });
    }
    for &(secs, name) in &[
        (10.0, "lock 5 Hz, 2 %, 10 s"),
        (30.0, "lock 5 Hz, 2 %, 30 s"),
    ] {
        v.push(Case {
            name,
            params: lock_gate(),
            zeta: 0.02,
            secs,
        });
    }
    v
}

#[test]
fn ssi_is_unbiased_under_sensor_noise_and_its_interval_covers() {
    let opts = SsiOptions::default();
    let mut failures = Vec::new();
    eprintln!(
        "{SEEDS} seeds per case; points = percentage points of zeta; cov = coverage of the 95 % \
         interval; sd = spread of the estimates; Au = sqrt(zeta/(2 pi N_c)); se = median \
         reported standard error"
    );
    eprintln!(
        "{:<24} | {:>8} {:>6} {:>5} {:>5} {:>5} {:>5} {:>5} {:>3} {:>4} | {:>8} {:>6} {:>5}",
        "case",
        "SSI bias",
        "|err|",
        "cov",
        "sd",
        "Au",
        "se",
        "N_c",
        "ord",
        "fail",
        "AR bias",
        "|err|",
        "cov"
    );
    for case in cases() {
        let (ssi, ar) = run(&case, &opts);
        let n_c = median(&ssi.cycles);
        let au = 100.0 * (case.zeta / (2.0 * PI * n_c)).sqrt();
        eprintln!(
            "{:<24} | {:>+8.2} {:>6.2} {:>5.2} {:>5.2} {:>5.2} {:>5.2} {:>5.0} {:>3} {:>4} | {:>+8.2} {:>6.2} {:>5.2}",
            case.name,
            ssi.bias(),
            ssi.mae(),
            ssi.coverage(),
            ssi.spread(),
            au,
            100.0 * median(&ssi.stderr),
            n_c,
            median(&ssi.orders),
            ssi.failed,
            ar.bias(),
            ar.mae(),
            ar.coverage(),
        );
        check!(
            failures,
            ssi.failed * 20 <= ssi.n(),
            "{}: SSI found no stable mode on {} seeds",
            case.name,
            ssi.failed
        );
        check!(
            failures,
            ssi.bias().abs() < ar.bias().abs(),
            "{}: SSI bias {:.2} not smaller than AR's {:.2}",
            case.name,
            ssi.bias(),
            ar.bias()
        );
        check!(
            failures,
            ssi.coverage() >= 0.85,
            "{}: SSI coverage {:.2}",
            case.name,
            ssi.coverage()
        );
        if case.secs >= 30.0 {
            check!(
                failures,
                ssi.mae() <= 0.5,
                "{}: SSI median |error| {:.2} points",
                case.name,
                ssi.mae()
            );
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
