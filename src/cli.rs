//! The command-line interface: argument definitions and the commands behind them.
//!
//! Exit codes: 0 success, 2 bad input (file, column, model, option) with a one-line message on
//! stderr naming the problem, 1 anything else.

use crate::analysis::{self, SeriesAnalysis, SeriesOptions, Signal};
use crate::bench::{self, BenchOptions};
use crate::cases;
use crate::data::TimeSeries;
use crate::identify::{Config, Initial};
use crate::model::Model;
use crate::ode::Method;
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

mod stability_map;

/// gatewatch: early warning of self-excited gate vibrations.
#[derive(Debug, Parser)]
#[command(name = "gatewatch", version, about, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Identify the coefficients of an equation of motion from a CSV time series.
    Identify(IdentifyArgs),
    /// Benchmarks.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Run the monitoring daemon.
    Serve(crate::service::cli::ServeArgs),
    /// Validate a configuration file without starting the daemon.
    CheckConfig(crate::service::cli::CheckConfigArgs),
    /// Stream a simulated gate's support force to a running daemon.
    Simulate(crate::service::cli::SimulateArgs),
    /// Map stable and unstable coefficients of a plane by simulation (Figure 8.13).
    StabilityMap(stability_map::StabilityMapArgs),
    /// Watch the daemon catch a simulated gate going self-excited (daemon, simulated gate and
    /// webhook receiver in one process).
    Demo(crate::service::cli::DemoArgs),
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// The chapter's seed cases (Table 8.1) with its protocol, beside its numbers.
    SeedCases(SeedCasesArgs),
    /// Write a seed case's data as CSV (columns t, y) to stdout or a file.
    Generate(GenerateArgs),
    /// The chapter's gate example (section 8.5) through the daemon's window analysis.
    GateExample(GateExampleArgs),
    /// Load measurements of the daemon: ingest throughput, identification latency, gates sustained.
    Daemon(crate::service::bench::BenchDaemonArgs),
}

/// Arguments of `gatewatch bench gate-example`.
#[derive(Debug, Args)]
pub struct GateExampleArgs {
    /// Runs (noise and DE seeds seed, seed + 1, ...).
    #[arg(long, default_value_t = 25)]
    runs: usize,
    /// Seed of the first run.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Measurement noise, fraction of the signal's standard deviation.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.01)]
    noise: f64,
    /// Drift of the force, N/s.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.2)]
    drift: f64,
    /// DE population.
    #[arg(long, default_value_t = 20)]
    population: usize,
    /// DE generations.
    #[arg(long, default_value_t = 40)]
    generations: usize,
    /// Without the FFT-biased initial population.
    #[arg(long)]
    no_fft_bias: bool,
    /// Print the runs as JSON.
    #[arg(long)]
    json: bool,
}

/// Arguments of `gatewatch bench generate`.
#[derive(Debug, Args)]
pub struct GenerateArgs {
    /// The case id, e.g. van_der_pol_2, or gate_example (the chapter's section 8.5 support force).
    #[arg(long = "case", value_name = "ID")]
    case: String,
    /// Seed of the noise (gate_example).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output file (stdout when absent).
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
}

