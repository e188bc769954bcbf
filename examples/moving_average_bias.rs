//! How the daemon's 1 s moving-average removal shifts the ambient (SSI-COV) damping reading,
//! across gate frequencies, and how much less an average over a whole number of the gate's
//! periods does (tried in stop 92, not shipped: docs/damping.md, "The 1 s moving average's
//! share, which depends on the gate"; figures in docs/benchmarks.md, "Stop 75" and "Stop 92").
//!
//! Every gate is the same in its own units: 100 cycles a window, 20 samples a period, `zeta` =
//! +2 %, no cubic damping, white sensor noise at 1/8 of the response at +1 %. Only the frequency
//! changes, so without the filter the reading's median error is the same at every frequency,
//! and whatever changes with the filter is the filter's doing. Each seed's record is read both
//! ways (paired). Seeded: the same output on every run.
//!
//! ```sh
//! cargo run --release --example moving_average_bias [SEEDS]    # default 300 seeds a frequency
//! ```

use gatewatch::simulate::{GateParams, GateSimulator, ZetaSchedule};
use gatewatch::spectral::{detrend_linear, remove_moving_average, ssi_cov_damping, SsiOptions};
use std::f64::consts::PI;

/// The true damping ratio of every gate.
const ZETA: f64 = 0.02;
/// The daemon's filter length (`SeriesOptions::moving_average_seconds`).
const MOVING_AVERAGE_SECONDS: f64 = 1.0;
/// Cycles in a window.
const CYCLES: f64 = 100.0;
/// Samples a period.
const SAMPLES_PER_PERIOD: f64 = 20.0;

fn main() {
    let seeds: u64 = match std::env::args().nth(1) {
        None => 300,
        Some(s) => match s.parse() {
            Ok(n) if n > 0 => n,
            _ => {
                eprintln!("moving_average_bias: SEEDS must be a positive whole number, not `{s}`");
                std::process::exit(2);
            }
        },
    };
    println!("zeta {:+.1} %, {CYCLES} cycles a window, {seeds} seeds a frequency; errors in percentage points (median)\n", ZETA * 100.0);
    println!("| f, Hz | f T | mode amplitude the filter keeps | without the filter | with the 1 s filter | shift of the median | spread without / with | f T, whole periods | with them | their shift | windows |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for f in [0.5, 1.0, 2.0, 3.3, 5.0, 7.7, 10.4] {
        let row = measure(f, seeds);
        println!(
            "| {f} | {:.2} | {:.2} | {:+.3} | {:+.3} | {:+.3} | {:.2} / {:.2} | {:.2} | {:+.3} | {:+.3} | {} |",
            row.f_t,
            row.kept,
            row.without,
            row.with,
            row.with - row.without,
            row.spread_without,
            row.spread_with,
            row.f_t_whole,
            row.whole,
            row.whole - row.without,
            row.windows
        );
    }
}

/// One frequency's figures.
struct Row {
    /// The frequency times the filter's length.
    f_t: f64,
    /// `|1 - H(f)|`: the fraction of the mode's amplitude left after the average is removed.
    kept: f64,
    /// Median error without the filter (linear detrending only), points.
    without: f64,
    /// Median error with it, points.
    with: f64,
    /// Spread (interquartile range / 1.349) without the filter, points.
    spread_without: f64,
    /// Spread with it, points.
    spread_with: f64,
    /// The frequency times the length of the whole-period average.
    f_t_whole: f64,
    /// Median error with the whole-period average, points.
    whole: f64,
    /// Windows read both ways.
    windows: usize,
}

fn measure(f: f64, seeds: u64) -> Row {
    let mass = 100.0;
    let rate = SAMPLES_PER_PERIOD * f;
    let mut p = GateParams {
        mass,
        stiffness: mass * (2.0 * PI * f).powi(2),
        c3: 0.0,
        forcing_std: 1.0,
        rate_hz: rate,
        ..GateParams::default()
    };
    p.noise_std = p.stationary_force_std(0.01) / 8.0;
    // the daemon's window: an odd number of samples (`analysis::model_free`)
    let w = ((MOVING_AVERAGE_SECONDS * rate).round() as usize) | 1;
    // the variant: the odd length nearest to a whole number of periods, at least one
    let periods = (MOVING_AVERAGE_SECONDS * f).round().max(1.0);
    let w_whole = 2 * ((periods * rate / f - 1.0) / 2.0).round() as usize + 1;
    let t = w as f64 / rate;
    let kept = (1.0 - (PI * f * t).sin() / (w as f64 * (PI * f / rate).sin())).abs();
    let opts = SsiOptions::default();
    let n = (CYCLES / f * rate) as usize;
    let burn = (10.0 / (ZETA * 2.0 * PI * f) * rate) as usize;
    let (mut without, mut with, mut whole) = (Vec::new(), Vec::new(), Vec::new());
    let mut x = vec![0.0; n];
    let mut filtered = vec![0.0; n];
    let mut filtered_whole = vec![0.0; n];
    let mut burn_in = vec![0.0; burn];
    for seed in 0..seeds {
        let mut sim = GateSimulator::new(p.clone(), ZetaSchedule::Constant(ZETA), 5000 + seed);
        sim.fill(&mut burn_in);
        sim.fill(&mut x);
        remove_moving_average(&x, w, &mut filtered);
        detrend_linear(&mut filtered);
        remove_moving_average(&x, w_whole, &mut filtered_whole);
        detrend_linear(&mut filtered_whole);
        detrend_linear(&mut x);
        if let (Ok(a), Ok(b), Ok(c)) = (
            ssi_cov_damping(&x, rate, f, &opts),
            ssi_cov_damping(&filtered, rate, f, &opts),
            ssi_cov_damping(&filtered_whole, rate, f, &opts),
        ) {
            without.push((a.zeta - ZETA) * 100.0);
            with.push((b.zeta - ZETA) * 100.0);
            whole.push((c.zeta - ZETA) * 100.0);
        }
    }
    Row {
        f_t: f * t,
        f_t_whole: f * w_whole as f64 / rate,
        whole: quantile(&mut whole, 0.5),
        kept,
        windows: without.len(),
        spread_without: spread(&mut without),
        spread_with: spread(&mut with),
        without: quantile(&mut without, 0.5),
        with: quantile(&mut with, 0.5),
    }
}

/// The `q` quantile (nearest rank), NaN when empty.
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Interquartile range / 1.349: the standard deviation of a normal sample, robust to tails.
fn spread(v: &mut [f64]) -> f64 {
    (quantile(v, 0.75) - quantile(v, 0.25)) / 1.349
}
