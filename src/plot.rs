//! Engineers' pictures, as SVG or PNG (chosen by the file's extension, `.svg` or `.png`).
//!
//! - [`fit`]: the data with the fitted model: training samples as dots, test samples as
//!   crosses, the model as a line;
//! - [`phase`]: the model's phase plane, `yd` against `y`;
//! - [`hysteresis`]: force against deflection (the chapter's Figure 8.15);
//! - [`convergence`]: the DE's best-so-far cost per generation on a log scale;
//! - [`stability_map`]: the stability map of a coefficient plane (Figure 8.13).
//!
//! [`identification`] writes the pictures of an identification (`gatewatch identify --plot`).
//!
//! Text is laid out (and, in PNG, drawn) with DejaVu Sans embedded in the binary
//! (`assets/DejaVuSans.ttf`, Bitstream Vera licence in `assets/DejaVuSans-LICENSE.txt`), so no
//! system font library is needed. SVG files name the font family `sans-serif`.

use crate::analysis::{SeriesAnalysis, Signal};
use crate::identify::InitialValues;
use crate::model::{Bound, Model};
use crate::ode::{self, Method, Options};
use crate::stability::StabilityMap;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::error::Error;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Once;

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
        static BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
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

struct FitFigure<'a> {
    t: &'a [f64],
    y: &'a [f64],
    train: &'a [usize],
    test: &'a [usize],
    model_t: &'a [f64],
    model_y: &'a [f64],
    units: &'a Units,
    title: &'a str,
}

impl Figure for FitFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (x0, x1) = span(self.t.iter().chain(self.model_t));
        let (y0, y1) = span(self.y.iter().chain(self.model_y));
        // Room above the data for the legend.
        let y1 = y1 + 0.25 * (y1 - y0);
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, TITLE_SIZE))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(label("time t", self.units.time.as_deref()))
            .y_desc(match &self.units.data {
                Some(d) => d.clone(),
                None => label("displacement y", self.units.signal.as_deref()),
            })
            .x_label_formatter(&tick_format(x0, x1))
            .y_label_formatter(&tick_format(y0, y1))
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        let at = |i: &usize| (self.t[*i], self.y[*i]);
        chart
            .draw_series(
                self.train
                    .iter()
                    .map(|i| Circle::new(at(i), 3, BLUE.filled())),
            )?
            .label(format!("training samples ({})", self.train.len()))
            .legend(|(x, y)| Circle::new((x + 10, y), 4, BLUE.filled()));
        chart
            .draw_series(
                self.test
                    .iter()
                    .map(|i| Cross::new(at(i), 4, ORANGE.stroke_width(2))),
            )?
            .label(format!("test samples ({})", self.test.len()))
            .legend(|(x, y)| Cross::new((x + 10, y), 5, ORANGE.stroke_width(2)));
        if !self.model_t.is_empty() {
            let pts = thin(self.model_t, self.model_y, (x0, x1), (y0, y1));
            chart.draw_series(LineSeries::new(pts.iter().copied(), BLACK))?;
            chart
                .draw_series(LineSeries::new(pts, BLACK.stroke_width(2)))?
                .label("identified model")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2))
                });
        }
        legend_box(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

/// The data with the fitted model: training samples `train` (indices into `t`, `y`) as dots,
/// test samples `test` as crosses, the model curve `(model_t, model_y)` as a line (empty when
/// the model could not be simulated).
#[allow(clippy::too_many_arguments)]
pub fn fit(
    path: &Path,
    t: &[f64],
    y: &[f64],
    train: &[usize],
    test: &[usize],
    model_t: &[f64],
    model_y: &[f64],
    units: &Units,
) -> Result<(), PlotError> {
    if t.is_empty() || t.len() != y.len() {
        return Err(no_data(
            path,
            "the time series is empty or t and y differ in length",
        ));
    }
    if train.iter().chain(test).any(|&i| i >= t.len()) {
        return Err(no_data(path, "a sample index is out of range"));
    }
    if model_t.len() != model_y.len() {
        return Err(no_data(path, "the model's t and y differ in length"));
    }
    render(
        path,
        &FitFigure {
            t,
            y,
            train,
            test,
            model_t,
            model_y,
            units,
            title: "Measured signal and identified model",
        },
    )
}

struct CurveFigure<'a> {
    x: &'a [f64],
    y: &'a [f64],
    x_desc: String,
    y_desc: String,
    title: &'a str,
    equal_zero_lines: bool,
}

