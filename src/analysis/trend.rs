//! The trend of a gate's damping ratio over the last minutes, and when it will cross a threshold.
//!
//! Each identified window gives `zeta0` with a 95 % interval. [`DampingTrend`] keeps the recent
//! ones (a bounded horizon of SAMPLE time) and fits a straight line `zeta0(t) = level + slope *
//! (t - t_last)` by iteratively reweighted least squares, each figure at the instant it stands
//! for (the middle of the record behind it, [`TrendPoint::lag`] before its window's end: a pooled
//! figure reaches back further than its window), `t_last` the newest window's end:
//!
//! - each window weighs `1 / var`, its variance read off its interval (`half width / 1.96`), so a
//!   confident window counts more than a vague one, but never more than four times the horizon's
//!   median window (an interval far narrower than its peers' is more likely wrong than right); a window
//!   without an interval is no evidence and is not kept at all;
//! - Huber weights on the standardised residuals (`k = 1.345`, 95 % efficiency under normal
//!   errors) make a window that is wildly off (a bad fit that was still trusted) count as if it
//!   were only `k` standard deviations off, so one outlier cannot fake a trend;
//! - the slope's standard error is scaled by how the residuals scatter against what the
//!   intervals claim (scale `max(1, chi2 / (n - 2))`: wider when they scatter more, never
//!   narrower than the intervals say) and inflated for the correlation
//!   between figures whose records overlap (each pair correlated by the share of record they
//!   have in common, [`TrendPoint::lag`] being half the record), so the intervals' optimism and
//!   the overlap both widen it.
//!
//! The crossing time is given twice: from the slope itself ("expected") and from the slope's
//! one-sided 95 % upper bound `slope + t se` ("confident"), with `t` Student's quantile on the
//! windows' effective number less the line's two parameters (`n / overlap - 2`: the scale is
//! estimated from residuals that overlapping windows make fewer than the windows; 1.645 with
//! many, more where overlapping records leave few: 1.83 for the 11 or so that 120 figures of
//! 60 s records read every 5 s are worth): only when even that bound is negative is the
//! decline taken as real, and the confident crossing is the latest the line would cross at
//! that bound. `docs/damping.md` ("Trend") explains the choices.
//!
//! Pure and deterministic: no randomness, no I/O; memory bounded by [`MAX_TREND_POINTS`].

use std::collections::VecDeque;

use serde::Serialize;

/// Most windows kept per gate whatever the horizon: 10 minutes at one window every 5 s is 120;
/// the bound keeps a long horizon with a fast cadence from growing the fit's cost without limit
/// (the oldest windows are dropped first).
pub const MAX_TREND_POINTS: usize = 1024;

/// Fewest windows before a trend is estimated: a line through fewer points has almost no
/// degrees of freedom left to estimate its own scatter.
pub const MIN_TREND_POINTS: usize = 6;

