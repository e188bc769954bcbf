//! `gatewatch identify` with several `--model`: each candidate identified on the same record
//! with the same settings and seeds, then ranked (`analysis::rank`: BIC, weights, the
//! accuracy/complexity front).

use super::identify::{series_for, Prepared};
use super::{input, progress_bar, CliError};
use crate::analysis::{self, CandidateFit, RankedCandidate, Signal};
use crate::identify::Initial;
use crate::model::Model;
use serde_json::json;
use std::io::Write;
use std::path::Path;

/// A fitted candidate's residuals, natural frequency (Hz) and residual sum of squares: what
/// the record's correlation factor is measured on.
type Residuals = (Vec<f64>, Option<f64>, f64);

/// Identifies every candidate and prints the ranking (a table, or one JSON object).
pub(super) fn run(
    equations: &[String],
    models: &[Model],
    p: &Prepared,
    json: bool,
    file: &Path,
) -> Result<(), CliError> {
    let per_model = (p.config.protocol.runs * p.config.search.generations) as u64;
    let bar = progress_bar(per_model * models.len() as u64, "identify");
    let mut fits = Vec::with_capacity(models.len());
    let mut noise: Vec<Option<Residuals>> = Vec::with_capacity(models.len());
    let mut failures = Vec::new();
    for (i, (eq, model)) in equations.iter().zip(models).enumerate() {
        let series = series_for(model, &p.series);
        let offset = per_model * i as u64;
        let generations = p.config.search.generations;
        let result = analysis::analyze_series(model, &series, &p.opts, None, |r, g, _| {
            bar.set_position(offset + (r * generations + g) as u64)
        });
        let fit = match result {
            Ok(a) if a.identification.best_run().train_integrated => {
                let fit = candidate(eq, model, &a, p);
                noise.push(a.prediction.as_ref().map(|pred| {
                    let residuals = a.data.y.iter().zip(pred).map(|(y, f)| y - f).collect();
                    let hz = a
                        .linearization
                        .omega0()
                        .map(|w| w / (2.0 * std::f64::consts::PI));
                    (residuals, hz, fit.rss)
                }));
                fit
            }
            Ok(_) => {
                failures.push((
                    eq.clone(),
                    "no trial of the identification integrated over the record".to_string(),
                ));
                noise.push(None);
                failed(eq, model)
            }
            Err(e) => {
                failures.push((eq.clone(), e.to_string()));
                noise.push(None);
                failed(eq, model)
            }
        };
        fits.push(fit);
    }
    bar.finish_and_clear();
    // One correlation factor for all: the residuals of the best fit, at its frequency, on the
    // record's grid (a record off its grid has no spectrum: counted as white).
    let rate = p.series.uniform_step().map(|dt| 1.0 / dt);
    let lambda = noise
        .iter()
        .flatten()
        .filter(|(_, _, rss)| rss.is_finite())
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .and_then(|(r, hz, _)| Some(analysis::correlation_factor(r, rate?, (*hz)?)))
        .unwrap_or(1.0);
    let ranked = analysis::rank(fits, lambda);
    if ranked.iter().all(|r| !r.bic.is_finite()) {
        let why: Vec<String> = failures
            .iter()
            .map(|(eq, e)| format!("'{eq}': {e}"))
            .collect();
        return Err(input(format!(
            "{}: no candidate could be fitted: {}",
            file.display(),
            why.join("; ")
        )));
    }
    let mut out = std::io::stdout().lock();
    if json {
        writeln!(out, "{}", ranking_json(&ranked, &failures, lambda))?;
    } else {
        write_ranking(&mut out, &ranked, &failures, lambda)?;
    }
    Ok(())
}

/// Free parameters: the coefficients less one per scale group (a scale-free structure fixes
/// one of each group's members), plus the initial conditions when they are estimated (fitted,
/// or a force signal's pre-run polished with the coefficients).
fn parameters(model: &Model, a: &analysis::SeriesAnalysis, p: &Prepared) -> usize {
    let initial = if p.signal == Signal::Force || matches!(p.config.initial, Initial::Fit) {
        2
    } else {
        0
    };
    model.n_coeffs() - a.identification.scale_groups.len().min(model.n_coeffs()) + initial
}

