//! The command-line interface: argument definitions and the dispatch to the commands, one file
//! per command (`identify` with its `report`, `seed_cases`, `generate`, `gate_example`,
//! `stability_map`).
//!
//! Exit codes: 0 success, 2 bad input (file, column, model, option) with a one-line message on
//! stderr naming the problem, 1 anything else.

use crate::cases;
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::process::ExitCode;

mod compare;
mod gate_example;
mod generate;
mod history;
mod identify;
mod report;
mod seed_cases;
mod stability_map;

pub use report::identification_json;

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
    Identify(identify::IdentifyArgs),
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
    /// Print a shell completion script, e.g. `gatewatch completions bash > /etc/bash_completion.d/gatewatch`.
    Completions(CompletionsArgs),
    /// Watch the daemon catch a simulated gate going self-excited (daemon, simulated gate and
    /// webhook receiver in one process).
    Demo(crate::service::cli::DemoArgs),
    /// Print a gate's identification history from the daemon's store (read-only).
    History(history::HistoryArgs),
}

/// Arguments of `gatewatch completions`.
#[derive(Debug, clap::Args)]
struct CompletionsArgs {
    /// The shell whose completion script is printed on stdout.
    #[arg(value_enum)]
    shell: clap_complete::Shell,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// The chapter's seed cases (Table 8.1) with its protocol, beside its numbers.
    SeedCases(seed_cases::SeedCasesArgs),
    /// Write a seed case's data as CSV (columns t, y) to stdout or a file.
    Generate(generate::GenerateArgs),
    /// The chapter's gate example (section 8.5) through the daemon's window analysis.
    GateExample(gate_example::GateExampleArgs),
    /// Load measurements of the daemon: ingest throughput, identification latency, gates sustained.
    Daemon(crate::service::bench::BenchDaemonArgs),
    /// The daemon under a long mixed load (steady, slow, broken and transient clients),
    /// recording RSS, open descriptors, p99 ingest latency and jobs replaced.
    Soak(crate::service::bench_soak::BenchSoakArgs),
    /// How well the daemon warns: each scenario streamed through the daemon in sample time,
    /// scored against the simulator's true damping (delays, false alarms, error, coverage).
    Warning(crate::service::bench_warning::BenchWarningArgs),
    /// A day of history for 16 gates through the real store: database size, and the time of
    /// `GET /api/v1/gates/{id}/history` for one gate's day.
    History(crate::service::bench_history::BenchHistoryArgs),
}

pub(crate) fn parse_param(s: &str) -> Result<(String, f64), String> {
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
            let _ = write!(
                std::io::stderr(),
                "{}",
                usage_error(&e.render().to_string())
            );
            return ExitCode::from(2);
        }
    };
    let result = match cli.command {
        Command::Serve(args) => return crate::service::cli::serve(args),
        Command::CheckConfig(args) => return crate::service::cli::check_config(args),
        Command::Simulate(args) => return crate::service::cli::simulate(args),
        Command::Demo(args) => return crate::service::cli::demo(args),
        Command::Bench(BenchCommand::Warning(args)) => {
            return crate::service::bench_warning::bench_warning(args)
        }
        Command::Bench(BenchCommand::Daemon(args)) => {
            return crate::service::bench::bench_daemon(args)
        }
        Command::Bench(BenchCommand::Soak(args)) => {
            return crate::service::bench_soak::bench_soak(args)
        }
        Command::Bench(BenchCommand::History(args)) => {
            return crate::service::bench_history::bench_history(args)
        }
        Command::Completions(args) => {
            use clap::CommandFactory;
            let mut cmd = Cli::command();
            // into memory first: clap_complete panics on a failed write (a closed pipe)
            let mut script = Vec::new();
            clap_complete::generate(args.shell, &mut cmd, "gatewatch", &mut script);
            std::io::stdout()
                .lock()
                .write_all(&script)
                .map_err(CliError::from)
        }
        Command::Identify(args) => identify::run(args),
        Command::History(args) => history::run(args),
        Command::StabilityMap(args) => stability_map::run(args),
        Command::Bench(BenchCommand::SeedCases(args)) => seed_cases::run(args),
        Command::Bench(BenchCommand::Generate(args)) => generate::run(args),
        Command::Bench(BenchCommand::GateExample(args)) => gate_example::run(args),
    };
    // A closed stderr (`2>&1 | head -1`) must not turn the message into a panic (exit 101).
    let mut stderr = std::io::stderr();
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Input(msg)) => {
            let _ = writeln!(stderr, "gatewatch: {msg}");
            ExitCode::from(2)
        }
        // The reader of the output went away (`gatewatch identify ... | head -1`): it has what
        // it wanted, so the command ends quietly with success, as ripgrep does. (Rust ignores
        // SIGPIPE, so the write fails with this error instead of killing the process as it
        // would a C program; SIGPIPE stays ignored, for the daemon's sockets.)
        Err(CliError::Other(e)) if crate::service::stdout::is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(CliError::Other(e)) => {
            let _ = writeln!(stderr, "gatewatch: error: {e:#}");
            ExitCode::from(1)
        }
    }
}

/// A command-line error as printed: a first line `gatewatch: ...` that names the problem (clap's
/// first line, with the missing arguments it lists on indented lines folded in, so scripts and
/// logs that keep one line keep the whole reason), then clap's own hint ("a similar subcommand
/// exists: 'identify'") and usage block unchanged, for the person at the terminal.
fn usage_error(rendered: &str) -> String {
    let mut lines = rendered.lines().peekable();
    let mut first = lines
        .next()
        .unwrap_or("error: invalid arguments")
        .trim_start_matches("error: ")
        .to_string();
    while let Some(more) = lines.next_if(|l| l.starts_with("  ") && !l.trim().is_empty()) {
        first.push(' ');
        first.push_str(more.trim());
    }
    let mut out = format!("gatewatch: {first}\n");
    for line in lines {
        out.push_str(line);
        out.push('\n');
    }
    out
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

fn opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    v.map_or_else(|| "n/a".to_string(), f)
}

fn find_case(id: &str) -> Result<&'static cases::SeedCase, CliError> {
    cases::find(id).ok_or_else(|| unknown_case(id, &[]))
}

/// `--case` names no seed case: the known ones, then the command's own `extra` cases.
fn unknown_case(id: &str, extra: &[&str]) -> CliError {
    let known: Vec<&str> = cases::CASES
        .iter()
        .map(|c| c.id)
        .chain(extra.iter().copied())
        .collect();
    input(format!(
        "--case: unknown case '{id}' (known: {})",
        known.join(", ")
    ))
}
