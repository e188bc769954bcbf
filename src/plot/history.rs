//! The damping over time from a gate's history (`gatewatch history --plot`): zeta0 with its
//! 95 % interval as a band, the alert thresholds when known, and a mark at each verdict change.

use super::*;
use std::path::Path;

/// One identified window as the picture needs it (the plot does not know the store).
#[derive(Debug, Clone, PartialEq)]
pub struct DampingPoint {
    /// Window end, Unix seconds.
    pub time: f64,
    /// Damping ratio at rest, when the window has one.
    pub zeta0: Option<f64>,
    /// Its 95 % interval, when the window has one.
    pub interval: Option<(f64, f64)>,
    /// The window's verdict (`damped`, `self_excited`, ...).
    pub verdict: String,
    /// Whether the window's report was trusted (it fed the alerts). Untrusted windows are drawn
    /// apart: hollow grey circles, off the zeta0 line and its band.
    pub trusted: bool,
}

/// The alert rule's thresholds on zeta0 (`[defaults.alert]` or the gate's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    /// Fires when zeta0 is confidently below this.
    pub fire_below: f64,
    /// Resolves when zeta0 is confidently above this.
    pub clear_above: f64,
}

/// Most verdict changes labelled with their verdict; beyond this the marks stay, unlabelled
/// (a flickering gate would write a wall of text).
const MAX_VERDICT_LABELS: usize = 20;

/// The time axis: the unit that keeps the numbers readable for the span.
fn time_unit(span_s: f64) -> (f64, &'static str) {
    if span_s <= 600.0 {
        (1.0, "s")
    } else if span_s <= 3.0 * 3600.0 {
        (60.0, "min")
    } else {
        (3600.0, "h")
    }
}

fn rfc3339(t: f64) -> String {
    let d = std::time::Duration::try_from_secs_f64(t.max(0.0)).unwrap_or_default();
    humantime::format_rfc3339_seconds(std::time::UNIX_EPOCH + d).to_string()
}

struct HistoryFigure<'a> {
    gate: &'a str,
    points: &'a [DampingPoint],
    thresholds: Option<Thresholds>,
}

