//! The identification problem: a model, the data, what the data are, the initial conditions and
//! the scales of the unknowns.

use super::IdentifyError;
use crate::data::TimeSeries;
use crate::model::Model;
use serde::Serialize;

/// What is identified from what. Built with [`Problem::new`] and the `with_*` methods, each of
/// which checks its value, so a `Problem` is always valid.
///
/// ```
/// use gatewatch::data::TimeSeries;
/// use gatewatch::identify::{Initial, Problem};
/// use gatewatch::model::Model;
///
/// let model = Model::parse("ydd + c1*yd + y = 0", &[]).unwrap();
/// let t: Vec<f64> = (0..100).map(|i| 0.1 * i as f64).collect();
/// let y = t.iter().map(|t| (-0.05 * t).exp() * t.cos()).collect();
/// let series = TimeSeries::new(t, y).unwrap();
/// let problem = Problem::new(&model, &series)
///     .unwrap()
///     .with_initial(Initial::Known { y0: 1.0, v0: -0.05 })
///     .unwrap();
/// assert!(Problem::new(&model, &series).unwrap().with_y_scale(-1.0).is_err());
/// # let _ = problem;
/// ```
#[derive(Debug, Clone)]
pub struct Problem<'a> {
    pub(super) model: &'a Model,
    pub(super) series: &'a TimeSeries,
    pub(super) initial: Initial,
    pub(super) output: Output,
    /// Physical value per unit of each DE coordinate (empty: 1).
    pub(super) scales: Vec<f64>,
    /// Magnitude of the displacement (`None`: the data's).
    pub(super) y_scale: Option<f64>,
    /// Scales of `(y0, v0)` when the polish may adjust known initial conditions.
    pub(super) polish_initial: Option<(f64, f64)>,
}

/// Known initial conditions must be finite.
pub(super) fn check_initial(initial: Initial) -> Result<(), IdentifyError> {
    match initial {
        Initial::Known { y0, v0 } if !(y0.is_finite() && v0.is_finite()) => {
            Err(IdentifyError::Invalid {
                field: "initial",
                reason: format!("y0 and v0 must be finite numbers, got {y0} and {v0}"),
            })
        }
        _ => Ok(()),
    }
}

fn positive(field: &'static str, v: f64) -> Result<(), IdentifyError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(IdentifyError::Invalid {
            field,
            reason: format!("must be a positive number, got {v}"),
        })
    }
}

impl<'a> Problem<'a> {
    /// Identify `model`'s coefficients from `series` (displacement data, initial conditions
    /// from the data, unit scales). The model must have unknowns.
    pub fn new(model: &'a Model, series: &'a TimeSeries) -> Result<Self, IdentifyError> {
        if model.n_coeffs() == 0 {
            return Err(IdentifyError::NoUnknowns);
        }
        Ok(Problem {
            model,
            series,
            initial: Initial::FromData,
            output: Output::Displacement,
            scales: Vec::new(),
            y_scale: None,
            polish_initial: None,
        })
    }

    /// With these initial conditions (known ones must be finite).
    pub fn with_initial(mut self, initial: Initial) -> Result<Self, IdentifyError> {
        check_initial(initial)?;
        self.initial = initial;
        Ok(self)
    }

    /// With data that are `output`.
    pub fn with_output(mut self, output: Output) -> Self {
        self.output = output;
        self
    }

    /// With the physical value per unit of each DE coordinate: empty (all 1), or one positive
    /// number per coordinate (the coefficients, then `y0`, `v0` when they are fitted). Set the
    /// initial conditions first.
    pub fn with_scales(mut self, scales: Vec<f64>) -> Result<Self, IdentifyError> {
        let d = self.dimension();
        if !scales.is_empty() && scales.len() != d {
            return Err(IdentifyError::Invalid {
                field: "scales",
                reason: format!(
                    "must have one entry per unknown ({d}), got {}",
                    scales.len()
                ),
            });
        }
        for &s in &scales {
            if !(s.is_finite() && s != 0.0) {
                return Err(IdentifyError::Invalid {
                    field: "scales",
                    reason: format!("must be finite and non-zero, got {s}"),
                });
            }
        }
        self.scales = scales;
        Ok(self)
    }

