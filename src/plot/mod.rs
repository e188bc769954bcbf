//! Engineers' pictures, as SVG or PNG (chosen by the file's extension, `.svg` or `.png`).
//!
//! - [`fit`]: the data with the fitted model: training samples as dots, test samples as
//!   crosses, the model as a line;
//! - [`fit_zoom`]: the fit of a long record: a zoom on a few periods above the residual;
//! - [`phase`]: the phase plane, `yd` against `y`: the model's trajectory beside the data;
//! - [`hysteresis`]: the support force against deflection, measured and model (the chapter's
//!   Figure 8.15);
//! - [`convergence`]: the DE's best-so-far cost per generation on a log scale, ending after the
//!   polish;
//! - [`stability_map`]: the stability map of a coefficient plane (Figure 8.13);
//! - [`damping_history`]: a gate's damping over time from the store's history, with its
//!   interval band, the alert thresholds and the verdict changes (`gatewatch history --plot`).
//!
//! [`identification`] writes the pictures of an identification (`gatewatch identify --plot`).
//!
//! Text is laid out (and, in PNG, drawn) with DejaVu Sans embedded in the binary
//! (`assets/DejaVuSans.ttf`, Bitstream Vera licence in `assets/DejaVuSans-LICENSE.txt`), so no
//! system font library is needed. SVG files name the font family `sans-serif`.
//!
//! # Layout
//! `mod.rs` holds the error, format, units and the drawing helpers every figure shares;
//! `series` the fit, phase and hysteresis figures; `zoom` the zoomed fit with its residual;
//! `convergence` the DE curve; `map` the
//! stability map; `report` the pictures of an identification; `history` the damping over time.

use plotters::coord::Shift;
use plotters::prelude::*;
use std::error::Error;
use std::path::{Path, PathBuf};
use std::sync::Once;

mod convergence;
mod damping;
mod history;
mod map;
mod report;
mod series;
#[cfg(test)]
mod tests;
mod zoom;

pub use convergence::convergence;
pub use damping::damping_curve;
pub use history::{damping_history, DampingPoint, Thresholds};
pub use map::stability_map;
pub use report::{identification, prepare_dir, trajectory};
pub use series::{fit, hysteresis, phase, Loop};
pub use zoom::fit_zoom;

/// Picture size in pixels (SVG user units).
const SIZE: (u32, u32) = (1000, 650);
const FONT: &str = "sans-serif";
const TITLE_SIZE: u32 = 26;
const LABEL_SIZE: u32 = 18;
const DESC_SIZE: u32 = 20;
/// Colour-blind-safe palette (Okabe-Ito).
const BLUE: RGBColor = RGBColor(0, 114, 178);
const ORANGE: RGBColor = RGBColor(213, 94, 0);
const GREEN: RGBColor = RGBColor(0, 158, 115);
const GREY: RGBColor = RGBColor(90, 90, 90);

/// Why a picture could not be written. Every message starts with the file's path.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The extension is neither `.svg` nor `.png`.
    #[error("{path}: unknown picture format (the file name must end in .svg or .png)")]
    Format {
        /// The file.
        path: PathBuf,
    },
    /// Nothing to draw (empty or mismatched data).
    #[error("{path}: nothing to plot: {reason}")]
    NoData {
        /// The file.
        path: PathBuf,
        /// What was missing.
        reason: String,
    },
    /// Drawing or writing failed (e.g. an unwritable directory).
    #[error("{path}: cannot write the picture: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        reason: String,
    },
}

/// Picture file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Scalable vector graphics.
    Svg,
    /// Portable network graphics.
    Png,
}

impl Format {
    /// The format named by `path`'s extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Format, PlotError> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("svg") => Ok(Format::Svg),
            Some("png") => Ok(Format::Png),
            _ => Err(PlotError::Format {
                path: path.to_path_buf(),
            }),
        }
    }

    /// The file extension, `svg` or `png`.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Svg => "svg",
            Format::Png => "png",
        }
    }
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "svg" => Ok(Format::Svg),
            "png" => Ok(Format::Png),
            other => Err(format!(
                "unknown picture format '{other}': expected svg or png"
            )),
        }
    }
}

