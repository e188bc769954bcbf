use super::*;
use approx::assert_relative_eq;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A window every 5 s whose `zeta0` scatters about `truth(t)` with sd `sd`, reporting an
/// honest 95 % interval `+- 1.96 sd`.
fn series(seed: u64, n: usize, sd: f64, truth: impl Fn(f64) -> f64) -> Vec<TrendPoint> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sd).unwrap();
    (0..n)
        .map(|i| {
            let t = 5.0 * i as f64;
            let z = truth(t) + noise.sample(&mut rng);
            TrendPoint {
                t,
                lag: 0.0,
                zeta0: z,
                low: z - 1.96 * sd,
                high: z + 1.96 * sd,
            }
        })
        .collect()
}

/// A figure is fitted at the instant it stands for, and the line is read at the newest window's
/// end: windows whose figures each read the drift `lag` seconds before their end (a pool's
/// records reach back) give the truth at the newest end, where a line through the windows' ends
/// reads it `lag` seconds late. Lags that differ from window to window (a pool that fills and
/// flushes) make no difference to an exact line.
#[test]
fn a_figure_stands_at_the_middle_of_its_record() {
    let truth = |t: f64| 0.02 - 2e-5 * t;
    let at = |lag: fn(usize) -> f64| -> Vec<TrendPoint> {
        (0..30)
            .map(|i| {
                let t = 5.0 * i as f64;
                let z = truth(t - lag(i));
                TrendPoint {
                    t,
                    lag: lag(i),
                    zeta0: z,
                    low: z - 0.002,
                    high: z + 0.002,
                }
            })
            .collect()
    };
    for lag in [|_| 20.0, |i| 5.0 + 2.5 * (i % 7) as f64] {
        let pts = at(lag);
        let e = fit_trend(&pts, 0.0).unwrap();
        assert_relative_eq!(e.slope_per_second, -2e-5, max_relative = 1e-9);
        assert_relative_eq!(e.level, truth(145.0), max_relative = 1e-9);
        assert_relative_eq!(
            e.crossing_seconds.unwrap(),
            1000.0 - 145.0,
            max_relative = 1e-6
        );
        assert_relative_eq!(e.span_seconds, 145.0);
        // the same figures kept at their windows' ends read the level late, by the lags
        let late: Vec<_> = pts.iter().map(|p| TrendPoint { lag: 0.0, ..*p }).collect();
        let l = fit_trend(&late, 0.0).unwrap();
        assert!(l.level > e.level + 2e-5 * 4.9, "{} {}", l.level, e.level);
    }
    // a negative or non-finite lag is refused
    let mut tr = DampingTrend::new(600.0);
    let p = at(|_| 10.0)[0];
    for lag in [-1.0, f64::NAN] {
        let e = tr.push(TrendPoint { lag, ..p }).unwrap_err();
        assert!(matches!(e, TrendError::NotFinite { .. }), "{e}");
    }
}

#[test]
fn exact_line_is_recovered() {
    let pts: Vec<_> = (0..20)
        .map(|i| {
            let t = 10.0 * i as f64;
            let z = 0.02 - 1e-5 * t;
            TrendPoint {
                t,
                lag: 0.0,
                zeta0: z,
                low: z - 0.002,
                high: z + 0.002,
            }
        })
        .collect();
    let e = fit_trend(&pts, 0.0).unwrap();
    assert_relative_eq!(e.slope_per_second, -1e-5, max_relative = 1e-9);
    // level at the newest window (t = 190): 0.02 - 0.0019
    assert_relative_eq!(e.level, 0.0181, max_relative = 1e-9);
    assert_relative_eq!(e.crossing_seconds.unwrap(), 1810.0, max_relative = 1e-6);
    // no scatter: the bound is the slope plus the intervals' own uncertainty, still negative
    assert!(e.crossing_seconds_confident.unwrap() >= e.crossing_seconds.unwrap());
    assert_eq!(e.windows, 20);
    assert_relative_eq!(e.span_seconds, 190.0);
    // no scatter at all: the intervals count at their variance (MIN_SCALE), not less;
    // sd = 0.002 / 1.96 each, sum of (t - mean t)^2 = 100 * 665
    let sd = 0.002 / Z95_TWO_SIDED;
    assert_relative_eq!(
        e.slope_stderr,
        (MIN_SCALE * sd * sd / 66_500.0).sqrt(),
        max_relative = 1e-9
    );
}

