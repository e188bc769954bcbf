//! Stability map (the chapter's Figure 8.13): which points of a coefficient plane give a gate
//! whose free vibration dies out, by Monte Carlo simulation.
//!
//! Two coefficients are ranged over a rectangle, every other one is fixed. The points are
//! drawn uniformly from a seeded ChaCha8 stream, all of them before any is evaluated, and then
//! simulated in parallel with rayon, so the map is the same whatever the number of threads.
//!
//! # One trial
//!
//! The model is integrated from `(y0, v0)` with Dormand-Prince at `rtol = 1e-3` (the chapter's
//! setting) over `periods` periods `T = 2*pi/w0` of the undamped linearised frequency
//! `w0 = sqrt(k)`, `k = -d(ydd)/dy` at `y = yd = 0`, `t = 0`, evaluated at the centre of the map
//! (both ranged coefficients at the middle of their ranges). A horizon can be given instead
//! ([`MapSpec::t_end`]); without one, a centre with no period is an error that says why: a
//! factor of `ydd` (the mass) of zero there, a stiffness that cannot be evaluated at rest, or
//! one that is not positive.
//!
//! The model must be autonomous (no `t`): the map asks whether the free vibration dies out, and
//! a forcing in `t` keeps the response going whatever the damping, so every trial of a forced
//! model was drawn unstable and the map said nothing. A model whose acceleration cannot be
//! evaluated at the initial state at any drawn point (`y/0`) is refused, as `identify` refuses
//! a model no trial can integrate, rather than drawn as a map of unstable trials.
//!
//! The state is watched at 50 output times per period through its amplitude
//! `r = sqrt(y^2 + (yd/w0)^2)` (for a linear oscillator of frequency `w0`, the radius of its
//! phase-plane ellipse), with `r0` its initial value. A trial is **unstable** when
//! - the solver fails on the way to a blow-up (non-finite state), or
//! - the solution leaves the bound `r > 100 * r0` ([`GROWTH_BOUND`]), or
//! - the solution has not decayed: the largest `r` over the last period exceeds `r0`.
//!
//! and **stable** otherwise: the free vibration has died down below its initial amplitude after
//! `periods` periods. A trial that hits the solver's step or work limit, or its smallest step
//! (a step size underflow), before the horizon is **undecided**: it is left out of the map and
//! counted ([`StabilityMap::undecided`]). Why: a long horizon (`--t-end 3e5`) ran out of steps
//! on stable trials, and 30 of 50 were drawn as unstable; and the smallest step grows with the
//! horizon (a step must move `t` by more than its rounding), so at `--t-end 1e12` it was above
//! the first step of every trial, and all of them were drawn as unstable where shorter horizons
//! were refused. An underflow is the solver's failure, not the gate's: a real blow-up leaves
//! the bound first. The last rule is what makes slowly growing trials unstable although they
//! stay far inside the bound for ten periods; a self-excited oscillator whose equilibrium is
//! unstable but which settles on a limit cycle larger than `r0` is unstable too, as an engineer
//! wants. Trials within the solver's accuracy of neutral (a linear oscillator with zero
//! damping) can fall on either side; away from the boundary the classification is exact for a
//! linear oscillator (see the tests).

use crate::model::Model;
use crate::number::Num;
use crate::ode::{self, Method, Options};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

/// A trial whose amplitude exceeds this multiple of its initial amplitude is unstable.
pub const GROWTH_BOUND: f64 = 100.0;

/// Output times per period at which the amplitude is watched.
const POINTS_PER_PERIOD: usize = 50;

/// Most periods a trial may be integrated over: the output times cost 8 bytes each
/// (`POINTS_PER_PERIOD` a period: 40 MB at the bound), and `--periods 1e12` asked for 400 TB.
pub const MAX_PERIODS: f64 = 100_000.0;

/// Most Monte Carlo samples (trials) of a map. Why: a trial over the default 10 periods takes
/// about 10 µs (10^6 trials: 10 s on two cores), but its cost grows with the horizon (up to
/// [`MAX_PERIODS`] periods), and each trial is a line of the CSV and a marker of the picture
/// (about 90 bytes of SVG: 90 MB at the bound). `--samples 1e8` ran for hours without a word.
pub const MAX_SAMPLES: usize = 1_000_000;