/// Arguments of `gatewatch identify`.
#[derive(Debug, Args)]
pub struct IdentifyArgs {
    /// CSV file with a header row.
    #[arg(long, value_name = "FILE")]
    input: PathBuf,
    /// The equation, e.g. 'ydd + (c1 + c2*y^2)*yd + y = 0'.
    #[arg(long, value_name = "EQUATION")]
    model: String,
    /// Known initial displacement y(t0) (with --v0).
    #[arg(
        long,
        requires = "v0",
        conflicts_with = "fit_initial",
        allow_hyphen_values = true
    )]
    y0: Option<f64>,
    /// Known initial velocity yd(t0) (with --y0).
    #[arg(
        long,
        requires = "y0",
        conflicts_with = "fit_initial",
        allow_hyphen_values = true
    )]
    v0: Option<f64>,
    /// Identify y(t0) and yd(t0) as two extra unknowns.
    #[arg(long)]
    fit_initial: bool,
    /// A known constant of the equation, NAME=VALUE (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE", value_parser = parse_param)]
    params: Vec<(String, f64)>,
    /// Column holding time.
    #[arg(long, default_value = "t")]
    time_column: String,
    /// Column holding the signal.
    #[arg(long, default_value = "y")]
    value_column: String,
    /// Fraction of the samples used for training.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.5)]
    train_fraction: f64,
    /// Seed of the train/test split.
    #[arg(long, default_value_t = 1)]
    split_seed: u64,
    /// DE population size.
    #[arg(long, default_value_t = 50)]
    population: usize,
    /// DE generations.
    #[arg(long, default_value_t = 120)]
    generations: usize,
    /// Independent runs.
    #[arg(long, default_value_t = 1)]
    runs: usize,
    /// Seed of the first run.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Relative tolerance of the fitness solver.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1e-3)]
    rtol: f64,
    /// Relative tolerance of the test solver.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1e-5)]
    test_rtol: f64,
    /// Fitness solver: auto, dopri5, rk4 or stiff. Auto: dopri5 (the chapter's ode45) for
    /// displacement data; rk4 on the sample grid, one step per sample, for uniformly sampled
    /// force signals, whose long windows it integrates three times cheaper (the polish and the
    /// test always use dopri5 at tight tolerance).
    #[arg(long, default_value = "auto")]
    solver: String,
    /// RK4 steps per sample interval (default 2; 1 with the automatic choice for force signals).
    #[arg(long)]
    substeps: Option<usize>,
    /// Skip the Levenberg-Marquardt polish of the DE winner.
    #[arg(long)]
    no_refine: bool,
    /// Never restart a stagnating DE population.
    #[arg(long)]
    no_restart: bool,
    /// Evaluate each generation on all cores (same result as serial).
    #[arg(long)]
    parallel: bool,
    /// What the values are: displacement, or the support force (section 8.5).
    #[arg(long, value_enum, default_value = "displacement")]
    signal: SignalArg,
    /// Installed stiffness in N/m (force signals; also usable as the constant `k`).
    #[arg(long, allow_negative_numbers = true, value_name = "N/m")]
    stiffness: Option<f64>,
    /// Do not bias the initial population with the spectrum's frequency and growth.
    #[arg(long)]
    no_fft_bias: bool,
    /// Force signals: seconds of the centred moving average removed first (0: none).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0)]
    moving_average: f64,
    /// Amplitude (unit of the signal) whose time of reach is predicted.
    #[arg(long, allow_negative_numbers = true)]
    amplitude_limit: Option<f64>,
    /// Above this fit NMAE the model is not trusted.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.2)]
    max_fit_nmae: f64,
    /// Print exactly one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Write pictures of the result into DIR (created if needed): fit, phase, convergence.
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
    /// Format of the --plot pictures: svg or png.
    #[arg(long, default_value = "svg", requires = "plot")]
    plot_format: crate::plot::Format,
}

/// What the samples of `identify` are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum SignalArg {
    /// Displacement y.
    Displacement,
    /// Support force (damping plus stiffness force).
    Force,
}

/// Arguments of `gatewatch bench seed-cases`.
#[derive(Debug, Args)]
pub struct SeedCasesArgs {
    /// Runs per case.
    #[arg(long, default_value_t = 25)]
    runs: usize,
    /// Only these cases (repeatable); all by default.
    #[arg(long = "case", value_name = "ID")]
    cases: Vec<String>,
    /// Seed of the first run.
    #[arg(long, default_value_t = 1)]
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
    /// Print the results as JSON.
    #[arg(long)]
    json: bool,
}

fn parse_param(s: &str) -> Result<(String, f64), String> {
    let (name, value) = s
        .split_once('=')
        .ok_or_else(|| format!("'{s}': expected NAME=VALUE"))?;
    let name = name.trim();
    if name.is_empty() {
        return Err(format!("'{s}': the name is empty"));
    }
    let v: f64 = value
        .trim()
        .parse()
        .map_err(|_| format!("'{s}': '{}' is not a number", value.trim()))?;
    if !v.is_finite() {
        return Err(format!("'{s}': the value must be finite"));
    }
    Ok((name.to_string(), v))
}

/// An error of a command: bad input (exit 2) or anything else (exit 1).
#[derive(Debug)]
pub enum CliError {
    /// The user's input is wrong: exit code 2.
    Input(String),
    /// Anything else: exit code 1.
    Other(anyhow::Error),
}

