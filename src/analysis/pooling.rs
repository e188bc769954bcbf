//! A gate's consecutive model-free estimates of `zeta0` pooled, so the record behind the reported
//! figure follows the gate's period, not the window's seconds (`docs/damping.md`, "Pooling
//! windows").
//!
//! # Why here, after the window's verdict
//! One 10 s window holds 100 cycles of the 10.4 Hz lab gate but 50 of a 5 Hz lock gate: Au's law
//! puts the physical spread of one lock-gate window at about 0.8 points at +2 %, above the 0.5
//! points an operator needs, and the envelope estimate of one limit-cycle window is often too wide
//! to exclude zero. [`ZetaPools`] keeps the gate's last estimates of each model-free source
//! ([`spectral::DampingPool`]: cycle-weighted, the overlap of consecutive windows counted in the
//! variance, flushed on a regime change once a second window confirms it) and replaces the
//! window's own figure and interval with the pooled ones. It runs on the gate's memory, in window order, after [`super::decide`] chose
//! the source; the verdict is then re-read from the pooled interval by the same rows.
//!
//! A model-based window, an untrusted one, an ambient one that left the gate's ambient level
//! (`analysis::departed`) or one whose variance grows (`analysis::read_growing_window`) empties
//! both pools: the regime changed (growth) or the estimate is no
//! evidence, and a pool must never carry a stale regime into the next. (The last: on the lock
//! gate's onset ramp the ambient pool of the +1 % windows read +1.28 % (-0.17, +2.73) at a true
//! -0.67 % on a window 3.5 times above the level.)

use serde::{Deserialize, Serialize};

use super::ambient_level::departed;
use super::report::{AmbientZeta, DampingReport, Verdict, Zeta0Source};
use super::trend::TrendReading;
use super::verdict::falls;
use crate::spectral::{self, DampingPool, PoolLocation, PoolOptions, Regime, WindowEstimate};

/// The pooling of a gate (`[defaults.pooling]` / `[gates.ID.pooling]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoolingSettings {
    /// Pool consecutive windows (default true); false reports every window alone.
    pub enabled: bool,
    /// Distinct cycles of the gate's frequency the pool aims for (default 150: Au's law puts
    /// the spread at about 0.45 points at +2 %, and the pool spans 15 s of the 10.4 Hz lab gate
    /// or 30 s of a 5 Hz lock gate, so it lags a fast onset by a few seconds only).
    pub min_cycles: f64,
    /// The pool never spans more sample time than this, s (default 60; bounds the lag behind
    /// a drift on a slow gate).
    pub max_seconds: f64,
}

impl Default for PoolingSettings {
    fn default() -> Self {
        PoolingSettings {
            enabled: true,
            min_cycles: 150.0,
            max_seconds: 60.0,
        }
    }
}

impl PoolingSettings {
    /// The pools these settings make, `None` when pooling is off; `Err` names the bad key.
    pub fn pools(&self) -> Result<Option<ZetaPools>, String> {
        if !(self.min_cycles.is_finite() && self.min_cycles > 0.0) {
            return Err("min_cycles: must be a positive number".into());
        }
        if !(self.max_seconds.is_finite() && self.max_seconds > 0.0) {
            return Err("max_seconds: must be a positive number of seconds".into());
        }
        if !self.enabled {
            return Ok(None);
        }
        let opts = PoolOptions {
            min_cycles: self.min_cycles,
            max_seconds: self.max_seconds,
            ..PoolOptions::default()
        };
        ZetaPools::new(opts).map(Some).map_err(|e| e.to_string())
    }
}

/// The gate's pools, one per model-free source.
#[derive(Debug, Clone, PartialEq)]
pub struct ZetaPools {
    ambient: DampingPool,
    envelope: DampingPool,
    /// The configured `max_seconds` (the pools' own follow the window: [`Self::follow_window`]).
    max_seconds: f64,
}

/// Windows' lengths a pool may span whatever `max_seconds` says ([`ZetaPools::follow_window`]).
/// Why three: a 1 Hz gate's 50 s windows in pools of 60 s never trusted its held limit cycle,
/// which a gate without an ambient level trusts from 140 distinct cycles of pooled record; in
/// pools of 150 s it fired at 150 s (docs/benchmarks.md, "Stop 85").
pub const POOL_MIN_WINDOWS: f64 = 3.0;

impl ZetaPools {
    /// Empty pools with `opts` (checked).
    pub fn new(opts: PoolOptions) -> Result<ZetaPools, spectral::SpectralError> {
        Ok(ZetaPools {
            // SSI-COV's estimates are skewed to the right and their spread grows with zeta:
            // Hodges-Lehmann in the square-root scale, not their mean (`spectral::pool`,
            // "Combination")
            ambient: DampingPool::new(PoolOptions {
                location: PoolLocation::SqrtHodgesLehmann,
                // its estimates read up to 100 cycles of history (`ambient_record_zeta`)
                count_records: true,
                // and one state of the gate: a reading whose window's RMS is three times the
                // newest's or a third of it, the bar at which a window counts as having left
                // its ambient level, ends the pool (docs/damping.md, "A pool holds one level")
                max_level_change: Some(super::ambient_level::DEPARTED_FROM_AMBIENT),
                ..opts
            })?,
            envelope: DampingPool::new(opts)?,
            max_seconds: opts.max_seconds,
        })
    }

    /// Lets the pools span [`POOL_MIN_WINDOWS`] windows of `window_seconds` where that is more
    /// than the configured `max_seconds`: the daemon lengthens a slow gate's window to hold
    /// `window_cycles` (`service::window_span`), and its pools follow. Returns the pools' bound.
    pub fn follow_window(&mut self, window_seconds: f64) -> f64 {
        let bound = if window_seconds.is_finite() {
            self.max_seconds.max(POOL_MIN_WINDOWS * window_seconds)
        } else {
            self.max_seconds
        };
        self.ambient.set_max_seconds(bound);
        self.envelope.set_max_seconds(bound);
        bound
    }

