//! `GateDampingDeclining`: the warning that a gate's damping is heading for `fire_below`.
//!
//! A window "predicts the crossing" when it is trusted, its gate's trend spans at least
//! `trend_min_span_seconds`, and the trend's confident crossing time (at the slope's one-sided
//! 95 % upper bound) is within `warn_lead_seconds` and within the trend's own span (a line is
//! not extrapolated further than its record reaches back). `warn_for_windows` such windows in a
//! row fire the warning; `warn_resolve_windows` trusted windows in a row whose trend no longer
//! predicts it (the slope flattened or turned, or the gate recovered far enough that the
//! crossing is beyond the lead) resolve it. An untrusted window, or one without a trend, is no
//! evidence either way: it breaks both streaks and leaves a firing warning firing. See
//! `docs/alerts.md`.

use std::collections::BTreeMap;
use std::time::SystemTime;

use super::annotations::{fmt_percent, fmt_sig};
use super::{Alert, AlertEvent, AlertRules, Observation, ALERT_DAMPING_DECLINING};
use crate::analysis::TrendEstimate;

/// How one window reads for the warning.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Reading {
    Unknown,
    /// The confident crossing (at the slope's 95 % bound) lies within the lead and within the
    /// trend's span.
    Predicts,
    /// Not confidently, but the fitted slope still crosses within the lead: holds a firing
    /// warning (calm for one that is not firing).
    Holds,
    /// Not even the fitted slope crosses within the lead.
    Calm,
}

fn classify(obs: &Observation, rules: &AlertRules) -> Reading {
    let Some(trend) = obs.trend.filter(|_| obs.trusted) else {
        return Reading::Unknown;
    };
    if trend.span_seconds < rules.trend_min_span_seconds {
        return Reading::Unknown;
    }
    // A line is not extrapolated further ahead than the record it was fitted on reaches back:
    // a trend spanning four minutes predicts at most four minutes ahead, whatever the lead
    // (docs/alerts.md, "No further ahead than the trend reaches back").
    if trend.crosses_within(rules.warn_lead_seconds.min(trend.span_seconds)) {
        Reading::Predicts
    } else if trend
        .crossing_seconds
        .is_some_and(|t| t <= rules.warn_lead_seconds)
    {
        Reading::Holds
    } else {
        Reading::Calm
    }
}

/// The warning's state for one gate.
#[derive(Debug, Clone, Default)]
pub(super) enum Declining {
    #[default]
    Quiet,
    Pending {
        windows: u32,
        since: SystemTime,
    },
    Firing {
        alert: Alert,
        calm: u32,
    },
}

impl Declining {
    /// The firing warning, if any.
    pub(super) fn alert(&self) -> Option<&Alert> {
        match self {
            Declining::Firing { alert, .. } => Some(alert),
            _ => None,
        }
    }

    pub(super) fn into_alert(self) -> Option<Alert> {
        match self {
            Declining::Firing { alert, .. } => Some(alert),
            _ => None,
        }
    }

    /// One window; returns the transition to notify, if any.
    pub(super) fn observe(
        &mut self,
        gate: &str,
        rules: &AlertRules,
        obs: &Observation,
        now: SystemTime,
    ) -> Option<AlertEvent> {
        match (classify(obs, rules), &mut *self) {
            (Reading::Unknown, Declining::Pending { .. }) => *self = Declining::Quiet,
            (Reading::Unknown, Declining::Firing { calm, .. }) => *calm = 0,
            (Reading::Unknown | Reading::Holds | Reading::Calm, Declining::Quiet) => {}
            (Reading::Holds | Reading::Calm, Declining::Pending { .. }) => *self = Declining::Quiet,
            (Reading::Calm, Declining::Firing { alert, calm }) => {
                *calm = calm.saturating_add(1);
                if *calm >= rules.warn_resolve_windows() {
                    let mut resolved = alert.clone();
                    resolved.ends_at = Some(now);
                    *self = Declining::Quiet;
                    return Some(AlertEvent::Resolved(resolved));
                }
            }
            (Reading::Predicts, Declining::Quiet) => {
                *self = Declining::Pending {
                    windows: 0,
                    since: now,
                };
                return self.observe(gate, rules, obs, now);
            }
            (Reading::Predicts, Declining::Pending { windows, since }) => {
                *windows = windows.saturating_add(1);
                if *windows >= rules.warn_for_windows() {
                    let alert = declining_alert(gate, rules, obs, *since);
                    *self = Declining::Firing {
                        alert: alert.clone(),
                        calm: 0,
                    };
                    return Some(AlertEvent::Firing(alert));
                }
            }
            (Reading::Predicts | Reading::Holds, Declining::Firing { alert, calm }) => {
                *calm = 0;
                // Same labels and startsAt; fresh figures for the re-sends.
                alert.annotations = declining_annotations(gate, rules, obs);
            }
        }
        None
    }
}