impl<E: Into<anyhow::Error>> From<E> for CliError {
    fn from(e: E) -> Self {
        CliError::Other(e.into())
    }
}

fn input(msg: impl std::fmt::Display) -> CliError {
    CliError::Input(msg.to_string())
}

/// Parses the process arguments and runs the command.
pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) {
                let _ = e.print();
                return if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
                    ExitCode::from(2)
                } else {
                    ExitCode::SUCCESS
                };
            }
            // One line: clap's first line, without its usage block. Clap lists missing required
            // arguments on indented lines after the first; fold them in so the line names them.
            let text = e.render().to_string();
            let mut lines = text.lines();
            let mut line = lines
                .next()
                .unwrap_or("error: invalid arguments")
                .trim_start_matches("error: ")
                .to_string();
            for more in lines.take_while(|l| l.starts_with("  ") && !l.trim().is_empty()) {
                line.push(' ');
                line.push_str(more.trim());
            }
            eprintln!("gatewatch: {line}");
            return ExitCode::from(2);
        }
    };
    let result = match cli.command {
        Command::Serve(args) => return crate::service::cli::serve(args),
        Command::CheckConfig(args) => return crate::service::cli::check_config(args),
        Command::Simulate(args) => return crate::service::cli::simulate(args),
        Command::Demo(args) => return crate::service::cli::demo(args),
        Command::Bench(BenchCommand::Daemon(args)) => {
            return crate::service::bench::bench_daemon(args)
        }
        Command::Identify(args) => run_identify(args),
        Command::StabilityMap(args) => stability_map::run(args),
        Command::Bench(BenchCommand::SeedCases(args)) => run_seed_cases(args),
        Command::Bench(BenchCommand::Generate(args)) => run_generate(args),
        Command::Bench(BenchCommand::GateExample(args)) => run_gate_example(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Input(msg)) => {
            eprintln!("gatewatch: {msg}");
            ExitCode::from(2)
        }
        Err(CliError::Other(e)) => {
            eprintln!("gatewatch: error: {e:#}");
            ExitCode::from(1)
        }
    }
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    // indicatif draws to stderr only when it is a terminal, so piped runs stay silent.
    let bar = ProgressBar::new(len);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} generations {elapsed}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(what.to_string());
    bar
}

fn run_identify(a: IdentifyArgs) -> Result<(), CliError> {
    let mut params = a.params.clone();
    if let Some(k) = a.stiffness {
        if !(k.is_finite() && k > 0.0) {
            return Err(input("--stiffness must be a positive number"));
        }
        if !params.iter().any(|(n, _)| n == "k") && a.model.contains('k') {
            params.push(("k".to_string(), k));
        }
    }
    let signal = match a.signal {
        SignalArg::Displacement => Signal::Displacement,
        SignalArg::Force => Signal::Force,
    };
    if signal == Signal::Force {
        if a.stiffness.is_none() {
            return Err(input(
                "--signal force needs --stiffness (the installed stiffness in N/m)",
            ));
        }
        if a.y0.is_some() || a.fit_initial {
            return Err(input("--signal force takes its initial conditions from the pre-run: drop --y0/--v0/--fit-initial"));
        }
    }
    if !(a.moving_average >= 0.0 && a.moving_average.is_finite()) {
        return Err(input("--moving-average must be >= 0 seconds"));
    }
    if a.max_fit_nmae.is_nan() || a.max_fit_nmae <= 0.0 {
        return Err(input("--max-fit-nmae must be > 0"));
    }
    if a.amplitude_limit
        .is_some_and(|v| !(v > 0.0 && v.is_finite()))
    {
        return Err(input("--amplitude-limit must be a positive number"));
    }
    let model = Model::parse(&a.model, &params).map_err(|e| input(format!("model: {e}")))?;
    let series = TimeSeries::from_csv(&a.input, &a.time_column, &a.value_column).map_err(input)?;
    let (solver, substeps) = match a.solver.as_str() {
        "auto" if signal == Signal::Force && series.uniform_step().is_some() => {
            (Method::Rk4, a.substeps.unwrap_or(1))
        }
        "auto" => (Method::Dopri5, a.substeps.unwrap_or(2)),
        other => (
            other
                .parse::<Method>()
                .map_err(|e| input(format!("--solver: {e}")))?,
            a.substeps.unwrap_or(2),
        ),
    };
    let initial = match (a.y0, a.v0, a.fit_initial) {
        (Some(y0), Some(v0), _) => Initial::Known { y0, v0 },
        (_, _, true) => Initial::Fit,
        _ => Initial::FromData,
    };
    let config = Config {
        initial,
        train_fraction: a.train_fraction,
        split_seed: a.split_seed,
        population: a.population,
        generations: a.generations,
        runs: a.runs,
        seed: a.seed,
        solver,
        rtol: a.rtol,
        test_rtol: a.test_rtol,
        substeps,
        refine: !a.no_refine,
        restart: !a.no_restart,
        parallel: a.parallel,
        ..Config::default()
    };
    let opts = SeriesOptions {
        signal,
        stiffness: a.stiffness,
        identify: config.clone(),
        fft_bias: !a.no_fft_bias,
        moving_average_seconds: a.moving_average,
        amplitude_limit: a.amplitude_limit,
        max_fit_nmae: a.max_fit_nmae,
    };
    let total = (a.runs * a.generations) as u64;
    let bar = progress_bar(total, "identify");
    let result = analysis::analyze_series(&model, &series, &opts, None, |r, g, _| {
        bar.set_position((r * a.generations + g) as u64)
    })
    .map_err(input)?;
    bar.finish_and_clear();
    let mut out = std::io::stdout().lock();
    if a.json {
        let v = identification_json(&model, &result);
        writeln!(out, "{v}")?;
    } else {
        write_identification(&mut out, &model, &result, &config)?;
    }
    if let Some(dir) = &a.plot {
        let units = match signal {
            Signal::Force => crate::plot::Units {
                time: Some("s".into()),
                signal: Some("m".into()),
                force: Some("N".into()),
                data: Some("support force F [N]".into()),
            },
            Signal::Displacement => crate::plot::Units::default(),
        };
        crate::plot::identification(dir, a.plot_format, &model, &result, signal, &units)
            .map_err(|e| input(format!("--plot: {e}")))?;
    }
    Ok(())
}

