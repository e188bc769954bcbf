//! `gatewatch bench seed-cases`: the chapter's protocol on its seed cases, beside its numbers.
//!
//! Per case: the data are generated ([`crate::cases`]), split once with a fixed seed (the
//! chapter's pseudo-code splits before its run loop), and identified in `runs` independent runs
//! with DE seeds `seed, seed + 1, ...` at the chapter's population and generations, one thread.

use crate::cases::{CaseError, SeedCase};
use crate::data::TimeSeries;
use crate::identify::{self, Config, IdentifyError, Initial, Protocol, Search};
use crate::ode::Method;
use serde::Serialize;

/// Options of a benchmark.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchOptions {
    /// Runs per case (chapter: 25).
    pub runs: usize,
    /// Seed of the first run.
    pub seed: u64,
    /// Seed of the train/test split.
    pub split_seed: u64,
    /// Fitness solver.
    pub solver: Method,
    /// Fitness tolerance (chapter: 1e-3).
    pub rtol: f64,
    /// Levenberg-Marquardt polish on or off.
    pub refine: bool,
    /// DE restart on stagnation on or off.
    pub restart: bool,
    /// Gaussian noise added to the data, as a fraction of its standard deviation (0: none).
    /// Errors are then measured against the noise-free truth.
    pub noise: f64,
    /// Bias half of the initial population with the spectrum (through the analysis pipeline).
    pub fft_bias: bool,
    /// Trials integrated in lockstep by the fitness (1, 4 or 8; results are identical).
    pub lanes: usize,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            runs: 25,
            seed: 1,
            split_seed: 1,
            solver: Method::Dopri5,
            rtol: 1e-3,
            refine: true,
            restart: true,
            noise: 0.0,
            fft_bias: false,
            lanes: crate::identify::LANES,
        }
    }
}

/// Results of one case.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaseReport {
    /// Case id.
    pub id: &'static str,
    /// Number of unknowns `#C`.
    pub unknowns: usize,
    /// Runs made.
    pub runs: usize,
    /// Mean test NMAE.
    pub mean_nmae: f64,
    /// Standard deviation of the test NMAE.
    pub std_nmae: f64,
    /// Smallest test NMAE.
    pub min_nmae: f64,
    /// Median test NMAE.
    pub median_nmae: f64,
    /// Runs with test NMAE below 0.01.
    pub successes: usize,
    /// Median wall time per run, seconds.
    pub median_seconds: f64,
    /// Mean objective evaluations per run.
    pub evaluations_per_run: f64,
    /// The chapter's evaluations per run: `NP + G * (NP + 1)`.
    pub chapter_evaluations: usize,
    /// The chapter's mean NMAE.
    pub chapter_mean: Option<f64>,
    /// The chapter's std NMAE.
    pub chapter_std: Option<f64>,
    /// The chapter's remark.
    pub chapter_note: &'static str,
    /// Median over the runs of the largest relative coefficient error against the truth (both
    /// normalised when the structure is scale-free, see [`identify::Identification::scale_groups`]).
    pub median_coefficient_error: f64,
}

