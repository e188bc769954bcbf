//! The annotations (summary, description, figures) and construction of each alert.

use std::collections::BTreeMap;
use std::time::{Duration, SystemTime};

use super::{rfc3339, Alert, AlertRules, Observation, ALERT_DATA_STALE, ALERT_NEGATIVE_DAMPING};

fn finite(x: Option<f64>) -> Option<f64> {
    x.filter(|v| v.is_finite())
}

/// A percentage with one decimal, or one significant digit below 1 %.
pub(super) fn fmt_percent(ratio: f64) -> String {
    let p = ratio * 100.0;
    let a = p.abs();
    if a >= 1.0 || a == 0.0 {
        format!("{p:.1}")
    } else {
        let decimals = (-a.log10()).ceil().clamp(1.0, 9.0) as usize;
        format!("{p:.decimals$}")
    }
}

pub(super) fn fmt_hz(f: f64) -> String {
    if f.abs() >= 1.0 {
        format!("{f:.1}")
    } else {
        format!("{f:.3}")
    }
}

pub(super) fn damping_annotations(
    gate: &str,
    rules: &AlertRules,
    obs: &Observation,
) -> BTreeMap<String, String> {
    let mut a = BTreeMap::new();
    let zeta = finite(obs.zeta0);
    let freq = finite(obs.frequency_hz);
    let amp = finite(obs.limit_cycle_amplitude);
    let ttl = finite(obs.time_to_limit);
    let pct = zeta.map(fmt_percent).unwrap_or_else(|| "?".to_string());
    let summary = match freq {
        Some(f) => format!(
            "gate {gate}: damping ratio {pct} % (self-excited vibration at {} Hz)",
            fmt_hz(f)
        ),
        None => format!("gate {gate}: damping ratio {pct} % (self-excited vibration)"),
    };
    let mut description = format!(
        "The equation of motion identified for gate {gate} has negative damping at rest \
         (damping ratio {pct} %, below {} %): oscillations grow by themselves.",
        fmt_percent(rules.fire_below)
    );
    if let Some(a) = amp {
        description.push_str(&format!(" Predicted limit-cycle amplitude: {a}."));
    }
    if let Some(t) = ttl {
        description.push_str(&format!(" Time to reach the amplitude limit: {t:.1} s."));
    }
    if !obs.equation.is_empty() {
        description.push_str(&format!(" Identified equation: {}", obs.equation));
    }
    a.insert("summary".to_string(), summary);
    a.insert("description".to_string(), description);
    if let Some(z) = zeta {
        a.insert("damping_ratio".to_string(), z.to_string());
    }
    if let Some(f) = freq {
        a.insert("frequency_hz".to_string(), f.to_string());
    }
    if let Some(v) = amp {
        a.insert("limit_cycle_amplitude".to_string(), v.to_string());
    }
    if let Some(t) = ttl {
        a.insert("time_to_limit_seconds".to_string(), t.to_string());
    }
    if !obs.equation.is_empty() {
        a.insert("equation".to_string(), obs.equation.to_string());
    }
    a
}

pub(super) fn damping_alert(
    gate: &str,
    rules: &AlertRules,
    obs: &Observation,
    starts_at: SystemTime,
) -> Alert {
    Alert::new(
        ALERT_NEGATIVE_DAMPING,
        gate,
        &rules.severity,
        damping_annotations(gate, rules, obs),
        starts_at,
    )
}

pub(super) fn stale_alert(
    gate: &str,
    rules: &AlertRules,
    last_seen: SystemTime,
    elapsed: Duration,
    now: SystemTime,
) -> Alert {
    let secs = elapsed.as_secs();
    let mut a = BTreeMap::new();
    a.insert(
        "summary".to_string(),
        format!("gate {gate}: no data for {secs} s"),
    );
    a.insert(
        "description".to_string(),
        format!(
            "No samples from gate {gate} since {} (limit {} s): its damping is not monitored.",
            rfc3339(last_seen),
            rules.stale_after_seconds
        ),
    );
    a.insert("last_seen".to_string(), rfc3339(last_seen));
    Alert::new(ALERT_DATA_STALE, gate, &rules.severity, a, now)
}
