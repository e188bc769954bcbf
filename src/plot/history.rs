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

/// Consecutive windows further apart than this many times the median spacing of the window
/// ends are a gap, across which neither the zeta0 line nor its band is drawn.
///
/// Why the median spacing: a gate's windows end every `identify_every_seconds`, which the store
/// does not record (and which may differ between gates and over time), but the median of the
/// spacings recovers it as long as fewer than half of them are gaps. Why 3: the worker pool
/// keeps only a gate's newest queued window, so under load one or two windows may be replaced
/// by the next (a spacing of 2 or 3 cadences) while the daemon runs and the windows, as long as
/// or longer than the cadence, still cover the signal; more than that is the daemon down, the
/// gate silent or its data refused, and a line drawn across it would show estimates that do
/// not exist.
const GAP_FACTOR: f64 = 3.0;

/// The spacing of window ends beyond which two consecutive windows are not joined:
/// [`GAP_FACTOR`] times the median of the positive spacings (equal ends, the same window
/// stored twice, say nothing of the cadence), with that median. `None` with fewer than two
/// distinct ends: nothing to join.
fn gap_threshold(points: &[DampingPoint]) -> Option<(f64, f64)> {
    let mut d: Vec<f64> = points
        .windows(2)
        .map(|w| w[1].time - w[0].time)
        .filter(|d| *d > 0.0)
        .collect();
    let median = crate::identify::median(&mut d)?;
    Some((GAP_FACTOR * median, median))
}

/// Runs of consecutive windows that may be joined by a line, as indices into `points` (oldest
/// first): a run ends before a window `keep` refuses (untrusted, or without the value drawn)
/// and before a window that ends more than `gap` seconds after the previous one.
fn runs(
    points: &[DampingPoint],
    gap: f64,
    keep: impl Fn(&DampingPoint) -> bool,
) -> Vec<Vec<usize>> {
    let mut out: Vec<Vec<usize>> = Vec::new();
    let mut open = false;
    for (i, q) in points.iter().enumerate() {
        if !keep(q) {
            open = false;
            continue;
        }
        let joined = open && i > 0 && q.time - points[i - 1].time <= gap;
        match out.last_mut() {
            Some(r) if joined => r.push(i),
            _ => out.push(vec![i]),
        }
        open = true;
    }
    out
}

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