fn declining_alert(gate: &str, rules: &AlertRules, obs: &Observation, since: SystemTime) -> Alert {
    Alert::new(
        ALERT_DAMPING_DECLINING,
        gate,
        &rules.warn_severity,
        declining_annotations(gate, rules, obs),
        since,
    )
}

/// Minutes with one decimal.
fn fmt_minutes(seconds: f64) -> String {
    format!("{:.1}", seconds / 60.0)
}

fn declining_annotations(
    gate: &str,
    rules: &AlertRules,
    obs: &Observation,
) -> BTreeMap<String, String> {
    let mut a = BTreeMap::new();
    let Some(trend): Option<TrendEstimate> = obs.trend else {
        return a;
    };
    let per_minute = trend.slope_per_second * 60.0;
    let now = match (obs.zeta0.filter(|z| z.is_finite()), obs.zeta0_interval) {
        (Some(z), Some((lo, hi))) => format!(
            "{} % (95 % interval {} to {} %)",
            fmt_percent(z),
            fmt_percent(lo),
            fmt_percent(hi)
        ),
        (Some(z), None) => format!("{} %", fmt_percent(z)),
        _ => "unknown".to_string(),
    };
    let confident = trend.crossing_seconds_confident;
    // A trend line already at or below the threshold "crosses it in 0 s" (the warning keeps
    // firing after the crossing, docs/alerts.md): say that it is there, not that it will be.
    let below = trend.level <= trend.threshold;
    let summary = if below {
        format!(
            "gate {gate}: damping ratio declining, its trend already at or below {} %",
            fmt_percent(rules.fire_below)
        )
    } else {
        match (confident, trend.crossing_seconds) {
            (Some(c), _) => format!(
                "gate {gate}: damping ratio declining, predicted to cross {} % within {} min",
                fmt_percent(rules.fire_below),
                fmt_minutes(c)
            ),
            // a firing warning held by the fitted slope (`Reading::Holds`)
            (None, Some(s)) => format!(
                "gate {gate}: damping ratio declining, at this rate crossing {} % in {} min \
                 (no longer at 95 % confidence)",
                fmt_percent(rules.fire_below),
                fmt_minutes(s)
            ),
            (None, None) => format!("gate {gate}: damping ratio no longer declining"),
        }
    };
    a.insert("summary".to_string(), summary);
    let mut description = format!(
        "The damping ratio of gate {gate} is {now} and {} by {} percentage points per minute \
         (trend over the last {} min of data, {} windows).",
        if per_minute > 0.0 { "rises" } else { "falls" },
        fmt_percent(per_minute.abs()),
        fmt_minutes(trend.span_seconds),
        trend.windows
    );
    if below {
        description.push_str(&format!(
            " Its trend line stands at {} %, already at or below {} %.",
            fmt_percent(trend.level),
            fmt_percent(rules.fire_below)
        ));
    } else if let Some(s) = trend.crossing_seconds {
        description.push_str(&format!(
            " At this rate it crosses {} % in {} min",
            fmt_percent(rules.fire_below),
            fmt_minutes(s)
        ));
        if let Some(c) = confident {
            description.push_str(&format!(
                " (at the latest in {} min, 95 % confidence)",
                fmt_minutes(c)
            ));
        }
        description.push('.');
    }
    a.insert("description".to_string(), description);
    // four significant digits, as GateNegativeDamping's (this one printed all 17)
    if let Some(z) = obs.zeta0.filter(|z| z.is_finite()) {
        a.insert("damping_ratio".to_string(), fmt_sig(z));
    }
    if let Some((lo, hi)) = obs.zeta0_interval {
        a.insert("damping_ratio_lower".to_string(), fmt_sig(lo));
        a.insert("damping_ratio_upper".to_string(), fmt_sig(hi));
    }
    a.insert("trend_per_minute".to_string(), fmt_sig(per_minute));
    if let Some(s) = trend.crossing_seconds {
        a.insert("crossing_seconds".to_string(), fmt_sig(s));
    }
    if let Some(c) = confident {
        a.insert("crossing_seconds_confident".to_string(), fmt_sig(c));
    }
    a
}