#[test]
fn the_intervals_are_a_floor_on_the_slopes_error() {
    // The estimates scatter by 0.3 points but claim 0.6: the slope's error is the claim's,
    // twice the honest one (the scatter may widen it, never narrow it below the intervals). A
    // steady gate still never predicts a crossing.
    let widen = |pts: Vec<TrendPoint>| -> Vec<TrendPoint> {
        pts.into_iter()
            .map(|p| TrendPoint {
                low: p.zeta0 - 2.0 * (p.zeta0 - p.low),
                high: p.zeta0 + 2.0 * (p.high - p.zeta0),
                ..p
            })
            .collect()
    };
    let mut ratios = Vec::new();
    for seed in 0..200 {
        let honest = fit_trend(&series(seed, 120, 0.003, |_| 0.005), 0.0).unwrap();
        let wide = fit_trend(&widen(series(seed, 120, 0.003, |_| 0.005)), 0.0).unwrap();
        assert!(!wide.crosses_within(600.0), "seed {seed}: {wide:?}");
        ratios.push(wide.slope_stderr / honest.slope_stderr);
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    assert!((1.8..2.2).contains(&median), "median ratio {median}");
}

#[test]
fn too_few_points_or_one_time_give_no_trend() {
    let pts = series(1, MIN_TREND_POINTS - 1, 0.003, |_| 0.01);
    assert!(fit_trend(&pts, 0.0).is_none());
    let same_t: Vec<_> = series(1, 10, 0.003, |_| 0.01)
        .into_iter()
        .map(|p| TrendPoint { t: 3.0, ..p })
        .collect();
    assert!(fit_trend(&same_t, 0.0).is_none());
    assert!(fit_trend(&series(1, 10, 0.003, |_| 0.01), f64::NAN).is_none());
}

#[test]
fn steady_gates_are_never_confidently_declining() {
    // +1 % and +0.5 %, sd 0.3 points (the ambient estimate's scatter on one 10 s window):
    // over 200 seeds, no 10-minute trend predicts a crossing of 0 within 10 minutes.
    for &truth in &[0.01, 0.005] {
        for seed in 0..200 {
            let pts = series(seed, 120, 0.003, |_| truth);
            let e = fit_trend(&pts, 0.0).unwrap();
            assert!(!e.crosses_within(600.0), "truth {truth} seed {seed}: {e:?}");
        }
    }
}

#[test]
fn slow_drift_is_seen_before_the_crossing() {
    // +2 % -> -2 % over 20 minutes: crosses 0 at t = 600 s. After 6 minutes of data the trend
    // must predict the crossing within 10 minutes, confidently, in every seed.
    let drift = |t: f64| 0.02 - 0.04 * t / 1200.0;
    for seed in 0..50 {
        let pts = series(seed, 73, 0.003, drift); // t = 0 .. 360 s
        let e = fit_trend(&pts, 0.0).unwrap();
        assert!(e.crosses_within(600.0), "seed {seed}: {e:?}");
        assert!(e.slope_per_second < 0.0);
        // the expected crossing is near the truth (240 s left)
        let left = e.crossing_seconds.unwrap();
        assert!((120.0..480.0).contains(&left), "seed {seed}: {left}");
    }
}

#[test]
fn one_wild_window_does_not_make_a_trend() {
    // a steady +1 % gate with one trusted window at -8 % (a bad fit) at the newest end, where a
    // plain least-squares line would tilt most
    let mut pts = series(7, 60, 0.003, |_| 0.01);
    let last = pts.len() - 1;
    pts[last].zeta0 = -0.08;
    pts[last].low = -0.08 - 0.006;
    pts[last].high = -0.08 + 0.006;
    let e = fit_trend(&pts, 0.0).unwrap();
    assert!(!e.crosses_within(600.0), "{e:?}");
    assert!(e.level > 0.005, "{e:?}");
}

#[test]
fn one_overconfident_window_does_not_make_a_trend() {
    // a steady +0.5 % lock gate (windows +- 1 point) and, at the newest end, one model window
    // reading -0.62 % (-0.71, -0.53): ten times narrower than its peers and wrong (24 h of
    // `bench warning --scenarios stable-low --gates lock`, where it fired GateDampingDeclining)
    for seed in 0..20 {
        let mut pts = series(seed, 120, 0.005, |_| 0.005);
        let last = pts.len() - 1;
        pts[last] = TrendPoint {
            t: pts[last].t,
            lag: 0.0,
            zeta0: -0.0062,
            low: -0.0071,
            high: -0.0053,
        };
        let e = fit_trend(&pts, 0.0).unwrap();
        assert!(!e.crosses_within(600.0), "seed {seed}: {e:?}");
    }
}

#[test]
fn wide_windows_weigh_less() {
    // alternate sharp windows on a flat +1 % with vague windows saying -5 %: the sharp ones win
    let pts: Vec<_> = (0..40)
        .map(|i| {
            let t = 5.0 * i as f64;
            if i % 2 == 0 {
                TrendPoint {
                    t,
                    lag: 0.0,
                    zeta0: 0.01,
                    low: 0.009,
                    high: 0.011,
                }
            } else {
                TrendPoint {
                    t,
                    lag: 0.0,
                    zeta0: -0.05,
                    low: -0.5,
                    high: 0.4,
                }
            }
        })
        .collect();
    let e = fit_trend(&pts, 0.0).unwrap();
    assert!((e.level - 0.01).abs() < 0.001, "{e:?}");
}

#[test]
fn horizon_and_bounds_are_kept() {
    let mut tr = DampingTrend::new(60.0);
    for i in 0..100 {
        let t = 5.0 * i as f64;
        tr.push(TrendPoint {
            t,
            lag: 0.0,
            zeta0: 0.01,
            low: 0.0,
            high: 0.02,
        })
        .unwrap();
    }
    // 60 s at one window per 5 s: t = 435 .. 495
    assert_eq!(tr.points().count(), 13);
    assert_relative_eq!(tr.points().next().unwrap().t, 435.0);
    // the same time again replaces the newest
    tr.push(TrendPoint {
        t: 495.0,
        lag: 0.0,
        zeta0: 0.02,
        low: 0.01,
        high: 0.03,
    })
    .unwrap();
    assert_eq!(tr.points().count(), 13);
    assert_relative_eq!(tr.points().last().unwrap().zeta0, 0.02);
    // the count bound holds whatever the horizon
    let mut long = DampingTrend::new(1e9);
    for i in 0..(MAX_TREND_POINTS + 10) {
        long.push(TrendPoint {
            t: i as f64,
            lag: 0.0,
            zeta0: 0.0,
            low: -0.1,
            high: 0.1,
        })
        .unwrap();
    }
    assert_eq!(long.points().count(), MAX_TREND_POINTS);
}

#[test]
fn bad_points_are_refused_with_their_time() {
    let mut tr = DampingTrend::new(600.0);
    let ok = TrendPoint {
        t: 10.0,
        lag: 0.0,
        zeta0: 0.01,
        low: 0.0,
        high: 0.02,
    };
    tr.push(ok).unwrap();
    let e = tr
        .push(TrendPoint {
            zeta0: f64::NAN,
            ..ok
        })
        .unwrap_err();
    assert!(matches!(e, TrendError::NotFinite { .. }));
    assert!(e.to_string().contains("t = 10"));
    let e = tr.push(TrendPoint { low: 0.03, ..ok }).unwrap_err();
    assert!(matches!(e, TrendError::Reversed { .. }));
    let e = tr.push(TrendPoint { t: 5.0, ..ok }).unwrap_err();
    assert_eq!(
        e,
        TrendError::OutOfOrder {
            t: 5.0,
            newest: 10.0
        }
    );
    assert_eq!(tr.points().count(), 1);
}

/// The bound's quantile follows the windows' effective number: 120 independent windows leave
/// it near the normal 1.645; windows that wander together (a pooled figure sharing most of its
/// record with its neighbours, here a moving average over 12 windows, a record of 60 s) are
/// worth about eleven, and the bound stands further above the slope (Student's t on
/// `n / overlap - 2`).
#[test]
fn correlated_windows_widen_the_bound_beyond_the_normal_quantile() {
    let ratio = |pts: &[TrendPoint]| {
        let e = fit_trend(pts, 0.0).unwrap();
        (e.slope_upper - e.slope_per_second) / e.slope_stderr
    };
    let independent = series(7, 120, 0.002, |_| 0.01);
    let r = ratio(&independent);
    assert!((1.645..1.75).contains(&r), "independent windows: t = {r}");
    // the same noise, each window the mean of the last 12 (as a 60 s pool every 5 s)
    let wide = series(7, 131, 0.002, |_| 0.01);
    let pooled: Vec<TrendPoint> = wide
        .windows(12)
        .map(|w| {
            let z = w.iter().map(|p| p.zeta0).sum::<f64>() / 12.0;
            let last = w[11];
            TrendPoint {
                t: last.t,
                lag: 30.0,
                zeta0: z,
                low: z - 1.96 * 0.002,
                high: z + 1.96 * 0.002,
            }
        })
        .collect();
    assert_eq!(pooled.len(), 120);
    let r = ratio(&pooled);
    // (1.83 here, t with 9 degrees of freedom: 60 s records every 5 s share 11/12, 10/12, ...
    // of their samples with their neighbours, so 120 windows count as about 11; with the
    // normal quantile it was 1.645 whatever the overlap)
    assert!(r > 1.75, "windows that share their record: t = {r}");
}

/// The slope's standard error counts the records the figures share, no more and no less: a
/// figure every 5 s, each the mean of the last `m` independent 5 s readings (a record of
/// `5 m` s, so `lag = 2.5 m`) with an honest interval. Over 400 seeds the slope scatters as
/// its standard error says, within sampling error, whether the records are 5, 20 or 50 s long
/// (0.97 to 0.99 here; the residuals' AR(1) factor, before stop 96, made the standard error
/// 1.28 and 1.26 times the scatter on the 20 s and 50 s records, replayed in
/// `benches/python/trend_replay.py`'s transcription).
#[test]
fn the_slopes_error_counts_the_shared_records() {
    for m in [1usize, 4, 10] {
        let (mut slopes, mut variances) = (Vec::new(), Vec::new());
        for seed in 0..400 {
            let raw = series(1000 + seed, 119 + m, 0.003, |_| 0.01);
            let sd = 0.003 / (m as f64).sqrt();
            let pts: Vec<TrendPoint> = raw
                .windows(m)
                .map(|w| {
                    let z = w.iter().map(|p| p.zeta0).sum::<f64>() / m as f64;
                    TrendPoint {
                        t: w[m - 1].t,
                        lag: 2.5 * m as f64,
                        zeta0: z,
                        low: z - 1.96 * sd,
                        high: z + 1.96 * sd,
                    }
                })
                .collect();
            assert_eq!(pts.len(), 120);
            let e = fit_trend(&pts, 0.0).unwrap();
            slopes.push(e.slope_per_second);
            variances.push(e.slope_stderr.powi(2));
        }
        let mean = slopes.iter().sum::<f64>() / 400.0;
        let scatter = slopes.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / 399.0;
        let claimed = variances.iter().sum::<f64>() / 400.0;
        let ratio = (claimed / scatter).sqrt();
        // 400 seeds: the scatter's own relative error is about 3.5 %
        assert!(
            (0.9..1.2).contains(&ratio),
            "records of {m} readings: se / sd {ratio}"
        );
    }
}

/// The overlap factor pairs each record only with those that start before it ends; it must
/// give what every pair gives, whatever the records' order and lengths (pooled figures stand
/// for instants out of their windows' order, and some carry no record at all).
#[test]
fn the_overlap_factor_sums_every_overlapping_pair() {
    fn every_pair(fitted: &[Fitted]) -> f64 {
        let sw: f64 = fitted.iter().map(|f| f.weight).sum();
        let sx: f64 = fitted.iter().map(|f| f.weight * f.x).sum();
        let u = |f: &Fitted| f.weight * (sw * f.x - sx) * f.sd;
        let (mut independent, mut shared) = (0.0, 0.0);
        for (i, a) in fitted.iter().enumerate() {
            independent += u(a) * u(a);
            for b in &fitted[i + 1..] {
                if a.half_record <= 0.0 || b.half_record <= 0.0 {
                    continue;
                }
                let common = (a.x + a.half_record).min(b.x + b.half_record)
                    - (a.x - a.half_record).max(b.x - b.half_record);
                if common > 0.0 {
                    let c = common / (2.0 * (a.half_record * b.half_record).sqrt());
                    shared += 2.0 * u(a) * u(b) * c;
                }
            }
        }
        ((independent + shared) / independent).max(1.0)
    }
    let mut rng = ChaCha8Rng::seed_from_u64(97);
    let unit = rand_distr::Uniform::new(0.0, 1.0).unwrap();
    for n in [3usize, 20, 120, 400] {
        let fitted: Vec<Fitted> = (0..n)
            .map(|i| {
                let half_record = match i % 5 {
                    0 => 0.0,
                    1 => 2.5,
                    _ => 30.0 * unit.sample(&mut rng),
                };
                Fitted {
                    // windows every 5 s, their figures standing up to 30 s before their ends
                    x: -5.0 * (n - 1 - i) as f64 - 30.0 * unit.sample(&mut rng),
                    half_record,
                    weight: 0.5 + unit.sample(&mut rng),
                    sd: 0.5 + unit.sample(&mut rng),
                }
            })
            .collect();
        let (banded, reference) = (overlap_factor(&fitted), every_pair(&fitted));
        assert!(
            reference > 1.05,
            "{n} figures: records overlap, {reference}"
        );
        assert_relative_eq!(banded, reference, max_relative = 1e-9);
    }
    // no records, no overlap
    let alone: Vec<Fitted> = (0..10)
        .map(|i| Fitted {
            x: i as f64,
            half_record: 0.0,
            weight: 1.0,
            sd: 1.0,
        })
        .collect();
    assert_eq!(overlap_factor(&alone), 1.0);
}

/// A line at or below the threshold crosses it "in 0 s" while it falls; flat or rising there it
/// predicts no crossing at all, so a warning that fired on the way down resolves once the gate
/// settles on its limit cycle (issue 8: the warning resolves when the trend flattens; the
/// damping alert stands for the gate below). Before, any line below the threshold read 0 s.
#[test]
fn below_the_threshold_only_a_falling_line_crosses() {
    let line = |slope: f64| -> Vec<TrendPoint> {
        (0..40)
            .map(|i| {
                let t = 5.0 * i as f64;
                let z = -0.02 + slope * (t - 195.0);
                TrendPoint {
                    t,
                    lag: 0.0,
                    zeta0: z,
                    low: z - 0.004,
                    high: z + 0.004,
                }
            })
            .collect()
    };
    let falling = fit_trend(&line(-2e-5), 0.0).unwrap();
    assert!(falling.level < 0.0);
    assert_eq!(falling.crossing_seconds, Some(0.0));
    assert_eq!(falling.crossing_seconds_confident, Some(0.0));
    for slope in [1e-7, 2e-5] {
        let e = fit_trend(&line(slope), 0.0).unwrap();
        assert!(e.level < 0.0, "{e:?}");
        assert_eq!(e.crossing_seconds, None, "slope {slope}: {e:?}");
        assert_eq!(e.crossing_seconds_confident, None, "slope {slope}: {e:?}");
    }
    // a flat line scattered below: whichever way the fitted slope tips, no confident crossing
    // unless the slope is confidently negative
    let noisy = series(3, 40, 0.003, |_| -0.02);
    let e = fit_trend(&noisy, 0.0).unwrap();
    assert_eq!(
        e.crossing_seconds.is_some(),
        e.slope_per_second < 0.0,
        "{e:?}"
    );
    assert_eq!(
        e.crossing_seconds_confident.is_some(),
        e.slope_upper < 0.0,
        "{e:?}"
    );
}
