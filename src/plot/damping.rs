//! The damping-amplitude curve `zeta_eq(A)`: the picture next to the hysteresis loop.

use super::series::CurveFigure;
use super::{label, no_data, render, PlotError};
use std::path::Path;

/// `zeta_eq` (in percent) against the amplitude over the amplitudes the window visited
/// (`curve`: `(amplitude, zeta_eq)` points, e.g. `DampingReport::zeta_eq_curve`). Where the
/// curve crosses the zero line is the limit cycle; its value at the left end is close to the
/// damping at rest. `amplitude_unit`: the signal's unit (force in force mode).
pub fn damping_curve(
    path: &Path,
    curve: &[(f64, f64)],
    amplitude_unit: Option<&str>,
) -> Result<(), PlotError> {
    if curve.is_empty() {
        return Err(no_data(path, "the zeta_eq(A) curve is empty"));
    }
    let a: Vec<f64> = curve.iter().map(|p| p.0).collect();
    let z: Vec<f64> = curve.iter().map(|p| 100.0 * p.1).collect();
    render(
        path,
        &CurveFigure {
            x: &a,
            y: &z,
            curve_label: "identified model: zeta_eq(A)",
            data: None,
            x_desc: label("amplitude A", amplitude_unit),
            y_desc: "equivalent damping ratio zeta_eq [%]".to_string(),
            title: "Damping against amplitude over the window",
            equal_zero_lines: true,
        },
    )
}
