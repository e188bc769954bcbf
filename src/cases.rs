//! The chapter's seed cases (its Table 8.1 and equation 8.5), as fixed in the project's
//! `seed-cases.md`: model structures, true coefficients, initial conditions, spans and sample
//! counts. The data are generated here, in code, by integrating the true ODE with a relative
//! tolerance of 1e-11; nothing is read from files at run time.

use crate::data::TimeSeries;
use crate::model::{Bound, Model, ModelError};
use crate::ode::{self, Method, Options};
use serde::Serialize;
use std::ops::ControlFlow;

/// The chapter's reported result for a case.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChapterResult {
    /// Mean test NMAE over its runs (`None`: reported only as a figure).
    pub mean: Option<f64>,
    /// Standard deviation.
    pub std: Option<f64>,
    /// What the table says besides the numbers.
    pub note: &'static str,
}

/// One benchmark case.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SeedCase {
    /// Identifier, e.g. `van_der_pol_2`.
    pub id: &'static str,
    /// Model structure to identify (the model language).
    pub model: &'static str,
    /// True coefficients, which generate the data.
    pub truth: &'static [f64],
    /// `y(0)`.
    pub y0: f64,
    /// `yd(0)`.
    pub v0: f64,
    /// Whether the initial conditions are identified too (otherwise known).
    pub fit_initial: bool,
    /// End time `T`; samples are uniform on `[0, T]`.
    pub t_end: f64,
    /// Number of samples.
    pub n: usize,
    /// The chapter's population size for this case.
    pub population: usize,
    /// The chapter's generations for this case.
    pub generations: usize,
    /// The chapter's result.
    pub chapter: ChapterResult,
}

const FORCED: &str = "c1*ydd + c2*yd + c3*y = c4*sin(c5*t)";
const POLY_DAMPING: &str = "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0";

/// All cases, in the order of `seed-cases.md`.
pub const CASES: &[SeedCase] = &[
    SeedCase {
        id: "forced_linear",
        model: FORCED,
        truth: &[2.5, 0.35, 0.3, 3.0, 2.2],
        y0: 0.0,
        v0: 0.25,
        fit_initial: false,
        t_end: 40.0,
        n: 465,
        population: 80,
        generations: 250,
        chapter: ChapterResult {
            mean: Some(39.2e-3),
            std: Some(69.5e-3),
            note: "",
        },
    },
    SeedCase {
        id: "forced_linear_ic",
        model: FORCED,
        truth: &[2.5, 0.35, 0.3, 3.0, 2.2],
        y0: 0.0,
        v0: 0.25,
        fit_initial: true,
        t_end: 40.0,
        n: 465,
        population: 80,
        generations: 250,
        chapter: ChapterResult {
            mean: None,
            std: None,
            note: "worse than forced_linear (Fig. 8.6)",
        },
    },
    SeedCase {
        id: "negative_damping_1",
        model: "ydd + c1*yd + y = 0",
        truth: &[-0.1434],
        y0: 0.1,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(3.44e-3),
            std: Some(0.0),
            note: "",
        },
    },
    SeedCase {
        id: "negative_damping_2",
        model: "ydd + (c1 + c2*y)*yd + y = 0",
        truth: &[-0.1434, 0.0],
        y0: 0.1,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(3.07e-3),
            std: Some(0.0),
            note: "",
        },
    },
    SeedCase {
        id: "negative_damping_3",
        model: POLY_DAMPING,
        truth: &[-0.1434, 0.0, 0.0],
        y0: 0.1,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(3.23e-3),
            std: Some(1.88e-3),
            note: "3 runs only",
        },
    },
    SeedCase {
        id: "nonlinear_damping",
        model: POLY_DAMPING,
        truth: &[-0.450, 2.728, 1.903],
        y0: 0.1,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(287e-3),
            std: Some(373e-3),
            note: "8 of 25 runs failed",
        },
    },
    SeedCase {
        id: "van_der_pol_2",
        model: "ydd + (c1 + c2*y^2)*yd + y = 0",
        truth: &[-1.2218, 1.2218],
        y0: 0.5,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(3.13e-3),
            std: Some(0.42e-3),
            note: "",
        },
    },
    SeedCase {
        id: "van_der_pol_3",
        model: POLY_DAMPING,
        truth: &[-1.2218, 0.0, 1.2218],
        y0: 0.5,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(3.26e-3),
            std: Some(0.82e-3),
            note: "",
        },
    },
    SeedCase {
        id: "nonlinear_mass",
        model: "(c1 + c2*y + c3*y^2)*ydd + y = 0",
        truth: &[1.7120, 1.4815, 0.4903],
        y0: 1.0,
        v0: 0.0,
        fit_initial: false,
        t_end: 30.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(3.28e-3),
            std: Some(0.078e-3),
            note: "",
        },
    },
    SeedCase {
        id: "mathieu",
        model: "ydd + (c1 + c2*sin(c3*t))*y = 0",
        truth: &[0.25, 0.34, 2.18],
        y0: 1.0,
        v0: 0.0,
        fit_initial: false,
        t_end: 40.0,
        n: 500,
        population: 50,
        generations: 120,
        chapter: ChapterResult {
            mean: Some(70.8e-3),
            std: Some(25.9e-3),
            note: "parametric excitation",
        },
    },
];

/// The case with this id.
pub fn find(id: &str) -> Option<&'static SeedCase> {
    CASES.iter().find(|c| c.id == id)
}

/// Why a case could not be generated (a defect of the definitions, never of user input).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CaseError {
    /// The model does not compile.
    #[error("case {id}: {source}")]
    Model {
        id: &'static str,
        source: ModelError,
    },
    /// The reference integration failed.
    #[error("case {id}: reference integration failed: {reason}")]
    Integration { id: &'static str, reason: String },
}

impl SeedCase {
    /// The compiled model structure.
    pub fn compiled(&self) -> Result<Model, CaseError> {
        Model::parse(self.model, &[]).map_err(|source| CaseError::Model {
            id: self.id,
            source,
        })
    }

    /// Number of unknowns `#C` (coefficients, plus two when the initial conditions are fitted).
    pub fn unknowns(&self) -> usize {
        self.truth.len() + if self.fit_initial { 2 } else { 0 }
    }

    /// The sample times: `n` points uniform on `[0, T]`.
    pub fn times(&self) -> Vec<f64> {
        let h = self.t_end / (self.n - 1) as f64;
        (0..self.n).map(|i| i as f64 * h).collect()
    }

    /// The noise-free data, integrated with Dormand-Prince at rtol 1e-11.
    pub fn generate(&self) -> Result<TimeSeries, CaseError> {
        let model = self.compiled()?;
        let t = self.times();
        let mut y = vec![0.0; t.len()];
        let opts = Options {
            rtol: 1e-11,
            atol: 1e-14,
            max_steps: 10_000_000,
            max_rhs_evals: 100_000_000,
            ..Options::default()
        };
        let sys = Bound {
            model: &model,
            coeffs: self.truth,
        };
        let o = ode::integrate(
            Method::Dopri5,
            &sys,
            [self.y0, self.v0],
            &t,
            &opts,
            |i, s| {
                y[i] = s[0];
                ControlFlow::Continue(())
            },
        );
        if let Some(f) = o.failure {
            return Err(CaseError::Integration {
                id: self.id,
                reason: f.to_string(),
            });
        }
        Ok(TimeSeries { t, y })
    }
}