fn coefficients_json(c: &[f64]) -> serde_json::Value {
    let map: serde_json::Map<String, serde_json::Value> = c
        .iter()
        .enumerate()
        .map(|(i, v)| (format!("c{}", i + 1), json!(v)))
        .collect();
    serde_json::Value::Object(map)
}

/// The `--json` object of `gatewatch identify` (field names are a stable interface).
pub fn identification_json(model: &Model, a: &SeriesAnalysis) -> serde_json::Value {
    let r = &a.identification;
    let best = r.best_run();
    json!({
        "damping": a.damping,
        "linearization": a.linearization,
        "model": model.equation(),
        "equation": model.substitute(&best.coefficients),
        "coefficients": coefficients_json(&best.coefficients),
        "initial": {"y0": best.initial.y0, "v0": best.initial.v0},
        "train_mae": best.train_mae,
        "test_nmae": best.test_nmae,
        "evaluations": best.evaluations,
        "seconds": best.seconds,
        "convergence": best.history,
        "coefficient_intervals": coefficient_intervals(r).map(|iv| {
            iv.iter()
                .enumerate()
                .map(|(i, (lo, hi))| (format!("c{}", i + 1), json!([lo, hi])))
                .collect::<serde_json::Map<String, serde_json::Value>>()
        }),
        "summary": {
            "mean_nmae": finite_or_null(r.summary.mean),
            "std_nmae": finite_or_null(r.summary.std),
            "min_nmae": finite_or_null(r.summary.min),
            "median_nmae": finite_or_null(r.summary.median),
        },
        "runs": r.runs.iter().map(|run| json!({
            "seed": run.seed,
            "coefficients": coefficients_json(&run.coefficients),
            "initial": {"y0": run.initial.y0, "v0": run.initial.v0},
            "train_mae": run.train_mae,
            "test_nmae": run.test_nmae,
            "evaluations": run.evaluations,
            "restarts": run.restarts,
            "seconds": run.seconds,
        })).collect::<Vec<_>>(),
    })
}