/// A ranged coefficient: `c{index+1}` drawn uniformly from `[min, max]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Range {
    /// 0-based coefficient index (`c1` is 0).
    pub index: usize,
    /// Lower end.
    pub min: f64,
    /// Upper end (`> min`).
    pub max: f64,
}

impl Range {
    /// The coefficient's name, `c1`, `c2`, ...
    pub fn name(&self) -> String {
        format!("c{}", self.index + 1)
    }
}

/// What to map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapSpec {
    /// Coefficient on the horizontal axis.
    pub x: Range,
    /// Coefficient on the vertical axis.
    pub y: Range,
    /// Fixed coefficients: `(0-based index, value)` for every coefficient not ranged.
    pub fixed: Vec<(usize, f64)>,
    /// Initial displacement.
    pub y0: f64,
    /// Initial velocity.
    pub v0: f64,
    /// Periods of the linearised undamped frequency to integrate over.
    pub periods: f64,
    /// Horizon instead of `periods` periods.
    pub t_end: Option<f64>,
    /// Monte Carlo samples (1 to [`MAX_SAMPLES`]).
    pub samples: usize,
    /// Seed of the sample stream.
    pub seed: u64,
}

impl MapSpec {
    /// The chapter's setting for the plane of `x` and `y`: `y0 = 0.1`, `v0 = 0`, 10 periods,
    /// 6000 samples, seed 1, no fixed coefficients yet.
    pub fn new(x: Range, y: Range) -> MapSpec {
        MapSpec {
            x,
            y,
            fixed: Vec::new(),
            y0: 0.1,
            v0: 0.0,
            periods: 10.0,
            t_end: None,
            samples: 6000,
            seed: 1,
        }
    }
}

/// One simulated point of the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trial {
    /// Value of the horizontal coefficient.
    pub x: f64,
    /// Value of the vertical coefficient.
    pub y: f64,
    /// Whether the free vibration decayed (see the module docs).
    pub stable: bool,
}

/// A computed map.
#[derive(Debug, Clone, PartialEq)]
pub struct StabilityMap {
    /// Name of the horizontal coefficient (`c1`).
    pub x_name: String,
    /// Name of the vertical coefficient (`c2`).
    pub y_name: String,
    /// The trials, in the order drawn.
    pub trials: Vec<Trial>,
    /// The horizon every trial was integrated over.
    pub t_end: f64,
    /// Trials left out: the solver's step or work limit, or its smallest step, stopped them
    /// before the horizon.
    pub undecided: usize,
}

/// Why a map cannot be computed or read. Messages name the command-line option at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StabilityError {
    /// A bad option; the message names it.
    #[error("{0}")]
    Option(String),
    /// A CSV file that cannot be read back.
    #[error("{path}: {reason}")]
    Csv {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        reason: String,
    },
}

fn option<T>(msg: String) -> Result<T, StabilityError> {
    Err(StabilityError::Option(msg))
}

/// Parses a coefficient name `cK` into its 0-based index, checking it is in `model`.
pub fn coefficient_index(model: &Model, name: &str, opt: &str) -> Result<usize, StabilityError> {
    let k = name
        .strip_prefix('c')
        .filter(|d| !d.is_empty() && d.chars().all(|c| c.is_ascii_digit()))
        .and_then(|d| d.parse::<usize>().ok())
        .filter(|&k| k >= 1);
    match k {
        Some(k) if k <= model.n_coeffs() => Ok(k - 1),
        _ => option(format!(
            "{opt}: '{name}' is not a coefficient of the model (it has {})",
            coefficient_list(model.n_coeffs())
        )),
    }
}

fn coefficient_list(n: usize) -> String {
    match n {
        0 => "none".to_string(),
        1 => "c1".to_string(),
        2 => "c1, c2".to_string(),
        _ => format!("c1..c{n}"),
    }
}