/// Why a benchmark failed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A case could not be generated.
    #[error(transparent)]
    Case(#[from] CaseError),
    /// The identification refused its settings.
    #[error("case {id}: {error}")]
    Identify {
        id: &'static str,
        /// The refusal; not a `source`, since the message holds it (`{:#}` printed it twice).
        error: IdentifyError,
    },
    /// The analysis pipeline failed.
    #[error("case {id}: {reason}")]
    Analysis { id: &'static str, reason: String },
}

/// Runs one case. `progress(run, generation)` is called after each generation.
pub fn run_case(
    case: &SeedCase,
    opts: &BenchOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<CaseReport, BenchError> {
    let clean = case.generate()?;
    let model = case.compiled()?;
    let data = if opts.noise > 0.0 {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let n = clean.len() as f64;
        let mean = clean.y.iter().sum::<f64>() / n;
        let std = (clean.y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed ^ 0x006e_6f69_7365);
        let y = clean
            .y
            .iter()
            .map(|v| {
                let z: f64 = StandardNormal.sample(&mut rng);
                v + opts.noise * std * z
            })
            .collect();
        TimeSeries {
            t: clean.t.clone(),
            y,
        }
    } else {
        clean.clone()
    };
    let config = Config {
        initial: if case.fit_initial {
            Initial::Fit
        } else {
            Initial::Known {
                y0: case.y0,
                v0: case.v0,
            }
        },
        search: Search {
            population: case.population,
            generations: case.generations,
            solver: opts.solver,
            rtol: opts.rtol,
            refine: opts.refine,
            parallel: false,
            lanes: opts.lanes,
            ..Search::default()
        },
        protocol: Protocol {
            runs: opts.runs,
            seed: opts.seed,
            split_seed: opts.split_seed,
            restart: opts.restart,
            ..Protocol::default()
        },
        ..Config::default()
    };
    let mut result = if opts.fft_bias {
        let series_options = crate::analysis::SeriesOptions {
            signal: crate::analysis::Signal::Displacement,
            identify: config.clone(),
            fft_bias: true,
            ..Default::default()
        };
        crate::analysis::analyze_series(&model, &data, &series_options, None, |r, g, _| {
            progress(r, g)
        })
        .map_err(|e| BenchError::Analysis {
            id: case.id,
            reason: e.to_string(),
        })?
        .identification
    } else {
        identify::identify(&model, &data, &config, |r, g, _| progress(r, g))
            .map_err(|error| BenchError::Identify { id: case.id, error })?
    };
    // Errors against the noise-free truth (identical to the reported ones without noise).
    for run in &mut result.runs {
        run.test_nmae = identify::predict(
            &model,
            &clean,
            &run.coefficients,
            run.initial,
            config.protocol.test_rtol,
            identify::Output::Displacement,
        )
        .and_then(|p| identify::nmae(result.test.iter().map(|&i| (p[i], clean.y[i]))));
    }
    result.summary = identify::summarize(
        result
            .runs
            .iter()
            .map(|r| r.test_nmae.unwrap_or(f64::INFINITY)),
    );
    // A scale-free structure (forced_linear) is compared after normalising both sides the same
    // way: its raw coefficients are one arbitrary point of a line through the truth.
    let truth = identify::normalize(&result.scale_groups, case.truth);
    let mut coefficient_errors: Vec<f64> = result
        .runs
        .iter()
        .map(|r| {
            result
                .normalized(&r.coefficients)
                .iter()
                .zip(&truth)
                .map(|(c, t)| {
                    if *t == 0.0 {
                        c.abs()
                    } else {
                        (c / t - 1.0).abs()
                    }
                })
                .fold(0.0, f64::max)
        })
        .collect();
    coefficient_errors.sort_by(f64::total_cmp);
    let median_coefficient_error = coefficient_errors[coefficient_errors.len() / 2];
    let mut seconds: Vec<f64> = result.runs.iter().map(|r| r.seconds).collect();
    seconds.sort_by(f64::total_cmp);
    let median_seconds = if seconds.len() % 2 == 1 {
        seconds[seconds.len() / 2]
    } else {
        0.5 * (seconds[seconds.len() / 2 - 1] + seconds[seconds.len() / 2])
    };
    Ok(CaseReport {
        id: case.id,
        unknowns: case.unknowns(),
        runs: result.runs.len(),
        mean_nmae: result.summary.mean,
        std_nmae: result.summary.std,
        min_nmae: result.summary.min,
        median_nmae: result.summary.median,
        successes: result
            .runs
            .iter()
            .filter(|r| r.test_nmae.is_some_and(|v| v < 0.01))
            .count(),
        median_seconds,
        evaluations_per_run: result
            .runs
            .iter()
            .map(|r| r.evaluations as f64)
            .sum::<f64>()
            / result.runs.len() as f64,
        chapter_evaluations: case.population + case.generations * (case.population + 1),
        chapter_mean: case.chapter.mean,
        chapter_std: case.chapter.std,
        chapter_note: case.chapter.note,
        median_coefficient_error,
    })
}

/// The comparison table, as Markdown.
pub fn table(reports: &[CaseReport]) -> String {
    let mut s = String::from(
        "| case | #C | mean NMAE | std NMAE | min NMAE | median NMAE | runs < 0.01 | median s/run | evals/run | median max coef. error | chapter mean (std) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in reports {
        let chapter = match (r.chapter_mean, r.chapter_std) {
            (Some(m), Some(sd)) => format!("{m:.3e} ({sd:.2e})"),
            (Some(m), None) => format!("{m:.3e}"),
            _ => "-".to_string(),
        };
        let note = if r.chapter_note.is_empty() {
            String::new()
        } else {
            format!(" {}", r.chapter_note)
        };
        s.push_str(&format!(
            "| {} | {} | {:.3e} | {:.2e} | {:.2e} | {:.2e} | {}/{} | {:.4} | {:.0} | {:.2e} | {}{} |\n",
            r.id,
            r.unknowns,
            r.mean_nmae,
            r.std_nmae,
            r.min_nmae,
            r.median_nmae,
            r.successes,
            r.runs,
            r.median_seconds,
            r.evaluations_per_run,
            r.median_coefficient_error,
            chapter,
            note
        ));
    }
    s
}

/// Options of `gatewatch bench gate-example`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GateExampleOptions {
    /// Runs; run `r` uses noise seed and DE seed `seed + r`.
    pub runs: usize,
    /// Seed of the first run.
    pub seed: u64,
    /// Measurement noise, fraction of the signal's standard deviation (chapter: 1 %).
    pub noise: f64,
    /// Linear drift of the force, N/s.
    pub drift: f64,
    /// DE population (the daemon's default).
    pub population: usize,
    /// DE generations (the daemon's default).
    pub generations: usize,
    /// FFT-biased initial population.
    pub fft_bias: bool,
}

/// One run of the gate example.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GateExampleRun {
    /// Seed of the noise and the DE.
    pub seed: u64,
    /// Identified mass, kg (truth 19.14).
    pub mass: f64,
    /// Identified linear damping, N s/m (truth -12.18).
    pub damping: f64,
    /// Identified cubic damping, N s^3/m^3 (truth 447.3).
    pub cubic: f64,
    /// Damping ratio at rest.
    pub zeta0: Option<f64>,
    /// The analysis's verdict.
    pub verdict: crate::analysis::Verdict,
    /// Whether mass and damping are within 2 % and zeta0 < 0.
    pub success: bool,
    /// Objective evaluations.
    pub evaluations: usize,
    /// Wall time of the analysis, seconds (one thread).
    pub seconds: f64,
}