/// With several runs, each coefficient's range over the runs (its spread: the uncertainty of
/// the identification itself).
fn coefficient_intervals(r: &crate::identify::Identification) -> Option<Vec<(f64, f64)>> {
    if r.runs.len() < 2 {
        return None;
    }
    let n = r.best_run().coefficients.len();
    Some(
        (0..n)
            .map(|j| {
                let v = r.runs.iter().map(|run| run.coefficients[j]);
                (
                    v.clone().fold(f64::INFINITY, f64::min),
                    v.fold(f64::NEG_INFINITY, f64::max),
                )
            })
            .collect(),
    )
}

fn finite_or_null(v: f64) -> serde_json::Value {
    if v.is_finite() {
        json!(v)
    } else {
        serde_json::Value::Null
    }
}

fn write_identification(
    out: &mut impl Write,
    model: &Model,
    a: &SeriesAnalysis,
    config: &Config,
) -> std::io::Result<()> {
    let r = &a.identification;
    let best = r.best_run();
    writeln!(out, "model:        {}", model.equation())?;
    writeln!(
        out,
        "identified:   {}",
        model.substitute(&best.coefficients)
    )?;
    let intervals = coefficient_intervals(r);
    for (i, c) in best.coefficients.iter().enumerate() {
        match intervals.as_ref().map(|iv| iv[i]) {
            Some((lo, hi)) => writeln!(
                out,
                "  c{:<3} = {c:.8e}   (runs: {lo:.6e} .. {hi:.6e})",
                i + 1
            )?,
            None => writeln!(out, "  c{:<3} = {c:.8e}", i + 1)?,
        }
    }
    let how = match config.initial {
        Initial::Known { .. } => "given",
        Initial::FromData => "from the data",
        Initial::Fit => "identified",
    };
    writeln!(
        out,
        "initial:      y0 = {:.6e}, v0 = {:.6e} ({how})",
        best.initial.y0, best.initial.v0
    )?;
    writeln!(out, "train MAE:    {:.3e}", best.train_mae)?;
    match best.test_nmae {
        Some(v) => writeln!(out, "test NMAE:    {v:.3e}")?,
        None => writeln!(out, "test NMAE:    n/a (the test integration failed)")?,
    }
    writeln!(
        out,
        "evaluations:  {} (of which {} in the polish)",
        best.evaluations, best.refine_evaluations
    )?;
    writeln!(out, "time:         {:.3} s", best.seconds)?;
    if r.runs.len() > 1 {
        writeln!(
            out,
            "runs:         {} (best by training error: seed {})",
            r.runs.len(),
            best.seed
        )?;
        writeln!(
            out,
            "test NMAE:    mean {:.3e}, std {:.3e}, min {:.3e}, median {:.3e}",
            r.summary.mean, r.summary.std, r.summary.min, r.summary.median
        )?;
    }
    write_damping(out, &a.damping)
}

fn opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    v.map_or_else(|| "n/a".to_string(), f)
}

fn write_damping(out: &mut impl Write, d: &analysis::DampingReport) -> std::io::Result<()> {
    writeln!(out, "damping:")?;
    let interval = d.zeta0_interval.map_or(String::new(), |(lo, hi)| {
        format!(" [{:.3} %, {:.3} %]", 100.0 * lo, 100.0 * hi)
    });
    writeln!(
        out,
        "  zeta0 (at rest):        {}{interval} ({})",
        opt(d.zeta0, |z| format!("{:.3} %", 100.0 * z)),
        d.zeta0_source.map_or("-", |s| s.as_str())
    )?;
    writeln!(
        out,
        "  zeta_eq (at amplitude): {}",
        opt(d.zeta_eq, |z| format!("{:.3} %", 100.0 * z))
    )?;
    writeln!(
        out,
        "  amplitude now:          {}",
        opt(d.amplitude, |v| format!("{v:.4e}"))
    )?;
    writeln!(
        out,
        "  energy fed per cycle:   {}",
        opt(d.energy_per_cycle, |v| format!("{v:.4e}"))
    )?;
    writeln!(
        out,
        "  limit-cycle amplitude:  {}",
        opt(d.limit_cycle_amplitude, |v| format!("{v:.4e}"))
    )?;
    writeln!(
        out,
        "  time to limit:          {}",
        opt(d.time_to_limit, |v| format!("{v:.1} s"))
    )?;
    writeln!(
        out,
        "  frequency:              {} (model {})",
        opt(d.frequency_hz, |v| format!("{v:.4} Hz")),
        opt(d.model_frequency_hz, |v| format!("{v:.4} Hz"))
    )?;
    writeln!(
        out,
        "  envelope growth:        {}",
        match (d.growth_rate, d.growth_rate_stderr) {
            (Some(g), Some(se)) => format!("{g:.4} 1/s (+- {se:.4})"),
            _ => "n/a".to_string(),
        }
    )?;
    if let Some((z, lo, hi)) = d.ambient_zeta.map(<(f64, f64, f64)>::from) {
        writeln!(
            out,
            "  ambient zeta (AR):      {:.3} % [{:.3} %, {:.3} %]",
            100.0 * z,
            100.0 * lo,
            100.0 * hi
        )?;
    }
    writeln!(
        out,
        "  fit NMAE:               {:.3e}; agrees with the spectrum: {}; trusted: {}",
        d.fit_nmae,
        if d.agrees { "yes" } else { "no" },
        if d.trusted { "yes" } else { "no" }
    )?;
    let verdict = match d.verdict {
        analysis::Verdict::Damped => "damped",
        analysis::Verdict::SelfExcited => "SELF-EXCITED (negative damping at rest)",
        analysis::Verdict::Unknown => "unknown (the model cannot be trusted)",
    };
    writeln!(out, "  verdict:                {verdict}")
}