/// Parses `--range` text `cK=MIN:MAX`.
pub fn parse_range(model: &Model, text: &str) -> Result<Range, StabilityError> {
    let bad = || {
        option(format!(
            "--range: '{text}': expected NAME=MIN:MAX, e.g. c1=-3:3"
        ))
    };
    let Some((name, span)) = text.split_once('=') else {
        return bad();
    };
    let Some((lo, hi)) = span.split_once(':') else {
        return bad();
    };
    let (Ok(min), Ok(max)) = (lo.trim().parse::<f64>(), hi.trim().parse::<f64>()) else {
        return bad();
    };
    if !min.is_finite() || !max.is_finite() {
        return option(format!("--range: '{text}': the ends must be finite"));
    }
    if min >= max {
        return option(format!(
            "--range: '{text}': the minimum must be below the maximum"
        ));
    }
    if !(max - min).is_finite() {
        return option(format!(
            "--range: '{text}': the range is wider than a float holds (at most about 1.8e308)"
        ));
    }
    let index = coefficient_index(model, name.trim(), "--range")?;
    Ok(Range { index, min, max })
}

/// Checks `spec` against `model`; returns the full coefficient vector at the map's centre.
fn check(model: &Model, spec: &MapSpec) -> Result<Vec<f64>, StabilityError> {
    if model.uses_time() {
        return option(
            "--model: the equation uses t, and the stability map needs an autonomous model: it \
             asks whether the free vibration dies out, and a forcing in t keeps the response \
             going whatever the damping (every trial would be drawn unstable); remove the terms in t"
                .to_string(),
        );
    }
    let n = model.n_coeffs();
    if spec.x.index == spec.y.index {
        return option(format!(
            "--range: {} is ranged twice; give two different coefficients",
            spec.x.name()
        ));
    }
    for r in [&spec.x, &spec.y] {
        if r.index >= n {
            return option(format!(
                "--range: '{}' is not a coefficient of the model (it has {})",
                r.name(),
                coefficient_list(n)
            ));
        }
        if !(r.min.is_finite() && r.max.is_finite() && r.min < r.max) {
            return option(format!(
                "--range: {}: the minimum must be below the maximum, both finite",
                r.name()
            ));
        }
    }
    let mut c = vec![f64::NAN; n];
    c[spec.x.index] = 0.5 * (spec.x.min + spec.x.max);
    c[spec.y.index] = 0.5 * (spec.y.min + spec.y.max);
    for &(i, v) in &spec.fixed {
        let name = format!("c{}", i + 1);
        if i >= n {
            return option(format!(
                "--fix: '{name}' is not a coefficient of the model (it has {})",
                coefficient_list(n)
            ));
        }
        if i == spec.x.index || i == spec.y.index {
            return option(format!("--fix: {name} is also ranged"));
        }
        if !c[i].is_nan() {
            return option(format!("--fix: {name} is fixed more than once"));
        }
        if !v.is_finite() {
            return option(format!("--fix: {name} must be finite"));
        }
        c[i] = v;
    }
    if let Some(i) = c.iter().position(|v| v.is_nan()) {
        return option(format!(
            "--fix: c{} is neither ranged nor fixed; give --fix c{}=VALUE",
            i + 1,
            i + 1
        ));
    }
    if spec.samples == 0 {
        return option("--samples must be at least 1".to_string());
    }
    if spec.samples > MAX_SAMPLES {
        return option(format!(
            "--samples must be at most {MAX_SAMPLES}, got {}",
            spec.samples
        ));
    }
    if !(spec.y0.is_finite() && spec.v0.is_finite()) {
        return option("--y0 and --v0 must be finite".to_string());
    }
    if spec.y0 == 0.0 && spec.v0 == 0.0 {
        return option(
            "--y0/--v0: the initial state is the equilibrium (0, 0), which never moves; give a disturbance such as --y0 0.1"
                .to_string(),
        );
    }
    if !(spec.periods.is_finite() && (1.0..=MAX_PERIODS).contains(&spec.periods)) {
        return option(format!(
            "--periods must be between 1 and {MAX_PERIODS}, got {}",
            Num(spec.periods)
        ));
    }
    if let Some(t) = spec.t_end {
        if !(t.is_finite() && t > 0.0) {
            return option(format!("--t-end must be positive, got {}", Num(t)));
        }
    }
    Ok(c)
}