    /// Pools the report of the window `[t_start, t_end]` (sample time) into its source's pool
    /// and rewrites `zeta0`, its interval, `zeta0_windows`, the verdict and `trusted` from the
    /// pooled estimate. Reports from the model, untrusted ambient ones, ambient ones from a
    /// window that left the gate's ambient level ([`departed`]: another regime, which the
    /// ambient windows before it must not average away) and reports without a frequency pass
    /// unchanged and empty the pools.
    pub fn apply(&mut self, t_start: f64, t_end: f64, d: &mut DampingReport) {
        let source = d.zeta0_source;
        // a window that neither rose nor fell is read with its history where that holds more
        // cycles than the window (`ambient_record_zeta`): the pool then counts that record
        let record = match (d.ambient_record_zeta, d.ambient_record_seconds) {
            (Some(a), Some(s))
                if !stands_alone(d) && a.low <= a.high && s.is_finite() && s > 0.0 =>
            {
                Some((a, s))
            }
            _ => None,
        };
        let pooled = match (source, d.zeta0, d.zeta0_interval, d.frequency_hz) {
            (Some(Zeta0Source::Ambient), Some(z), Some(iv), Some(f))
                if d.trusted && !departed(d) && !d.ssi_growing =>
            {
                self.envelope.clear();
                // "the same mode" is tested on the estimate's own pole, not the spectral peak:
                // the peak of one 10 s window of a 2 Hz gate scatters by 3 % (a bin is 5 %), and
                // flushed the pool at every eighth window on the 5 % test
                let f = d
                    .ambient_frequency_hz
                    .filter(|g| g.is_finite() && *g > 0.0)
                    .unwrap_or(f);
                let rms = d.signal_rms;
                match record {
                    Some((a, s)) => push(
                        &mut self.ambient,
                        (t_start, t_end, s),
                        a.zeta,
                        (a.low, a.high),
                        (f, rms),
                    ),
                    None => push(&mut self.ambient, (t_start, t_end, 0.0), z, iv, (f, rms)),
                }
            }
            (Some(Zeta0Source::Envelope), Some(z), Some(iv), Some(f)) => {
                self.ambient.clear();
                // the relaxation reads up to RELAXATION_CYCLES of the gate's history:
                // consecutive estimates share that record, not only their windows' overlap
                // (`envelope_record_seconds`, the record the estimate read; a report without it,
                // stored before stop 83, claims the whole 100 cycles)
                let record = d
                    .envelope_record_seconds
                    .filter(|s| s.is_finite() && *s > 0.0)
                    .unwrap_or(super::model_free::RELAXATION_CYCLES / f);
                push(
                    &mut self.envelope,
                    (t_start, t_end, record),
                    z,
                    iv,
                    (f, None),
                )
            }
            _ => None,
        };
        let Some(p) = pooled else {
            self.ambient.clear();
            self.envelope.clear();
            return;
        };
        let lag = t_end - p.record_middle;
        if p.windows < 2 {
            // alone in its pool: the window's own (possibly asymmetric) interval and verdict, or
            // its record's ...
            d.zeta0_windows = Some(1);
            d.zeta0_lag_seconds = Some(lag);
            if let (Some(Zeta0Source::Ambient), Some((a, _))) = (source, record) {
                d.zeta0 = Some(a.zeta);
                d.zeta0_interval = Some((a.low, a.high));
                (d.verdict, d.trusted) = ambient_rows((a.low, a.high), d.regime);
            }
            if source == Some(Zeta0Source::Ambient) {
                // a rising window has no record: its own reading, spanned with the filter's
                span_the_prediction_errors(d);
            }
            if source == Some(Zeta0Source::Envelope) {
                // ... but a lone limit-cycle window is no evidence yet: a limit cycle is a state
                // a gate stays in, and a noise-driven +0.5 % window whose envelope happens to be
                // steady (and whose SSI point happens to be below 0.1 %) is classified as one
                // about once in a few hundred windows; its envelope relaxation then read
                // -1.8 % (-3.4, -0.2) on the lab gate (`bench warning`, stable-low).
                d.verdict = Verdict::Unknown;
                d.trusted = false;
            }
            return;
        }
        if source == Some(Zeta0Source::Ambient) && stands_alone(d) {
            // the window's own figure, interval and verdict stand; the pool keeps it, and the
            // trend reads the pool's figure (`trend_reading`)
            d.zeta0_windows = Some(1);
            d.pooled_zeta = Some(AmbientZeta::from(&p));
            d.pooled_lag_seconds = Some(lag);
            span_the_prediction_errors(d);
            return;
        }
        d.zeta0 = Some(p.zeta);
        d.zeta0_interval = Some(p.interval);
        d.zeta0_windows = Some(p.windows);
        d.zeta0_lag_seconds = Some(lag);
        d.zeta0_held = p.held;
        (d.verdict, d.trusted) = match source {
            // the rows of `decide` for the envelope: negative, or cannot tell (untrusted); on a
            // gate still at its ambient level a pool is evidence only from
            // `MIN_CYCLE_POOL_CYCLES` on
            Some(Zeta0Source::Envelope)
                if p.interval.1 < 0.0
                    && (departed(d) || p.record_cycles >= MIN_CYCLE_POOL_CYCLES) =>
            {
                (Verdict::SelfExcited, true)
            }
            Some(Zeta0Source::Envelope) => {
                if p.interval.1 < 0.0 {
                    // short of the cycles: no evidence for the alert, but the trend reads the
                    // pool's figure as before (`trend_reading`): without it the lock gate's
                    // slow drift warned 50 s later on one of 40 seeds (stop 82)
                    d.pooled_zeta = Some(AmbientZeta::from(&p));
                    d.pooled_lag_seconds = Some(lag);
                }
                (Verdict::Unknown, false)
            }
            _ => ambient_rows(p.interval, d.regime),
        };
    }
}

