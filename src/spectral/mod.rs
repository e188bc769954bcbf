//! Model-free signal analysis of a gate window: pre-processing, dominant frequency, Hilbert
//! envelope growth rate, ambient (noise-driven) damping from an AR model, and a classification of
//! the window as self-excited or damped.
//!
//! These figures need no equation of motion; the analysis uses them to check the identified model
//! and as a fallback verdict. Everything here is plain numerics (no async, no metrics).
//!
//! # Pieces (one file each)
//! - `preprocess`: [`remove_moving_average`], [`detrend_linear`], [`hann_into`].
//! - `analyzer`: [`SpectralAnalyzer`], FFTs planned once per window length, with reused buffers;
//!   [`SpectralAnalyzer::dominant_frequency`] (Hann window + exact 3-point Hann interpolation),
//!   [`SpectralAnalyzer::envelope`] (analytic signal by FFT) and
//!   [`SpectralAnalyzer::growth_rate`] (least-squares slope of the log envelope).
//! - `ambient`: [`ambient_damping`], AR(p) least squares, pole to damping ratio, delta-method interval.
//! - `pool`: [`DampingPool`], a gate's consecutive ambient estimates combined until they hold
//!   enough cycles, flushed on a regime change.
//! - `relaxation`: [`envelope_relaxation`], `zeta0` of a limit cycle from the relaxation of the
//!   envelope's perturbations (stochastic averaging).
//! - `whittle`: the debiased Whittle fit of an OU spectrum through a known filter, behind the
//!   relaxation's experimental estimator ([`envelope_relaxation_whittle`]).
//! - `drift`: [`envelope_drift`], `zeta0` from the envelope's drift across the amplitudes a
//!   window visits (stochastic averaging; the end of a growth, a shrinking cycle).
//! - `classify`: [`classify`] and the options and result of
//!   [`SpectralAnalyzer::analyze_window`], the building blocks put together.

mod ambient;
mod analyzer;
mod classify;
mod drift;
mod pool;
mod preprocess;
mod relaxation;
mod ssi;
#[cfg(test)]
mod tests;
mod whittle;

pub use ambient::{ambient_damping, normal_quantile, AmbientDamping, ArOptions};
pub use analyzer::{GrowthOptions, GrowthRate, Peak, SpectralAnalyzer};
pub use classify::{
    classify, AmbientMethod, ClassifyOptions, Regime, WindowOptions, WindowSpectral,
};
pub use drift::{envelope_drift, DriftOptions, EnvelopeDrift};
pub use pool::{DampingPool, PoolLocation, PoolOptions, PooledEstimate, WindowEstimate};
pub use preprocess::{damping_from_growth, detrend_linear, hann, hann_into, remove_moving_average};
pub use relaxation::{
    envelope_relaxation, envelope_relaxation_whittle, EnvelopeRelaxation, RelaxationOptions,
    NOISE_BAND,
};
pub use ssi::{ssi_cov_damping, t_quantile, SsiError, SsiEstimate, SsiOptions};

/// Why a spectral computation could not be done.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpectralError {
    /// The slice length differs from the analyzer's planned length.
    #[error("signal has {got} samples, the analyzer was planned for {expected}")]
    Length {
        /// Planned length.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// Too few samples for the requested computation.
    #[error("too short: {0}")]
    TooShort(String),
    /// NaN or infinite samples.
    #[error("signal contains non-finite values")]
    NonFinite,
    /// Nothing usable in the signal (constant, no peak above the floor, no oscillatory pole...).
    #[error("no result: {0}")]
    NoResult(String),
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    Invalid(String),
}

/// `Err(NonFinite)` when any sample is NaN or infinite.
fn check_finite(x: &[f64]) -> Result<(), SpectralError> {
    if x.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SpectralError::NonFinite)
    }
}