/// `k = -d(ydd)/dy` at `t = 0`, `y = yd = 0`: the linearised stiffness per unit mass.
fn linear_stiffness(model: &Model, c: &[f64]) -> f64 {
    let h = 1e-6;
    -(model.accel(0.0, h, 0.0, c) - model.accel(0.0, -h, 0.0, c)) / (2.0 * h)
}

/// Why the centre `c` of the map, of linearised stiffness `k`, has no period: the mass (factor
/// of `ydd`) at rest is zero or not finite, the stiffness is not finite (a division by zero at
/// rest), or it is not positive. Why the mass first: with a zero mass `k` is infinite, and
/// "stiffness inf is not positive" named the wrong cause.
fn no_period(model: &Model, c: &[f64], k: f64) -> StabilityError {
    let mass = model.mass(0.0, 0.0, 0.0, c);
    let why = if mass == 0.0 || !mass.is_finite() {
        format!(
            "the factor of ydd, the mass, is {} at rest there, so the acceleration is undetermined",
            Num(mass + 0.0)
        )
    } else if !k.is_finite() {
        format!("the linearised stiffness cannot be evaluated at rest there (it is {k}: a division by zero?)")
    } else {
        // `+ 0.0` turns a negative zero (`-(0*y)`) into the zero it is
        format!("the linearised stiffness {:.3e} is not positive", k + 0.0)
    };
    StabilityError::Option(format!(
        "--periods: the model has no undamped oscillation at the centre of the map ({why}), so it has no period; give the horizon with --t-end"
    ))
}

/// Refuses a model whose acceleration at the initial state `(y0, v0)` is not finite at any of
/// the drawn `points`: no trial could start (`y/0`), and each would be drawn unstable.
fn check_evaluable(
    model: &Model,
    spec: &MapSpec,
    centre: &[f64],
    points: &[(f64, f64)],
) -> Result<(), StabilityError> {
    let mut c = centre.to_vec();
    let evaluable = points.iter().any(|&(x, y)| {
        c[spec.x.index] = x;
        c[spec.y.index] = y;
        model.accel(0.0, spec.y0, spec.v0, &c).is_finite()
    });
    if evaluable {
        return Ok(());
    }
    option(format!(
        "--model: the model could not be simulated: its acceleration at the initial state (y0 = {}, v0 = {}) is not finite at any of the {} points of the map (a division by zero or a vanishing factor of ydd)",
        Num(spec.y0),
        Num(spec.v0),
        points.len()
    ))
}

/// Draws the trial points: `samples` pairs `(x, y)` from ChaCha8 seeded with `seed`.
pub fn draw(spec: &MapSpec) -> Vec<(f64, f64)> {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    (0..spec.samples)
        .map(|_| {
            let u: f64 = rng.random();
            let v: f64 = rng.random();
            (
                spec.x.min + (spec.x.max - spec.x.min) * u,
                spec.y.min + (spec.y.max - spec.y.min) * v,
            )
        })
        .collect()
}

/// Computes the map (in parallel on rayon's pool; the result does not depend on its size).
pub fn map(model: &Model, spec: &MapSpec) -> Result<StabilityMap, StabilityError> {
    let centre = check(model, spec)?;
    let points = draw(spec);
    check_evaluable(model, spec, &centre, &points)?;
    let k = linear_stiffness(model, &centre);
    let w0 = if k.is_finite() && k > 0.0 {
        Some(k.sqrt())
    } else {
        None
    };
    let (t_end, w0) = match (spec.t_end, w0) {
        (Some(t), Some(w)) => (t, w),
        // Without a linear frequency, the horizon sets the time scale of the amplitude.
        (Some(t), None) => (t, spec.periods * std::f64::consts::TAU / t),
        (None, Some(w)) => (spec.periods * std::f64::consts::TAU / w, w),
        (None, None) => return Err(no_period(model, &centre, k)),
    };
    let n_out = ((spec.periods * POINTS_PER_PERIOD as f64).ceil() as usize).max(2) + 1;
    let times: Vec<f64> = (0..n_out)
        .map(|i| t_end * i as f64 / (n_out - 1) as f64)
        .collect();
    let last_period_start = t_end * (1.0 - 1.0 / spec.periods);
    let outcomes: Vec<(f64, f64, Option<bool>)> = points
        .par_iter()
        .map(|&(x, y)| {
            let mut c = centre.clone();
            c[spec.x.index] = x;
            c[spec.y.index] = y;
            (
                x,
                y,
                decays(model, &c, spec.y0, spec.v0, w0, &times, last_period_start),
            )
        })
        .collect();
    let trials: Vec<Trial> = outcomes
        .iter()
        .filter_map(|&(x, y, stable)| stable.map(|stable| Trial { x, y, stable }))
        .collect();
    let undecided = outcomes.len() - trials.len();
    if trials.is_empty() {
        return option(format!(
            "--t-end/--periods: none of the {undecided} trials reached the horizon t = {:.4} within the solver's step limit and above its smallest step; shorten the horizon",
            Num(t_end)
        ));
    }
    Ok(StabilityMap {
        x_name: spec.x.name(),
        y_name: spec.y.name(),
        trials,
        t_end,
        undecided,
    })
}