/// z of a two-sided 95 % interval: half width = 1.96 standard deviations.
const Z95_TWO_SIDED: f64 = 1.959_963_984_540_054;
/// Probability of a one-sided 95 % bound (its quantile: Student's t on the effective windows).
const Z95_ONE_SIDED_PROB: f64 = 0.95;
/// Probability of each end of a two-sided 95 % band.
const Z95_TWO_SIDED_PROB: f64 = 0.975;
/// Huber's tuning constant (95 % efficiency at the normal distribution).
const HUBER_K: f64 = 1.345;
/// IRLS iterations: the weights settle in a few; a fixed count keeps the cost fixed.
const IRLS_ITERATIONS: usize = 10;
/// Least scale of the slope's variance: the residuals may say the windows' intervals are too
/// narrow, never that they are too wide. The intervals are a floor.
///
/// History: 1 until session 20, then 0.5 until stop 84. The windows' intervals were then
/// conservative (the pooled ambient estimates covered the truth in 97 to 100 % of the windows,
/// against 95 % claimed), and with the overlap factor below a floor of 1 counted the same
/// caution twice: the lock gate's slow drift warned 25 s after zero (docs/benchmarks.md, "The
/// trend's scale", session 20). Since stop 84 a slow gate's ambient estimate reads 100 cycles
/// of its history, and its intervals are about as wide as its readings scatter (24 h at +0.5 %:
/// the median interval 3.55 -> 1.97 points on the 2 Hz barrier gate, 2.09 -> 1.48 on the 5 Hz
/// lock gate, each still covering the truth in 99 % of the windows). On those,
/// the floor of 0.5 let the scatter of about ten independent values in a horizon make the slope
/// bound tighter than the intervals: in 24 h of the barrier gate at +0.5 % two false
/// `GateDampingDeclining`, and two of 200 cold starts (none at 1). The scatter of a fitted line's
/// correlated residuals understates the readings' own, so it may widen the slope's error but
/// not narrow it below what the intervals say (docs/benchmarks.md, "Stop 84").
const MIN_SCALE: f64 = 1.0;
/// Floor of a window's standard deviation (0.01 percentage point): an interval of zero width
/// would otherwise take all the weight.
const MIN_SD: f64 = 1e-4;

/// One window's damping ratio with its 95 % interval, kept at the sample time of the window's
/// end and fitted at the instant it stands for, `lag` seconds before.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrendPoint {
    /// Sample time of the window's last sample, seconds (any origin; Unix seconds in the daemon).
    pub t: f64,
    /// Seconds before `t` that the figure stands for: the middle of the record it read (half
    /// the window for a window read alone; more for a pooled figure, whose records reach back).
    /// The line is fitted at `t - lag` and read at the newest window's end. The record is
    /// taken as `2 lag` long, ending at `t`: figures whose records overlap are correlated, and
    /// the slope's error counts it (0: a figure that shares no record).
    pub lag: f64,
    /// The window's `zeta0`.
    pub zeta0: f64,
    /// Lower end of its 95 % interval.
    pub low: f64,
    /// Upper end of its 95 % interval.
    pub high: f64,
}

/// The fitted trend at the newest window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrendEstimate {
    /// Windows in the fit.
    pub windows: usize,
    /// Sample time spanned by them, seconds.
    pub span_seconds: f64,
    /// The line's value at the newest window's end (the smoothed current `zeta0`).
    pub level: f64,
    /// Standard error of `level`, scaled as the slope's and inflated for the windows' overlap
    /// and the line's misfit, whichever is larger (the band's: [`TrendEstimate::band_at`]).
    pub level_stderr: f64,
    /// Covariance of `level` and the slope (per second), for the band away from the newest
    /// window ([`TrendEstimate::band_at`]).
    #[serde(skip)]
    pub level_slope_covariance: f64,
    /// The slope's standard error as the band reckons it (inflated as `level_stderr`; at least
    /// `slope_stderr`).
    #[serde(skip)]
    pub band_slope_stderr: f64,
    /// Student's t quantile of a two-sided 95 % band on the windows' effective number less two.
    #[serde(skip)]
    pub band_quantile: f64,
    /// Slope, damping ratio per second of sample time (negative: declining).
    pub slope_per_second: f64,
    /// Standard error of the slope (inflated for excess scatter and window overlap).
    pub slope_stderr: f64,
    /// One-sided 95 % upper bound of the slope: `slope + t stderr`, `t` Student's 95 % quantile
    /// on the windows' effective number less two (1.645 with many independent windows).
    pub slope_upper: f64,
    /// The threshold the crossing times refer to (the alert's `fire_below`).
    pub threshold: f64,
    /// Seconds from the newest window until the line crosses `threshold` at the fitted slope;
    /// 0 when the level is already below it; `None` when the slope is not negative.
    pub crossing_seconds: Option<f64>,
    /// The same at the slope's upper bound: set only when even that bound is negative, i.e.
    /// the decline is significant at 95 % (one-sided). The figure an alert may act on.
    pub crossing_seconds_confident: Option<f64>,
}

