//! A declining gate's `zeta0_interval` reaches down to what its trend forecasts.
//!
//! Near zero a gate whose damping grows with amplitude shows the damping at the amplitude it
//! has, and its noise-driven motion holds that above zero: the window reads high and cannot tell
//! how far below its reading `zeta0` lies (docs/damping.md, "Near zero, on a gate whose damping
//! grows with amplitude"). The trend's line through the windows before the reading's record,
//! most of them further from zero where that shift is small, forecasts where `zeta0` stands now.
//! Where the gate declines with confidence (or did within the trend's horizon and its line still
//! falls: near zero the high windows flatten it) and that forecast's 95 % band reaches below the
//! window's own interval, the report's interval is widened down to it: the union of two 95 %
//! intervals covers `zeta0` whenever either does. `zeta0` and the upper end stay the window's,
//! and the window's own interval is kept as `window_interval`, which the trend and the alert
//! read ([`DampingReport::own_interval`]): the trend never reads its own forecast back, and the
//! alert decides on the window's evidence as before. docs/damping.md, "A declining gate's
//! interval reaches down to its trend".

use super::{trend_reading, DampingReport, DampingTrend, TrendEstimate};

/// Widen window `d`'s `zeta0_interval` down to the lower end of the 95 % band that `history`
/// (the gate's trend, this window observed) forecasts for the instant the window's figure stands
/// for, from the windows that ended before the figure's record began (twice its lag before the
/// window's end, `window_end`; `window_seconds` the window's length). Only where `trend` (the
/// estimate after this window) declines with confidence over `min_span_seconds`
/// (`trend_min_span_seconds`), or its fitted slope is negative and `history` declined so within
/// its horizon ([`DampingTrend::declined_within_horizon`]), and where the forecast reaches below
/// the window's own lower end. Returns whether it widened.
pub fn reach_down_to_trend(
    d: &mut DampingReport,
    trend: &TrendEstimate,
    history: &DampingTrend,
    window_end: f64,
    window_seconds: f64,
    min_span_seconds: f64,
) -> bool {
    let (Some(_), Some((low, high))) = (d.zeta0, d.own_interval()) else {
        return false;
    };
    // A confident decline now, or one confirmed within the horizon while the line still falls:
    // near zero the windows read high and flatten the line until its slope's bound rises above
    // zero, though the gate goes on declining (the hysteresis of `GateDampingDeclining`, which
    // fires on a confident crossing and holds while the fitted line crosses).
    let declining = trend.declines(min_span_seconds)
        || (trend.slope_per_second < 0.0
            && history.declined_within_horizon(window_end, min_span_seconds));
    if !declining {
        return false;
    }
    let lag = trend_reading(d, window_seconds).lag_seconds;
    let Some((floor, _)) = history.forecast_band(window_end - 2.0 * lag, window_end - lag) else {
        return false;
    };
    if !(floor.is_finite() && floor < low) {
        return false;
    }
    d.window_interval = Some((low, high));
    d.zeta0_interval = Some((floor, high));
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::{TrendPoint, Zeta0Source};

    /// A gate drifting from +2 % down by 0.2 points a minute, one window every 5 s, each read
    /// `bias` high near the end (the last `biased` windows), with intervals of +-0.3 points.
    fn drifting(biased: usize, bias: f64) -> DampingTrend {
        let mut tr = DampingTrend::new(600.0);
        let n = 121;
        for i in 0..n {
            let t = 5.0 * i as f64;
            let truth = 0.02 - 0.002 * t / 60.0;
            let z = truth + if i + biased >= n { bias } else { 0.0 };
            tr.push(TrendPoint {
                t,
                lag: 5.0,
                zeta0: z,
                low: z - 0.003,
                high: z + 0.003,
            })
            .unwrap();
        }
        tr
    }

    fn window(z: f64, half: f64) -> DampingReport {
        DampingReport {
            zeta0: Some(z),
            zeta0_interval: Some((z - half, z + half)),
            zeta0_source: Some(Zeta0Source::Ambient),
            zeta0_lag_seconds: Some(5.0),
            trusted: true,
            ..DampingReport::default()
        }
    }

    #[test]
    fn a_declining_gate_near_zero_reads_down_to_its_forecast() {
        // the last minute's windows read 0.4 points high, as near zero
        let tr = drifting(12, 0.004);
        let trend = tr.estimate(0.0).unwrap();
        assert!(trend.declines(300.0), "{trend:?}");
        // the newest window: truth at 600 s is 0 %, read +0.4 % (+0.1, +0.7)
        let mut d = window(0.004, 0.003);
        assert!(reach_down_to_trend(&mut d, &trend, &tr, 600.0, 10.0, 300.0));
        let (low, high) = d.zeta0_interval.unwrap();
        assert_eq!(d.window_interval, Some((0.004 - 0.003, 0.004 + 0.003)));
        assert_eq!(high, 0.007, "the upper end is the window's");
        assert_eq!(d.zeta0, Some(0.004), "the figure is the window's");
        // the forecast from the windows before the record (up to 590 s) reaches below the truth
        assert!(low < 0.0 && low > -0.01, "{low}");
        // the trend and the alert read the window's own
        assert_eq!(d.own_interval(), d.window_interval);
        let reading = trend_reading(&d, 10.0);
        assert_eq!(reading.interval, d.window_interval);
    }

    #[test]
    fn only_a_confident_decline_over_the_span_widens_and_only_downwards() {
        let tr = drifting(0, 0.0);
        let trend = tr.estimate(0.0).unwrap();
        // a window already below the forecast is left alone
        let mut low = window(-0.004, 0.002);
        assert!(!reach_down_to_trend(
            &mut low, &trend, &tr, 600.0, 10.0, 300.0
        ));
        assert_eq!(low.window_interval, None);
        assert_eq!(low.zeta0_interval, Some((-0.006, -0.002)));
        // a young trend (span below the minimum) does not widen
        let mut d = window(0.006, 0.002);
        assert!(!reach_down_to_trend(
            &mut d, &trend, &tr, 600.0, 10.0, 900.0
        ));
        assert_eq!(d.zeta0_interval, Some((0.004, 0.008)));
        // nor a steady gate's trend
        let mut steady = DampingTrend::new(600.0);
        for i in 0..121 {
            let z = 0.01 + if i % 2 == 0 { 0.001 } else { -0.001 };
            let t = 5.0 * i as f64;
            steady
                .push(TrendPoint {
                    t,
                    lag: 5.0,
                    zeta0: z,
                    low: z - 0.003,
                    high: z + 0.003,
                })
                .unwrap();
        }
        let flat = steady.estimate(0.0).unwrap();
        assert!(!flat.declines(300.0));
        let mut d = window(0.02, 0.001);
        assert!(!reach_down_to_trend(
            &mut d, &flat, &steady, 600.0, 10.0, 300.0
        ));
        // a window without an interval or a figure is not touched
        let mut none = DampingReport {
            zeta0_interval: None,
            ..window(0.006, 0.002)
        };
        assert!(!reach_down_to_trend(
            &mut none, &trend, &tr, 600.0, 10.0, 300.0
        ));
        assert_eq!(none.window_interval, None);
    }

    #[test]
    fn a_decline_confirmed_within_the_horizon_reaches_while_the_line_falls() {
        // A drift from +2 % down by 0.2 points a minute, windows every 5 s reading +-0.4 points
        // about the truth with +-0.6 point intervals, observed as the daemon does; from 600 s
        // (the truth at 0) the windows hold at +0.3 % (the amplitude shift) while the truth
        // goes on down. `pushed` holds the same windows without `observe`: no memory.
        let mut observed = DampingTrend::new(600.0);
        let mut pushed = DampingTrend::new(600.0);
        let mut last_confident = None;
        for i in 0..=200 {
            let t = 5.0 * i as f64;
            let scatter = 0.004 * (((i * 7919) % 17) as f64 / 8.0 - 1.0);
            let z = scatter
                + if t <= 600.0 {
                    0.02 - 0.002 * t / 60.0
                } else {
                    0.003
                };
            let e = observed.observe(t, trend_reading(&window(z, 0.006), 10.0), 0.0);
            if e.is_some_and(|e| e.declines(300.0)) {
                last_confident = Some(t);
            }
            let p = TrendPoint {
                t,
                lag: 5.0,
                zeta0: z,
                low: z - 0.006,
                high: z + 0.006,
            };
            pushed.push(p).unwrap();
        }
        // the held windows flattened the line: its bound rose above zero, its slope still falls
        let trend = observed.estimate(0.0).unwrap();
        assert_eq!(pushed.estimate(0.0), Some(trend), "the same windows");
        assert!(
            !trend.declines(300.0) && trend.slope_per_second < 0.0,
            "{trend:?}"
        );
        let confirmed = last_confident.expect("the drift declined with confidence");
        assert!(confirmed > 600.0 && confirmed < 1000.0, "{confirmed}");
        assert!(observed.declined_within_horizon(1000.0, 300.0));
        assert!(
            !observed.declined_within_horizon(1000.0, 900.0),
            "a span too short"
        );
        assert!(
            !observed.declined_within_horizon(confirmed + 601.0, 300.0),
            "forgotten"
        );
        assert!(
            !pushed.declined_within_horizon(1000.0, 300.0),
            "push alone records nothing"
        );
        // a window reading +0.8 % (+0.4, +1.2) at 1000 s, truth -1.33 %: without the memory it
        // is left alone, with it it reads down to the line's forecast
        let mut alone = window(0.008, 0.004);
        assert!(!reach_down_to_trend(
            &mut alone, &trend, &pushed, 1000.0, 10.0, 300.0
        ));
        let own = window(0.008, 0.004).zeta0_interval;
        assert_eq!(alone.zeta0_interval, own);
        let mut d = window(0.008, 0.004);
        assert!(reach_down_to_trend(
            &mut d, &trend, &observed, 1000.0, 10.0, 300.0
        ));
        let (low, high) = d.zeta0_interval.unwrap();
        let forecast = observed.forecast_band(990.0, 995.0).unwrap();
        assert_eq!(low, forecast.0, "the forecast's lower end");
        assert!(low < 0.003, "{low}");
        assert_eq!(
            Some(high),
            own.map(|o| o.1),
            "the upper end is the window's"
        );
        assert_eq!(d.window_interval, own);
        // a rising line does not reach, memory or not
        let rising = TrendEstimate {
            slope_per_second: 1e-6,
            slope_upper: 2e-6,
            ..trend
        };
        let mut up = window(0.008, 0.004);
        assert!(!reach_down_to_trend(
            &mut up, &rising, &observed, 1000.0, 10.0, 300.0
        ));
        // forgetting the windows forgets the decline
        observed.clear();
        assert!(!observed.declined_within_horizon(1000.0, 300.0));
    }

    #[test]
    fn the_forecast_leaves_out_the_windows_that_share_the_record() {
        // the last 30 s read 2 points high
        let tr = drifting(6, 0.02);
        // the forecast until 570 s is the line through the windows up to 570 s alone
        let mut before = DampingTrend::new(600.0);
        for p in tr.points().filter(|p| p.t <= 570.0) {
            before.push(*p).unwrap();
        }
        let alone = before.estimate(0.0).unwrap().band_at(585.0 - 570.0);
        assert_eq!(tr.forecast_band(570.0, 585.0), Some(alone));
        // truth at 585 s is +0.05 %: that band brackets it
        assert!(alone.0 < 0.0005 && alone.1 > 0.0005, "{alone:?}");
        // a pooled figure standing 15 s back: its record began 30 s before the window's end,
        // and the window reads down to that forecast at the figure's instant
        let trend = tr.estimate(0.0).unwrap();
        let mut d = window(0.02, 0.003);
        d.zeta0_lag_seconds = Some(15.0);
        assert!(reach_down_to_trend(&mut d, &trend, &tr, 600.0, 10.0, 0.0));
        assert_eq!(d.zeta0_interval, Some((alone.0, 0.023)));
        // too few windows before the record: no forecast, nothing widened
        assert_eq!(tr.forecast_band(20.0, 30.0), None);
    }
}
