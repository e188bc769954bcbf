//! `gatewatch bench generate`: a seed case's data (or the gate example's force) as CSV.

use super::{input, unknown_case, CliError};
use crate::data::TimeSeries;
use clap::Args;
use std::io::Write;
use std::path::PathBuf;

/// The case beside the seed cases: the chapter's section 8.5 support force.
const GATE_EXAMPLE: &str = "gate_example";

/// Arguments of `gatewatch bench generate`.
#[derive(Debug, Args)]
pub struct GenerateArgs {
    /// The case id, e.g. van_der_pol_2, or gate_example (the chapter's section 8.5 support force).
    #[arg(long = "case", value_name = "ID")]
    case: String,
    /// Seed of the noise (gate_example).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// Output file (stdout when absent).
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
}

pub(super) fn run(a: GenerateArgs) -> Result<(), CliError> {
    let data = if a.case == GATE_EXAMPLE {
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
        crate::cases::find(&a.case)
            .ok_or_else(|| unknown_case(&a.case, &[GATE_EXAMPLE]))?
            .generate()?
    };
    match a.output {
        // A path that cannot be written is the user's input, named like stability-map's.
        Some(path) => data
            .to_csv(&path, "t", "y")
            .map_err(|e| input(format!("--output: {}: {e}", path.display())))?,
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