impl Figure for CurveFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (x0, x1) = span(self.x);
        let (y0, y1) = span(self.y);
        let y1 = y1 + 0.25 * (y1 - y0);
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, TITLE_SIZE))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(90)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(self.x_desc.as_str())
            .y_desc(self.y_desc.as_str())
            .x_label_formatter(&tick_format(x0, x1))
            .y_label_formatter(&tick_format(y0, y1))
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        if self.equal_zero_lines {
            let axis = GREY.mix(0.6);
            if x0 < 0.0 && x1 > 0.0 {
                chart.draw_series(LineSeries::new([(0.0, y0), (0.0, y1)], axis))?;
            }
            if y0 < 0.0 && y1 > 0.0 {
                chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], axis))?;
            }
        }
        let pts = thin(self.x, self.y, (x0, x1), (y0, y1));
        // plotters' bitmap lines wider than 1 px leave gaps on steep segments; a 1 px line
        // (continuous) underneath fills them.
        chart.draw_series(LineSeries::new(pts.iter().copied(), BLUE))?;
        chart
            .draw_series(LineSeries::new(pts, BLUE.stroke_width(2)))?
            .label("trajectory")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        let start = (self.x[0], self.y[0]);
        chart
            .draw_series([Circle::new(start, 6, GREEN.filled())])?
            .label("start")
            .legend(|(x, y)| Circle::new((x + 10, y), 5, GREEN.filled()));
        let end = (self.x[self.x.len() - 1], self.y[self.y.len() - 1]);
        chart
            .draw_series([TriangleMarker::new(end, 7, ORANGE.filled())])?
            .label("end")
            .legend(|(x, y)| TriangleMarker::new((x + 10, y), 6, ORANGE.filled()));
        legend_box(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

fn check_curve(path: &Path, x: &[f64], y: &[f64]) -> Result<(), PlotError> {
    if x.is_empty() || x.len() != y.len() {
        return Err(no_data(
            path,
            "the curve is empty or its coordinates differ in length",
        ));
    }
    Ok(())
}

/// The model's phase plane: velocity `yd` against displacement `y` along a trajectory, with its
/// start and end marked.
pub fn phase(path: &Path, y: &[f64], yd: &[f64], units: &Units) -> Result<(), PlotError> {
    check_curve(path, y, yd)?;
    render(
        path,
        &CurveFigure {
            x: y,
            y: yd,
            x_desc: label("displacement y", units.signal.as_deref()),
            y_desc: label("velocity yd", units.velocity().as_deref()),
            title: "Phase plane of the identified model",
            equal_zero_lines: true,
        },
    )
}

/// The hysteresis loop (the chapter's Figure 8.15): `force` against `deflection`, start and
/// end marked. The loop's area is the work the force does per cycle.
pub fn hysteresis(
    path: &Path,
    deflection: &[f64],
    force: &[f64],
    units: &Units,
) -> Result<(), PlotError> {
    check_curve(path, deflection, force)?;
    render(
        path,
        &CurveFigure {
            x: deflection,
            y: force,
            x_desc: label("deflection y", units.signal.as_deref()),
            y_desc: label("force F", units.force.as_deref()),
            title: "Hysteresis loop: force against deflection",
            equal_zero_lines: true,
        },
    )
}

struct ConvergenceFigure<'a> {
    history: &'a [f64],
}

