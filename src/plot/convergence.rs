//! The DE's convergence curve.

use super::*;
use std::path::Path;

struct ConvergenceFigure<'a> {
    history: &'a [f64],
    /// The training cost after the polish, drawn one step after the last generation.
    polished: Option<f64>,
    /// Unit of the cost (the data's), when known.
    unit: Option<&'a str>,
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
            .chain(self.polished.iter())
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        let x1 = if self.polished.is_some() {
            n as f64
        } else {
            (n.max(2) - 1) as f64
        };
        let title = "Differential evolution: convergence";
        // The cost is a mean absolute error of the data, so it has their unit.
        let cost = match self.unit {
            Some(u) if !u.is_empty() => format!("best training cost (MAE) [{u}]"),
            _ => "best training cost (MAE, unit of the data)".to_string(),
        };
        let unit = self
            .unit
            .filter(|u| !u.is_empty())
            .map_or(String::new(), |u| format!(" {u}"));
        let x_desc = if self.polished.is_some() {
            "generation (last point: after the polish)"
        } else {
            "generation"
        };
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
                .x_desc(x_desc)
                .y_desc(cost.as_str())
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
        let has_zero = self
            .history
            .iter()
            .chain(self.polished.iter())
            .any(|v| *v <= 0.0);
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
            .x_desc(x_desc)
            .y_desc(format!("{cost}, log scale"))
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
        if let (Some(p), Some(&last)) = (self.polished, pts.last()) {
            let at = (n as f64, if p > 0.0 { p.min(hi) } else { floor });
            chart.draw_series(DashedLineSeries::new(
                [last, at],
                6,
                4,
                GREEN.stroke_width(2),
            ))?;
            chart
                .draw_series([Circle::new(at, 6, GREEN.filled())])?
                .label(format!(
                    "after the polish: {p:.3e}{unit} (the training error)"
                ))
                .legend(|(x, y)| Circle::new((x + 10, y), 5, GREEN.filled()));
        }
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
/// `polished`, the training cost after the local polish of the DE winner, is drawn one step
/// after the last generation, so the curve ends at the training error the run reports.
/// `unit` is the data's (the cost is their mean absolute error), when known.
pub fn convergence(
    path: &Path,
    history: &[f64],
    polished: Option<f64>,
    unit: Option<&str>,
) -> Result<(), PlotError> {
    if history.is_empty() {
        return Err(no_data(path, "the convergence history is empty"));
    }
    render(
        path,
        &ConvergenceFigure {
            history,
            polished,
            unit,
        },
    )
}
