//! The stability map of a coefficient plane (Figure 8.13).

use super::*;
use crate::stability::StabilityMap;
use std::path::Path;

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
