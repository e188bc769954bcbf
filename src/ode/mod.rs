//! ODE integrators for small fixed-size systems (`N` states, stack-allocated).
//!
//! Three methods, one calling convention ([`integrate`]):
//! - [`Method::Dopri5`]: Dormand-Prince 5(4), adaptive step, dense output onto the requested times;
//! - [`Method::Rk4`]: classical fixed-step Runge-Kutta on the sample grid, `Options::substeps` steps
//!   per sample interval;
//! - [`Method::Rosenbrock`]: a linearly implicit (stiff) method with error control.
//!
//! Nothing is allocated: stage vectors are `[f64; N]` arrays on the stack. Every call returns an
//! [`Outcome`] with how many requested times were reached, work statistics, and, when the
//! integration stopped early, a [`Failure`] that says why and where.
//!
//! # Which method
//!
//! - `Dopri5` for general use: 5th-order accuracy, 6 evaluations per step, output times cost
//!   nothing extra (continuous extension), so the step is chosen by the dynamics, not the
//!   sampling.
//! - `Rk4` when the sample grid is fine compared to the dynamics (the DE's usual case): no error
//!   estimate, no rejections, predictable cost `4 * substeps * (times.len() - 1)`.
//! - `Rosenbrock` (Rodas4) when the model may be stiff (large damping or stiffness
//!   coefficients): an explicit method then needs thousands of tiny steps where Rodas4 needs a
//!   few hundred.
//!
//! # Failures (all methods)
//!
//! - The state `y0` itself is checked first (`NonFinite`/`BlowUp` at `times[0]`, `reached = 0`).
//! - `BlowUp { t }`: `t` is the end of the first accepted step whose state has a component
//!   above `Options::bound`.
//! - `NonFinite { t }`: `t` is the last time at which the state was finite (the start of the
//!   step that could not be completed). The adaptive methods first treat a non-finite trial
//!   step as a rejection and shrink `h` by 5; they report `NonFinite` only if that persists
//!   down to the step-size floor.
//! - `StepSizeUnderflow { t, h }`: `h` fell below `16 * eps * max(|times[0]|, |t_end|)`. The
//!   adaptive methods also report it at `times[0]` when `t_end - times[0]` is not positive and
//!   finite (a caller bug such as a NaN time), instead of stepping on NaN.
//! - `StepLimit { t }`: the next step would exceed `Options::max_steps` (accepted + rejected),
//!   so `accepted + rejected == max_steps` on return.
//! - `WorkLimit { t }`: the next step would exceed `Options::max_rhs_evals`, so
//!   `Stats::rhs_evals <= max_rhs_evals` always.
//! - `Stopped { t }`: `t` is the requested time whose observation returned `Break` (it counts
//!   in `reached`).
//!
//! Exact evaluation counts are documented in each method's module and checked by the tests.

use std::ops::ControlFlow;

pub use lanes::LaneSystem;

/// A first-order system `dy/dt = f(t, y)` with `N` states.
pub trait System<const N: usize> {
    /// Writes `f(t, y)` into `dy`.
    fn rhs(&self, t: f64, y: &[f64; N], dy: &mut [f64; N]);

    /// Writes the Jacobian `jac[i][j] = d f_i / d y_j` into `jac`. The default uses forward
    /// differences: `N + 1` right-hand-side evaluations (`f(t, y)` and one per column), which
    /// the integrator counts in [`Stats::rhs_evals`] through [`System::jacobian_cost`].
    /// A system that overrides this with an analytic Jacobian should override
    /// [`System::jacobian_cost`] too.
    fn jacobian(&self, t: f64, y: &[f64; N], jac: &mut [[f64; N]; N]) {
        let mut f0 = [0.0; N];
        self.rhs(t, y, &mut f0);
        let mut yp = *y;
        let mut fp = [0.0; N];
        for j in 0..N {
            let h = f64::EPSILON.sqrt() * y[j].abs().max(1.0);
            yp[j] = y[j] + h;
            self.rhs(t, &yp, &mut fp);
            for i in 0..N {
                jac[i][j] = (fp[i] - f0[i]) / h;
            }
            yp[j] = y[j];
        }
    }

