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

/// The pictures of an identification, written into `dir` (created if needed), with `format`'s
/// extension; returns the files written:
/// - `fit`: the data with the model. Displacement: the whole record, training and test samples
///   apart, the model as a line. Force: a zoom on the last few periods before the edge samples
///   the moving average spoils (samples and model) above the residual over the whole record,
///   those edges shaded.
/// - `phase`: the model's phase plane, with the states estimated from the data beside it
///   (displacement: `y` and its central difference; force: `F/k`, the quasi-static deflection the
///   pre-run starts from, and its central difference).
/// - `hysteresis` (force): the whole support force against the deflection over the last three
///   periods before those edges, measured and model: the chapter's Figure 8.15, whose area is the energy fed in per
///   cycle.
/// - `damping`: the model's equivalent damping ratio `zeta_eq(A)` over the amplitudes the window
///   visited (the report's `zeta_eq_curve`), when the model is an oscillator at rest.
/// - `convergence`: the DE's best cost per generation, ending at the training error after the
///   polish.
pub fn identification(
    dir: &Path,
    format: Format,
    model: &Model,
    analysis: &SeriesAnalysis,
    signal: Signal,
    units: &Units,
) -> Result<Vec<PathBuf>, PlotError> {
    prepare_dir(dir)?;
    let result = &analysis.identification;
    let series = &analysis.data;
    let best = result.best_run();
    let c = &best.coefficients;
    let (t0, t1) = match (series.t.first(), series.t.last()) {
        (Some(a), Some(b)) => (*a, *b),
        _ => return Err(no_data(dir, "the time series is empty")),
    };
    let file = |name: &str| dir.join(format!("{name}.{}", format.extension()));
    let mut written = Vec::new();
    // The model sampled densely (at least 40 points per sample interval of a short record, 20 000
    // at most) so its curves are smooth where the samples are sparse.
    let points = (series.len() * 8).clamp(2000, 20_000);
    let (mt, my, myd) = trajectory(model, c, best.initial, t0, t1, points);
    // The last periods of the record are drawn from before the edge samples whose centred
    // moving average was truncated (`SeriesAnalysis::edge_samples`): there the data carry the
    // average's lag as an offset, and the zoom showed a residual of ~0 jump to +6 N and the
    // loop's measured points 1 to 8 N above the model's.
    let edge = analysis.edge_samples;
    let (v0, v1) = if series.len() > 2 * edge + 1 {
        (series.t[edge], series.t[series.len() - 1 - edge])
    } else {
        (t0, t1)
    };
    let period = analysis
        .linearization
        .omega0()
        .map(|w| 2.0 * std::f64::consts::PI / w)
        .filter(|p| p.is_finite() && *p > 0.0);

    let fit_path = file("fit");
    match (signal, &analysis.prediction) {
        (Signal::Force, Some(predicted)) => {
            let force: Vec<f64> = mt
                .iter()
                .zip(my.iter().zip(&myd))
                .map(|(&t, (&y, &yd))| model.residual(t, y, yd, c))
                .collect();
            // Four periods when the period is known and shorter than the reliable part of the
            // record; else a tenth of it.
            let width = period.map_or((v1 - v0) / 10.0, |p| (4.0 * p).min(v1 - v0));
            let zoom = (v1 - width, v1);
            fit_zoom(
                &fit_path,
                &series.t,
                &series.y,
                predicted,
                (&mt, &force),
                zoom,
                (v0, v1),
                units,
            )?;
        }
        _ => {
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

    if !mt.is_empty() {
        let (data_y, data_label): (Vec<f64>, &str) = match signal {
            Signal::Force => match stiffness(model, c) {
                Some(k) => (
                    series.y.iter().map(|f| f / k).collect(),
                    "data: F/k (quasi-static) and its rate",
                ),
                None => (Vec::new(), ""),
            },
            _ => (series.y.clone(), "data: y and its central difference"),
        };
        let data_yd = central_difference(&series.t, &data_y);
        // A force record holds many periods of a slowly changing orbit, which drawn whole fill
        // a disc: show the last three periods, as the hysteresis loop does.
        // (Before the moving average's truncated edge, as the zoom.)
        let (from, to) = match (signal, period) {
            // Unless the model's trajectory ended early (it diverged): then all of it.
            (Signal::Force, Some(p)) if mt.last().is_some_and(|&t| t >= v1 - 3.0 * p) => {
                (v1 - 3.0 * p, v1)
            }
            _ => (f64::NEG_INFINITY, f64::INFINITY),
        };
        let keep = |t: &[f64], a: &[f64]| -> Vec<f64> {
            t.iter()
                .zip(a)
                .filter(|(t, _)| **t >= from && **t <= to)
                .map(|(_, v)| *v)
                .collect()
        };
        let (dy, dyd) = (keep(&series.t, &data_y), keep(&series.t, &data_yd));
        let (py, pyd) = (keep(&mt, &my), keep(&mt, &myd));
        let p = file("phase");
        let data = (!dy.is_empty()).then_some((&dy[..], &dyd[..], data_label));
        phase(&p, data, &py, &pyd, units)?;
        written.push(p);
    }

    if let (Signal::Force, Some(period), Some(tr)) = (signal, period, &analysis.trajectory) {
        // The last three periods before the moving average's truncated edge: the loop the gate
        // is on now.
        let (from, to) = (v1 - 3.0 * period, v1);
        let inside = |t: f64| t >= from && t <= to;
        // The model's restoring force at rest: what the velocity-dependent part leaves out.
        let restoring = |t: f64, y: f64| model.residual(t, y, 0.0, c);
        let mut measured = (Vec::new(), Vec::new(), Vec::new());
        for (s, (&t, &f)) in tr.iter().zip(series.t.iter().zip(&series.y)) {
            if inside(t) {
                measured.0.push(s[0]);
                measured.1.push(f);
                measured.2.push(f - restoring(t, s[0]));
            }
        }
        let mut modelled = (Vec::new(), Vec::new(), Vec::new());
        for (&t, (&y, &yd)) in mt.iter().zip(my.iter().zip(&myd)) {
            if inside(t) {
                let f = model.residual(t, y, yd, c);
                modelled.0.push(y);
                modelled.1.push(f);
                modelled.2.push(f - restoring(t, y));
            }
        }
        if !modelled.0.is_empty() && !measured.0.is_empty() {
            let p = file("hysteresis");
            hysteresis(
                &p,
                (&measured.0, &measured.1),
                (&modelled.0, &modelled.1),
                (&measured.0, &measured.2),
                (&modelled.0, &modelled.2),
                units,
            )?;
            written.push(p);
        }
    }

    if !analysis.damping.zeta_eq_curve.is_empty() {
        let p = file("damping");
        let unit = match signal {
            Signal::Force => units.force.as_deref(),
            Signal::Displacement => units.signal.as_deref(),
        };
        damping_curve(&p, &analysis.damping.zeta_eq_curve, unit)?;
        written.push(p);
    }

    let p = file("convergence");
    let polished = (best.refine_evaluations > 0).then_some(best.train_mae);
    let cost_unit = match signal {
        Signal::Force => units.force.as_deref(),
        Signal::Displacement => units.signal.as_deref(),
    };
    convergence(&p, &best.history, polished, cost_unit)?;
    written.push(p);
    Ok(written)
}

/// The stiffness of a force model: the coefficient of `y` in its residual, `F(y=1) - F(y=0)`
/// at rest (`None` when it is not positive).
fn stiffness(model: &Model, c: &[f64]) -> Option<f64> {
    let k = model.residual(0.0, 1.0, 0.0, c) - model.residual(0.0, 0.0, 0.0, c);
    (k.is_finite() && k > 0.0).then_some(k)
}

/// `dy/dt` by central differences (one-sided at the ends); empty for fewer than two samples.
fn central_difference(t: &[f64], y: &[f64]) -> Vec<f64> {
    let n = y.len().min(t.len());
    if n < 2 {
        return Vec::new();
    }
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            (y[b] - y[a]) / (t[b] - t[a])
        })
        .collect()
}