/// Distinct cycles of record (`PooledEstimate::record_cycles`) a pool of limit-cycle readings
/// needs before it is evidence (`trusted`, a verdict) on a gate that has not left its ambient
/// level (`analysis::departed`), or has no level yet. Above the departure ratio the lone-window
/// rule alone holds (the alert then reads such a window by its regime too). Short of the cycles
/// the pool's figure still goes to the trend (`DampingReport::pooled_zeta`).
///
/// Why: the envelope's relaxation reads every window it is given as a cycle, so negative, and a
/// lightly damped stable gate's envelope is now and then steady for a few windows. A stretch of
/// a noise-driven envelope lasts a number of cycles (its correlation time is `1 / (2 pi zeta)`
/// cycles), not of windows; two windows are 156 cycles of the lab gate (10.4 Hz, the window its
/// record) but 125 of a 5 Hz lock gate (20 s records 5 s apart). In 180 h of the lock gate at
/// +0.5 % (stop 82) three such stretches gave a pool of two windows a confident negative reading,
/// and in stop 81 two in a row paged (seed 24); the lab gate's pairs never did. At 140 cycles a
/// lock pool needs three windows (150 cycles), the lab gate's two as before, each with a margin
/// of a tenth for the frequency's scatter; on the lock gate's slow drift 3 of 40 first
/// `GateNegativeDamping` came 5 s later (docs/benchmarks.md, "Stop 82").
pub const MIN_CYCLE_POOL_CYCLES: f64 = 140.0;

/// Share of the departure ratio from which a noise-driven window counts as rising
/// ([`rising`]).
pub const RISING_SHARE: f64 = 0.5;

/// Whether an ambient window rose towards the departure ratio: it stands at least
/// [`RISING_SHARE`] of `departure_ratio` above the gate's ambient level (1.5 on a gate whose
/// windows hold 50 cycles or more). Such a window is reported alone, with its own figure and
/// interval, though it still joins the pool. Why: the pool claims that its windows saw one state
/// of the gate, and its robust location outvotes a newest window that saw another. On 100
/// onsets of the lock gate the pooled growth windows (below the departure ratio) read 1.4 points
/// high, 42 % of them covered, while the own readings of the 13 that stood 1.5 times above the
/// level or more covered the truth, 13 of 13; on a steady lock gate about one window in ten
/// stands so high by chance (one in twenty on the lab gate), and loses only the pool's precision
/// (`docs/damping.md`, "A rising window stands alone").
pub fn rising(d: &DampingReport) -> bool {
    match (d.ambient_ratio, d.departure_ratio) {
        (Some(r), Some(bar)) => r >= RISING_SHARE * bar,
        _ => false,
    }
}

/// Whether a window's envelope fell: its growth rate (`growth_rate`) lies more than
/// [`FALLING_SIGMAS`](super::FALLING_SIGMAS) standard errors below zero ([`falls`]). An ambient
/// window that fell is reported as a [`rising`] one is: alone, by its own SSI-COV reading, not by its 100-cycle record, though it
/// still joins the pool. Why: a decay after a recovery is another state of the gate, and the
/// record and the pool both reach back into the cycle before it. On the 1 Hz surge gate the
/// record reaches 100 s back and the decay's windows read 0.82 points low, 35 % covered; their
/// own readings 0.46 points, 98 %. A steady gate's envelope falls so far by chance in about one
/// window in forty (2.7 % on 300 h of the lock gate at +0.5 %, which raised no alert with the
/// rule), and such a window loses only the record's precision, as a rising one does
/// (`docs/damping.md`, "A falling window stands alone").
pub fn falling(d: &DampingReport) -> bool {
    match (d.growth_rate, d.growth_rate_stderr) {
        (Some(g), Some(se)) => falls(g, se),
        _ => false,
    }
}

/// On an ambient window that [`rising`] and is read by its own SSI-COV estimate, the interval
/// becomes the hull of SSI-COV's and the prediction-error method's (`prediction_error_zeta`, read
/// on the worker from [`RISING_SHARE`] of the departure ratio up), and the verdict follows it;
/// the figure stays SSI-COV's. Why: a window that rose may have seen the gate's damping change
/// (an onset that crossed zero a few seconds before) or a steady gate's chance swell, and
/// neither reading is right in both. SSI-COV assumes a stationary response: on the lab gate's
/// onset its windows that stood 1.6 to 3 times above the level at -0.33 % read +0.2 to +1.0 %
/// with intervals that ended above the truth (the growth row 77 % covered over 200 seeds), the
/// response still carrying the positive damping of the seconds before. The filter re-anchors
/// the state at every sample and read those windows right in the median (94 % covered at
/// -0.33 %), but on a steady gate's chance swells its cubic term reads a confident negative
/// damping now and then (stop 77: 82 of 843 lock windows at 1.5 to 2 times the level). The
/// hull says "somewhere across these"; it is below zero only where both are, so no alert fires
/// that would not have, and the trend reads the pool's figure for such a window anyway
/// ([`trend_reading`]). `docs/damping.md`, "A rising window's interval spans its prediction
/// errors".
fn span_the_prediction_errors(d: &mut DampingReport) {
    let (true, Some(p), Some((low, high))) = (rising(d), d.prediction_error_zeta, d.zeta0_interval)
    else {
        return;
    };
    if !(p.low.is_finite() && p.high.is_finite() && p.low <= p.high) {
        return;
    }
    let hull = (low.min(p.low), high.max(p.high));
    d.zeta0_interval = Some(hull);
    (d.verdict, d.trusted) = ambient_rows(hull, d.regime);
}

/// Whether an ambient window is reported alone: it [`rising`] or [`falling`].
fn stands_alone(d: &DampingReport) -> bool {
    rising(d) || falling(d)
}

/// What the gate's trend reads of a window's report, the window `window_seconds` long: the
/// pool's figure where a rising or falling window is reported alone
/// (`DampingReport::pooled_zeta`), else the report's own. Why the pool's: the trend weighs each
/// window by its interval and fits a line through minutes of them; the lone figures of the
/// windows that stand high by chance, a tenth of a steady gate's, made it warn on steady gates
/// (replayed on 20 six-hour lock days at +0.5 % and 400 cold starts: three false
/// `GateDampingDeclining`), while the pool they join follows a real drift as before.
///
/// The figure stands for the middle of the record behind it: a pool's records
/// (`pooled_lag_seconds`, `zeta0_lag_seconds`), or the window's middle for a figure the window
/// read alone. A report stored without the lags reads as the window's middle too.
pub fn trend_reading(d: &DampingReport, window_seconds: f64) -> TrendReading {
    let own = window_middle_lag(window_seconds);
    let lag = |l: Option<f64>| l.filter(|l| l.is_finite() && *l >= 0.0).unwrap_or(own);
    match d.pooled_zeta {
        Some(p) => TrendReading {
            zeta0: Some(p.zeta),
            interval: Some((p.low, p.high)),
            trusted: ambient_rows((p.low, p.high), d.regime).1,
            lag_seconds: lag(d.pooled_lag_seconds),
        },
        None => TrendReading {
            zeta0: d.zeta0,
            interval: d.own_interval(),
            trusted: d.trusted,
            lag_seconds: lag(d.zeta0_lag_seconds),
        },
    }
}