/// One trial: whether the free vibration from `(y0, v0)` decays (the module docs' rules);
/// `None` when the solver's step or work limit, or its smallest step, stopped it first.
fn decays(
    model: &Model,
    c: &[f64],
    y0: f64,
    v0: f64,
    w0: f64,
    times: &[f64],
    last_period_start: f64,
) -> Option<bool> {
    let r = |s: &[f64; 2]| (s[0] * s[0] + (s[1] / w0).powi(2)).sqrt();
    let r0 = r(&[y0, v0]);
    let opts = Options {
        rtol: 1e-3,
        atol: 1e-6 * r0.clamp(1e-12, 1.0),
        bound: 1e3 * GROWTH_BOUND * (y0.abs() + v0.abs()),
        ..Options::default()
    };
    let sys = crate::model::Bound { model, coeffs: c };
    let mut last_max = 0.0f64;
    let outcome = ode::integrate(Method::Dopri5, &sys, [y0, v0], times, &opts, |i, s| {
        let ri = r(s);
        // NaN counts as out of bounds.
        if ri.is_nan() || ri > GROWTH_BOUND * r0 {
            return ControlFlow::Break(());
        }
        if times[i] >= last_period_start {
            last_max = last_max.max(ri);
        }
        ControlFlow::Continue(())
    });
    match outcome.failure {
        Some(
            ode::Failure::StepLimit { .. }
            | ode::Failure::WorkLimit { .. }
            | ode::Failure::StepSizeUnderflow { .. },
        ) => None,
        Some(_) => Some(false),
        None => Some(last_max <= r0),
    }
}

impl StabilityMap {
    /// Number of stable trials.
    pub fn stable_count(&self) -> usize {
        self.trials.iter().filter(|t| t.stable).count()
    }

    /// Writes the map as CSV: header `x_name,y_name,stable`, one row per trial, `stable` as
    /// 1 or 0, values in Rust's shortest round-trip notation.
    pub fn write_csv(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(out, "{},{},stable", self.x_name, self.y_name)?;
        for t in &self.trials {
            writeln!(out, "{},{},{}", t.x, t.y, u8::from(t.stable))?;
        }
        Ok(())
    }

