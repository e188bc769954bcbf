//! The pictures of an identification (`gatewatch identify --plot`).

use super::*;
use crate::analysis::{SeriesAnalysis, Signal};
use crate::identify::InitialValues;
use crate::model::{Bound, Model};
use crate::ode::{self, Method, Options};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

pub fn trajectory(
    model: &Model,
    coefficients: &[f64],
    initial: InitialValues,
    t0: f64,
    t1: f64,
    points: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let points = points.max(2);
    let times: Vec<f64> = (0..points)
        .map(|i| t0 + (t1 - t0) * i as f64 / (points - 1) as f64)
        .collect();
    let scale = initial.y0.abs().max(initial.v0.abs()).max(1e-12);
    let opts = Options {
        rtol: 1e-8,
        atol: 1e-11 * scale,
        bound: 1e6 * scale,
        max_steps: 1_000_000,
        max_rhs_evals: 10_000_000,
        ..Options::default()
    };
    let sys = Bound {
        model,
        coeffs: coefficients,
    };
    let (mut y, mut yd) = (Vec::with_capacity(points), Vec::with_capacity(points));
    let o = ode::integrate(
        Method::Dopri5,
        &sys,
        [initial.y0, initial.v0],
        &times,
        &opts,
        |_, s| {
            y.push(s[0]);
            yd.push(s[1]);
            ControlFlow::Continue(())
        },
    );
    let mut t = times;
    t.truncate(o.reached);
    (t, y, yd)
}

/// Makes sure pictures can be written into `dir`: creates it if needed and creates (then
/// removes) a probe file in it. Called before a long computation whose pictures go there, so an
/// unwritable directory is reported before, not after, the work.
pub fn prepare_dir(dir: &Path) -> Result<(), PlotError> {
    let fail = |path: &Path, e: std::io::Error| PlotError::Write {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    std::fs::create_dir_all(dir).map_err(|e| fail(dir, e))?;
    let probe = dir.join(format!(".gatewatch-probe-{}", std::process::id()));
    std::fs::File::create(&probe).map_err(|e| fail(dir, e))?;
    // The probe proved the directory writable; failing to remove it loses nothing.
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// The pictures of an identification, written into `dir` (created if needed): `fit` (data and
/// model output), `phase` (the model's phase plane), `convergence`, and in force mode
/// `hysteresis` (the velocity-dependent part of the modelled support force against deflection
/// over the last cycles: the chapter's Figure 8.15, whose enclosed area is the energy fed in per
/// cycle), with `format`'s extension. Returns the files written.
pub fn identification(
    dir: &Path,
    format: Format,
    model: &Model,
    analysis: &SeriesAnalysis,
    signal: Signal,
    units: &Units,
) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir).map_err(|e| PlotError::Write {
        path: dir.to_path_buf(),
        reason: e.to_string(),
    })?;
    let result = &analysis.identification;
    let series = &analysis.data;
    let best = result.best_run();
    let (t0, t1) = match (series.t.first(), series.t.last()) {
        (Some(a), Some(b)) => (*a, *b),
        _ => return Err(no_data(dir, "the time series is empty")),
    };
    let file = |name: &str| dir.join(format!("{name}.{}", format.extension()));
    let fit_path = file("fit");
    let mut written = Vec::new();
    match (signal, &analysis.prediction) {
        // The support force is only known at the samples (it needs the state there).
        (Signal::Force, Some(p)) => {
            fit(
                &fit_path,
                &series.t,
                &series.y,
                &result.train,
                &result.test,
                &series.t,
                p,
                units,
            )?;
        }
        _ => {
            let points = (series.len() * 8).clamp(2000, 20_000);
            let (mt, my, _) = trajectory(model, &best.coefficients, best.initial, t0, t1, points);
            fit(
                &fit_path,
                &series.t,
                &series.y,
                &result.train,
                &result.test,
                &mt,
                &my,
                units,
            )?;
        }
    }
    written.push(fit_path);
    if let Some(tr) = &analysis.trajectory {
        let (y, yd): (Vec<f64>, Vec<f64>) = tr.iter().map(|s| (s[0], s[1])).unzip();
        let p = file("phase");
        phase(&p, &y, &yd, units)?;
        written.push(p);
        if signal == Signal::Force {
            if let Some(w) = analysis.linearization.omega0() {
                let period = 2.0 * std::f64::consts::PI / w;
                let (defl, force): (Vec<f64>, Vec<f64>) = tr
                    .iter()
                    .zip(&series.t)
                    .filter(|(_, &t)| t >= t1 - 3.0 * period)
                    .map(|(s, &t)| {
                        let c = &best.coefficients;
                        (
                            s[0],
                            model.residual(t, s[0], s[1], c) - model.residual(t, s[0], 0.0, c),
                        )
                    })
                    .unzip();
                let p = file("hysteresis");
                hysteresis(&p, &defl, &force, units)?;
                written.push(p);
            }
        }
    }
    let p = file("convergence");
    convergence(&p, &best.history)?;
    written.push(p);
    Ok(written)
}
