//! The alert rules (thresholds and timing) and their validation.

use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Thresholds and timing of the alert rules (global, or per gate via
/// [`AlertEngine::set_rules`](super::AlertEngine::set_rules)).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlertRules {
    /// A window counts as negative damping when its whole 95 % interval for `zeta0` lies below
    /// this (upper end `< fire_below`), or, with [`AlertRules::fire_probability`], when
    /// `P(zeta0 < fire_below)` reaches that level (default 0.0: confidently negative).
    pub fire_below: f64,
    /// Hysteresis: a firing alert resolves only on windows that are
    /// [`AlertRules::resolve_probability`] sure of `zeta0` lying at or above this (default
    /// 0.005).
    pub clear_above: f64,
    /// Decide on probability instead of the interval's upper end: a window is negative when
    /// `P(zeta0 < fire_below) >= fire_probability`, from a normal approximation of its 95 %
    /// interval (centre the midpoint, sd the half width / 1.96). Unset (default): the interval
    /// rule, which is this rule at 0.975. In (0, 1).
    pub fire_probability: Option<f64>,
    /// Consecutive negative trusted windows before firing (default 2; 0 acts as 1).
    pub for_windows: u32,
    /// One trusted window with `P(zeta0 < fire_below)` at or above this, standing at least
    /// [`super::at_once_ratio`] times above the gate's ambient level, fires at once
    /// without waiting for `for_windows` (default 0.975, its 95 % interval below `fire_below`;
    /// 1: off; 0.999 until session 37, when the growth windows' model intervals became honest,
    /// docs/alerts.md). Why: at 10 Hz a gate goes from zero damping to -1 % and its limit
    /// cycle within three 5 s hops, so two confident windows come only after -1 %. Why the
    /// ambient level: on a stable +0.5 % lock gate a model-sourced window read -2.5 % (-2.8,
    /// -2.1) once in 8.7 h of stream at the gate's usual level (docs/alerts.md).
    pub fire_at_once_probability: f64,
    /// How far above its ambient level a window must stand to fire at once. Unset (the
    /// default): [`super::at_once_ratio`] of the gate's departure ratio, 3.5 where its windows
    /// hold about 38 cycles or more, 4.68 where they hold 20. At least 1. A site sets it for a gate
    /// where it prefers another balance between a chance excursion's page and a few seconds on
    /// a fast onset (docs/alerts.md, "On a gate whose windows hold few cycles").
    pub fire_at_once_min_ratio: Option<f64>,
    /// A window the spectrum classifies as a limit cycle, standing at least the at-once bar
    /// above the gate's ambient level ([`super::at_once_ratio`] or `fire_at_once_min_ratio`),
    /// reads negative whatever its interval and its trust (default true; docs/alerts.md, "A
    /// steady cycle far above the ambient level"). Never at once: two such windows in a row,
    /// or one and a window negative by its interval, fire. Why: a gate's first cycle windows
    /// are read by the envelope's relaxation, whose first readings are untrusted or wide, and
    /// on 2 of 100 lock-gate onsets the alert waited 35 and 45 s past -1 % for them while the
    /// gate stood 5 to 14 times above its ambient level.
    pub fire_on_limit_cycle: bool,
    /// The same for a window the spectrum classifies as self-excited (`regime =
    /// self_excited`: its envelope grows by more than three standard errors), standing at least
    /// the at-once bar above the gate's ambient level (default true; docs/alerts.md, "A growing
    /// oscillation far above the ambient level"). Never at once either: an impact on the gate
    /// late in one window grows that window's envelope, and the next window sees it decay. Why:
    /// on the onset the window that ends at -1 % often grows far above the level while its
    /// estimates' intervals still reach zero (3 of the lab gate's 7 late seeds in 100).
    pub fire_on_growth: bool,
    /// A window reads good, the evidence for resolving a firing alert, when `P(zeta0 >=
    /// clear_above) >= resolve_probability` under the normal approximation of its 95 % interval
    /// (as `fire_probability`), and it is not negative. In (0.5, 1); default 0.9. 0.975 is the
    /// whole-interval rule (lower end `>= clear_above`) that was the only one until session 44.
    /// Why 0.9: at 0.975 a 5 Hz lock gate that recovered to +2 % (its windows' intervals about
    /// +-1.6 points wide, 99 % of them covering the truth) kept paging for 25 to 155 s after
    /// reaching +2 %, and 5 of 20 seeds were still paging 180 s after; at 0.9 every seed resolved
    /// 15 to 45 s after it, and no run of the onset, slow drift, step or held limit cycle
    /// resolved while the gate was still below zero (replayed on 20 seeds of each,
    /// docs/benchmarks.md, "Resolving on probability (session 44)"). Firing stays at 0.975:
    /// a page should need more evidence than its end, and the band between `fire_below` and
    /// `clear_above` keeps an alert that resolved early from firing again on the same evidence.
    pub resolve_probability: f64,
    /// Consecutive good windows (see `resolve_probability`) before resolving (default 2; 0 acts
    /// as 1).
    pub resolve_windows: u32,
    /// Sample time over which the trend of `zeta0` is fitted, seconds (default 600).
    pub trend_horizon_seconds: f64,
    /// The trend acts only once its windows span at least this much sample time, seconds
    /// (default 300): a line through the first few windows says little, and says it too
    /// confidently. Why 240 and not 120 (until session 45): a gate's pooled figures are
    /// correlated over up to a minute, and the lag-1 autocorrelation the trend then read off 24
    /// residuals is biased low (a true 0.85 reads about 0.5; since stop 96 the trend counts the
    /// shared records instead), so a trend over the first two to four minutes of a new gate
    /// claimed more independent windows than it had. In 400 cold
    /// starts of steady +1 % and +0.5 % gates (`bench warning --seeds 100 --scenarios
    /// stable,stable-low --hours 0.1`) it warned 9 times on the lab gate and 3 times on the lock
    /// gate at 120 s, between 135 and 345 s of stream; at 240 s twice. One slow drift's warning
    /// of 40 moved (195 to 310 s of stream, still 410 s before zero); correcting the
    /// autocorrelation's bias instead would also widen the full horizon's trend, and moved 5 of 20
    /// lock gates' slow-drift warnings to or past the zero crossing. Why 300 (stop 68): in
    /// stop 67's 1,200 cold starts the two warnings left at 240 s both fired at the first
    /// window 240 s allowed, and 300 s removes them without moving a slow drift's warning; 800
    /// held-out cold starts gave one warning, at 540 s, at every span from 240 to 420 s
    /// (docs/alerts.md, "A cold start waits five minutes").
    pub trend_min_span_seconds: f64,
    /// `GateDampingDeclining` fires when the trend predicts, with 95 % confidence (one-sided,
    /// on the slope), that `zeta0` crosses `fire_below` within this many seconds (default 600),
    /// and no further ahead than the trend's span (a trend of four minutes predicts at most four
    /// minutes ahead; docs/alerts.md, "No further ahead than the trend reaches back").
    pub warn_lead_seconds: f64,
    /// Consecutive trusted windows predicting the crossing before `GateDampingDeclining` fires
    /// (default 2; 0 acts as 1).
    pub warn_for_windows: u32,
    /// Consecutive trusted windows no longer predicting it, not even at the fitted slope, before
    /// it resolves (default 2; 0 acts as 1).
    pub warn_resolve_windows: u32,
    /// Value of `GateDampingDeclining`'s `severity` label (default "warning").
    pub warn_severity: String,
    /// No samples for this long (wall clock) fires `GateDataStale` (default 30). A value that
    /// is not a positive finite number disables the staleness check.
    pub stale_after_seconds: f64,
    /// Value of the `severity` label (default "critical").
    pub severity: String,
}