impl Figure for HistoryFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let p = self.points;
        let (t0, t_end) = (p[0].time, p[p.len() - 1].time);
        let (scale, unit) = time_unit(t_end - t0);
        let x = |t: f64| (t - t0) / scale;
        let (x0, x1) = (0.0, x(t_end).max(1e-9));
        let pct = |z: f64| 100.0 * z;
        let values: Vec<f64> = p
            .iter()
            .flat_map(|q| {
                q.zeta0
                    .into_iter()
                    .chain(q.interval.into_iter().flat_map(|(a, b)| [a, b]))
            })
            .chain(
                self.thresholds
                    .into_iter()
                    .flat_map(|t| [t.fire_below, t.clear_above]),
            )
            .chain([0.0])
            .map(pct)
            .collect();
        let (y0, y1) = span(&values);
        // room above the data for the legend, and below it for the verdict labels (at the top
        // they were hidden under the legend)
        let h = y1 - y0;
        let (y0, y1) = (y0 - 0.1 * h, y1 + 0.3 * h);
        let caption = format!("Damping of gate {} over time", self.gate);
        let mut chart = ChartBuilder::on(root)
            .caption(&caption, (FONT, TITLE_SIZE))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(format!(
                "window end, {unit} since {} (to {}, {} windows)",
                rfc3339(t0),
                rfc3339(t_end),
                p.len()
            ))
            .y_desc("damping ratio at rest zeta0 [%]")
            .x_label_formatter(&tick_format(x0, x1))
            .y_label_formatter(&tick_format(y0, y1))
            .label_style((FONT, LABEL_SIZE))
            .axis_desc_style((FONT, DESC_SIZE))
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        // the band: one polygon per run of consecutive windows with an interval
        let mut runs: Vec<Vec<(f64, (f64, f64))>> = Vec::new();
        let mut open = false;
        for q in p.iter().filter(|q| q.trusted) {
            match q.interval {
                Some((a, b)) if a.is_finite() && b.is_finite() => {
                    if !open {
                        runs.push(Vec::new());
                    }
                    if let Some(r) = runs.last_mut() {
                        r.push((x(q.time), (pct(a), pct(b))));
                    }
                    open = true;
                }
                _ => open = false,
            }
        }
        let band = BLUE.mix(0.2);
        chart
            .draw_series(runs.iter().map(|r| {
                let upper = r.iter().map(|(t, (_, b))| (*t, *b));
                let lower = r.iter().rev().map(|(t, (a, _))| (*t, *a));
                Polygon::new(upper.chain(lower).collect::<Vec<_>>(), band.filled())
            }))?
            .label("95 % interval of zeta0 (trusted windows)")
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], band.filled()));
        chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], GREY))?;
        if let Some(t) = self.thresholds {
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, pct(t.fire_below)), (x1, pct(t.fire_below))],
                    8,
                    6,
                    ORANGE.stroke_width(2),
                ))?
                .label(format!("fire below {} %", pct(t.fire_below)))
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], ORANGE.stroke_width(2))
                });
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, pct(t.clear_above)), (x1, pct(t.clear_above))],
                    8,
                    6,
                    GREEN.stroke_width(2),
                ))?
                .label(format!("clear above {} %", pct(t.clear_above)))
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], GREEN.stroke_width(2))
                });
        }
        // zeta0 of the trusted windows as a line (the alerts' input), the untrusted ones as
        // hollow grey circles off it: drawn alike, a window the daemon ignored read as evidence.
        let zeta = |trusted: bool| -> Vec<(f64, f64)> {
            p.iter()
                .filter(|q| q.trusted == trusted)
                .filter_map(|q| {
                    q.zeta0
                        .filter(|z| z.is_finite())
                        .map(|z| (x(q.time), pct(z)))
                })
                .collect()
        };
        let (trusted, untrusted) = (zeta(true), zeta(false));
        let (xs, ys): (Vec<f64>, Vec<f64>) = trusted.iter().copied().unzip();
        chart
            .draw_series(LineSeries::new(
                thin(&xs, &ys, (x0, x1), (y0, y1)),
                BLUE.stroke_width(2),
            ))?
            .label(if untrusted.is_empty() {
                format!("zeta0 ({} windows)", trusted.len())
            } else {
                format!("zeta0, trusted ({} windows)", trusted.len())
            })
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        if !untrusted.is_empty() {
            let hollow = GREY.stroke_width(1);
            chart
                .draw_series(untrusted.iter().map(|&q| Circle::new(q, 4, hollow)))?
                .label(format!(
                    "zeta0, untrusted ({} windows): not fed to the alerts",
                    untrusted.len()
                ))
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, hollow));
        }
        // verdict changes: a vertical mark, labelled with the new verdict
        let changes: Vec<(f64, &str)> = p
            .windows(2)
            .filter(|w| w[0].verdict != w[1].verdict)
            .map(|w| (x(w[1].time), w[1].verdict.as_str()))
            .collect();
        let top = y1 - 0.04 * (y1 - y0);
        let bottom = y0 + 0.015 * (y1 - y0);
        chart
            .draw_series(
                changes
                    .iter()
                    .map(|(t, _)| PathElement::new(vec![(*t, y0), (*t, top)], GREY.mix(0.6))),
            )?
            .label(format!("verdict change ({})", changes.len()))
            .legend(|(x, y)| PathElement::new(vec![(x + 10, y - 8), (x + 10, y + 8)], GREY));
        if changes.len() <= MAX_VERDICT_LABELS {
            // At the bottom, beside the mark: to its right in the left half, to its left in the
            // right half, so a change near the end is not clipped at the plot's edge.
            use plotters::style::text_anchor::{HPos, Pos, VPos};
            let mid = 0.5 * (x0 + x1);
            chart.draw_series(changes.iter().map(|(t, v)| {
                let (h, text) = if *t <= mid {
                    (HPos::Left, format!(" {v}"))
                } else {
                    (HPos::Right, format!("{v} "))
                };
                Text::new(
                    text,
                    (*t, bottom),
                    TextStyle::from((FONT, LABEL_SIZE - 4).into_font())
                        .color(&GREY)
                        .pos(Pos::new(h, VPos::Bottom)),
                )
            }))?;
        }
        legend_box(&mut chart, SeriesLabelPosition::UpperLeft)
    }
}

/// Damping over time for gate `gate`: zeta0 (percent) of each trusted window against its end
/// time as a line, untrusted windows as hollow grey circles, the 95 % interval as a band, the alert thresholds as dashed lines when known, a mark at
/// each verdict change. `points` oldest first. The x axis counts from the first window (in s,
/// min or h, by the span), and its title names the first and last window ends in RFC 3339.
pub fn damping_history(
    path: &Path,
    gate: &str,
    points: &[DampingPoint],
    thresholds: Option<Thresholds>,
) -> Result<(), PlotError> {
    if points.is_empty() {
        return Err(no_data(
            path,
            format!("gate {gate} has no identification in the range"),
        ));
    }
    if points.iter().any(|q| !q.time.is_finite()) {
        return Err(no_data(path, "a window end time is not finite"));
    }
    if points.windows(2).any(|w| w[1].time < w[0].time) {
        return Err(no_data(path, "the windows are not in time order"));
    }
    render(
        path,
        &HistoryFigure {
            gate,
            points,
            thresholds,
        },
    )
}