/// Units of the axes; `None` leaves the label without one.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Units {
    /// Unit of time, e.g. `s`.
    pub time: Option<String>,
    /// Unit of the signal (deflection), e.g. `mm`.
    pub signal: Option<String>,
    /// Unit of force, e.g. `kN`.
    pub force: Option<String>,
    /// Axis label of the data in the fit plot when they are not the displacement, e.g.
    /// `support force F [N]`.
    pub data: Option<String>,
}

impl Units {
    fn velocity(&self) -> Option<String> {
        match (&self.signal, &self.time) {
            (Some(s), Some(t)) => Some(format!("{s}/{t}")),
            (None, Some(t)) => Some(format!("1/{t}")),
            _ => None,
        }
    }
}

fn label(name: &str, unit: Option<&str>) -> String {
    match unit {
        Some(u) if !u.is_empty() => format!("{name} [{u}]"),
        _ => name.to_string(),
    }
}

fn register_font() {
    static FONT_ONCE: Once = Once::new();
    FONT_ONCE.call_once(|| {
        static BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
        // The embedded file is a valid TrueType font; a failure would only lose the text.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, BYTES);
    });
}

type DrawResult = Result<(), Box<dyn Error>>;

/// Something that draws itself on any backend.
trait Figure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static;
}

fn render(path: &Path, figure: &impl Figure) -> Result<(), PlotError> {
    let format = Format::from_path(path)?;
    register_font();
    let write = |e: Box<dyn Error>| PlotError::Write {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    // Fail early (and clearly) when the file cannot be created; the backends only write on
    // `present`.
    std::fs::File::create(path).map_err(|e| write(e.into()))?;
    match format {
        Format::Svg => {
            let root = SVGBackend::new(path, SIZE).into_drawing_area();
            figure.draw(&root).map_err(write)?;
            root.present().map_err(|e| write(e.into()))
        }
        Format::Png => {
            let root = BitMapBackend::new(path, SIZE).into_drawing_area();
            figure.draw(&root).map_err(write)?;
            root.present().map_err(|e| write(e.into()))
        }
    }
}

/// `[lo, hi]` of the finite values with 5 % padding; a unit span around a constant.
fn span<'a>(values: impl IntoIterator<Item = &'a f64>) -> (f64, f64) {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    if hi - lo <= 1e-12 * lo.abs().max(hi.abs()).max(1e-300) {
        let d = lo.abs().max(1.0) * 0.5;
        return (lo - d, hi + d);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// Tick labels with as many decimals as the axis needs (`5000`, `0.25`, `1.5e6`), instead of
/// plotters' default that prints `5000.0`.
fn tick_format(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let step = (hi - lo).abs() / 10.0;
    let decimals = if step > 0.0 {
        (-step.log10().floor()).clamp(0.0, 12.0) as usize
    } else {
        0
    };
    let big = lo.abs().max(hi.abs()) >= 1e6 || (hi - lo).abs() < 1e-4;
    move |v: &f64| {
        if big {
            format!("{v:.2e}")
        } else {
            let s = format!("{v:.decimals$}");
            if s.starts_with('-') && s.trim_start_matches(['-', '0', '.']).is_empty() {
                s[1..].to_string()
            } else {
                s
            }
        }
    }
}

/// Drops points closer than about half a pixel to the last kept one (a bitmap line through
/// sub-pixel segments comes out dotted); the last point is always kept.
fn thin(x: &[f64], y: &[f64], (x0, x1): (f64, f64), (y0, y1): (f64, f64)) -> Vec<(f64, f64)> {
    let (dx, dy) = (
        0.5 * (x1 - x0) / SIZE.0 as f64,
        0.5 * (y1 - y0) / SIZE.1 as f64,
    );
    let mut out: Vec<(f64, f64)> = Vec::with_capacity(x.len());
    for (i, (&a, &b)) in x.iter().zip(y).enumerate() {
        let keep = match out.last() {
            None => true,
            Some(&(pa, pb)) => (a - pa).abs() > dx || (b - pb).abs() > dy || i + 1 == x.len(),
        };
        if keep {
            out.push((a, b));
        }
    }
    out
}

fn no_data(path: &Path, reason: impl Into<String>) -> PlotError {
    PlotError::NoData {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn legend_box<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(GREY)
        .label_font((FONT, LABEL_SIZE))
        .draw()?;
    Ok(())
}