/// The chapter's gate example (section 8.5) through the daemon's per-window analysis:
/// `19.14*ydd + (-12.18 + 447.3*yd^2)*yd + 81360*y = 0`, support force at 200 Hz for 10 s with
/// noise and drift, identified with `c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0`.
pub fn run_gate_example(opts: &GateExampleOptions) -> Result<Vec<GateExampleRun>, BenchError> {
    use crate::analysis::{AnalysisSettings, Analyzer, Signal, Verdict, WindowInput};
    use crate::simulate::{self, WorkedExampleOptions};
    let analyzer = Analyzer::new(AnalysisSettings {
        signal: Signal::Force,
        force_terms: Default::default(),
        stiffness: Some(simulate::EX_K),
        model: "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0".to_string(),
        params: vec![("k".to_string(), simulate::EX_K)],
        population: opts.population,
        generations: opts.generations,
        amplitude_limit: None,
        max_fit_nmae: 0.2,
        polish_rtol: crate::analysis::DEFAULT_POLISH_RTOL,
        polish_solver: crate::analysis::PolishSolver::default(),
        model_interval: crate::analysis::ModelInterval::default(),
        ssi_reference: crate::analysis::SsiReference::default(),
    })
    .map_err(|e| BenchError::Analysis {
        id: "gate_example",
        reason: e.to_string(),
    })?;
    (0..opts.runs)
        .map(|r| {
            let seed = opts.seed + r as u64;
            let ex = simulate::worked_example(&WorkedExampleOptions {
                noise_fraction: opts.noise,
                drift_per_s: opts.drift,
                seed,
                ..WorkedExampleOptions::default()
            });
            let input = WindowInput {
                t0: 0.0,
                rate_hz: ex.rate_hz,
                values: &ex.force,
                history: &[],
            };
            let a = if opts.fft_bias {
                analyzer.analyze(input, None, seed)
            } else {
                analyzer.analyze_unbiased(input, seed)
            }
            .map_err(|e| BenchError::Analysis {
                id: "gate_example",
                reason: e.to_string(),
            })?;
            let c = |i: usize| a.coefficients.get(i).map_or(f64::NAN, |c| c.1);
            let (mass, damping, cubic) = (c(0), c(1), c(2));
            let zeta0 = a.damping.zeta0;
            let success = (mass / simulate::EX_MASS - 1.0).abs() < 0.02
                && (damping / simulate::EX_C1 - 1.0).abs() < 0.02
                && zeta0.is_some_and(|z| z < 0.0);
            Ok(GateExampleRun {
                seed,
                mass,
                damping,
                cubic,
                zeta0,
                verdict: if a.damping.trusted {
                    a.damping.verdict
                } else {
                    Verdict::Unknown
                },
                success,
                evaluations: a.evaluations,
                seconds: a.seconds,
            })
        })
        .collect()
}
