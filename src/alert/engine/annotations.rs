//! The annotations (summary, description, figures) and construction of each alert.

use std::collections::BTreeMap;
use std::time::{Duration, SystemTime};

use super::{rfc3339, Alert, AlertRules, Observation, ALERT_DATA_STALE, ALERT_NEGATIVE_DAMPING};
use crate::analysis::Zeta0Source;

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

/// `x` to 4 significant digits with the trailing zeros dropped (`49.55`, `-0.012`, `4270`),
/// in scientific notation outside 1e-3..1e6 (`1.235e7`): what an operator reads in an alert,
/// not the 17 digits of an `f64` (`49.54840061414192`).
pub(super) fn fmt_sig(x: f64) -> String {
    fn trim(s: &str) -> &str {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.')
        } else {
            s
        }
    }
    let a = x.abs();
    if a == 0.0 || !a.is_finite() {
        return format!("{x}");
    }
    if !(1e-3..1e6).contains(&a) {
        let s = format!("{x:.3e}");
        return match s.split_once('e') {
            Some((mantissa, exp)) => format!("{}e{exp}", trim(mantissa)),
            None => s,
        };
    }
    let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
    trim(&format!("{x:.decimals$}")).to_string()
}

/// How a `zeta0` that is not the model's was estimated, for the description.
fn source_phrase(source: Zeta0Source) -> &'static str {
    match source {
        Zeta0Source::Model => "from the identified equation of motion",
        Zeta0Source::Ambient => "estimated model-free from the ambient vibration",
        Zeta0Source::Envelope => {
            "estimated model-free from the relaxation of the limit cycle's envelope"
        }
        Zeta0Source::Amplitude => {
            "read from the limit cycle's amplitude through the damping law of the gate's last \
             growth"
        }
        Zeta0Source::PredictionError => {
            "read by the prediction errors of the equation of motion under the turbulent forcing"
        }
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
    let below = fmt_percent(rules.fire_below);
    // The equation is credited with the damping only when it is where zeta0 came from: a
    // model-free estimate (ambient, envelope, amplitude) said "the equation of motion ... has
    // negative damping" next to an equation that may not.
    let by_model = obs.zeta0_source == Some(Zeta0Source::Model);
    let mut description = match obs.zeta0_source {
        Some(Zeta0Source::Model) => format!(
            "The equation of motion identified for gate {gate} has negative damping at rest \
             (damping ratio {pct} %, below {below} %): oscillations grow by themselves."
        ),
        Some(source) => format!(
            "Gate {gate} has negative damping at rest (damping ratio {pct} %, below {below} %, \
             {} (zeta0_source {source})): oscillations grow by themselves.",
            source_phrase(source)
        ),
        None => format!(
            "Gate {gate} has negative damping at rest (damping ratio {pct} %, below {below} %): \
             oscillations grow by themselves."
        ),
    };
    // read negative by its regime: say what the evidence is, and what the figure is not
    let by_regime = super::negative_by_regime_only(obs, rules);
    if let Some(evidence) = by_regime {
        let ratio = obs.ambient_ratio.map_or("?".to_string(), fmt_sig);
        let interval = match obs.zeta0_interval {
            Some((lo, hi)) if lo.is_finite() && hi.is_finite() => {
                format!(
                    " (95 % interval {} to {} %)",
                    fmt_percent(lo),
                    fmt_percent(hi)
                )
            }
            _ => " (no interval)".to_string(),
        };
        let what = if evidence == super::RegimeEvidence::Growth {
            format!(
                "Gate {gate}'s oscillation grows by itself {ratio} times above its ambient \
                 level (its envelope grows significantly): only a negative damping at rest makes \
                 it grow, whatever its size."
            )
        } else {
            format!(
                "Gate {gate} holds a steady self-sustained oscillation (a limit cycle) {ratio} \
                 times above its ambient level: only a negative damping at rest sustains one, \
                 whatever its size."
            )
        };
        description = format!(
            "{what} This window's damping ratio, {pct} %{interval}, does not yet tell the size."
        );
    }
    let unit = if obs.amplitude_unit.is_empty() {
        String::new()
    } else {
        format!(" {}", obs.amplitude_unit)
    };
    if let Some(a) = amp {
        description.push_str(&format!(
            " Limit-cycle amplitude predicted by the identified equation: {}{unit}.",
            fmt_sig(a)
        ));
    }
    if let Some(t) = ttl {
        description.push_str(&format!(
            " Time to reach the amplitude limit: {} s.",
            fmt_sig(t)
        ));
    }
    if !obs.equation.is_empty() {
        if by_model {
            description.push_str(&format!(" Identified equation: {}", obs.equation));
        } else {
            description.push_str(&format!(
                " Equation identified in the same window (not the source of this damping \
                 ratio): {}",
                obs.equation
            ));
        }
    }
    a.insert("summary".to_string(), summary);
    a.insert("description".to_string(), description);
    // what made the window negative: its interval below fire_below, or its regime
    let evidence = by_regime.map_or("interval", super::RegimeEvidence::as_str);
    a.insert("evidence".to_string(), evidence.to_string());
    if let Some(z) = zeta {
        a.insert("damping_ratio".to_string(), fmt_sig(z));
    }
    if let Some(s) = obs.zeta0_source {
        a.insert("zeta0_source".to_string(), s.as_str().to_string());
    }
    if let Some(f) = freq {
        a.insert("frequency_hz".to_string(), fmt_sig(f));
    }
    if let Some(v) = amp {
        a.insert("limit_cycle_amplitude".to_string(), fmt_sig(v));
    }
    if let Some(t) = ttl {
        a.insert("time_to_limit_seconds".to_string(), fmt_sig(t));
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
