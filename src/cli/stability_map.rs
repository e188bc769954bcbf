//! `gatewatch stability-map`: the stability map of a coefficient plane (see [`crate::stability`]).

use super::{input, parse_param, CliError};
use crate::model::Model;
use crate::number::Num;
use crate::stability::{self, MapSpec};
use clap::Args;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `gatewatch stability-map`.
#[derive(Debug, Args)]
pub struct StabilityMapArgs {
    /// The equation, e.g. 'ydd + (c1 + c2*y + c3*y^2)*yd + y = 0'; autonomous (no t): the map
    /// is of the free vibration.
    #[arg(long, value_name = "EQUATION")]
    model: String,
    /// A ranged coefficient, NAME=MIN:MAX, e.g. c1=-3:3 (exactly two).
    #[arg(
        long = "range",
        value_name = "NAME=MIN:MAX",
        allow_hyphen_values = true
    )]
    ranges: Vec<String>,
    /// A fixed coefficient, NAME=VALUE (every coefficient not ranged; repeatable).
    #[arg(long = "fix", value_name = "NAME=VALUE", value_parser = parse_param, allow_hyphen_values = true)]
    fixed: Vec<(String, f64)>,
    /// A known constant of the equation, NAME=VALUE (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE", value_parser = parse_param)]
    params: Vec<(String, f64)>,
    /// Initial displacement.
    #[arg(long, default_value_t = 0.1, allow_hyphen_values = true)]
    y0: f64,
    /// Initial velocity.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    v0: f64,
    /// Periods of the undamped linearised frequency (at the map's centre) to integrate over.
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
    periods: f64,
    /// Horizon of every trial, instead of --periods periods.
    #[arg(
        long,
        value_name = "T",
        conflicts_with = "periods",
        allow_negative_numbers = true
    )]
    t_end: Option<f64>,
    /// Monte Carlo samples (1 to 1000000: each is a trial, a CSV line and a marker).
    #[arg(long, allow_negative_numbers = true, default_value_t = 6000)]
    samples: usize,
    /// Seed of the samples.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    seed: u64,
    /// CSV output (columns NAME,NAME,stable); stdout when absent.
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Picture of the map (.svg or .png).
    #[arg(long, value_name = "FILE")]
    plot: Option<PathBuf>,
}

/// Runs `gatewatch stability-map`.
pub fn run(a: StabilityMapArgs) -> Result<(), CliError> {
    let model = Model::parse(&a.model, &a.params).map_err(|e| input(format!("--model: {e}")))?;
    if a.ranges.len() != 2 {
        return Err(input(format!(
            "--range: give exactly two ranged coefficients, e.g. --range c1=-3:3 --range c2=-3:3 (got {})",
            a.ranges.len()
        )));
    }
    let x = stability::parse_range(&model, &a.ranges[0]).map_err(input)?;
    let y = stability::parse_range(&model, &a.ranges[1]).map_err(input)?;
    let mut spec = MapSpec::new(x, y);
    for (name, value) in &a.fixed {
        let i = stability::coefficient_index(&model, name, "--fix").map_err(input)?;
        spec.fixed.push((i, *value));
    }
    spec.y0 = a.y0;
    spec.v0 = a.v0;
    spec.periods = a.periods;
    spec.t_end = a.t_end;
    spec.samples = a.samples;
    spec.seed = a.seed;
    if let Some(p) = &a.plot {
        crate::plot::Format::from_path(p).map_err(|e| input(format!("--plot: {e}")))?;
    }
    // Every output is checked before the trials, which can take minutes, as identify does.
    for (flag, path) in [("--output", &a.output), ("--plot", &a.plot)] {
        if let Some(path) = path {
            check_writable(path).map_err(|e| input(format!("{flag}: {}: {e}", path.display())))?;
        }
    }
    if let (Some(output), Some(plot)) = (&a.output, &a.plot) {
        if same_file(output, plot) {
            return Err(input(format!(
                "--output and --plot name the same file ({}): the picture would overwrite the table",
                plot.display()
            )));
        }
    }
    let map = stability::map(&model, &spec).map_err(input)?;
    let stable = map.stable_count();
    if map.undecided > 0 {
        let _ = writeln!(
            std::io::stderr(),
            "gatewatch stability-map: {} of {} trials left out of the map, undecided: the solver's step limit or its smallest step stopped them before t = {:.4} (shorten --t-end or --periods)",
            map.undecided,
            map.undecided + map.trials.len(),
            Num(map.t_end)
        );
    }
    match &a.output {
        Some(path) => {
            let file = std::fs::File::create(path)
                .map_err(|e| input(format!("--output: {}: {e}", path.display())))?;
            let mut w = std::io::BufWriter::new(file);
            map.write_csv(&mut w)
                .and_then(|()| w.flush())
                .map_err(|e| input(format!("--output: {}: {e}", path.display())))?;
        }
        None => map.write_csv(&mut std::io::stdout().lock())?,
    }
    if let Some(p) = &a.plot {
        let fixed: Vec<String> = spec
            .fixed
            .iter()
            .map(|(i, v)| format!("c{} = {}", i + 1, Num(*v)))
            .collect();
        let mut note = format!(
            "{}\n\ny0 = {}, v0 = {}\nhorizon t = {:.4}\n",
            model.equation(),
            Num(spec.y0),
            Num(spec.v0),
            Num(map.t_end)
        );
        if !fixed.is_empty() {
            note.push_str(&format!("fixed: {}\n", fixed.join(", ")));
        }
        note.push_str("\nunstable: grows, fails, or has not decayed below its initial amplitude");
        if map.undecided > 0 {
            note.push_str(&format!(
                "\n{} undecided trials (solver step limit or smallest step) not shown",
                map.undecided
            ));
        }
        crate::plot::stability_map(p, &map, &note).map_err(|e| input(format!("--plot: {e}")))?;
    }
    if a.output.is_some() {
        writeln!(
            std::io::stdout().lock(),
            "{} trials over t = 0..{:.4}: {stable} stable, {} unstable",
            map.trials.len(),
            Num(map.t_end),
            map.trials.len() - stable
        )?;
    }
    Ok(())
}

/// Whether the file `path` can be written, without changing it: an existing file is opened for
/// appending (nothing appended), a new one created and removed again.
fn check_writable(path: &std::path::Path) -> std::io::Result<()> {
    if path.is_dir() {
        return Err(std::io::Error::other("is a directory"));
    }
    if path.exists() {
        return std::fs::OpenOptions::new()
            .append(true)
            .open(path)
            .map(drop);
    }
    std::fs::File::create(path)?;
    // The file was created a moment ago: failing to remove it leaves an empty file that the
    // run overwrites.
    let _ = std::fs::remove_file(path);
    Ok(())
}

/// Whether two output paths name one file: the same name in the same directory, however each
/// is spelled (`map.svg`, `./map.svg`, `out/../map.svg`).
fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    let key = |p: &std::path::Path| {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => std::path::Path::new("."),
        };
        Some(dir.canonicalize().ok()?.join(p.file_name()?))
    };
    match (key(a), key(b)) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}