    /// Reads a map written by [`StabilityMap::write_csv`] (`t_end` is not stored: it reads NaN).
    pub fn read_csv(path: &Path) -> Result<StabilityMap, StabilityError> {
        let err = |reason: String| StabilityError::Csv {
            path: path.to_path_buf(),
            reason,
        };
        let text =
            std::fs::read_to_string(path).map_err(|e| err(format!("cannot read the file: {e}")))?;
        let mut lines = text.lines();
        let header = lines
            .next()
            .ok_or_else(|| err("the file is empty".into()))?;
        let cols: Vec<&str> = header.split(',').map(str::trim).collect();
        let [x_name, y_name, "stable"] = cols.as_slice() else {
            return Err(err(format!(
                "line 1: expected the header NAME,NAME,stable, got '{header}'"
            )));
        };
        let mut trials = Vec::new();
        for (i, line) in lines.enumerate() {
            let line_no = i + 2;
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            let parse = |s: &str| {
                s.parse::<f64>()
                    .map_err(|_| err(format!("line {line_no}: '{s}' is not a number")))
            };
            let [x, y, s] = f.as_slice() else {
                return Err(err(format!("line {line_no}: expected 3 fields")));
            };
            let stable = match *s {
                "1" => true,
                "0" => false,
                other => {
                    return Err(err(format!(
                        "line {line_no}: stable must be 1 or 0, got '{other}'"
                    )))
                }
            };
            trials.push(Trial {
                x: parse(x)?,
                y: parse(y)?,
                stable,
            });
        }
        Ok(StabilityMap {
            x_name: x_name.to_string(),
            y_name: y_name.to_string(),
            trials,
            t_end: f64::NAN,
            undecided: 0,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn linear() -> Model {
        Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap()
    }

    fn spec(samples: usize) -> MapSpec {
        let mut s = MapSpec::new(
            Range {
                index: 0,
                min: -2.0,
                max: 2.0,
            },
            Range {
                index: 1,
                min: -1.0,
                max: 3.0,
            },
        );
        s.samples = samples;
        s.seed = 7;
        s
    }

    #[test]
    fn linear_damping_is_stable_iff_both_coefficients_positive_away_from_the_boundary() {
        // ydd + c1*yd + c2*y = 0 is asymptotically stable iff c1 > 0 and c2 > 0.
        let m = map(&linear(), &spec(800)).unwrap();
        assert_eq!(m.trials.len(), 800);
        let margin = 0.1;
        let mut checked = 0;
        for t in &m.trials {
            if t.x.abs() < margin || t.y.abs() < margin {
                continue;
            }
            let expected = t.x > 0.0 && t.y > 0.0;
            assert_eq!(t.stable, expected, "c1 = {}, c2 = {}", t.x, t.y);
            checked += 1;
        }
        assert!(checked > 600, "{checked}");
        let stable = m.stable_count();
        assert!(stable > 200 && stable < 600, "{stable}");
    }

    /// A horizon longer than the solver's step limit reaches leaves trials undecided, not
    /// unstable: every trial here is a damped linear oscillator.
    #[test]
    fn trials_the_step_limit_stops_are_undecided_not_unstable() {
        let mut s = spec(40);
        s.x.min = 0.1;
        s.x.max = 3.0;
        s.y.min = 0.1;
        s.y.max = 1.0;
        s.t_end = Some(3e5);
        let m = map(&linear(), &s).unwrap();
        assert!(m.undecided > 0, "the horizon is beyond the step limit");
        assert_eq!(m.trials.len() + m.undecided, 40);
        assert!(
            m.trials.iter().all(|t| t.stable),
            "a damped oscillator drawn unstable"
        );
        // none reaches the horizon: a clear error, not an empty map
        s.t_end = Some(1e9);
        let e = map(&linear(), &s).unwrap_err();
        assert!(e.to_string().contains("none of the 40 trials"), "{e}");
    }

    /// At `--t-end 1e12` the solver's smallest step (16 ulps of the horizon, 3.6e-3) is above
    /// every trial's first step: the step size underflows at once. That is the solver's
    /// failure, refused as at 1e9, not 200 unstable trials.
    #[test]
    fn a_step_size_underflow_is_undecided_not_unstable() {
        let model = Model::parse("ydd + (c1 + c2*y + c3*y^2)*yd + y = 0", &[]).unwrap();
        let mut s = MapSpec::new(
            Range {
                index: 0,
                min: -3.0,
                max: 3.0,
            },
            Range {
                index: 1,
                min: -3.0,
                max: 3.0,
            },
        );
        s.fixed = vec![(2, 1.0)];
        s.samples = 200;
        s.t_end = Some(1e12);
        let e = map(&model, &s).unwrap_err();
        assert!(e.to_string().contains("none of the 200 trials"), "{e}");
        // the same plane over ten periods is decided, with unstable trials where c1 < 0
        s.t_end = None;
        let m = map(&model, &s).unwrap();
        assert_eq!(m.undecided, 0);
        assert!(m.stable_count() > 0 && m.stable_count() < 200);
    }

    #[test]
    fn periods_and_ranges_are_bounded() {
        let mut s = spec(4);
        s.periods = 1e12;
        let e = map(&linear(), &s).unwrap_err();
        assert!(
            e.to_string().contains("--periods must be between 1 and"),
            "{e}"
        );
        let e = parse_range(&linear(), "c1=-1e308:1e308").unwrap_err();
        assert!(e.to_string().contains("wider than a float holds"), "{e}");
    }

    #[test]
    fn slowly_growing_trials_inside_the_bound_are_unstable() {
        // c1 = -0.02: the amplitude grows by exp(0.01 * t_end) = about 1.4 over ten periods of
        // w0 = sqrt(1.0) (t_end = 20 pi for the centre c2 = 1), far inside 100 * r0.
        let model = linear();
        let c = [-0.02, 1.0];
        let t_end = 20.0 * std::f64::consts::PI;
        let times: Vec<f64> = (0..=500).map(|i| t_end * i as f64 / 500.0).collect();
        assert_eq!(
            decays(&model, &c, 0.1, 0.0, 1.0, &times, 0.9 * t_end),
            Some(false)
        );
        // and slowly decaying ones stable.
        let c = [0.02, 1.0];
        assert_eq!(
            decays(&model, &c, 0.1, 0.0, 1.0, &times, 0.9 * t_end),
            Some(true)
        );
    }

    #[test]
    fn van_der_pol_limit_cycle_is_unstable() {
        // ydd + (c1 + c2*y^2)*yd + y = 0: c1 < 0 feeds energy near the equilibrium (a limit
        // cycle of amplitude about 2 for c2 = 1); c1 > 0 with c2 > 0 decays from y0 = 0.1.
        let model = Model::parse("ydd + (c1 + c2*y^2)*yd + y = 0", &[]).unwrap();
        let mut s = MapSpec::new(
            Range {
                index: 0,
                min: -1.0,
                max: 1.0,
            },
            Range {
                index: 1,
                min: 0.5,
                max: 1.5,
            },
        );
        s.samples = 200;
        let m = map(&model, &s).unwrap();
        for t in m.trials.iter().filter(|t| t.x.abs() > 0.1) {
            assert_eq!(t.stable, t.x > 0.0, "c1 = {}, c2 = {}", t.x, t.y);
        }
    }

    #[test]
    fn same_map_whatever_the_thread_count() {
        let model = linear();
        let s = spec(300);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| map(&model, &s).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(3));
        let mut other = s.clone();
        other.seed = 8;
        assert_ne!(one.trials, map(&model, &other).unwrap().trials);
    }

    #[test]
    fn csv_round_trip() {
        let m = map(&linear(), &spec(50)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.csv");
        let mut f = std::fs::File::create(&path).unwrap();
        m.write_csv(&mut f).unwrap();
        drop(f);
        let back = StabilityMap::read_csv(&path).unwrap();
        assert_eq!(back.x_name, "c1");
        assert_eq!(back.y_name, "c2");
        assert_eq!(back.trials, m.trials);
        std::fs::write(&path, "c1,c2,stable\n1,2,maybe\n").unwrap();
        let e = StabilityMap::read_csv(&path).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("maybe"), "{e}");
    }

    #[test]
    fn bad_specs_name_the_option() {
        let model = Model::parse("ydd + (c1 + c2*y + c3*y^2)*yd + y = 0", &[]).unwrap();
        let r = |t: &str| parse_range(&model, t);
        assert!(r("c1=-3:3").is_ok());
        for (text, needle) in [
            ("c1-3:3", "expected NAME=MIN:MAX"),
            ("c1=3", "expected NAME=MIN:MAX"),
            ("c1=a:3", "expected NAME=MIN:MAX"),
            ("c1=3:-3", "minimum must be below"),
            ("c1=1:1", "minimum must be below"),
            ("c4=0:1", "'c4' is not a coefficient"),
            ("k=0:1", "'k' is not a coefficient"),
        ] {
            let e = r(text).unwrap_err().to_string();
            assert!(
                e.starts_with("--range") && e.contains(needle),
                "{text}: {e}"
            );
        }
        let mut s = MapSpec::new(r("c1=-3:3").unwrap(), r("c2=-3:3").unwrap());
        let e = map(&model, &s).unwrap_err().to_string();
        assert!(e.contains("--fix") && e.contains("c3"), "{e}");
        s.fixed = vec![(2, 1.0)];
        s.samples = 0;
        let e = map(&model, &s).unwrap_err().to_string();
        assert!(e.contains("--samples"), "{e}");
        s.samples = 10;
        s.fixed = vec![(2, 1.0), (0, 1.0)];
        let e = map(&model, &s).unwrap_err().to_string();
        assert!(e.contains("--fix: c1 is also ranged"), "{e}");
        s.fixed = vec![(2, 1.0)];
        s.y0 = 0.0;
        let e = map(&model, &s).unwrap_err().to_string();
        assert!(e.contains("--y0"), "{e}");
    }

    #[test]
    fn no_period_without_stiffness_asks_for_t_end() {
        // Centre of c2 in [-3, 3] is 0: no undamped oscillation there.
        let model = linear();
        let mut s = spec(20);
        s.y.min = -3.0;
        s.y.max = 3.0;
        let e = map(&model, &s).unwrap_err().to_string();
        assert!(e.contains("--t-end"), "{e}");
        s.t_end = Some(40.0);
        assert_eq!(map(&model, &s).unwrap().t_end, 40.0);
    }

    /// The plane of the reviewer's maps: c1 and c2 over -1..1, centre 0.
    fn centred(samples: usize) -> MapSpec {
        let mut s = spec(samples);
        (s.x.min, s.x.max, s.y.min, s.y.max) = (-1.0, 1.0, -1.0, 1.0);
        s
    }

    #[test]
    fn a_centre_without_a_period_names_its_cause() {
        // A zero mass at the centre, not an "infinite stiffness".
        let model = Model::parse("c1*ydd + c2*yd + y = 0", &[]).unwrap();
        let e = map(&model, &centred(20)).unwrap_err().to_string();
        assert!(
            e.contains("the factor of ydd, the mass, is 0 at rest") && e.contains("--t-end"),
            "{e}"
        );
        assert!(!e.contains("inf"), "{e}");
        // A zero stiffness is 0, not a negative zero.
        let e = map(&linear(), &centred(20)).unwrap_err().to_string();
        assert!(
            e.contains("linearised stiffness 0.000e0 is not positive"),
            "{e}"
        );
        assert!(!e.contains("-0"), "{e}");
        // A stiffness that cannot be evaluated at rest, the mass being fine.
        let model = Model::parse("ydd + c1*yd + y/c2 = 0", &[]).unwrap();
        let e = map(&model, &centred(20)).unwrap_err().to_string();
        assert!(e.contains("cannot be evaluated at rest"), "{e}");
        // with a horizon, the trials off the singular centre are mapped
        let mut s = centred(20);
        s.t_end = Some(20.0);
        assert_eq!(map(&model, &s).unwrap().trials.len(), 20);
    }

    #[test]
    fn a_model_no_trial_can_start_is_refused() {
        // `y/0` is no constant part (the parser folds `1/0`): every trial divides by zero.
        let model = Model::parse("ydd + c1*yd + c2*y/0 = 0", &[]).unwrap();
        for t_end in [None, Some(5.0)] {
            let mut s = centred(10);
            s.t_end = t_end;
            let e = map(&model, &s).unwrap_err().to_string();
            assert!(
                e.starts_with("--model: the model could not be simulated")
                    && e.contains("not finite at any of the 10 points")
                    && e.contains("division by zero"),
                "{e}"
            );
        }
    }

    #[test]
    fn a_forced_model_is_refused() {
        let model = Model::parse("ydd + c1*yd + c2*y = c3*sin(t)", &[]).unwrap();
        let mut s = centred(10);
        s.fixed = vec![(2, 1.0)];
        s.t_end = Some(10.0);
        let e = map(&model, &s).unwrap_err().to_string();
        assert!(
            e.starts_with("--model: the equation uses t") && e.contains("autonomous"),
            "{e}"
        );
    }
}
