//! The fit of a long record: a zoom on a few periods, where samples and model can be told
//! apart, above the residual over the whole record, where a drift or a growing misfit shows.
//! (Drawn whole, ten seconds of a 2 Hz force at 100 Hz are a solid band.)

use super::*;
use std::path::Path;

struct ZoomFigure<'a> {
    t: &'a [f64],
    measured: &'a [f64],
    predicted: &'a [f64],
    model_t: &'a [f64],
    model_y: &'a [f64],
    zoom: (f64, f64),
    /// The part of the record the pre-processing left reliable; the rest is shaded.
    valid: (f64, f64),
    units: &'a Units,
}

impl Figure for ZoomFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (top, bottom) = root.split_vertically(SIZE.1 * 62 / 100);
        let (z0, z1) = self.zoom;
        let inside = |t: &f64| *t >= z0 && *t <= z1;
        let data: Vec<(f64, f64)> = self
            .t
            .iter()
            .zip(self.measured)
            .filter(|(t, y)| inside(t) && y.is_finite())
            .map(|(t, y)| (*t, *y))
            .collect();
        let (mt, my): (Vec<f64>, Vec<f64>) = self
            .model_t
            .iter()
            .zip(self.model_y)
            .filter(|(t, _)| inside(t))
            .map(|(t, y)| (*t, *y))
            .unzip();
        let (y0, y1) = span(data.iter().map(|p| &p.1).chain(&my));
        let y1 = y1 + 0.3 * (y1 - y0);
        let data_desc = match &self.units.data {
            Some(d) => d.clone(),
            None => label("signal y", self.units.signal.as_deref()),
        };
        let time_desc = label("time t", self.units.time.as_deref());
        let mut chart = ChartBuilder::on(&top)
            .caption(
                format!(
                    "Measured and identified model, t = {z0:.2} to {z1:.2}{} (zoom)",
                    self.units
                        .time
                        .as_deref()
                        .map_or(String::new(), |u| format!(" {u}"))
                ),
                (FONT, TITLE_SIZE),
            )
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(90)
            .build_cartesian_2d(z0..z1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(time_desc.as_str())
            .y_desc(data_desc.as_str())
            .x_label_formatter(&tick_format(z0, z1))
            .y_label_formatter(&tick_format(y0, y1))
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        chart
            .draw_series(data.iter().map(|p| Circle::new(*p, 3, BLUE.filled())))?
            .label(format!("measured ({} samples shown)", data.len()))
            .legend(|(x, y)| Circle::new((x + 10, y), 4, BLUE.filled()));
        let pts = thin(&mt, &my, (z0, z1), (y0, y1));
        chart
            .draw_series(LineSeries::new(pts, BLACK.stroke_width(2)))?
            .label("identified model")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
        legend_box(&mut chart, SeriesLabelPosition::UpperRight)?;

        let residual: Vec<f64> = self
            .measured
            .iter()
            .zip(self.predicted)
            .map(|(m, p)| m - p)
            .collect();
        let (x0, x1) = span(self.t);
        let (r0, r1) = span(residual.iter().chain([0.0].iter()));
        let r1 = r1 + 0.35 * (r1 - r0);
        let mut chart = ChartBuilder::on(&bottom)
            .margin(20)
            .x_label_area_size(50)
            .y_label_area_size(90)
            .build_cartesian_2d(x0..x1, r0..r1)?;
        chart
            .configure_mesh()
            .x_desc(time_desc.as_str())
            .y_desc(label(
                "residual",
                self.units.force.as_deref().or(self.units.signal.as_deref()),
            ))
            .x_label_formatter(&tick_format(x0, x1))
            .y_label_formatter(&tick_format(r0, r1))
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        // The zoomed interval, shaded, so the two panels can be related.
        chart.draw_series([Rectangle::new(
            [(z0, r0), (z1, r1)],
            GREY.mix(0.15).filled(),
        )])?;
        // The edges where the centred moving average was truncated: the data carry its lag
        // there, so the residual leaves zero for a reason that is not the model's.
        let (v0, v1) = self.valid;
        let edges: Vec<(f64, f64)> = [(x0, v0.max(x0)), (v1.min(x1), x1)]
            .into_iter()
            .filter(|(a, b)| b > a)
            .collect();
        if !edges.is_empty() {
            let tint = ORANGE.mix(0.12);
            chart
                .draw_series(
                    edges
                        .iter()
                        .map(|&(a, b)| Rectangle::new([(a, r0), (b, r1)], tint.filled())),
                )?
                .label("edges: moving average truncated (not fitted to)")
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], tint.filled()));
        }
        chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], GREY.mix(0.6)))?;
        let pts = thin(self.t, &residual, (x0, x1), (r0, r1));
        chart
            .draw_series(LineSeries::new(pts, ORANGE.stroke_width(1)))?
            .label("residual: measured - model (whole record; shaded: the zoom)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], ORANGE.stroke_width(2)));
        legend_box(&mut chart, SeriesLabelPosition::UpperLeft)
    }
}

/// The fit of a long record: the samples (`t`, `measured`) and the model (densely sampled
/// `model = (t, y)`) over `zoom` (a few periods), above the residual `measured - predicted`
/// (`predicted`: the model at the samples) over the whole record, with the times outside
/// `valid` (where a pre-processing such as a truncated moving average spoils the data) shaded.
#[allow(clippy::too_many_arguments)]
pub fn fit_zoom(
    path: &Path,
    t: &[f64],
    measured: &[f64],
    predicted: &[f64],
    (model_t, model_y): (&[f64], &[f64]),
    zoom: (f64, f64),
    valid: (f64, f64),
    units: &Units,
) -> Result<(), PlotError> {
    if t.is_empty() || t.len() != measured.len() || t.len() != predicted.len() {
        return Err(no_data(
            path,
            "the time series is empty or the measured and predicted values differ in length",
        ));
    }
    if model_t.len() != model_y.len() {
        return Err(no_data(path, "the model's t and y differ in length"));
    }
    if zoom.0.partial_cmp(&zoom.1) != Some(std::cmp::Ordering::Less) {
        return Err(no_data(path, "the zoom interval is empty"));
    }
    render(
        path,
        &ZoomFigure {
            t,
            measured,
            predicted,
            model_t,
            model_y,
            zoom,
            valid,
            units,
        },
    )
}