impl TrendEstimate {
    /// Whether the trend says, with 95 % confidence, that `threshold` is crossed within
    /// `lead_seconds` (or already was).
    pub fn crosses_within(&self, lead_seconds: f64) -> bool {
        self.crossing_seconds_confident
            .is_some_and(|t| t <= lead_seconds)
    }

    /// Whether the trend declines with 95 % confidence (its slope's one-sided upper bound is
    /// negative) over at least `min_span_seconds` of windows: the trend `GateDampingDeclining`
    /// may act on (`trend_min_span_seconds`).
    pub fn declines(&self, min_span_seconds: f64) -> bool {
        self.slope_upper < 0.0 && self.span_seconds >= min_span_seconds
    }

    /// The line's two-sided 95 % confidence band `offset_seconds` after the newest window's end
    /// (negative: before it), from the level's and the slope's errors and their covariance,
    /// each inflated for the windows' overlap or for the line's misfit, whichever is larger: a
    /// claim on where `zeta0` itself lies must own the line's misfit (near zero the windows read
    /// high and bend away from it), which the slope's test of a decline need not (see
    /// `overlap_factor`).
    pub fn band_at(&self, offset_seconds: f64) -> (f64, f64) {
        let x = offset_seconds;
        let centre = self.level + self.slope_per_second * x;
        let var = self.level_stderr.powi(2)
            + x * x * self.band_slope_stderr.powi(2)
            + 2.0 * x * self.level_slope_covariance;
        let half = self.band_quantile * var.max(0.0).sqrt();
        (centre - half, centre + half)
    }
}

/// What the trend reads of one window's report (`analysis::trend_reading`): its figure, 95 %
/// interval and whether it is evidence, and how long before the window's end that figure
/// stands.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrendReading {
    /// The figure (`None`: no evidence).
    pub zeta0: Option<f64>,
    /// Its 95 % interval (`None`: no evidence).
    pub interval: Option<(f64, f64)>,
    /// Whether the window is evidence at all.
    pub trusted: bool,
    /// Seconds from the window's end back to the middle of the record behind the figure.
    pub lag_seconds: f64,
}

/// Why a point was refused by [`DampingTrend::push`].
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum TrendError {
    /// A time, lag, value or bound is NaN or infinite, or the lag is negative.
    #[error("trend point at t = {t} (lag {lag} s): zeta0 {zeta0} and interval ({low}, {high}) must be finite, the lag finite and not negative")]
    NotFinite {
        t: f64,
        lag: f64,
        zeta0: f64,
        low: f64,
        high: f64,
    },
    /// The interval's ends are reversed.
    #[error("trend point at t = {t}: interval ({low}, {high}) has its lower end above the upper")]
    Reversed { t: f64, low: f64, high: f64 },
    /// The point is older than the newest one kept (windows arrive in sample-time order).
    #[error("trend point at t = {t} is older than the newest point kept (t = {newest})")]
    OutOfOrder { t: f64, newest: f64 },
}

/// The recent windows of one gate and the robust trend through them.
#[derive(Debug, Clone)]
pub struct DampingTrend {
    horizon_seconds: f64,
    points: VecDeque<TrendPoint>,
    /// The newest window end at which the trend [`DampingTrend::observe`] returned declined
    /// with confidence (its slope's one-sided 95 % bound below zero), and its span then.
    confident_decline: Option<(f64, f64)>,
}

impl DampingTrend {
    /// A trend over the last `horizon_seconds` of sample time (a non-positive or non-finite
    /// horizon keeps only the newest window, so never yields a trend).
    pub fn new(horizon_seconds: f64) -> DampingTrend {
        DampingTrend {
            horizon_seconds: if horizon_seconds.is_finite() {
                horizon_seconds.max(0.0)
            } else {
                0.0
            },
            points: VecDeque::new(),
            confident_decline: None,
        }
    }