fn candidate(eq: &str, model: &Model, a: &analysis::SeriesAnalysis, p: &Prepared) -> CandidateFit {
    let (rss, samples) = match &a.prediction {
        Some(pred) => {
            let mut rss = 0.0;
            let mut n = 0;
            for (&y, &f) in a.data.y.iter().zip(pred) {
                rss += (y - f) * (y - f);
                n += 1;
            }
            (if rss.is_finite() { rss } else { f64::INFINITY }, n)
        }
        None => (f64::INFINITY, a.data.y.len()),
    };
    CandidateFit {
        equation: eq.to_string(),
        parameters: parameters(model, a, p),
        samples,
        rss,
        fit_nmae: a.damping.fit_nmae,
        test_nmae: a.identification.best_run().test_nmae,
        zeta0: a.linearization.zeta0(),
    }
}

fn failed(eq: &str, model: &Model) -> CandidateFit {
    CandidateFit {
        equation: eq.to_string(),
        parameters: model.n_coeffs(),
        samples: 0,
        rss: f64::INFINITY,
        fit_nmae: f64::INFINITY,
        test_nmae: None,
        zeta0: None,
    }
}

fn finite(x: f64) -> serde_json::Value {
    if x.is_finite() {
        json!(x)
    } else {
        serde_json::Value::Null
    }
}

fn ranking_json(
    ranked: &[RankedCandidate],
    failures: &[(String, String)],
    lambda: f64,
) -> serde_json::Value {
    let n = ranked.first().map_or(0, |r| r.fit.samples);
    let candidates: Vec<serde_json::Value> = ranked
        .iter()
        .map(|r| {
            let failure = failures
                .iter()
                .find(|(eq, _)| *eq == r.fit.equation)
                .map(|(_, e)| e.clone());
            json!({
                "equation": r.fit.equation,
                "parameters": r.fit.parameters,
                "samples": r.fit.samples,
                "rss": finite(r.fit.rss),
                "fit_nmae": finite(r.fit.fit_nmae),
                "test_nmae": r.fit.test_nmae,
                "zeta0": r.fit.zeta0,
                "aic": finite(r.aic),
                "bic": finite(r.bic),
                "delta_bic": finite(r.delta_bic),
                "weight": r.weight,
                "on_front": r.on_front,
                "failure": failure,
            })
        })
        .collect();
    json!({
        "ranked_by": "bic",
        "samples": n,
        "correlation_factor": lambda,
        "effective_samples": n as f64 / lambda,
        "best": ranked.first().map(|r| r.fit.equation.clone()),
        "candidates": candidates,
    })
}

fn write_ranking(
    out: &mut impl Write,
    ranked: &[RankedCandidate],
    failures: &[(String, String)],
    lambda: f64,
) -> std::io::Result<()> {
    let n = ranked.first().map_or(0, |r| r.fit.samples);
    writeln!(
        out,
        "Candidate equations ranked by BIC (lower is better): {n} samples; the residuals are \
         correlated at the gate's frequency by a factor {lambda:.1}, so they count as {:.0} \
         independent ones",
        n as f64 / lambda
    )?;
    writeln!(
        out,
        "{:>4}  {:>12}  {:>8}  {:>6}  {:>6}  {:>8}  {:>9}  {:>9}  {:>5}  equation",
        "rank", "BIC", "dBIC", "weight", "params", "fit NMAE", "test NMAE", "zeta0", "front"
    )?;
    for (i, r) in ranked.iter().enumerate() {
        let num = |x: f64, digits: usize| {
            if x.is_finite() {
                format!("{x:.digits$}")
            } else {
                "n/a".to_string()
            }
        };
        writeln!(
            out,
            "{:>4}  {:>12}  {:>8}  {:>6}  {:>6}  {:>8}  {:>9}  {:>9}  {:>5}  {}",
            i + 1,
            num(r.bic, 1),
            num(r.delta_bic, 1),
            format!("{:.3}", r.weight),
            r.fit.parameters,
            num(r.fit.fit_nmae, 4),
            r.fit
                .test_nmae
                .map_or("n/a".to_string(), |v| format!("{v:.4}")),
            r.fit
                .zeta0
                .map_or("n/a".to_string(), |z| format!("{:+.3} %", 100.0 * z)),
            if r.on_front { "*" } else { "" },
            r.fit.equation
        )?;
    }
    for (eq, e) in failures {
        writeln!(out, "not fitted: '{eq}': {e}")?;
    }
    writeln!(
        out,
        "front (*): no candidate with fewer coefficients fits as well (residual sums of squares \
         within {:.3} % count as equal), and none with as many ranks above it. A dBIC under about \
         10 does not decide; where the ranking and the front disagree, the record does not \
         either (docs/damping.md, \"Which equation\").",
        100.0 * analysis::FRONT_TIE
    )
}