/// A span of seconds as people read it (`1m 30s`, `500ms`), to the millisecond.
fn duration(s: f64) -> String {
    let ms = (s * 1000.0).round().clamp(0.0, u64::MAX as f64) as u64;
    humantime::format_duration(std::time::Duration::from_millis(ms)).to_string()
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
        // gaps in time: shaded, and neither the line nor the band crosses them
        let (gap, median) = gap_threshold(p).unwrap_or((f64::INFINITY, 0.0));
        let gaps: Vec<(f64, f64)> = p
            .windows(2)
            .filter(|w| w[1].time - w[0].time > gap)
            .map(|w| (x(w[0].time), x(w[1].time)))
            .collect();
        if !gaps.is_empty() {
            let shade = BLACK.mix(0.07);
            chart
                .draw_series(
                    gaps.iter()
                        .map(|&(a, b)| Rectangle::new([(a, y0), (b, y1)], shade.filled())),
                )?
                .label(format!(
                    "no windows for over {} ({GAP_FACTOR}x the median spacing, {}): {} gap{}",
                    duration(gap),
                    duration(median),
                    gaps.len(),
                    if gaps.len() == 1 { "" } else { "s" }
                ))
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 20, y + 6)], shade.filled())
                });
        }
        // the band: one polygon per run of consecutive trusted windows with an interval, no
        // run across an untrusted window or a gap; a window alone gets an error bar
        let interval = |q: &DampingPoint| match q.interval {
            Some((a, b)) if q.trusted && a.is_finite() && b.is_finite() => Some((a, b)),
            _ => None,
        };
        let band_runs: Vec<Vec<(f64, (f64, f64))>> = runs(p, gap, |q| interval(q).is_some())
            .iter()
            .map(|r| {
                r.iter()
                    .filter_map(|&i| interval(&p[i]).map(|(a, b)| (x(p[i].time), (pct(a), pct(b)))))
                    .collect()
            })
            .collect();
        let band = BLUE.mix(0.2);
        chart
            .draw_series(band_runs.iter().filter(|r| r.len() > 1).map(|r| {
                let upper = r.iter().map(|(t, (_, b))| (*t, *b));
                let lower = r.iter().rev().map(|(t, (a, _))| (*t, *a));
                Polygon::new(upper.chain(lower).collect::<Vec<_>>(), band.filled())
            }))?
            .label("95 % interval of zeta0 (trusted windows)")
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], band.filled()));
        chart.draw_series(band_runs.iter().filter(|r| r.len() == 1).map(|r| {
            let (t, (a, b)) = r[0];
            PathElement::new(vec![(t, a), (t, b)], BLUE.mix(0.4).stroke_width(3))
        }))?;
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
        // The line is broken at each untrusted window (or one without a finite zeta0) and at
        // each gap: joined across them it would show estimates nobody made. A trusted window
        // alone between two breaks is a dot.
        let finite = |q: &DampingPoint| q.zeta0.filter(|z| z.is_finite());
        let zeta = |trusted: bool| -> Vec<(f64, f64)> {
            p.iter()
                .filter(|q| q.trusted == trusted)
                .filter_map(|q| finite(q).map(|z| (x(q.time), pct(z))))
                .collect()
        };
        let (trusted, untrusted) = (zeta(true), zeta(false));
        let lines: Vec<Vec<(f64, f64)>> = runs(p, gap, |q| q.trusted && finite(q).is_some())
            .iter()
            .map(|r| {
                let (xs, ys): (Vec<f64>, Vec<f64>) = r
                    .iter()
                    .filter_map(|&i| finite(&p[i]).map(|z| (x(p[i].time), pct(z))))
                    .unzip();
                thin(&xs, &ys, (x0, x1), (y0, y1))
            })
            .collect();
        chart.draw_series(
            lines
                .iter()
                .filter(|l| l.len() == 1)
                .map(|l| Circle::new(l[0], 3, BLUE.filled())),
        )?;
        chart
            .draw_series(
                lines
                    .iter()
                    .filter(|l| l.len() > 1)
                    .map(|l| PathElement::new(l.clone(), BLUE.stroke_width(2))),
            )?
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
            let size = LABEL_SIZE - 4;
            // Changes a few pixels apart wrote their labels over each other ("unknowdampedunknown"):
            // each label takes the lowest of three rows where it overlaps no label already
            // placed, or stays unlabelled (its mark remains). Its width is estimated from its
            // characters (0.6 of the font size each, generous for the sans-serif digits and
            // letters used); the placement is in pixels, from the chart's own mapping.
            let row_height = (y1 - y0) * 0.045;
            let mut rows: [Vec<(i32, i32)>; 3] = Default::default();
            let mut labels = Vec::new();
            for (t, v) in &changes {
                let (h, text) = if *t <= mid {
                    (HPos::Left, format!(" {v}"))
                } else {
                    (HPos::Right, format!("{v} "))
                };
                let px = chart.backend_coord(&(*t, bottom)).0;
                let width = (text.chars().count() as f64 * 0.6 * size as f64).ceil() as i32;
                let span = if matches!(h, HPos::Left) {
                    (px, px + width)
                } else {
                    (px - width, px)
                };
                let free = rows.iter().position(|placed| {
                    placed
                        .iter()
                        .all(|&(a, b)| span.1 + 2 < a || b + 2 < span.0)
                });
                if let Some(r) = free {
                    rows[r].push(span);
                    labels.push((text, *t, bottom + r as f64 * row_height, h));
                }
            }
            chart.draw_series(labels.into_iter().map(|(text, t, y, h)| {
                Text::new(
                    text,
                    (t, y),
                    TextStyle::from((FONT, size).into_font())
                        .color(&GREY)
                        .pos(Pos::new(h, VPos::Bottom)),
                )
            }))?;
        }
        legend_box(&mut chart, SeriesLabelPosition::UpperLeft)
    }
}

/// Damping over time for gate `gate`: zeta0 (percent) of each trusted window against its end
/// time as a line, untrusted windows as hollow grey circles, the 95 % interval as a band, the
/// alert thresholds as dashed lines when known, a mark at each verdict change. The line and
/// the band break at every untrusted window and at every gap in time (consecutive windows more
/// than 3 times the median spacing apart, shaded grey): they join only windows that follow one
/// another and were all trusted. `points` oldest first. The x axis counts from the first
/// window (in s, min or h, by the span), and its title names the first and last window ends in
/// RFC 3339.
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