impl Figure for ConvergenceFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let n = self.history.len();
        let positive: Vec<f64> = self
            .history
            .iter()
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        let x1 = (n.max(2) - 1) as f64;
        let title = "Differential evolution: convergence";
        if positive.is_empty() {
            // Every cost is 0 (an exact fit) or unusable: a log scale cannot show it.
            let mut chart = ChartBuilder::on(root)
                .caption(title, (FONT, TITLE_SIZE))
                .margin(20)
                .x_label_area_size(55)
                .y_label_area_size(90)
                .build_cartesian_2d(0.0..x1, -1.0..1.0)?;
            chart
                .configure_mesh()
                .x_desc("generation")
                .y_desc("best training cost (MAE)")
                .label_style((FONT, LABEL_SIZE))
                .axis_desc_style((FONT, DESC_SIZE))
                .draw()?;
            let pts = self
                .history
                .iter()
                .enumerate()
                .map(|(g, c)| (g as f64, if c.is_finite() { *c } else { 0.0 }));
            chart.draw_series(LineSeries::new(pts, BLUE.stroke_width(2)))?;
            return Ok(());
        }
        let min = positive.iter().copied().fold(f64::INFINITY, f64::min);
        let max = positive.iter().copied().fold(0.0, f64::max);
        // Costs of exactly 0 are drawn on a floor a decade below the smallest positive cost.
        let floor = min / 10.0;
        let has_zero = self.history.iter().any(|v| *v <= 0.0);
        let lo = if has_zero { floor / 2.0 } else { min / 2.0 };
        let hi = if max > lo * 10.0 {
            max * 2.0
        } else {
            lo * 100.0
        };
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, TITLE_SIZE))
            .margin(20)
            .margin_right(40)
            .x_label_area_size(55)
            .y_label_area_size(100)
            .build_cartesian_2d(0.0..x1, (lo..hi).log_scale())?;
        let fmt = |v: &f64| format!("{v:.0e}");
        let generation = |v: &f64| format!("{v:.0}");
        chart
            .configure_mesh()
            .x_desc("generation")
            .y_desc("best training cost (MAE), log scale")
            .y_label_formatter(&fmt)
            .x_label_formatter(&generation)
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .draw()?;
        let pts: Vec<(f64, f64)> = self
            .history
            .iter()
            .enumerate()
            .filter(|(_, c)| !c.is_nan())
            .map(|(g, c)| (g as f64, if *c > 0.0 { c.min(hi) } else { floor }))
            .collect();
        // A best-so-far cost only rises where the search moved to a longer fitted horizon
        // (the continuation stages of `identify`): mark those generations.
        let stages: Vec<f64> = self
            .history
            .windows(2)
            .enumerate()
            .filter(|(_, w)| w[1] > w[0])
            .map(|(g, _)| (g + 1) as f64)
            .collect();
        if !stages.is_empty() {
            let dashed = GREY.mix(0.8).stroke_width(1);
            for &g in &stages {
                chart.draw_series(DashedLineSeries::new([(g, lo), (g, hi)], 6, 4, dashed))?;
            }
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())?
                .label("longer fitted horizon")
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], GREY.mix(0.8).stroke_width(1))
                });
        }
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), BLUE.stroke_width(2)))?
            .label("best so far")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        if has_zero {
            chart
                .draw_series(
                    self.history
                        .iter()
                        .enumerate()
                        .filter(|(_, c)| **c <= 0.0)
                        .map(|(g, _)| TriangleMarker::new((g as f64, floor), 5, ORANGE.filled())),
                )?
                .label("cost 0 (exact), drawn at the floor")
                .legend(|(x, y)| TriangleMarker::new((x + 10, y), 5, ORANGE.filled()));
        }
        legend_box(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

/// The DE's convergence curve: best-so-far training cost per generation (`history[g]` after
/// generation `g`, `history[0]` the initial population), log scale. Costs of 0 are drawn on a
/// marked floor below the smallest positive cost; if every cost is 0 the scale is linear.
pub fn convergence(path: &Path, history: &[f64]) -> Result<(), PlotError> {
    if history.is_empty() {
        return Err(no_data(path, "the convergence history is empty"));
    }
    render(path, &ConvergenceFigure { history })
}

struct MapFigure<'a> {
    map: &'a StabilityMap,
    subtitle: &'a str,
}