/// Seconds from a window's end back to its middle, the instant a figure the window read alone
/// stands for (0 for a window of no finite, positive length).
pub fn window_middle_lag(window_seconds: f64) -> f64 {
    if window_seconds.is_finite() && window_seconds > 0.0 {
        0.5 * window_seconds
    } else {
        0.0
    }
}

/// The verdict and `trusted` of an ambient estimate with 95 % interval `(low, high)` on a
/// window of `regime`: the rows of `decide` for the ambient estimate (below zero: self-excited;
/// above zero: damped, or cannot tell on a window the spectrum calls growing or a limit cycle;
/// across zero: undecided, trusted).
pub(super) fn ambient_rows((low, high): (f64, f64), regime: Option<Regime>) -> (Verdict, bool) {
    let alarm = matches!(regime, Some(Regime::SelfExcited | Regime::LimitCycle));
    match () {
        _ if high < 0.0 => (Verdict::SelfExcited, true),
        _ if low > 0.0 && alarm => (Verdict::Unknown, false),
        _ if low > 0.0 => (Verdict::Damped, true),
        _ => (Verdict::Unknown, true),
    }
}

/// Pushes one window's estimate (the window's span and the seconds of record the estimate read, 0
/// for the window's); `None` when the pool refuses it (then the pools are emptied and
/// the window stands alone).
fn push(
    pool: &mut DampingPool,
    (t_start, t_end, record_seconds): (f64, f64, f64),
    zeta: f64,
    (low, high): (f64, f64),
    (frequency_hz, rms): (f64, Option<f64>),
) -> Option<spectral::PooledEstimate> {
    // the window's own interval is 95 % two-sided (normal or Student-t): its half width over
    // the normal quantile is the standard error the pool weighs; a t interval gives a slightly
    // larger one, on the safe side
    let stderr = (high - low) / (2.0 * spectral::normal_quantile(0.975));
    pool.push(WindowEstimate {
        t_start,
        t_end,
        zeta,
        stderr,
        frequency_hz,
        record_seconds,
        rms,
    })
    .ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::AmbientZeta;

    fn ambient(zeta: f64, half: f64) -> DampingReport {
        DampingReport {
            zeta0: Some(zeta),
            zeta0_interval: Some((zeta - half, zeta + half)),
            zeta0_source: Some(Zeta0Source::Ambient),
            ambient_zeta: Some(AmbientZeta {
                zeta,
                low: zeta - half,
                high: zeta + half,
            }),
            frequency_hz: Some(5.0),
            trusted: true,
            verdict: Verdict::Unknown,
            regime: Some(Regime::Undecided),
            ..DampingReport::unknown()
        }
    }

    #[test]
    fn settings_are_checked_and_can_turn_pooling_off() {
        assert!(PoolingSettings::default().pools().unwrap().is_some());
        let off = PoolingSettings {
            enabled: false,
            ..PoolingSettings::default()
        };
        assert!(off.pools().unwrap().is_none());
        for bad in [
            PoolingSettings {
                min_cycles: 0.0,
                ..PoolingSettings::default()
            },
            PoolingSettings {
                max_seconds: f64::NAN,
                ..PoolingSettings::default()
            },
        ] {
            assert!(bad.pools().is_err(), "{bad:?}");
        }
    }

    /// A 1 Hz gate's 40 s windows every 5 s: pools of 60 s hold five of them; following the
    /// window (`follow_window`, three windows: 120 s) they hold as many as `max_windows` (16),
    /// and a window shorter than a third of `max_seconds` leaves the bound as configured.
    #[test]
    fn pools_follow_a_lengthened_window() {
        let held = |follow: Option<f64>| {
            let mut pools = PoolingSettings::default().pools().unwrap().unwrap();
            let bound = follow.map(|w| pools.follow_window(w));
            let mut last = None;
            for i in 0..40 {
                let t = 40.0 + 5.0 * f64::from(i);
                let mut d = DampingReport {
                    frequency_hz: Some(1.0),
                    ..ambient(0.01, 0.01)
                };
                pools.apply(t - 40.0, t, &mut d);
                last = d.zeta0_windows;
            }
            (bound, last)
        };
        assert_eq!(held(None), (None, Some(5)));
        assert_eq!(held(Some(40.0)), (Some(120.0), Some(16)));
        assert_eq!(held(Some(10.0)), (Some(60.0), Some(5)));
    }

    /// Windows of 10 s every 5 s at 5 Hz (50 cycles each): the pool narrows the interval and
    /// the narrower interval changes the verdict from "cannot tell" to damped.
    #[test]
    fn consecutive_windows_narrow_the_interval_and_settle_the_verdict() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        let mut widths = Vec::new();
        let mut last = DampingReport::unknown();
        for k in 0..8 {
            let t0 = 5.0 * k as f64;
            let mut d = ambient(0.008 + 0.001 * (k % 2) as f64, 0.01);
            pools.apply(t0, t0 + 10.0, &mut d);
            let (low, high) = d.zeta0_interval.unwrap();
            widths.push(high - low);
            last = d;
        }
        assert!(
            (widths[0] - 0.02).abs() < 1e-12,
            "the first window stands alone"
        );
        assert!(
            widths[7] < 0.6 * widths[0],
            "pooled widths {widths:?} did not narrow"
        );
        assert!(last.zeta0_windows.unwrap() >= 4, "{last:?}");
        assert_eq!((last.verdict, last.trusted), (Verdict::Damped, true));
        let z = last.zeta0.unwrap();
        assert!((0.008..=0.009).contains(&z), "pooled {z}");
    }

    /// One window's SSI-COV estimate is skewed to the right: a high one among steady ones
    /// (0.9 to 1.1 %, then 3 %) keeps the pooled figure within the steady ones, near their middle
    /// (the square-root Hodges-Lehmann estimate: 1.075 %), where their mean would have moved by a
    /// quarter of the excess (1.5 %).
    #[test]
    fn the_ambient_pool_is_not_pulled_by_one_high_window() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        let mut d = DampingReport::unknown();
        for (k, (z, half)) in [(0.010, 0.01), (0.011, 0.01), (0.009, 0.01), (0.030, 0.03)]
            .into_iter()
            .enumerate()
        {
            let t0 = 5.0 * k as f64;
            d = ambient(z, half);
            pools.apply(t0, t0 + 10.0, &mut d);
        }
        assert_eq!(d.zeta0_windows, Some(4), "{d:?}");
        let z = d.zeta0.unwrap();
        assert!((0.0100..=0.0110).contains(&z), "pooled {z}");
        let mean = (0.010 + 0.011 + 0.009 + 0.030) / 4.0;
        assert!(
            z - 0.0105 < 0.1 * (mean - 0.0105),
            "pooled {z}, pulled towards the mean {mean}"
        );
        // the interval is centred on it
        let (low, high) = d.zeta0_interval.unwrap();
        assert!((0.5 * (low + high) - z).abs() < 1e-12);
    }

    /// "The same mode" is tested on the ambient estimate's pole (`ambient_frequency_hz`), not on
    /// the window's spectral peak, whose bin is 5 % of a 2 Hz gate's frequency: a peak 8 % off
    /// does not flush the pool while the pole stays; a pole 8 % off does.
    #[test]
    fn the_ambient_pool_follows_the_pole_not_the_peak() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        // the windows at the old pole read +1 %, those at the new pole +1.2 %: the figure
        // says which windows a report rests on
        let window = |peak: f64, pole: f64| DampingReport {
            frequency_hz: Some(peak),
            ambient_frequency_hz: Some(pole),
            ..ambient(if pole > 2.1 { 0.012 } else { 0.01 }, 0.01)
        };
        let mut d = window(2.0, 2.0);
        pools.apply(0.0, 10.0, &mut d);
        let mut d = window(2.16, 2.0);
        pools.apply(5.0, 15.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(2), "the peak moved, the pole did not");
        // the pole moved: another mode, once the next window confirms it; the first is held
        // back and the old pool's figure stands for it
        let mut d = window(2.0, 2.16);
        pools.apply(10.0, 20.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(2), "held");
        assert!(d.zeta0_held, "the report says the window was held");
        assert!(
            (d.zeta0.unwrap() - 0.01).abs() < 1e-9,
            "held: {:?}",
            d.zeta0
        );
        let mut d = window(2.0, 2.16);
        pools.apply(15.0, 25.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(2), "the two windows at the new pole");
        assert!(!d.zeta0_held, "confirmed, no longer held");
        assert!(
            (d.zeta0.unwrap() - 0.012).abs() < 1e-9,
            "new: {:?}",
            d.zeta0
        );
        // back at the old pole: held again, the new pool's figure standing for it
        let mut d = window(2.0, 2.0);
        pools.apply(20.0, 30.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(2), "held again");
        assert!(d.zeta0_held);
        assert!(
            (d.zeta0.unwrap() - 0.012).abs() < 1e-9,
            "held: {:?}",
            d.zeta0
        );
    }

    /// A growing window (alarm) never becomes damped through pooling, and a model-based window
    /// empties the pools.
    #[test]
    fn alarm_and_model_windows_are_respected() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        let mut positive = 0;
        for k in 0..4 {
            let t0 = 5.0 * k as f64;
            let mut d = ambient(0.02, 0.03);
            d.regime = Some(Regime::SelfExcited);
            pools.apply(t0, t0 + 10.0, &mut d);
            assert_ne!(d.verdict, Verdict::Damped, "window {k}: {d:?}");
            if d.zeta0_interval.unwrap().0 > 0.0 {
                assert!(!d.trusted);
                positive += 1;
            }
        }
        // the pooled interval of the fourth window lies above zero: the check above ran
        assert!(positive >= 1, "no pooled interval above zero");
        let mut model = DampingReport {
            zeta0: Some(-0.01),
            zeta0_interval: Some((-0.02, 0.0)),
            zeta0_source: Some(Zeta0Source::Model),
            frequency_hz: Some(5.0),
            trusted: true,
            verdict: Verdict::SelfExcited,
            ..DampingReport::unknown()
        };
        let before = model.clone();
        pools.apply(20.0, 30.0, &mut model);
        assert_eq!(model, before, "a model-based report passes unchanged");
        let mut d = ambient(0.02, 0.03);
        pools.apply(25.0, 35.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(1), "the pools were emptied");
    }

    /// An ambient window that left the gate's ambient level (ratio 3 or more) is reported alone
    /// and empties the pool: the windows before it belong to another regime.
    #[test]
    fn a_window_that_left_the_ambient_level_is_not_pooled() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        for k in 0..4 {
            let t0 = 5.0 * k as f64;
            let mut d = ambient(0.01, 0.01);
            d.ambient_ratio = Some(1.5);
            pools.apply(t0, t0 + 10.0, &mut d);
        }
        let mut departed = ambient(0.005, 0.04);
        departed.ambient_ratio = Some(3.5);
        let before = departed.clone();
        pools.apply(20.0, 30.0, &mut departed);
        assert_eq!(departed, before, "the departed window passes unchanged");
        let mut next = ambient(0.01, 0.01);
        next.ambient_ratio = Some(2.9);
        pools.apply(25.0, 35.0, &mut next);
        assert_eq!(next.zeta0_windows, Some(1), "the pools were emptied");
    }

    /// The ambient pool holds one level of the gate: on a decay after a recovery (each window's
    /// RMS 30 % below the one before, the figures low at first and right later), the newest
    /// window is pooled only with the windows whose RMS lies within three times its own
    /// (`DEPARTED_FROM_AMBIENT`), while a window without a measured RMS is pooled as before.
    #[test]
    fn the_ambient_pool_holds_one_level() {
        let run = |rms: &dyn Fn(usize) -> Option<f64>| {
            let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
            let mut last = ambient(0.0, 0.0);
            for k in 0..8 {
                let t0 = 5.0 * k as f64;
                // 0.2 % in the decay's first windows, 2 % once the gate is back
                let mut d = ambient(if k < 4 { 0.002 } else { 0.02 }, 0.03);
                d.signal_rms = rms(k);
                pools.apply(t0, t0 + 10.0, &mut d);
                last = d;
            }
            last
        };
        let decay = run(&|k| Some(300.0 * 0.7f64.powi(k as i32)));
        // 300 x 0.7^7 = 25: 0.7^-3 = 2.9 keeps the three windows before it, all at 2 %, and
        // 0.7^-4 = 4.2 ends the pool
        assert_eq!(decay.zeta0_windows, Some(4), "{decay:?}");
        assert!((decay.zeta0.unwrap() - 0.02).abs() < 1e-9, "{decay:?}");
        let unmeasured = run(&|_| None);
        assert!(unmeasured.zeta0_windows.unwrap() > 4, "{unmeasured:?}");
        assert!(unmeasured.zeta0.unwrap() < 0.02 - 1e-4, "{unmeasured:?}");
    }

    /// Pools of 150 cycles and at most 60 s: three 20 s records at 5 Hz, or five 10 s windows.
    fn record_pool_options() -> PoolOptions {
        PoolOptions {
            min_cycles: 150.0,
            max_seconds: 60.0,
            ..PoolOptions::default()
        }
    }

    /// A window with an ambient record (`ambient_record_zeta`: its history read with it) is
    /// pooled by the record: alone in its pool it reports the record's figure and interval;
    /// pooled, the record's 20 s count, so three windows hold the pool's 150 cycles at 5 Hz
    /// (five 10 s windows without records). A rising window is pooled and reported by its own
    /// reading whatever its record.
    #[test]
    fn the_ambient_pool_reads_each_windows_record() {
        let opts = record_pool_options();
        let window = |zeta: f64, record: Option<f64>| {
            let mut d = ambient(zeta, 0.02);
            d.ambient_record_zeta = record.map(|z| AmbientZeta {
                zeta: z,
                low: z - 0.008,
                high: z + 0.008,
            });
            d.ambient_record_seconds = record.map(|_| 20.0);
            d
        };
        let mut pools = ZetaPools::new(opts).unwrap();
        let mut first = window(0.02, Some(0.012));
        pools.apply(0.0, 10.0, &mut first);
        assert_eq!(first.zeta0, Some(0.012));
        assert_eq!(first.zeta0_interval, Some((0.004, 0.02)));
        assert_eq!(
            (first.zeta0_windows, first.verdict),
            (Some(1), Verdict::Damped)
        );
        let mut last = first;
        for k in 1..8 {
            let t0 = 5.0 * k as f64;
            last = window(0.02, Some(0.012));
            pools.apply(t0, t0 + 10.0, &mut last);
        }
        assert_eq!(last.zeta0_windows, Some(3));
        assert!((last.zeta0.unwrap() - 0.012).abs() < 1e-12);
        let mut plain = ZetaPools::new(opts).unwrap();
        for k in 0..8 {
            let t0 = 5.0 * k as f64;
            last = window(0.02, None);
            plain.apply(t0, t0 + 10.0, &mut last);
        }
        assert_eq!(last.zeta0_windows, Some(5));
        // rising: its own 0.02 stands; the pool it joins (robust, by records) stays at 0.012
        let mut up = window(0.02, Some(0.012));
        up.ambient_ratio = Some(1.6);
        up.departure_ratio = Some(3.0);
        pools.apply(40.0, 50.0, &mut up);
        assert_eq!((up.zeta0, up.zeta0_windows), (Some(0.02), Some(1)));
        let p = up.pooled_zeta.expect("the pool's figure");
        assert!((p.zeta - 0.012).abs() < 1e-12, "pooled {p:?}");
        // beside one record, a rising window's own 0.02 (not its record's 0.05) joins the pool
        let mut fresh = ZetaPools::new(opts).unwrap();
        fresh.apply(0.0, 10.0, &mut window(0.02, Some(0.012)));
        let mut up = window(0.02, Some(0.05));
        up.ambient_ratio = Some(1.6);
        up.departure_ratio = Some(3.0);
        fresh.apply(5.0, 15.0, &mut up);
        let p = up.pooled_zeta.expect("a pool of two");
        assert!(p.zeta > 0.0121 && p.zeta < 0.02, "pooled {p:?}");
    }

    /// A window that rose to half the departure ratio is reported alone, with its own figure,
    /// interval and verdict, yet joins the pool: the pool's figure is in `pooled_zeta`, which
    /// the trend reads, and the next window, standing lower, is pooled with it.
    #[test]
    fn a_rising_window_stands_alone_but_joins_the_pool() {
        let window = |zeta, half, ratio| {
            let mut d = ambient(zeta, half);
            d.ambient_ratio = Some(ratio);
            d.departure_ratio = Some(3.0);
            d
        };
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        let mut without = ZetaPools::new(PoolOptions::default()).unwrap();
        for k in 0..4 {
            let t0 = 5.0 * k as f64;
            pools.apply(t0, t0 + 10.0, &mut window(0.01, 0.01, 1.0));
            without.apply(t0, t0 + 10.0, &mut window(0.01, 0.01, 1.0));
        }
        let mut up = window(0.004, 0.012, 1.6);
        let own = up.clone();
        assert!(rising(&own) && !rising(&window(0.004, 0.012, 1.4)));
        pools.apply(20.0, 30.0, &mut up);
        assert_eq!(
            (up.zeta0, up.zeta0_interval, up.verdict, up.trusted),
            (own.zeta0, own.zeta0_interval, own.verdict, own.trusted),
            "the window's own figure stands"
        );
        assert_eq!((up.zeta0_windows, up.zeta0_held), (Some(1), false));
        let p = up.pooled_zeta.expect("the pool's figure");
        assert!((0.008..0.0101).contains(&p.zeta), "pooled {p:?}");
        assert!(p.high - p.low < 0.02, "narrower than one window's: {p:?}");
        // the pool's figure, at the middle of its windows: behind the rising window's own middle
        let lag = up.pooled_lag_seconds.expect("the pool's lag");
        assert!((5.5..=15.0).contains(&lag), "lag {lag}");
        assert_eq!(
            trend_reading(&up, 10.0),
            TrendReading {
                zeta0: Some(p.zeta),
                interval: Some((p.low, p.high)),
                trusted: true,
                lag_seconds: lag,
            }
        );
        let mut next = window(0.01, 0.01, 1.4);
        pools.apply(25.0, 35.0, &mut next);
        let mut next_without = window(0.01, 0.01, 1.4);
        without.apply(25.0, 35.0, &mut next_without);
        assert!(next.zeta0_windows.unwrap() >= 2 && next.pooled_zeta.is_none());
        assert_eq!(
            trend_reading(&next, 10.0),
            TrendReading {
                zeta0: next.zeta0,
                interval: next.zeta0_interval,
                trusted: next.trusted,
                lag_seconds: next.zeta0_lag_seconds.expect("a pooled figure's lag"),
            }
        );
        assert_ne!(
            (next.zeta0_windows, next.zeta0_interval),
            (next_without.zeta0_windows, next_without.zeta0_interval),
            "the rising window is in the pool"
        );
    }

    /// A rising window read by its own SSI-COV estimate has its interval span the
    /// prediction-error method's reading of it too: its figure stays, its verdict follows the
    /// hull, and the pool's figure the trend reads does not move. A window that did not rise
    /// keeps its interval, and so does a rising one the filter did not read.
    #[test]
    fn a_rising_windows_interval_spans_its_prediction_errors() {
        let window = |ratio: f64, pem: Option<(f64, f64, f64)>| {
            let mut d = ambient(0.004, 0.003);
            d.verdict = Verdict::Damped;
            d.ambient_ratio = Some(ratio);
            d.departure_ratio = Some(3.0);
            d.prediction_error_zeta = pem.map(AmbientZeta::from);
            d
        };
        let (low, high) = window(1.0, None).zeta0_interval.unwrap();
        assert!(low > 0.0);
        let run = |mut last: DampingReport| {
            let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
            for k in 0..4 {
                let t0 = 5.0 * k as f64;
                pools.apply(t0, t0 + 10.0, &mut window(1.0, None));
            }
            pools.apply(20.0, 30.0, &mut last);
            last
        };
        let filter = Some((-0.003, -0.006, 0.0));
        let up = run(window(1.6, filter));
        assert_eq!(up.zeta0, Some(0.004));
        assert_eq!(up.zeta0_interval, Some((-0.006, high)));
        assert_eq!((up.verdict, up.trusted), (Verdict::Unknown, true));
        let plain = run(window(1.6, None));
        assert_eq!(plain.zeta0_interval, Some((low, high)));
        assert_eq!(plain.verdict, Verdict::Damped);
        assert_eq!(up.pooled_zeta, plain.pooled_zeta);
        assert!(up.pooled_zeta.is_some());
        // below half the departure ratio the window is pooled, and the filter's reading is not
        // used
        assert_eq!(
            run(window(1.4, filter)).zeta0_interval,
            run(window(1.4, None)).zeta0_interval
        );
        // alone in its pool (the first window after a flush) the hull holds as well
        let mut fresh = ZetaPools::new(PoolOptions::default()).unwrap();
        let mut first = window(1.6, filter);
        fresh.apply(0.0, 10.0, &mut first);
        assert_eq!(first.zeta0_interval, Some((-0.006, high)));
    }

    /// A window whose envelope fell by more than two standard errors (a decay after a
    /// recovery) is reported by its own reading, not by its record, which reaches back into the
    /// cycle before it; it joins the pool, whose figure the trend reads. A window whose envelope
    /// fell by less, or whose fall has no standard error, is read by its record as before.
    #[test]
    fn a_falling_window_stands_alone_by_its_own_reading() {
        let opts = record_pool_options();
        let window = |zeta: f64, growth: Option<(f64, f64)>| {
            let mut d = ambient(zeta, 0.01);
            d.ambient_record_zeta = Some(AmbientZeta {
                zeta: 0.004,
                low: 0.0,
                high: 0.008,
            });
            d.ambient_record_seconds = Some(20.0);
            d.growth_rate = growth.map(|g| g.0);
            d.growth_rate_stderr = growth.map(|g| g.1);
            d
        };
        // a fall of 2.5 standard errors stands alone; one of 1.5, or none, does not
        let down = window(0.02, Some((-0.05, 0.02)));
        assert!(falling(&down) && !rising(&down));
        for steady in [
            window(0.02, Some((-0.03, 0.02))),
            window(0.02, Some((0.05, 0.02))),
            window(0.02, None),
            window(0.02, Some((-0.05, f64::NAN))),
        ] {
            assert!(!falling(&steady), "{:?}", steady.growth_rate);
        }
        let mut pools = ZetaPools::new(opts).unwrap();
        for k in 0..4 {
            let t0 = 5.0 * k as f64;
            let mut d = window(0.02, Some((-0.03, 0.02)));
            pools.apply(t0, t0 + 10.0, &mut d);
            assert!(
                (d.zeta0.unwrap() - 0.004).abs() < 1e-12,
                "read by its record"
            );
        }
        let mut down = window(0.02, Some((-0.05, 0.02)));
        let own = down.clone();
        pools.apply(20.0, 30.0, &mut down);
        assert_eq!(
            (down.zeta0, down.zeta0_interval, down.verdict, down.trusted),
            (own.zeta0, own.zeta0_interval, own.verdict, own.trusted),
            "the window's own figure stands"
        );
        assert_eq!(down.zeta0_windows, Some(1));
        let p = down.pooled_zeta.expect("the pool's figure");
        assert!((0.0039..0.012).contains(&p.zeta), "pooled {p:?}");
        assert!(
            p.high - p.low < 0.02,
            "narrower than the window's own: {p:?}"
        );
        let r = trend_reading(&down, 10.0);
        assert_eq!(
            (r.zeta0, r.interval, r.trusted),
            (Some(p.zeta), Some((p.low, p.high)), true)
        );
        assert_eq!(Some(r.lag_seconds), down.pooled_lag_seconds);
        // alone in its pool, it still reads its own figure, not its record's
        let mut fresh = ZetaPools::new(opts).unwrap();
        let mut first = window(0.02, Some((-0.05, 0.02)));
        fresh.apply(0.0, 10.0, &mut first);
        assert_eq!((first.zeta0, first.zeta0_windows), (Some(0.02), Some(1)));
    }

    /// The envelope estimates of a limit cycle pool too, and a negative pooled interval makes
    /// the window trusted and self-excited.
    #[test]
    fn envelope_estimates_pool_to_a_confident_negative() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        let mut last = DampingReport::unknown();
        for k in 0..8 {
            let t0 = 5.0 * k as f64;
            let mut d = DampingReport {
                zeta0: Some(-0.02),
                zeta0_interval: Some((-0.035, 0.001)),
                zeta0_source: Some(Zeta0Source::Envelope),
                frequency_hz: Some(5.0),
                trusted: false,
                verdict: Verdict::Unknown,
                regime: Some(Regime::LimitCycle),
                ..DampingReport::unknown()
            };
            pools.apply(t0, t0 + 10.0, &mut d);
            if k == 0 {
                assert_eq!((d.verdict, d.trusted), (Verdict::Unknown, false));
            }
            last = d;
        }
        assert_eq!((last.verdict, last.trusted), (Verdict::SelfExcited, true));
        assert!(last.zeta0_interval.unwrap().1 < 0.0);
    }

    /// A lone envelope estimate (the first limit-cycle window after ambient ones) is untrusted
    /// even when its interval lies below zero; the second one, pooled, decides.
    #[test]
    fn a_lone_limit_cycle_window_is_no_evidence() {
        let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
        let envelope = || DampingReport {
            zeta0: Some(-0.018),
            zeta0_interval: Some((-0.034, -0.002)),
            zeta0_source: Some(Zeta0Source::Envelope),
            frequency_hz: Some(10.0),
            trusted: true,
            verdict: Verdict::SelfExcited,
            regime: Some(Regime::LimitCycle),
            ..DampingReport::unknown()
        };
        let mut d = ambient(0.005, 0.006);
        pools.apply(0.0, 10.0, &mut d);
        let mut d = envelope();
        pools.apply(5.0, 15.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(1));
        assert_eq!((d.verdict, d.trusted), (Verdict::Unknown, false));
        let mut d = envelope();
        pools.apply(10.0, 20.0, &mut d);
        assert_eq!(d.zeta0_windows, Some(2));
        assert_eq!((d.verdict, d.trusted), (Verdict::SelfExcited, true));
        // an ambient window empties the envelope pool: the next envelope window is alone again
        let mut d = ambient(0.005, 0.006);
        pools.apply(15.0, 25.0, &mut d);
        let mut d = envelope();
        pools.apply(20.0, 30.0, &mut d);
        assert_eq!((d.verdict, d.trusted), (Verdict::Unknown, false));
    }

    /// On a gate at its ambient level a pool of limit-cycle readings decides once it holds
    /// `MIN_CYCLE_POOL_CYCLES` distinct cycles: two windows of a 10 Hz gate (150 cycles), three
    /// of a 5 Hz gate whose readings each read 20 s of history (125 cycles with two, 150 with
    /// three), five where each read only its 10 s window (`envelope_record_seconds`: 125
    /// cycles with four, 150 with five); a report without the figure (stored before stop 83)
    /// counts 100 cycles. A gate that left its level decides from the second window as before.
    /// Short of the cycles, the trend still reads the pool's figure.
    #[test]
    fn a_cycle_pool_at_the_ambient_level_decides_after_enough_cycles() {
        let envelope = |f: f64, ratio: f64, record: Option<f64>| DampingReport {
            envelope_record_seconds: record,
            zeta0: Some(-0.018),
            zeta0_interval: Some((-0.034, -0.002)),
            zeta0_source: Some(Zeta0Source::Envelope),
            frequency_hz: Some(f),
            ambient_ratio: Some(ratio),
            departure_ratio: Some(3.0),
            trusted: true,
            verdict: Verdict::SelfExcited,
            regime: Some(Regime::LimitCycle),
            ..DampingReport::unknown()
        };
        // (frequency, ambient ratio, seconds each reading read, window the pool first decides)
        for (f, ratio, record, decides) in [
            (10.0, 2.0, Some(10.0), 2),
            (5.0, 2.0, Some(20.0), 3),
            (5.0, 2.0, None, 3),
            (5.0, 2.0, Some(10.0), 5),
            (5.0, 4.0, Some(10.0), 2),
        ] {
            let mut pools = ZetaPools::new(PoolOptions::default()).unwrap();
            // (not past four windows of the 10 Hz gate, whose fifth makes the first unneeded)
            for k in 1..=decides.max(4) {
                let t0 = 5.0 * k as f64;
                let mut d = envelope(f, ratio, record);
                pools.apply(t0, t0 + 10.0, &mut d);
                let want = if k >= decides {
                    (Verdict::SelfExcited, true)
                } else {
                    (Verdict::Unknown, false)
                };
                assert_eq!(
                    (d.verdict, d.trusted),
                    want,
                    "{f} Hz, ratio {ratio}, record {record:?}, window {k}"
                );
                assert_eq!(d.zeta0_windows, Some(k));
                // short of the cycles, the trend still reads the pool's figure as trusted
                if (2..decides).contains(&k) {
                    let r = trend_reading(&d, 10.0);
                    assert_eq!(
                        (r.zeta0, r.interval, r.trusted),
                        (d.zeta0, d.zeta0_interval, true)
                    );
                } else {
                    assert_eq!(d.pooled_zeta, None);
                }
            }
        }
    }
}
