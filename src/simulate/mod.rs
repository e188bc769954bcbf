//! Synthetic gate signals: a noise-driven single-degree-of-freedom gate whose damping follows a
//! scenario, and the chapter's worked example (section 8.5, equation 8.8).
//!
//! The gate model is
//!
//! ```text
//! m*ydd + c(t)*yd + c3*yd^3 + k*y = f(t),      c(t) = 2*zeta(t)*sqrt(k*m)
//! ```
//!
//! * `zeta(t)` follows a [`ZetaSchedule`]: constant, a linear ramp, a piecewise-linear table or an
//!   arbitrary closure. A negative `zeta` means self-excitation (negative damping).
//! * `c3 > 0` is a cubic velocity damping: negligible at ambient amplitudes, it makes a
//!   self-excited growth saturate into a limit cycle whose displacement amplitude is, by harmonic
//!   balance, `Y = sqrt(-4*c/(3*c3*omega^2))` (see [`GateParams::limit_cycle_force_amplitude`]).
//! * `f(t)` is turbulent forcing: one independent Gaussian value `N(0, forcing_std^2)` per output
//!   sample, **linearly interpolated** between samples. This keeps the force continuous (so RK4
//!   sees a smooth right-hand side within a sample and converges at its design order), and makes
//!   the forcing band-limited to roughly the sample rate: its power spectral density is flat to
//!   within a few percent below `rate_hz/10`, then falls off as `sinc^4`. At low frequency the
//!   equivalent two-sided force PSD is `forcing_std^2 / rate_hz / (2 pi)` per rad/s, so the
//!   stationary force response of a linear gate has standard deviation
//!   `forcing_std * sqrt(k / (2 c rate_hz))` (about 2.9 N for the defaults at `zeta = 1 %`).
//!
//! Integration is a fixed-step classical RK4 with `substeps` steps per output sample. The
//! simulator is a stream: [`GateSimulator::next_sample`] / [`GateSimulator::fill`] produce samples
//! one at a time with no allocation, so a daemon can run it indefinitely, and the random draws are
//! made per sample in a fixed order, so a seed gives the same samples whatever the chunk sizes.
//!
//! Output sample `i` is taken at `t = i / rate_hz`; sample 0 is the initial state.
//!
//! # Layout
//! - `schedule`: [`ZetaSchedule`] and the predefined [`Scenario`]s.
//! - `gate`: [`GateParams`] and the streaming [`GateSimulator`].
//! - `scenarios`: the named scenarios an operator meets ([`ScenarioName`], with the true
//!   `zeta0(t)` beside the signal), the gate presets ([`GatePreset`]) and [`NoiseLevel`].
//! - `faults`: [`SensorFaults`] (spikes, dropouts, clipping, a DC offset).
//! - `impacts`: [`Impacts`] (blows on the gate: debris, ice, a vessel).
//! - `worked_example`: the chapter's worked example, [`worked_example`].

mod faults;
mod gate;
mod impacts;
mod scenarios;
mod schedule;
#[cfg(test)]
mod tests;
mod worked_example;

pub use faults::SensorFaults;
pub use gate::{GateParams, GateSimulator};
pub use impacts::Impacts;
pub use scenarios::{GatePreset, NoiseLevel, ScenarioDef, ScenarioName};
pub use schedule::{Scenario, ZetaSchedule};
pub use worked_example::{
    worked_example, WorkedExample, WorkedExampleOptions, EX_C1, EX_C3, EX_K, EX_MASS, EX_V0, EX_Y0,
};

/// What the simulator outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Output {
    /// Support force `F = k*y`, N.
    #[default]
    Force,
    /// Displacement `y`, m.
    Displacement,
}
