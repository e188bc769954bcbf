//! `gatewatch identify`: the coefficients of an equation of motion from a CSV time series.

use super::report::{identification_json, write_identification};
use super::{input, parse_param, progress_bar, CliError};
use crate::analysis::{self, SeriesOptions, Signal};
use crate::data::{GridDeparture, TimeSeries};
use crate::identify::{Config, IdentifyError, Initial, Protocol, Search};
use crate::model::Model;
use crate::number::Num;
use crate::ode::Method;
use clap::Args;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `gatewatch identify`.
#[derive(Debug, Args)]
pub struct IdentifyArgs {
    /// CSV file with a header row.
    #[arg(long, value_name = "FILE")]
    input: PathBuf,
    /// The equation, e.g. 'ydd + (c1 + c2*y^2)*yd + y = 0'. Repeat it to compare candidate
    /// structures on the record: each is identified with the same seeds and they are ranked by
    /// BIC, with the accuracy/complexity front (docs/damping.md, "Which equation").
    #[arg(long = "model", value_name = "EQUATION", required = true)]
    models: Vec<String>,
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
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    split_seed: u64,
    /// DE population size (4 to 10000: each member costs an integration per generation).
    #[arg(long, allow_negative_numbers = true, default_value_t = 50)]
    population: usize,
    /// DE generations (at most 100000).
    #[arg(long, allow_negative_numbers = true, default_value_t = 120)]
    generations: usize,
    /// Independent runs (1 to 1000).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    runs: usize,
    /// Seed of the first run.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
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
    #[arg(long, allow_negative_numbers = true)]
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
    /// What a force signal holds: all (every term but the inertia, the damping plus the
    /// stiffness force: section 8.5) or stiffness (the terms without yd: a load cell in series
    /// with the spring; docs/damping.md, "What the support force holds").
    #[arg(long, value_name = "TERMS")]
    force_terms: Option<analysis::ForceTerms>,
    /// Installed stiffness in N/m: with --signal force, what turns the force into a deflection
    /// (required there); and the constant `k` of an equation that names it. Refused on a
    /// displacement record whose equations have no `k`, where it would do nothing.
    #[arg(long, allow_negative_numbers = true, value_name = "N/m")]
    stiffness: Option<f64>,
    /// Do not bias the initial population with the spectrum's frequency and growth.
    #[arg(long)]
    no_fft_bias: bool,
    /// With --signal force only (refused on a displacement record, which is not detrended):
    /// seconds of the centred moving average removed first (0: none; default 1).
    #[arg(long, allow_negative_numbers = true)]
    moving_average: Option<f64>,
    /// Amplitude (unit of the signal) whose time of reach is predicted.
    #[arg(long, allow_negative_numbers = true)]
    amplitude_limit: Option<f64>,
    /// Above this fit NMAE the model is not trusted.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.2)]
    max_fit_nmae: f64,
    /// How zeta0's 95 % interval is computed: newey-west (the residuals' covariance) or forcing
    /// (the turbulent forcing through the fitted model, for a record of a gate under flow;
    /// docs/damping.md, "zeta0_interval").
    #[arg(long, default_value = "newey-west")]
    model_interval: analysis::ModelInterval,
    /// Which reference instants the ambient (SSI-COV) estimate's correlations use: lagged or
    /// common (the mode's damping on a record whose variance grows or decays; docs/damping.md,
    /// "Growing windows: the correlations' reference instants").
    #[arg(long, default_value = "lagged")]
    ssi_reference: analysis::SsiReference,
    /// Print exactly one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Write pictures of the result into DIR (created if needed): fit, phase, convergence,
    /// damping and, for force signals, hysteresis. One equation only: with several --model,
    /// compare them first, then plot the chosen one.
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

/// The record and the settings every candidate equation is identified with.
pub(super) struct Prepared {
    /// The record as loaded (times as in the file).
    pub series: TimeSeries,
    /// The analysis settings.
    pub opts: SeriesOptions,
    /// The identification settings (also in `opts`).
    pub config: Config,
    /// What the values are.
    pub signal: Signal,
}

/// `--param` and, where the equation names `k`, `--stiffness` as the constant `k`.
fn params_for(a: &IdentifyArgs, equation: &str) -> Vec<(String, f64)> {
    let mut params = a.params.clone();
    if let Some(k) = a.stiffness {
        if !params.iter().any(|(n, _)| n == "k") && equation.contains('k') {
            params.push(("k".to_string(), k));
        }
    }
    params
}

/// The series an equation is identified on: time counted from the first sample unless the
/// equation uses `t`. Why: at Unix-epoch times (1.7e9 s) a float holds a time to 2.4e-7 s, and
/// the analysis lost its precision there (a fit NMAE of 0.5 where the same record from t = 0
/// fits to 0.01, or a failed test integration). For a model without `t` the shift changes
/// nothing else; a model with `t` (a forcing `sin(c3*t)`) keeps the file's times, which its
/// coefficients refer to. No output prints an absolute time.
pub(super) fn series_for(model: &Model, series: &TimeSeries) -> TimeSeries {
    let mut series = series.clone();
    if !model.uses_time() {
        let t0 = series.t[0];
        series.t.iter_mut().for_each(|t| *t -= t0);
    }
    series
}

pub(super) fn run(a: IdentifyArgs) -> Result<(), CliError> {
    if let Some(k) = a.stiffness {
        if !(k.is_finite() && k > 0.0) {
            return Err(input("--stiffness must be a positive number"));
        }
    }
    // `k` is the stiffness's name in the equation: a `--param k` beside a different
    // `--stiffness` made the equation use one value and the force-to-deflection conversion the
    // other, and the coefficients came out scaled (a mass of 192 for 19.14), without a word.
    if let (Some(k), Some((_, v))) = (a.stiffness, a.params.iter().find(|(n, _)| n == "k")) {
        if *v != k {
            return Err(input(format!(
                "--param k={v} conflicts with --stiffness {k}: `k` in the equation is the stiffness; give it once, as --stiffness"
            )));
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
    } else if a.force_terms.is_some() {
        return Err(input(
            "--force-terms says what a force signal holds: it needs --signal force",
        ));
    } else if a.moving_average.is_some() {
        return Err(input(
            "--moving-average removes a force signal's drift: it needs --signal force (a displacement record is fitted as it is)",
        ));
    }
    let moving_average = a
        .moving_average
        .unwrap_or(SeriesOptions::default().moving_average_seconds);
    if !(moving_average >= 0.0 && moving_average.is_finite()) {
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
    // The same column as time and signal loaded as a series whose every "time" was its value
    // and was refused, if at all, as a time that does not increase on some line.
    if a.time_column == a.value_column {
        return Err(input(format!(
            "--time-column and --value-column both name the column '{}'; give the time and the signal columns",
            a.time_column
        )));
    }
    if a.models.len() > 1 && a.plot.is_some() {
        return Err(input(
            "--plot draws one equation: compare the candidates first, then run identify with the chosen --model and --plot",
        ));
    }
    // Every equation is parsed before the record is read and before any fit, which can take
    // minutes: a typo in the third candidate is named at once.
    let several = a.models.len() > 1;
    let models = a
        .models
        .iter()
        .enumerate()
        .map(|(i, eq)| {
            Model::parse(eq, &params_for(&a, eq)).map_err(|e| {
                if several {
                    input(format!("--model {} ('{eq}'): {e}", i + 1))
                } else {
                    input(format!("model: {e}"))
                }
            })
        })
        .collect::<Result<Vec<Model>, CliError>>()?;
    check_stiffness_used(&a, signal, &models)?;
    let (series, lines) =
        TimeSeries::from_csv_with_lines(&a.input, &a.time_column, &a.value_column)
            .map_err(input)?;
    if let Some(why) = epoch_in_another_unit(&series) {
        return Err(input(format!(
            "{}: column '{}' line {}: {why}",
            a.input.display(),
            a.time_column,
            lines.first().copied().unwrap_or(2)
        )));
    }
    // A force signal's drift removal and spectral analysis need a uniform grid; without one they
    // were skipped silently and the window failed later for another reason ("no dominant
    // frequency"), on a file whose only fault was its timing.
    if signal == Signal::Force {
        if let Some(departure) = series.grid_departure() {
            return Err(input(format!(
                "{}: --signal force needs uniformly sampled times: {}; resample the data, or fit it as --signal displacement",
                a.input.display(),
                describe_departure(&series, &lines, departure)
            )));
        }
    }
    // the default's, said once the arguments are all accepted
    let mut skipped_moving_average = None;
    // A moving average of one sample, or of the whole record, removes nothing: `--moving-average
    // 20` on a 10 s record gave what `0` gives, without a word.
    if let (Signal::Force, Some(step)) = (signal, series.uniform_step()) {
        let span = analysis::moving_average_samples(step, series.len(), moving_average);
        if moving_average > 0.0 && span.is_none() {
            let why = format!(
                "a moving average of {} s spans {} samples of this record of {} samples every {} s; it must span more than one sample and fewer than the record",
                Num(moving_average),
                Num((moving_average / step).round()),
                series.len(),
                // a step of 1/200 s reads 0.004999999999999999 from the times
                Num(crate::number::round_significant(step, 12))
            );
            if a.moving_average.is_some() {
                return Err(input(format!("--moving-average: {why} (0 turns it off)")));
            }
            skipped_moving_average = Some(why);
        }
    }
    let (solver, substeps) = match a.solver.as_str() {
        "auto" if signal == Signal::Force && series.uniform_step().is_some() => {
            (Method::Rk4, a.substeps.unwrap_or(1))
        }
        "auto" => (Method::Dopri5, a.substeps.unwrap_or(2)),
        other => (
            other
                .parse::<Method>()
                .map_err(|_| {
                    input(format!(
                        "--solver: unknown solver '{other}': expected auto (the default), dopri5, rk4 or stiff"
                    ))
                })?,
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
        search: Search {
            population: a.population,
            generations: a.generations,
            solver,
            rtol: a.rtol,
            substeps,
            refine: !a.no_refine,
            parallel: a.parallel,
            ..Search::default()
        },
        protocol: Protocol {
            runs: a.runs,
            seed: a.seed,
            train_fraction: a.train_fraction,
            split_seed: a.split_seed,
            test_rtol: a.test_rtol,
            restart: !a.no_restart,
            ..Protocol::default()
        },
        ..Config::default()
    };
    config.validate().map_err(|e| input(in_flags(e)))?;
    // Said here in the file's terms: the core's own refusal ("window not analysable", "the
    // split needs ...") names neither the file nor its rows.
    let needed = crate::identify::min_samples(a.train_fraction);
    if series.len() < needed {
        return Err(input(format!(
            "{}: {} data row{} too few: identify needs at least {needed}, to train on 4 and \
             test on 2 when split at --train-fraction {}",
            a.input.display(),
            series.len(),
            if series.len() == 1 { " is" } else { "s are" },
            a.train_fraction
        )));
    }
    // A constant record (a sensor that was off, a column of zeros) holds no vibration: a fit to
    // it printed a zeta0 of 216396 % and exited 0.
    if series.y.iter().all(|&v| v == series.y[0]) {
        return Err(input(format!(
            "{}: column '{}' holds the same value ({}) on every line: there is no oscillation in the record to identify",
            a.input.display(),
            a.value_column,
            series.y[0]
        )));
    }
    let opts = SeriesOptions {
        signal,
        force_terms: a.force_terms.unwrap_or_default(),
        stiffness: a.stiffness,
        identify: config.clone(),
        fft_bias: !a.no_fft_bias,
        moving_average_seconds: moving_average,
        amplitude_limit: a.amplitude_limit,
        max_fit_nmae: a.max_fit_nmae,
        // `--solver` and the polish flags choose the integrations here.
        polish_solver: analysis::PolishSolver::Dopri5,
        model_interval: a.model_interval,
        ssi_reference: a.ssi_reference,
    };
    // Every output is checked before the identification, which can take minutes.
    if let Some(dir) = &a.plot {
        check_plot_dir(dir)?;
        crate::plot::prepare_dir(dir).map_err(|e| input(format!("--plot: {e}")))?;
    }
    if let Some(why) = skipped_moving_average {
        let _ = writeln!(
            std::io::stderr(),
            "gatewatch identify: the force's drift is not removed: {why} (--moving-average)"
        );
    }
    let prepared = Prepared {
        series,
        opts,
        config,
        signal,
    };
    if several {
        return super::compare::run(&a.models, &models, &prepared, a.json, a.input.as_path());
    }
    let Prepared {
        series,
        opts,
        config,
        signal,
    } = prepared;
    let model = &models[0];
    let params = params_for(&a, &a.models[0]);
    let series = series_for(model, &series);
    let total = (a.runs * a.generations) as u64;
    let bar = progress_bar(total, "identify");
    let result = analysis::analyze_series(model, &series, &opts, None, |r, g, _| {
        bar.set_position((r * a.generations + g) as u64)
    })
    .map_err(|e| input(format!("{}: {e}", a.input.display())))?;
    bar.finish_and_clear();
    // A failed integration costs a finite penalty in the search (so the search has a direction),
    // so a model that no trial can integrate still yields a "best" run with a finite "training
    // error". Printing its coefficients as identified would pass a failure off as a result. (A
    // fit whose training integration completed but whose simulation over the whole record
    // failed is still reported, with "n/a" and a fit NMAE of inf, and is not called agreeing.)
    if !result.identification.best_run().train_integrated {
        return Err(input(format!(
            "{}: the model could not be simulated on this data: no trial of the identification integrated over the record; {}",
            a.input.display(),
            not_integrated_hint(
                (signal == Signal::Displacement).then_some(model),
                &series,
                &params,
                a.y0.zip(a.v0)
            )
        )));
    }
    let mut out = std::io::stdout().lock();
    if a.json {
        let v = identification_json(model, &result);
        writeln!(out, "{v}")?;
    } else {
        write_identification(&mut out, model, &result, &config, a.max_fit_nmae, signal)?;
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
        crate::plot::identification(dir, a.plot_format, model, &result, signal, &units)
            .map_err(|e| input(format!("--plot: {e}")))?;
    }
    Ok(())
}

/// Refuses `--stiffness` where it does nothing: on a displacement record it is only the
/// constant `k`, and no equation names `k` (a force record needs it for the deflection).
fn check_stiffness_used(
    a: &IdentifyArgs,
    signal: Signal,
    models: &[Model],
) -> Result<(), CliError> {
    if a.stiffness.is_none() || signal == Signal::Force || models.iter().any(|m| m.uses_param("k"))
    {
        return Ok(());
    }
    let which = if models.len() > 1 {
        "no equation names `k`"
    } else {
        "the equation does not name `k`"
    };
    Err(input(format!(
        "--stiffness is used as the constant `k` of the equation or, with --signal force, to turn the force into a deflection; {which} and the record is a displacement: drop it, or write `k` in the equation"
    )))
}

/// `--plot` names a directory the pictures go into. An existing file was refused only after
/// the identification, as "File exists", and a picture's name (`out.svg`) became a directory of
/// that name: both are refused up front, saying what the option takes.
fn check_plot_dir(dir: &std::path::Path) -> Result<(), CliError> {
    if dir.exists() {
        if dir.is_dir() {
            return Ok(());
        }
        return Err(input(format!(
            "--plot: {}: exists and is not a directory; --plot takes a directory, into which the pictures (fit, phase, convergence, ...) are written",
            dir.display()
        )));
    }
    let picture = dir
        .extension()
        .and_then(|e| e.to_str())
        .filter(|e| ["svg", "png"].contains(&e.to_ascii_lowercase().as_str()));
    if let Some(ext) = picture {
        return Err(input(format!(
            "--plot: {}: looks like a picture's file name (.{ext}); --plot takes a directory, into which the pictures (fit, phase, convergence, ...) are written (the format is --plot-format)",
            dir.display()
        )));
    }
    Ok(())
}

/// Where the times leave their grid, in a user's terms: the file's line (`lines[i]` is sample
/// `i`'s), time, and the gap's length.
fn describe_departure(series: &TimeSeries, lines: &[u64], d: GridDeparture) -> String {
    let time = |i: usize| series.t.get(i).copied().unwrap_or(f64::NAN);
    let line = |i: usize| lines.get(i).copied().unwrap_or(0);
    match d {
        GridDeparture::Spacing {
            index,
            spacing,
            step,
        } => {
            let missing = (spacing / step).round() - 1.0;
            let gap = match missing {
                m if m >= 2.0 => format!(": a gap of about {m:.0} missing samples"),
                m if m >= 1.0 => ": a gap of about 1 missing sample".to_string(),
                _ => String::new(),
            };
            format!(
                "line {} (t = {}) comes {spacing:.6e} s after the previous sample, where the median step is {step:.6e} s{gap}",
                line(index),
                time(index)
            )
        }
        GridDeparture::OffGrid {
            index,
            deviation,
            step,
        } => format!(
            "line {} (t = {}) is {deviation:+.3e} s ({:.1} % of a step) off the uniform grid of step {step:.6e} s that fits the times best, beyond the {:.0} % allowed (timestamps that jitter, or a clock that drifts)",
            line(index),
            time(index),
            100.0 * deviation.abs() / step,
            100.0 * crate::data::GRID_TOLERANCE
        ),
    }
}

/// The core's error about a setting, told in this command's flags (the core names its fields).
fn in_flags(e: IdentifyError) -> String {
    let IdentifyError::Invalid { field, reason } = &e else {
        return e.to_string();
    };
    let flag = match *field {
        "initial" => return "--y0 and --v0 must be finite numbers".to_string(),
        "train_fraction" => "--train-fraction",
        "population" => "--population",
        "generations" => "--generations",
        "runs" => "--runs",
        "rtol" => "--rtol",
        "test_rtol" => "--test-rtol",
        "substeps" => "--substeps",
        // Not options of this command: the core's own name is the most precise one.
        _ => return e.to_string(),
    };
    format!("{flag} {reason}")
}

/// Why the record's times must be Unix time in milliseconds, microseconds or nanoseconds,
/// when they must: a first time of 1e11 or more is past the year 5000 read in seconds, and
/// Unix milliseconds (1.7e12) were read as seconds: a 19 kg gate sampled at 200 Hz came out
/// as 1.9e7 kg at 0.0104 Hz, marked trusted, exit 0.
fn epoch_in_another_unit(series: &TimeSeries) -> Option<String> {
    const LATEST_SECONDS: f64 = 1e11;
    let first = *series.t.first()?;
    if first.abs() < LATEST_SECONDS {
        return None;
    }
    let unit = [
        (1e3, "milliseconds"),
        (1e6, "microseconds"),
        (1e9, "nanoseconds"),
    ]
    .into_iter()
    .find(|(k, _)| (first / k).abs() < LATEST_SECONDS)
    .map_or("another unit", |(_, name)| name);
    Some(format!(
        "the first time, {}, is more than 1e11 s (3,000 years) after 1970 if it is in seconds: \
         are the times Unix time in {unit}? gatewatch reads times in seconds; convert the \
         column (divide by 1000 for milliseconds)",
        Num(first)
    ))
}

/// What to check when no trial integrated: the input first (a time column in milliseconds
/// makes every period a thousand times longer than the solver's step budget; a stiffness of
/// 1e300 overflows the state), then the equation. Said with the numbers: the sample rate and
/// length the times imply, the known constants far from any physical size, and a given initial
/// state far outside the record (`--y0 1e308` was blamed on the times or the equation), and
/// (`displacement_model`: displacement data) a record far from order one that the equation
/// does not let the search rescale.
fn not_integrated_hint(
    displacement_model: Option<&Model>,
    series: &TimeSeries,
    params: &[(String, f64)],
    initial: Option<(f64, f64)>,
) -> String {
    let mut steps: Vec<f64> = series.t.windows(2).map(|w| w[1] - w[0]).collect();
    steps.sort_by(f64::total_cmp);
    let mut hint = String::from("check the input: ");
    if let Some(&step) = steps.get(steps.len() / 2) {
        let span = series.t[series.len() - 1] - series.t[0];
        hint.push_str(&format!(
            "the times imply a sample rate of {:.4} Hz over {:.6} s; they must be in seconds (times in milliseconds make this 1000 times too low)",
            // scientific where four decimals would print 300 digits or none (times of
            // 1e-300 s read "over 0.000000 s")
            crate::number::Num(1.0 / step),
            crate::number::Num(span)
        ));
    }
    // Constants whose size no double-precision integration of a gate survives.
    let extreme: Vec<String> = params
        .iter()
        .filter(|(_, v)| *v != 0.0 && !(1e-9..=1e12).contains(&v.abs()))
        .map(|(n, v)| {
            let flag = if n == "k" {
                "--stiffness/--param"
            } else {
                "--param"
            };
            format!("{flag} {n}={v:e}")
        })
        .collect();
    if !extreme.is_empty() {
        hint.push_str(&format!(
            "; {} is far outside a physical size (N/m, kg, N s/m)",
            extreme.join(", ")
        ));
    } else if !params.is_empty() {
        hint.push_str("; and the sizes of --stiffness/--param against the data");
    }
    let largest = series.y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if let Some((y0, v0)) = initial {
        // a start a thousand times the largest value recorded is not this record's state
        if y0.abs() > 1e3 * largest
            || y0.abs() > crate::data::MAX_ABS_VALUE
            || v0.abs() > crate::data::MAX_ABS_VALUE
        {
            hint.push_str(&format!(
                "; the initial state --y0 {y0:e} --v0 {v0:e} against the record's largest |y| of {largest:e}"
            ));
        }
    }
    // A record far from order one is searched at its own scale (`analysis::displacement_scales`)
    // unless the equation fixes its solutions' size; then the search starts its coefficients
    // in [-1, 1], which fit a record of order one.
    let fixed_size = displacement_model.is_some_and(|m| m.amplitude_exponents().is_none());
    if fixed_size && !(1e-2..=1e2).contains(&largest) {
        hint.push_str(&format!(
            "; the record's largest |y| of {largest:e} against an equation that fixes its solutions' size (a term without a coefficient, such as y^3 beside y, or a coefficient inside a function of y or yd), whose coefficients are searched from [-1, 1]: the data's unit"
        ));
    }
    hint.push_str("; else the equation: a division by zero or a vanishing factor of ydd");
    hint
}