fn run_gate_example(a: GateExampleArgs) -> Result<(), CliError> {
    if a.runs == 0 {
        return Err(input("--runs must be at least 1"));
    }
    if !(0.0..1.0).contains(&a.noise) {
        return Err(input("--noise must be in [0, 1)"));
    }
    if a.population < 4 {
        return Err(input("--population must be at least 4"));
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
            "| {} | {:.3} | {:.3} | {:.1} | {} | {:?} | {} | {} | {:.3} |",
            r.seed,
            r.mass,
            r.damping,
            r.cubic,
            opt(r.zeta0, |z| format!("{:.4}", 100.0 * z)),
            r.verdict,
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

fn find_case(id: &str) -> Result<&'static cases::SeedCase, CliError> {
    cases::find(id).ok_or_else(|| {
        let known: Vec<&str> = cases::CASES.iter().map(|c| c.id).collect();
        input(format!(
            "--case: unknown case '{id}' (known: {})",
            known.join(", ")
        ))
    })
}

fn run_generate(a: GenerateArgs) -> Result<(), CliError> {
    let data = if a.case == "gate_example" {
        // The chapter's worked example (section 8.5): support force, 200 Hz, 10 s, 1 % noise,
        // a slow drift of 0.2 N/s.
        let ex = crate::simulate::worked_example(&crate::simulate::WorkedExampleOptions {
            drift_per_s: 0.2,
            seed: a.seed,
            ..Default::default()
        });
        let t = (0..ex.force.len()).map(|i| i as f64 / ex.rate_hz).collect();
        TimeSeries::new(t, ex.force).map_err(|e| CliError::Other(e.into()))?
    } else {
        find_case(&a.case)?.generate()?
    };
    match a.output {
        Some(path) => data.to_csv(&path, "t", "y")?,
        None => {
            let mut out = std::io::stdout().lock();
            writeln!(out, "t,y")?;
            for (t, y) in data.t.iter().zip(&data.y) {
                writeln!(out, "{t:.17e},{y:.17e}")?;
            }
        }
    }
    Ok(())
}

fn run_seed_cases(a: SeedCasesArgs) -> Result<(), CliError> {
    if a.runs == 0 {
        return Err(input("--runs must be at least 1"));
    }
    if !(0.0..1.0).contains(&a.noise) {
        return Err(input("--noise must be in [0, 1)"));
    }
    let selected: Vec<&cases::SeedCase> = if a.cases.is_empty() {
        cases::CASES.iter().collect()
    } else {
        a.cases
            .iter()
            .map(|id| {
                cases::find(id).ok_or_else(|| {
                    let known: Vec<&str> = cases::CASES.iter().map(|c| c.id).collect();
                    input(format!(
                        "--case: unknown case '{id}' (known: {})",
                        known.join(", ")
                    ))
                })
            })
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
            eprintln!(
                "{}: mean NMAE {:.3e}, {}/{} runs below 0.01, median {:.4} s/run",
                report.id, report.mean_nmae, report.successes, report.runs, report.median_seconds
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