    /// With the displacement's magnitude (positive), for tolerances and bounds.
    pub fn with_y_scale(mut self, y_scale: f64) -> Result<Self, IdentifyError> {
        positive("y_scale", y_scale)?;
        self.y_scale = Some(y_scale);
        Ok(self)
    }

    /// Let the polish adjust known initial conditions too, with these (positive) scales of
    /// `(y0, v0)`.
    pub fn with_polish_initial(mut self, (y, v): (f64, f64)) -> Result<Self, IdentifyError> {
        positive("polish_initial", y)?;
        positive("polish_initial", v)?;
        self.polish_initial = Some((y, v));
        Ok(self)
    }

    /// The model.
    pub fn model(&self) -> &'a Model {
        self.model
    }

    /// The data.
    pub fn series(&self) -> &'a TimeSeries {
        self.series
    }

    /// What the data are.
    pub fn output(&self) -> Output {
        self.output
    }

    /// The initial conditions as configured.
    pub fn initial(&self) -> Initial {
        self.initial
    }

    /// Unknowns of the search: the coefficients, plus `y0` and `v0` when fitted.
    pub fn dimension(&self) -> usize {
        self.model.n_coeffs()
            + if matches!(self.initial, Initial::Fit) {
                2
            } else {
                0
            }
    }
}

/// Where the initial conditions `y(t0)`, `yd(t0)` come from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Initial {
    /// Given by the caller (finite).
    Known {
        /// `y(t0)`.
        y0: f64,
        /// `yd(t0)`.
        v0: f64,
    },
    /// `y0` is the first sample; `v0` the slope at `t0` of a least-squares quadratic through the
    /// first samples (up to 7).
    #[default]
    FromData,
    /// Identified as two extra unknowns after the coefficients.
    Fit,
}

/// What the fitness compares with the data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Output {
    /// The displacement `y` (section 8.4).
    #[default]
    Displacement,
    /// The support force `R(t, y, yd)`: everything in `M*ydd + R = 0` but the inertia term,
    /// i.e. the damping force plus the stiffness force (section 8.5, equation 8.7).
    Force,
    /// The restoring force `R(t, y, 0)`: the terms of `R` without `yd`, the stiffness force
    /// alone. A load cell in series with the gate's spring measures this when the damping
    /// (the flow's, which drives a self-excitation) acts on the gate's body, not through the
    /// support. The damping then shows only through the motion, as in the displacement.
    #[serde(rename = "restoring-force")]
    RestoringForce,
}

impl Output {
    /// Whether the output is a force (`R` or its restoring part), not the displacement.
    pub fn is_force(self) -> bool {
        !matches!(self, Output::Displacement)
    }

    /// The `yd` at which the model's `R` is evaluated for this output: the state's own, or 0
    /// for the restoring force.
    #[inline]
    pub fn force_yd(self, yd: f64) -> f64 {
        if self == Output::RestoringForce {
            0.0
        } else {
            yd
        }
    }

    /// [`Output::force_yd`] on `L` lanes.
    #[inline]
    pub fn force_yd_lanes<const L: usize>(self, yd: &[f64; L]) -> [f64; L] {
        if self == Output::RestoringForce {
            [0.0; L]
        } else {
            *yd
        }
    }

    /// The observed value at state `s = [y, yd]` and time `t`: `y`, or the model's `R` there
    /// (coefficients `c`); the one rule the fitness and the prediction share.
    #[inline(always)]
    pub fn value(self, model: &Model, t: f64, s: &[f64; 2], c: &[f64]) -> f64 {
        match self {
            Output::Displacement => s[0],
            Output::Force | Output::RestoringForce => {
                model.residual(t, s[0], self.force_yd(s[1]), c)
            }
        }
    }
}