impl Figure for MapFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let title = format!(
            "Stability map in the ({}, {}) plane",
            self.map.x_name, self.map.y_name
        );
        let root = root.titled(&title, (FONT, TITLE_SIZE))?;
        let (plot_area, side) = root.split_horizontally(SIZE.0 - 230);
        let xs: Vec<f64> = self.map.trials.iter().map(|t| t.x).collect();
        let ys: Vec<f64> = self.map.trials.iter().map(|t| t.y).collect();
        let (x0, x1) = span(&xs);
        let (y0, y1) = span(&ys);
        let mut chart = ChartBuilder::on(&plot_area)
            .margin(15)
            .x_label_area_size(55)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(self.map.x_name.as_str())
            .y_desc(self.map.y_name.as_str())
            .x_label_formatter(&tick_format(x0, x1))
            .y_label_formatter(&tick_format(y0, y1))
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        let n = self.map.trials.len();
        let radius = if n > 3000 { 2 } else { 3 };
        chart.draw_series(
            self.map
                .trials
                .iter()
                .filter(|t| t.stable)
                .map(|t| Circle::new((t.x, t.y), radius, BLUE.filled())),
        )?;
        chart.draw_series(
            self.map
                .trials
                .iter()
                .filter(|t| !t.stable)
                .map(|t| Circle::new((t.x, t.y), radius, ORANGE.filled())),
        )?;
        // The legend beside the plot, where it hides no trial.
        let stable = self.map.stable_count();
        let style = TextStyle::from((FONT, LABEL_SIZE)).color(&BLACK);
        let rows = [
            (BLUE, format!("stable ({stable})")),
            (ORANGE, format!("unstable ({})", n - stable)),
        ];
        for (k, (colour, text)) in rows.iter().enumerate() {
            let y = 40 + 32 * k as i32;
            side.draw(&Circle::new((18, y), 7, colour.filled()))?;
            side.draw_text(text, &style, (34, y - 10))?;
        }
        let small = TextStyle::from((FONT, LABEL_SIZE - 3)).color(&GREY);
        let mut y = 130;
        for line in wrap(self.subtitle, 26) {
            side.draw_text(&line, &small, (8, y))?;
            y += 22;
        }
        Ok(())
    }
}

/// Greedy word wrap to `width` characters.
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for paragraph in text.lines() {
        let mut line = String::new();
        for word in paragraph.split_whitespace() {
            if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > width {
                lines.push(std::mem::take(&mut line));
            }
            if !line.is_empty() {
                line.push(' ');
            }
            line.push_str(word);
        }
        lines.push(line);
    }
    lines
}

/// The stability map: each trial a dot, stable and unstable in two colours, with the counts
/// and `note` (e.g. the equation and the fixed coefficients; lines wrap) beside the plot.
pub fn stability_map(path: &Path, map: &StabilityMap, note: &str) -> Result<(), PlotError> {
    if map.trials.is_empty() {
        return Err(no_data(path, "the map has no trials"));
    }
    render(
        path,
        &MapFigure {
            map,
            subtitle: note,
        },
    )
}

/// A model trajectory on a uniform grid of `points` times over `[t0, t1]`: `(t, y, yd)`, up to
/// where the integration stopped (Dormand-Prince, `rtol = 1e-8`).
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

