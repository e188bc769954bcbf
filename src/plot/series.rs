//! Curves over samples: the data with the fitted model, the phase plane, the hysteresis loop.

use super::*;
use std::path::Path;

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

pub(super) struct CurveFigure<'a> {
    pub(super) x: &'a [f64],
    pub(super) y: &'a [f64],
    /// The curve's legend entry.
    pub(super) curve_label: &'a str,
    /// Data drawn as dots beside the curve, with their legend entry.
    pub(super) data: Option<(&'a [f64], &'a [f64], String)>,
    pub(super) x_desc: String,
    pub(super) y_desc: String,
    pub(super) title: &'a str,
    pub(super) equal_zero_lines: bool,
}

impl Figure for CurveFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (dx, dy): (&[f64], &[f64]) = match &self.data {
            Some((x, y, _)) => (x, y),
            None => (&[], &[]),
        };
        let (x0, x1) = span(self.x.iter().chain(dx));
        let (y0, y1) = span(self.y.iter().chain(dy));
        let y1 = y1 + 0.25 * (y1 - y0);
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, TITLE_SIZE))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(90)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            // Few enough ticks for a half-width panel (hysteresis).
            .x_labels(6)
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
            .label(self.curve_label)
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        // The data on top: a dense model curve would hide them.
        if let Some((x, y, label)) = &self.data {
            chart
                .draw_series(
                    x.iter()
                        .zip(y.iter())
                        .filter(|(a, b)| a.is_finite() && b.is_finite())
                        .map(|(a, b)| Circle::new((*a, *b), 2, GREY.mix(0.7).filled())),
                )?
                .label(label.as_str())
                .legend(|(x, y)| Circle::new((x + 10, y), 4, GREY.mix(0.7).filled()));
        }
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

/// The phase plane, `yd` against `y`: the model's trajectory as a line with its start and end
/// marked, and, when given, the states estimated from the data (`data`: `y`, `yd` and their
/// legend entry) as dots beside it.
pub fn phase(
    path: &Path,
    data: Option<(&[f64], &[f64], &str)>,
    y: &[f64],
    yd: &[f64],
    units: &Units,
) -> Result<(), PlotError> {
    check_curve(path, y, yd)?;
    if let Some((dy, dyd, _)) = data {
        check_curve(path, dy, dyd)?;
    }
    render(
        path,
        &CurveFigure {
            x: y,
            y: yd,
            curve_label: "identified model",
            data: data.map(|(a, b, l)| (a, b, l.to_string())),
            x_desc: label("displacement y", units.signal.as_deref()),
            y_desc: label("velocity yd", units.velocity().as_deref()),
            title: "Phase plane: data and identified model",
            equal_zero_lines: true,
        },
    )
}

/// Two figures side by side.
struct SideBySide<'a>(CurveFigure<'a>, CurveFigure<'a>);

impl Figure for SideBySide<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        let (left, right) = root.split_horizontally(SIZE.0 / 2);
        self.0.draw(&left)?;
        self.1.draw(&right)
    }
}

/// One set of points of a hysteresis picture: deflection and force.
pub type Loop<'a> = (&'a [f64], &'a [f64]);

/// The hysteresis loop (the chapter's Figure 8.15), measured (dots, at the model's deflection)
/// and model (a line, sampled densely so the loop is smooth), in two panels: the whole support
/// force against deflection (`measured`, `model`), where the stiffness force dominates and the
/// loop is thin, and its velocity-dependent part, the force minus the model's restoring force at
/// rest (`measured_part`, `model_part`), whose loop area is the work the force does per cycle.
pub fn hysteresis<'a>(
    path: &Path,
    measured: Loop<'a>,
    model: Loop<'a>,
    measured_part: Loop<'a>,
    model_part: Loop<'a>,
    units: &Units,
) -> Result<(), PlotError> {
    for (x, y) in [measured, model, measured_part, model_part] {
        check_curve(path, x, y)?;
    }
    // one panel: the model's loop as the curve, the measured one as dots
    let panel = |(x, y): Loop<'a>, (mx, my): Loop<'a>, force: &str, title: &'a str| CurveFigure {
        x,
        y,
        curve_label: "identified model",
        data: Some((mx, my, "measured".to_string())),
        x_desc: label("deflection y (model)", units.signal.as_deref()),
        y_desc: label(force, units.force.as_deref()),
        title,
        equal_zero_lines: true,
    };
    let whole = panel(
        model,
        measured,
        "support force F",
        "Support force against deflection",
    );
    let part = panel(
        model_part,
        measured_part,
        "F minus restoring force at rest",
        "Its velocity-dependent part",
    );
    render(path, &SideBySide(whole, part))
}
