//! `gatewatch bench seed-cases`: the chapter's seed cases with its protocol, beside its numbers.

use super::{find_case, input, progress_bar, CliError};
use crate::bench::{self, BenchOptions};
use crate::cases;
use crate::ode::Method;
use clap::Args;
use serde_json::json;
use std::io::Write;

/// Arguments of `gatewatch bench seed-cases`.
#[derive(Debug, Args)]
pub struct SeedCasesArgs {
    /// Runs per case.
    #[arg(long, allow_negative_numbers = true, default_value_t = 25)]
    runs: usize,
    /// Only these cases (repeatable); all by default.
    #[arg(long = "case", value_name = "ID")]
    cases: Vec<String>,
    /// Seed of the first run.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// Fitness solver: dopri5, rk4 or stiff.
    #[arg(long, default_value = "dopri5")]
    solver: Method,
    /// Relative tolerance of the fitness solver.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1e-3)]
    rtol: f64,
    /// Skip the Levenberg-Marquardt polish (the chapter's protocol).
    #[arg(long)]
    no_refine: bool,
    /// Never restart a stagnating population (the chapter's protocol).
    #[arg(long)]
    no_restart: bool,
    /// Gaussian noise added to the data, fraction of its standard deviation (errors are then
    /// measured against the noise-free truth).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0)]
    noise: f64,
    /// Bias half of the initial population with the spectrum's frequency and growth.
    #[arg(long)]
    fft_bias: bool,
    /// Trials the fitness integrates in lockstep: 1 (one by one), 4 or 8. Results are
    /// identical; only the time differs.
    #[arg(long, allow_negative_numbers = true, default_value_t = crate::identify::LANES)]
    lanes: usize,
    /// Print the results as JSON.
    #[arg(long)]
    json: bool,
}

pub(super) fn run(a: SeedCasesArgs) -> Result<(), CliError> {
    if a.runs == 0 {
        return Err(input("--runs must be at least 1"));
    }
    // The library's bound (crate::identify::MAX_RUNS says why), checked before any case runs.
    if a.runs > crate::identify::MAX_RUNS {
        return Err(input(format!(
            "--runs must be at most {}, got {}",
            crate::identify::MAX_RUNS,
            a.runs
        )));
    }
    if !matches!(a.lanes, 1 | 4 | 8) {
        return Err(input("--lanes must be 1, 4 or 8"));
    }
    if !(0.0..1.0).contains(&a.noise) {
        return Err(input("--noise must be in [0, 1)"));
    }
    // Checked here, as the other flags: the cases refused it one by one, as an error (exit 1).
    if !(crate::identify::MIN_TOLERANCE..1.0).contains(&a.rtol) {
        return Err(input(format!(
            "--rtol must be in [1e-14, 1), got {}",
            crate::number::Num(a.rtol)
        )));
    }
    let selected: Vec<&cases::SeedCase> = if a.cases.is_empty() {
        cases::CASES.iter().collect()
    } else {
        a.cases
            .iter()
            .map(|id| find_case(id))
            .collect::<Result<_, _>>()?
    };
    let opts = BenchOptions {
        runs: a.runs,
        seed: a.seed,
        solver: a.solver,
        rtol: a.rtol,
        refine: !a.no_refine,
        restart: !a.no_restart,
        noise: a.noise,
        fft_bias: a.fft_bias,
        lanes: a.lanes,
        ..BenchOptions::default()
    };
    let mut reports = Vec::new();
    for case in selected {
        let bar = progress_bar((a.runs * case.generations) as u64, case.id);
        let report = bench::run_case(case, &opts, |r, g| {
            bar.set_position((r * case.generations + g) as u64)
        })?;
        bar.finish_and_clear();
        if !a.json {
            // progress only: a closed stderr must not stop the run
            let _ = writeln!(
                std::io::stderr(),
                "{}: mean NMAE {:.3e}, {}/{} runs below 0.01, median {:.4} s/run",
                report.id,
                report.mean_nmae,
                report.successes,
                report.runs,
                report.median_seconds
            );
        }
        reports.push(report);
    }
    let mut out = std::io::stdout().lock();
    if a.json {
        writeln!(out, "{}", json!({"options": opts, "cases": reports}))?;
    } else {
        writeln!(
            out,
            "solver {} rtol {:e}, polish {}, restart {}, FFT bias {}, noise {} %, {} runs per case, one thread",
            opts.solver,
            opts.rtol,
            if opts.refine { "on" } else { "off" },
            if opts.restart { "on" } else { "off" },
            if opts.fft_bias { "on" } else { "off" },
            100.0 * opts.noise,
            opts.runs
        )?;
        write!(out, "{}", bench::table(&reports))?;
    }
    Ok(())
}