/// The pictures of an identification, written into `dir` (created if needed): `fit` (data and
/// model output), `phase` (the model's phase plane), `convergence`, and in force mode
/// `hysteresis` (the velocity-dependent part of the modelled support force against deflection
/// over the last cycles: the chapter's Figure 8.15, whose enclosed area is the energy fed in per
/// cycle), with `format`'s extension. Returns the files written.
pub fn identification(
    dir: &Path,
    format: Format,
    model: &Model,
    analysis: &SeriesAnalysis,
    signal: Signal,
    units: &Units,
) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir).map_err(|e| PlotError::Write {
        path: dir.to_path_buf(),
        reason: e.to_string(),
    })?;
    let result = &analysis.identification;
    let series = &analysis.data;
    let best = result.best_run();
    let (t0, t1) = match (series.t.first(), series.t.last()) {
        (Some(a), Some(b)) => (*a, *b),
        _ => return Err(no_data(dir, "the time series is empty")),
    };
    let file = |name: &str| dir.join(format!("{name}.{}", format.extension()));
    let fit_path = file("fit");
    let mut written = Vec::new();
    match (signal, &analysis.prediction) {
        // The support force is only known at the samples (it needs the state there).
        (Signal::Force, Some(p)) => {
            fit(
                &fit_path,
                &series.t,
                &series.y,
                &result.train,
                &result.test,
                &series.t,
                p,
                units,
            )?;
        }
        _ => {
            let points = (series.len() * 8).clamp(2000, 20_000);
            let (mt, my, _) = trajectory(model, &best.coefficients, best.initial, t0, t1, points);
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
    if let Some(tr) = &analysis.trajectory {
        let (y, yd): (Vec<f64>, Vec<f64>) = tr.iter().map(|s| (s[0], s[1])).unzip();
        let p = file("phase");
        phase(&p, &y, &yd, units)?;
        written.push(p);
        if signal == Signal::Force {
            if let Some(w) = analysis.linearization.omega0() {
                let period = 2.0 * std::f64::consts::PI / w;
                let (defl, force): (Vec<f64>, Vec<f64>) = tr
                    .iter()
                    .zip(&series.t)
                    .filter(|(_, &t)| t >= t1 - 3.0 * period)
                    .map(|(s, &t)| {
                        let c = &best.coefficients;
                        (
                            s[0],
                            model.residual(t, s[0], s[1], c) - model.residual(t, s[0], 0.0, c),
                        )
                    })
                    .unzip();
                let p = file("hysteresis");
                hysteresis(&p, &defl, &force, units)?;
                written.push(p);
            }
        }
    }
    let p = file("convergence");
    convergence(&p, &best.history)?;
    written.push(p);
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stability::Trial;

    fn sine(n: usize) -> (Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
        let y = t.iter().map(|t| (-0.05 * t).exp() * t.sin()).collect();
        (t, y)
    }

    #[test]
    fn format_follows_the_extension() {
        assert_eq!(
            Format::from_path(Path::new("a/fit.svg")).unwrap(),
            Format::Svg
        );
        assert_eq!(
            Format::from_path(Path::new("fit.PNG")).unwrap(),
            Format::Png
        );
        let e = Format::from_path(Path::new("fit.pdf"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("fit.pdf:") && e.contains(".svg or .png"),
            "{e}"
        );
        assert!(Format::from_path(Path::new("fit")).is_err());
    }

    #[test]
    fn svg_and_png_files_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let (t, y) = sine(200);
        let train: Vec<usize> = (0..200).step_by(2).collect();
        let test: Vec<usize> = (1..200).step_by(2).collect();
        let units = Units {
            time: Some("s".into()),
            signal: Some("mm".into()),
            force: Some("kN".into()),
            data: None,
        };
        for ext in ["svg", "png"] {
            let p = dir.path().join(format!("fit.{ext}"));
            fit(&p, &t, &y, &train, &test, &t, &y, &units).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            if ext == "svg" {
                let text = String::from_utf8(bytes).unwrap();
                assert!(text.starts_with("<svg"), "{}", &text[..50]);
                assert!(text.contains("time t [s]"));
                assert!(text.contains("displacement y [mm]"));
                assert!(text.contains("test samples (100)"));
            } else {
                assert_eq!(&bytes[1..4], b"PNG");
            }
        }
        let p = dir.path().join("phase.svg");
        phase(&p, &y, &t, &units).unwrap();
        assert!(std::fs::read_to_string(&p)
            .unwrap()
            .contains("velocity yd [mm/s]"));
        let p = dir.path().join("loop.svg");
        hysteresis(&p, &y, &t, &units).unwrap();
        assert!(std::fs::read_to_string(&p)
            .unwrap()
            .contains("force F [kN]"));
    }

    #[test]
    fn convergence_with_zero_costs_draws_them_on_a_floor() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.svg");
        convergence(&p, &[1e3, 10.0, 0.5, 0.0, 0.0]).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.contains("log scale") && text.contains("drawn at the floor"));
        convergence(&p, &[0.0, 0.0]).unwrap();
        assert!(!std::fs::read_to_string(&p).unwrap().contains("log scale"));
        assert!(convergence(&p, &[]).is_err());
    }

    #[test]
    fn stability_map_counts_both_classes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("map.svg");
        let map = StabilityMap {
            x_name: "c1".into(),
            y_name: "c2".into(),
            trials: vec![
                Trial {
                    x: 1.0,
                    y: 1.0,
                    stable: true,
                },
                Trial {
                    x: -1.0,
                    y: 1.0,
                    stable: false,
                },
            ],
            t_end: 1.0,
        };
        stability_map(&p, &map, "ydd + c1*yd + c2*y = 0").unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.contains("stable (1)") && text.contains("unstable (1)"));
    }

    #[test]
    fn unwritable_or_unknown_paths_are_errors_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let (t, y) = sine(10);
        let p = dir.path().join("missing").join("fit.svg");
        let e = fit(&p, &t, &y, &[0], &[1], &[], &[], &Units::default()).unwrap_err();
        assert!(matches!(e, PlotError::Write { .. }));
        assert!(e.to_string().contains("missing"), "{e}");
        let p = dir.path().join("fit.jpg");
        let e = fit(&p, &t, &y, &[0], &[1], &[], &[], &Units::default()).unwrap_err();
        assert!(matches!(e, PlotError::Format { .. }));
        let e = fit(
            &dir.path().join("f.svg"),
            &t,
            &y,
            &[99],
            &[],
            &[],
            &[],
            &Units::default(),
        )
        .unwrap_err();
        assert!(matches!(e, PlotError::NoData { .. }));
    }
}
