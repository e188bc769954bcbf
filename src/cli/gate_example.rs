//! `gatewatch bench gate-example`: the chapter's gate example through the daemon's analysis.

use super::{input, opt, CliError};
use crate::bench;
use crate::identify::{MAX_GENERATIONS, MAX_POPULATION, MAX_RUNS};
use clap::Args;
use serde_json::json;
use std::io::Write;

/// Arguments of `gatewatch bench gate-example`.
#[derive(Debug, Args)]
pub struct GateExampleArgs {
    /// Runs (noise and DE seeds seed, seed + 1, ...).
    #[arg(long, allow_negative_numbers = true, default_value_t = 25)]
    runs: usize,
    /// Seed of the first run.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// Measurement noise, fraction of the signal's standard deviation.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.01)]
    noise: f64,
    /// Drift of the force, N/s.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.2)]
    drift: f64,
    /// DE population.
    #[arg(long, allow_negative_numbers = true, default_value_t = 20)]
    population: usize,
    /// DE generations.
    #[arg(long, allow_negative_numbers = true, default_value_t = 40)]
    generations: usize,
    /// Without the FFT-biased initial population.
    #[arg(long)]
    no_fft_bias: bool,
    /// Print the runs as JSON.
    #[arg(long)]
    json: bool,
}

/// Largest `--drift`, N/s.
const MAX_DRIFT: f64 = 1000.0;

pub(super) fn run(a: GateExampleArgs) -> Result<(), CliError> {
    if a.runs == 0 {
        return Err(input("--runs must be at least 1"));
    }
    // The library's bounds (crate::identify::MAX_RUNS and the others say why), checked here
    // in this command's flags before any run starts.
    if a.runs > MAX_RUNS {
        return Err(input(format!(
            "--runs must be at most {MAX_RUNS}, got {}",
            a.runs
        )));
    }
    if a.population > MAX_POPULATION {
        return Err(input(format!(
            "--population must be at most {MAX_POPULATION}, got {}",
            a.population
        )));
    }
    if a.generations > MAX_GENERATIONS {
        return Err(input(format!(
            "--generations must be at most {MAX_GENERATIONS}, got {}",
            a.generations
        )));
    }
    if !(0.0..1.0).contains(&a.noise) {
        return Err(input("--noise must be in [0, 1)"));
    }
    if a.population < 4 {
        return Err(input("--population must be at least 4"));
    }
    if a.generations == 0 {
        return Err(input("--generations must be at least 1"));
    }
    // the drift of a 10 s record: a few newtons per second at most are a sensor's; past a
    // kilonewton per second the record is the drift (and NaN or 1e300 failed in the analysis,
    // naming no flag)
    if !(-MAX_DRIFT..=MAX_DRIFT).contains(&a.drift) {
        return Err(input(format!(
            "--drift must be a number from -{MAX_DRIFT} to {MAX_DRIFT} N/s, got {}",
            crate::number::Num(a.drift)
        )));
    }
    let opts = bench::GateExampleOptions {
        runs: a.runs,
        seed: a.seed,
        noise: a.noise,
        drift: a.drift,
        population: a.population,
        generations: a.generations,
        fft_bias: !a.no_fft_bias,
    };
    let runs = bench::run_gate_example(&opts)?;
    let mut out = std::io::stdout().lock();
    if a.json {
        writeln!(out, "{}", json!({"options": opts, "runs": runs}))?;
        return Ok(());
    }
    writeln!(out, "| seed | mass kg | damping N s/m | cubic N s^3/m^3 | zeta0 % | verdict | ok | evaluations | seconds |")?;
    writeln!(out, "|---|---|---|---|---|---|---|---|---|")?;
    for r in &runs {
        writeln!(
            out,
            "| {} | {:.3} | {:.3} | {:.1} | {} | {} | {} | {} | {:.3} |",
            r.seed,
            r.mass,
            r.damping,
            r.cubic,
            opt(r.zeta0, |z| format!("{:.4}", 100.0 * z)),
            r.verdict.as_str(),
            if r.success { "yes" } else { "no" },
            r.evaluations,
            r.seconds
        )?;
    }
    let mut secs: Vec<f64> = runs.iter().map(|r| r.seconds).collect();
    secs.sort_by(f64::total_cmp);
    writeln!(
        out,
        "\n{} of {} runs: mass and damping within 2 % and zeta0 < 0; median {:.3} s per run, max {:.3} s",
        runs.iter().filter(|r| r.success).count(),
        runs.len(),
        secs[secs.len() / 2],
        secs[secs.len() - 1]
    )?;
    Ok(())
}