    /// How many right-hand-side evaluations one call of [`System::jacobian`] costs, for the
    /// work statistics and [`Options::max_rhs_evals`]: `N + 1` for the default finite
    /// differences; return 0 (or the true cost) when `jacobian` is overridden.
    fn jacobian_cost(&self) -> usize {
        N + 1
    }

    /// Whether `f` does not depend on `t`. The Rosenbrock method needs `df/dt` and takes it by
    /// a forward difference (one extra evaluation per Jacobian) unless this returns `true`.
    /// The default `false` is always correct, only slower.
    fn is_autonomous(&self) -> bool {
        false
    }
}

/// Which integration scheme to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Dormand-Prince 5(4), adaptive (MATLAB's ode45), Hairer's `DOPRI5` step control (PI,
    /// beta = 0.04) and 4th-order dense output. Work: `rhs_evals = 1 + [initial step chosen
    /// automatically] + 6 * (accepted + rejected)`.
    Dopri5,
    /// Classical RK4 with `Options::substeps` fixed steps between consecutive output times.
    /// Work: `rhs_evals = 4 * accepted`, no rejections.
    Rk4,
    /// Rosenbrock (linearly implicit) adaptive method for stiff problems (cf. MATLAB's ode15s):
    /// Hairer & Wanner's Rodas4, order 4(3), L-stable, with 3rd-order dense output. Work:
    /// `rhs_evals = [initial step chosen automatically] + jacobian_evals * (1 +
    /// System::jacobian_cost() + [not System::is_autonomous()]) + 5 * (accepted + rejected)`,
    /// one LU per step attempt, one Jacobian per accepted step.
    #[serde(rename = "stiff")]
    Rosenbrock,
}

impl Method {
    /// The name used on the command line and in JSON (`dopri5`, `rk4`, `stiff`).
    pub fn name(self) -> &'static str {
        match self {
            Method::Dopri5 => "dopri5",
            Method::Rk4 => "rk4",
            Method::Rosenbrock => "stiff",
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "dopri5" | "ode45" => Ok(Method::Dopri5),
            "rk4" => Ok(Method::Rk4),
            "stiff" | "rosenbrock" => Ok(Method::Rosenbrock),
            other => Err(format!(
                "unknown solver '{other}': expected dopri5, rk4 or stiff"
            )),
        }
    }
}

/// Integration settings. Every limit exists so that one pathological system (a chattering
/// `sign()` term, extreme stiffness, a blow-up) costs a bounded amount of work.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Relative tolerance of the adaptive methods.
    pub rtol: f64,
    /// Absolute tolerance of the adaptive methods.
    pub atol: f64,
    /// Fixed RK4 steps per interval between consecutive output times (RK4 only, >= 1).
    pub substeps: usize,
    /// Maximum number of steps (accepted + rejected) before [`Failure::StepLimit`].
    pub max_steps: usize,
    /// Maximum number of right-hand-side evaluations before [`Failure::WorkLimit`].
    pub max_rhs_evals: usize,
    /// A state component whose magnitude exceeds this is a blow-up ([`Failure::BlowUp`]).
    pub bound: f64,
    /// Initial step; `None` chooses one automatically (Hairer's algorithm).
    pub initial_step: Option<f64>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            rtol: 1e-3,
            atol: 1e-6,
            substeps: 2,
            max_steps: 100_000,
            max_rhs_evals: 1_000_000,
            bound: 1e12,
            initial_step: None,
        }
    }
}