    /// The horizon, seconds of sample time.
    pub fn horizon_seconds(&self) -> f64 {
        self.horizon_seconds
    }

    /// The windows kept, oldest first.
    pub fn points(&self) -> impl Iterator<Item = &TrendPoint> {
        self.points.iter()
    }

    /// Forget every window (e.g. after a gap in the data or a change of the gate's settings).
    pub fn clear(&mut self) {
        self.points.clear();
        self.confident_decline = None;
    }

    /// Whether the trend declined with confidence over at least `min_span_seconds`
    /// ([`TrendEstimate::declines`]) at a window that ended within its horizon before `now`: a
    /// decline it confirmed and has not yet forgotten. Recorded by [`DampingTrend::observe`].
    pub fn declined_within_horizon(&self, now: f64, min_span_seconds: f64) -> bool {
        self.confident_decline.is_some_and(|(t, span)| {
            span >= min_span_seconds && t <= now && now - t <= self.horizon_seconds
        })
    }

    /// Add a window and drop those older than the horizon (and beyond [`MAX_TREND_POINTS`]).
    /// A point at the same time as the newest replaces it (a window identified twice).
    pub fn push(&mut self, p: TrendPoint) -> Result<(), TrendError> {
        let finite = p.t.is_finite() && p.zeta0.is_finite() && p.low.is_finite();
        if !(finite && p.high.is_finite() && p.lag.is_finite() && p.lag >= 0.0) {
            return Err(TrendError::NotFinite {
                t: p.t,
                lag: p.lag,
                zeta0: p.zeta0,
                low: p.low,
                high: p.high,
            });
        }
        if p.low > p.high {
            return Err(TrendError::Reversed {
                t: p.t,
                low: p.low,
                high: p.high,
            });
        }
        if let Some(last) = self.points.back() {
            if p.t < last.t {
                return Err(TrendError::OutOfOrder {
                    t: p.t,
                    newest: last.t,
                });
            }
            if p.t == last.t {
                self.points.pop_back();
            }
        }
        self.points.push_back(p);
        while self
            .points
            .front()
            .is_some_and(|f| p.t - f.t > self.horizon_seconds)
            || self.points.len() > MAX_TREND_POINTS
        {
            self.points.pop_front();
        }
        Ok(())
    }

    /// One identified window, as the daemon calls it: a trusted window with a finite `zeta0` and
    /// 95 % interval joins the trend (kept at `t`, its last sample's time, fitted at the instant
    /// its figure stands for, [`TrendReading::lag_seconds`] before); any other window is no
    /// evidence and is skipped (so is a window older than the newest kept: a replay). Returns the
    /// trend afterwards against `threshold`, and remembers it where it declines with confidence
    /// ([`DampingTrend::declined_within_horizon`]).
    pub fn observe(
        &mut self,
        t: f64,
        reading: TrendReading,
        threshold: f64,
    ) -> Option<TrendEstimate> {
        let TrendReading {
            zeta0,
            interval,
            trusted,
            lag_seconds,
        } = reading;
        if let (true, Some(zeta0), Some((low, high))) = (trusted, zeta0, interval) {
            // A refused point (non-finite, reversed, out of order) is simply not evidence.
            let _ = self.push(TrendPoint {
                t,
                lag: lag_seconds,
                zeta0,
                low,
                high,
            });
        }
        let estimate = self.estimate(threshold);
        if let (Some(e), Some(newest)) = (estimate, self.points.back()) {
            if e.slope_upper < 0.0 {
                self.confident_decline = Some((newest.t, e.span_seconds));
            }
        }
        estimate
    }

    /// The trend and its crossing of `threshold`; `None` with fewer than
    /// [`MIN_TREND_POINTS`] windows or when they all share one time.
    pub fn estimate(&self, threshold: f64) -> Option<TrendEstimate> {
        fit(self.points.iter().copied(), self.points.len(), threshold)
    }