impl Default for AlertRules {
    fn default() -> Self {
        AlertRules {
            fire_below: 0.0,
            clear_above: 0.005,
            fire_probability: None,
            for_windows: 2,
            fire_at_once_probability: 0.975,
            fire_at_once_min_ratio: None,
            fire_on_limit_cycle: true,
            fire_on_growth: true,
            resolve_probability: 0.9,
            resolve_windows: 2,
            trend_horizon_seconds: 600.0,
            trend_min_span_seconds: 300.0,
            warn_lead_seconds: 600.0,
            warn_for_windows: 2,
            warn_resolve_windows: 2,
            warn_severity: "warning".to_string(),
            stale_after_seconds: 30.0,
            severity: "critical".to_string(),
        }
    }
}

/// A rule set that makes no sense (see [`AlertRules::validate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RulesError {
    /// A threshold is NaN or infinite.
    #[error("alert rule `{0}` must be a finite number")]
    NotFinite(&'static str),
    /// `clear_above < fire_below`: there would be no hysteresis band, windows could be
    /// negative and "good" at once.
    #[error("alert rule clear_above ({clear_above}) must be >= fire_below ({fire_below})")]
    ClearBelowFire { fire_below: f64, clear_above: f64 },
    /// `stale_after_seconds` is not a positive finite number.
    #[error("alert rule stale_after_seconds must be a positive finite number, got {0}")]
    BadStaleAfter(f64),
    /// The severity label is empty.
    #[error("alert rule severity must not be empty")]
    EmptySeverity,
    /// `fire_probability` is not strictly between 0 and 1.
    #[error("alert rule fire_probability must be in (0, 1), got {0}")]
    BadProbability(f64),
    /// `fire_at_once_probability` is not in (0.5, 1].
    #[error("alert rule fire_at_once_probability must be in (0.5, 1], got {0}")]
    BadAtOnceProbability(f64),
    /// `resolve_probability` is not in (0.5, 1).
    #[error("alert rule resolve_probability must be in (0.5, 1), got {0}")]
    BadResolveProbability(f64),
    /// `fire_at_once_min_ratio` is not a finite number of at least 1.
    #[error("alert rule fire_at_once_min_ratio must be a finite number >= 1, got {0}")]
    BadAtOnceRatio(f64),
    /// A duration of the trend is not a positive finite number of seconds.
    #[error("alert rule `{0}` must be a positive finite number of seconds, got {1}")]
    BadSeconds(&'static str, f64),
}

impl AlertRules {
    /// Check the rules for consistency. The engine never panics on invalid rules (it behaves as
    /// documented on each field), but a daemon should reject them when loading its config.
    pub fn validate(&self) -> Result<(), RulesError> {
        if !self.fire_below.is_finite() {
            return Err(RulesError::NotFinite("fire_below"));
        }
        if !self.clear_above.is_finite() {
            return Err(RulesError::NotFinite("clear_above"));
        }
        if self.clear_above < self.fire_below {
            return Err(RulesError::ClearBelowFire {
                fire_below: self.fire_below,
                clear_above: self.clear_above,
            });
        }
        if !(self.stale_after_seconds.is_finite() && self.stale_after_seconds > 0.0) {
            return Err(RulesError::BadStaleAfter(self.stale_after_seconds));
        }
        if self.severity.trim().is_empty() || self.warn_severity.trim().is_empty() {
            return Err(RulesError::EmptySeverity);
        }
        if let Some(p) = self.fire_probability {
            if !(p > 0.0 && p < 1.0) {
                return Err(RulesError::BadProbability(p));
            }
        }
        let p = self.fire_at_once_probability;
        if !(p > 0.5 && p <= 1.0) {
            return Err(RulesError::BadAtOnceProbability(p));
        }
        if let Some(r) = self.fire_at_once_min_ratio {
            if !(r.is_finite() && r >= 1.0) {
                return Err(RulesError::BadAtOnceRatio(r));
            }
        }
        let p = self.resolve_probability;
        if !(p > 0.5 && p < 1.0) {
            return Err(RulesError::BadResolveProbability(p));
        }
        for (name, v) in [
            ("trend_horizon_seconds", self.trend_horizon_seconds),
            ("warn_lead_seconds", self.warn_lead_seconds),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(RulesError::BadSeconds(name, v));
            }
        }
        if !(self.trend_min_span_seconds.is_finite() && self.trend_min_span_seconds >= 0.0) {
            return Err(RulesError::BadSeconds(
                "trend_min_span_seconds",
                self.trend_min_span_seconds,
            ));
        }
        Ok(())
    }

    pub(super) fn for_windows(&self) -> u32 {
        self.for_windows.max(1)
    }

    /// The default rules with `fire_at_once_probability` disabled: for tests about the
    /// counting of windows, whose observations carry point-like intervals.
    #[cfg(test)]
    pub(crate) fn counting() -> Self {
        AlertRules {
            fire_at_once_probability: 1.0,
            ..AlertRules::default()
        }
    }

    /// Whether one window's interval is far enough below `fire_below` to fire at once
    /// (`fire_at_once_probability`; 1 disables, even for a zero-width interval).
    pub(super) fn fires_at_once(&self, low: f64, high: f64) -> bool {
        self.fire_at_once_probability < 1.0
            && Self::probability_below(low, high, self.fire_below) >= self.fire_at_once_probability
    }

    pub(super) fn resolve_windows(&self) -> u32 {
        self.resolve_windows.max(1)
    }

    pub(super) fn warn_for_windows(&self) -> u32 {
        self.warn_for_windows.max(1)
    }

    pub(super) fn warn_resolve_windows(&self) -> u32 {
        self.warn_resolve_windows.max(1)
    }

    /// Whether one window's interval is far enough above `clear_above` to count towards
    /// resolving (`resolve_probability`).
    pub(super) fn reads_good(&self, low: f64, high: f64) -> bool {
        1.0 - Self::probability_below(low, high, self.clear_above) >= self.resolve_probability
    }

    /// `P(zeta0 < threshold)` under a normal approximation of the 95 % interval `(low, high)`:
    /// centre the midpoint, standard deviation the half width / 1.96. A zero-width interval
    /// gives 0 or 1.
    pub fn probability_below(low: f64, high: f64, threshold: f64) -> f64 {
        let mid = 0.5 * (low + high);
        let sd = (high - low) / (2.0 * 1.959_963_984_540_054);
        if sd > 0.0 {
            0.5 * libm::erfc((mid - threshold) / (sd * std::f64::consts::SQRT_2))
        } else if mid < threshold {
            1.0
        } else {
            0.0
        }
    }

    pub(super) fn stale_after(&self) -> Option<Duration> {
        if self.stale_after_seconds.is_finite() && self.stale_after_seconds > 0.0 {
            Duration::try_from_secs_f64(self.stale_after_seconds).ok()
        } else {
            None
        }
    }
}