impl Options {
    /// Checks the settings the integrators rely on: `rtol > 0` and `atol > 0` finite (with
    /// `atol = 0` a state component passing through zero makes the error scale vanish),
    /// `substeps >= 1`, `max_steps >= 1`, `max_rhs_evals >= 1`, `bound > 0` (infinity allowed)
    /// and an initial step, if given, positive and finite. The integrators do not panic on
    /// invalid options (they treat `substeps = 0` as 1 and ignore an unusable initial step),
    /// but their results are only meaningful for options that pass this check.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.rtol.is_finite() && self.rtol > 0.0) {
            return Err(format!(
                "rtol must be positive and finite, got {}",
                self.rtol
            ));
        }
        if !(self.atol.is_finite() && self.atol > 0.0) {
            return Err(format!(
                "atol must be positive and finite, got {}",
                self.atol
            ));
        }
        if self.substeps == 0 {
            return Err("substeps must be at least 1".into());
        }
        if self.max_steps == 0 {
            return Err("max_steps must be at least 1".into());
        }
        if self.max_rhs_evals == 0 {
            return Err("max_rhs_evals must be at least 1".into());
        }
        if self.bound.is_nan() || self.bound <= 0.0 {
            return Err(format!("bound must be positive, got {}", self.bound));
        }
        if let Some(h) = self.initial_step {
            if !(h.is_finite() && h > 0.0) {
                return Err(format!("initial_step must be positive and finite, got {h}"));
            }
        }
        Ok(())
    }
}

/// Work done by one integration.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Stats {
    /// Right-hand-side evaluations, including those spent on finite-difference Jacobians.
    pub rhs_evals: usize,
    /// Jacobian evaluations (Rosenbrock only).
    pub jacobian_evals: usize,
    /// LU decompositions (Rosenbrock only).
    pub lu_decompositions: usize,
    /// Accepted steps.
    pub accepted: usize,
    /// Rejected steps (error test failed or non-finite trial).
    pub rejected: usize,
}

/// Why an integration stopped before the last requested time.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Failure {
    /// The step size fell below what floating point can resolve at `t`.
    #[error("step size underflow at t = {t} (h = {h:e})")]
    StepSizeUnderflow { t: f64, h: f64 },
    /// The state or its derivative became NaN or infinite at `t`.
    #[error("non-finite state at t = {t}")]
    NonFinite { t: f64 },
    /// A state component exceeded `Options::bound` at `t`.
    #[error("solution exceeded the bound at t = {t} (|y| = {value:e})")]
    BlowUp { t: f64, value: f64 },
    /// `Options::max_steps` was reached at `t`.
    #[error("step limit reached at t = {t}")]
    StepLimit { t: f64 },
    /// `Options::max_rhs_evals` was reached at `t`.
    #[error("work limit (right-hand-side evaluations) reached at t = {t}")]
    WorkLimit { t: f64 },
    /// The observer asked to stop at `t`.
    #[error("stopped by the caller at t = {t}")]
    Stopped { t: f64 },
}

/// The result of [`integrate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Number of requested times whose state was delivered to the observer (`times[0]`, the
    /// initial condition, counts).
    pub reached: usize,
    /// Work statistics.
    pub stats: Stats,
    /// `None` when every requested time was reached.
    pub failure: Option<Failure>,
}

impl Outcome {
    /// Whether every requested time was reached.
    pub fn is_complete(&self) -> bool {
        self.failure.is_none()
    }
}

mod dopri5;
mod dopri5_lanes;
pub mod lanes;
mod rk4;
mod rosenbrock;
mod util;

/// Integrates `sys` from `times[0]`, where the state is `y0`, and hands the state at every
/// requested time to `observe(index, &state)`, in order, starting with index 0 (`y0` itself).
///
/// `times` must be strictly increasing (the caller guarantees it; an empty slice returns at once).
/// `observe` returning `ControlFlow::Break(())` stops the integration with [`Failure::Stopped`];
/// a fitness function uses this to abandon a candidate that can no longer win.
pub fn integrate<const N: usize, S, F>(
    method: Method,
    sys: &S,
    y0: [f64; N],
    times: &[f64],
    opts: &Options,
    observe: F,
) -> Outcome
where
    S: System<N> + ?Sized,
    F: FnMut(usize, &[f64; N]) -> ControlFlow<()>,
{
    match method {
        Method::Dopri5 => dopri5::integrate(sys, y0, times, opts, observe),
        Method::Rk4 => rk4::integrate(sys, y0, times, opts, observe),
        Method::Rosenbrock => rosenbrock::integrate(sys, y0, times, opts, observe),
    }
}