    /// The line through the windows that ended at or before `until` alone, read at sample
    /// time `at`: its two-sided 95 % band there. A forecast of a reading whose record began at
    /// `until` from windows that share none of its samples; `None` where fewer than
    /// [`MIN_TREND_POINTS`] such windows are kept.
    pub fn forecast_band(&self, until: f64, at: f64) -> Option<(f64, f64)> {
        let before = self.points.iter().copied().filter(|p| p.t <= until);
        let newest = before.clone().next_back()?.t;
        let e = fit(before.clone(), before.count(), 0.0)?;
        Some(e.band_at(at - newest))
    }
}

/// The weighted robust line fit of [`DampingTrend::estimate`], over `points` in time order.
/// Exposed for callers (benchmarks) that keep their own series.
pub fn fit_trend(points: &[TrendPoint], threshold: f64) -> Option<TrendEstimate> {
    fit(points.iter().copied(), points.len(), threshold)
}

fn fit(
    points: impl Iterator<Item = TrendPoint> + Clone,
    n: usize,
    threshold: f64,
) -> Option<TrendEstimate> {
    if n < MIN_TREND_POINTS || !threshold.is_finite() {
        return None;
    }
    // Kept by their windows' ends, fitted at the instants their figures stand for, and read at
    // the newest window's end: a pooled figure stands for the middle of its records (a median
    // 16 s before its window's end on the 5 Hz lock gate, 30 s on the 2 Hz barrier gate), and
    // a line through the windows' ends would lag a drift by as much (docs/damping.md, "Trend").
    let t_last = points.clone().last()?.t;
    let t_first = points.clone().next()?.t;
    if t_last <= t_first {
        return None;
    }
    let x_of = |p: &TrendPoint| p.t - p.lag - t_last;
    // Each window's prior precision from its interval, never above four times that of the
    // horizon's (lower) median window (sd floored at half the median sd). Why: a model-sourced
    // window whose interval was ten times too narrow (-0.62 % (-0.71, -0.53) on a stable
    // +0.5 % lock gate) took the weight of 7 ordinary windows even after Huber's down-weighting,
    // at the line's end, and faked a confident decline (`bench warning`, 24 h of `stable-low`).
    // The floor at the median itself cost the slow drift's warning 55 s on the lab gate; half
    // of it costs nothing there (docs/benchmarks.md).
    let raw_sd = |p: &TrendPoint| ((p.high - p.low) / (2.0 * Z95_TWO_SIDED)).max(MIN_SD);
    let mut sds: Vec<f64> = points.clone().map(|p| raw_sd(&p)).collect();
    sds.sort_by(f64::total_cmp);
    let median_sd = sds[(sds.len() - 1) / 2]; // the lower median
    let sd = |p: &TrendPoint| raw_sd(p).max(0.5 * median_sd);
    let mut level = 0.0;
    let mut slope = 0.0;
    let mut sw = 0.0;
    let mut sx = 0.0;
    let mut sxx = 0.0;
    for it in 0..IRLS_ITERATIONS {
        let (mut s0, mut s1, mut s2, mut sy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for p in points.clone() {
            let x = x_of(&p);
            let s = sd(&p);
            let robust = if it == 0 {
                1.0
            } else {
                huber((p.zeta0 - level - slope * x) / s)
            };
            let w = robust / (s * s);
            s0 += w;
            s1 += w * x;
            s2 += w * x * x;
            sy += w * p.zeta0;
            sxy += w * x * p.zeta0;
        }
        let det = s0 * s2 - s1 * s1;
        if !(det.is_finite() && det > 0.0) {
            return None;
        }
        slope = (s0 * sxy - s1 * sy) / det;
        level = (sy - s1 * slope) / s0;
        (sw, sx, sxx) = (s0, s1, s2);
    }
    // Scale: how much more (or less) the residuals scatter than the intervals say, never below
    // MIN_SCALE.
    let mut chi2 = 0.0;
    let mut fitted = Vec::with_capacity(n);
    let (mut r_prev, mut c0, mut c1) = (None::<f64>, 0.0, 0.0);
    for p in points.clone() {
        let x = x_of(&p);
        let s = sd(&p);
        let r = (p.zeta0 - level - slope * x) / s;
        let robust = huber(r);
        chi2 += robust * r * r;
        c0 += r * r;
        if let Some(q) = r_prev {
            c1 += r * q;
        }
        r_prev = Some(r);
        fitted.push(Fitted {
            x,
            half_record: p.lag,
            weight: robust / (s * s),
            sd: s,
        });
    }
    let scale = (chi2 / (n - 2) as f64).max(MIN_SCALE);
    // The slope's test counts the correlation the shared records give the figures; the band,
    // a claim on where zeta0 itself lies, also the line's misfit, which the residuals' lag-1
    // autocorrelation shows (AR(1) factor; residuals at rounding level carry none). See
    // `overlap_factor`.
    let overlap = overlap_factor(&fitted);
    let rho = if c0 > 1e-6 * n as f64 {
        (c1 / c0).clamp(0.0, 0.9)
    } else {
        0.0
    };
    let band_overlap = overlap.max((1.0 + rho) / (1.0 - rho));
    let det = sw * sxx - sx * sx;
    let k = scale * overlap / det;
    let k_band = scale * band_overlap / det;
    let slope_stderr = (sw * k).sqrt();
    // The slope's error rests on the residuals' scatter, and overlapping windows leave fewer
    // independent residuals than windows: about n / overlap of them, less the line's two
    // parameters, give the t quantile. Why: with the normal quantile a steady +0.5 % lock gate
    // warned once in 24 h (the scale read off about 10 independent values at a window that
    // ended a run of low ones) once its pooled estimate was no longer biased high; a 2 Hz
    // barrier gate warned twice a day (`bench warning`, docs/benchmarks.md, session 39).
    let dof = (n as f64 / overlap - 2.0).max(1.0);
    let band_dof = (n as f64 / band_overlap - 2.0).max(1.0);
    let quantile = crate::spectral::t_quantile(Z95_ONE_SIDED_PROB, dof);
    let slope_upper = slope + quantile * slope_stderr;
    // A line already at or below the threshold "crosses it in 0 s" while it still falls; a flat
    // or rising one predicts nothing (the warning resolves when the trend flattens, issue 8,
    // and the damping alert stands for a gate that stays below).
    let crossing = |s: f64| {
        if s >= 0.0 || s.is_nan() {
            None
        } else if level <= threshold {
            Some(0.0)
        } else {
            Some((level - threshold) / -s)
        }
    };
    Some(TrendEstimate {
        windows: n,
        span_seconds: t_last - t_first,
        level,
        // x = 0 at the newest window's end: the level's variance and its covariance with the
        // slope, as the band reckons them
        level_stderr: (sxx * k_band).sqrt(),
        level_slope_covariance: -sx * k_band,
        band_slope_stderr: (sw * k_band).sqrt(),
        band_quantile: crate::spectral::t_quantile(Z95_TWO_SIDED_PROB, band_dof),
        slope_per_second: slope,
        slope_stderr,
        slope_upper,
        threshold,
        crossing_seconds: crossing(slope),
        crossing_seconds_confident: if slope_upper < 0.0 {
            crossing(slope_upper)
        } else {
            None
        },
    })
}

/// One figure as the fit weighed it, for [`overlap_factor`].
struct Fitted {
    /// Where it was fitted, seconds from the newest window's end (the middle of its record).
    x: f64,
    /// Half its record: the figure read the samples from `x - half_record` to `x + half_record`
    /// ([`TrendPoint::lag`]).
    half_record: f64,
    /// Its weight in the fit (Huber's weight over its variance).
    weight: f64,
    /// Its standard deviation.
    sd: f64,
}

/// How much the figures' shared records inflate the slope's variance: the variance of the
/// weighted least-squares slope with each pair of figures correlated by the share of record
/// they have in common (`overlap / sqrt(length_i length_j)`), over its variance were they
/// independent. At least 1; 1 where no two records overlap (a figure of no record, `lag` 0,
/// shares none).
///
/// Why from the records and not from the residuals (their lag-1 autocorrelation `r` and the
/// AR(1) factor `(1 + r) / (1 - r)`, until stop 96): figures read from overlapping records are
/// a moving average of the gate's motion, whose correlation falls linearly with the distance
/// and ends where the records part, while the AR(1) factor assumes a correlation that decays
/// geometrically for ever. Simulated (`the_slopes_error_counts_the_shared_records`), it made
/// the slope's standard error 1.28 and 1.26 times its scatter on 20 s and 50 s records read
/// every 5 s (the 5 Hz lock gate's and the 2 Hz barrier gate's 100 cycles), this factor 0.97
/// to 1.06 (the test's seeds and the replay's). And where the windows near zero read high and
/// bend away from the line, the residuals' correlation took the bend for overlap and held a
/// real decline's slope more uncertain still. The line's misfit is the band's business
/// ([`TrendEstimate::band_at`] keeps the larger of the two factors). On steady days
/// (docs/benchmarks.md, "Stop 96") the slope over its standard error scattered with a
/// standard deviation under 1 with either.
///
/// Cost: the records sorted by their start, each paired only with those that start before it
/// ends, `O(n log n + n k)` for `n` figures of which `k` overlap each (4 to 10 at the bench's
/// cadences). Every pair, as until stop 97, cost 0.45 ms at an hour's 720 figures and 1 ms at
/// [`MAX_TREND_POINTS`], twice per window (`cargo bench --bench trend`, docs/benchmarks.md).
fn overlap_factor(fitted: &[Fitted]) -> f64 {
    let (sw, sx) = fitted.iter().fold((0.0, 0.0), |(s0, s1), f| {
        (s0 + f.weight, s1 + f.weight * f.x)
    });
    // The slope is sum_i c_i z_i with c_i = w_i (sw x_i - sx) / det; u_i = c_i sd_i up to the
    // common factor 1 / det, which cancels in the ratio.
    let u = |f: &Fitted| f.weight * (sw * f.x - sx) * f.sd;
    let independent: f64 = fitted.iter().map(|f| u(f) * u(f)).sum();
    // (start, end, half record, u) of every figure with a record, by start.
    let mut records: Vec<(f64, f64, f64, f64)> = fitted
        .iter()
        .filter(|f| f.half_record > 0.0)
        .map(|f| {
            (
                f.x - f.half_record,
                f.x + f.half_record,
                f.half_record,
                u(f),
            )
        })
        .collect();
    records.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut shared = 0.0;
    for (i, &(a_start, a_end, a_half, ua)) in records.iter().enumerate() {
        debug_assert!(a_start <= a_end);
        // Later records start no earlier: one that starts at or after this one's end shares
        // nothing with it, nor does any after it.
        for &(b_start, b_end, b_half, ub) in records[i + 1..].iter() {
            if b_start >= a_end {
                break;
            }
            let common = a_end.min(b_end) - b_start;
            if common > 0.0 {
                let correlation = common / (2.0 * (a_half * b_half).sqrt());
                shared += 2.0 * ua * ub * correlation;
            }
        }
    }
    if independent > 0.0 && independent.is_finite() && shared.is_finite() {
        ((independent + shared) / independent).max(1.0)
    } else {
        1.0
    }
}

/// Huber's weight of a standardised residual.
fn huber(r: f64) -> f64 {
    let a = r.abs();
    if a <= HUBER_K {
        1.0
    } else {
        HUBER_K / a
    }
}

#[cfg(test)]
#[path = "trend_tests.rs"]
mod tests;
