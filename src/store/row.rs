//! A stored identification as the history route reads it ([`HistoryRow`]), and what is done
//! to a record before it is stored: its summary pulled into columns, its damping report's
//! zeta_eq(A) curve kept at fewer points.
//!
//! Why the curve is thinned (`docs/operations.md`, "Size"): the analysis samples the model's
//! zeta_eq(A) at 17 amplitudes with every digit of an f64, about 700 of the 1 350 bytes of a
//! report, more than everything else an engineer reads in it. The curve is smooth (a
//! polynomial in A for the chapter's models) and only ever drawn; the model that makes it, the
//! equation with its coefficients, is stored in full, so the exact curve can be recomputed.
//! Every second point (the ends kept: 17 = 2 x 8 + 1, so the 9 points kept are exactly the
//! analysis's own points) at 4 significant digits draws the same picture. The figures an
//! engineer reads (zeta0 and its interval, frequency, growth, fit...) are kept exactly.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{IdentificationRecord, StoreError};

/// Points of the zeta_eq(A) curve kept in a stored damping report (the analysis makes 17).
pub const CURVE_STORED_POINTS: usize = 9;

/// Significant digits of the stored curve's numbers (the picture needs 3).
pub const CURVE_STORED_DIGITS: usize = 4;

/// One stored identification: the summary columns, and the stored JSON as text. Its serde form
/// is the message the NATS store keeps for it (`nats`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HistoryRow {
    /// Gate id.
    pub gate: String,
    /// Wall-clock time of the identification, Unix seconds.
    pub time: f64,
    /// Sample time of the window's first sample, Unix seconds.
    pub window_start: f64,
    /// Sample time of the window's last sample, Unix seconds.
    pub window_end: f64,
    /// The identified equation with numbers.
    pub equation: String,
    /// The coefficients as stored: a JSON array of `[name, value]`.
    pub coefficients: String,
    /// The damping report as stored: a JSON object (its curve thinned, see the module).
    pub damping: String,
    /// The report's verdict.
    pub verdict: String,
    /// Fit error.
    pub fit_nmae: f64,
    /// Identification path.
    pub path: String,
    /// The report's `zeta0`.
    pub zeta0: Option<f64>,
    /// The report's `zeta0_interval`.
    pub zeta0_interval: Option<(f64, f64)>,
    /// The report's `frequency_hz`.
    pub frequency_hz: Option<f64>,
    /// The report's `trusted`.
    pub trusted: bool,
}

impl HistoryRow {
    /// The record, its JSON parsed; the error names the gate and the window.
    pub fn into_record(self) -> Result<IdentificationRecord, StoreError> {
        let decode = |what: &str, e: serde_json::Error| StoreError::Decode {
            operation: "history",
            message: format!("{what} of gate {} at {}: {e}", self.gate, self.window_end),
        };
        Ok(IdentificationRecord {
            coefficients: serde_json::from_str(&self.coefficients)
                .map_err(|e| decode("coefficients", e))?,
            damping: serde_json::from_str(&self.damping).map_err(|e| decode("damping", e))?,
            gate: self.gate,
            time: self.time,
            window_start: self.window_start,
            window_end: self.window_end,
            equation: self.equation,
            verdict: self.verdict,
            fit_nmae: self.fit_nmae,
            path: self.path,
        })
    }
}

/// The row a store keeps for `r`: its damping report compacted ([`compact_damping`]), the
/// summary taken from the compacted report, the coefficients and the report as JSON text. What
/// SQLite's columns hold, for a store without columns (`nats`).
pub(crate) fn stored_row(r: &IdentificationRecord) -> HistoryRow {
    let damping = compact_damping(&r.damping);
    let summary = Summary::of(&damping);
    HistoryRow {
        gate: r.gate.clone(),
        time: r.time,
        window_start: r.window_start,
        window_end: r.window_end,
        equation: r.equation.clone(),
        coefficients: serde_json::to_string(&r.coefficients).unwrap_or_else(|_| "[]".into()),
        damping: damping.to_string(),
        verdict: r.verdict.clone(),
        fit_nmae: r.fit_nmae,
        path: r.path.clone(),
        zeta0: summary.zeta0,
        zeta0_interval: summary.zeta0_low.zip(summary.zeta0_high),
        frequency_hz: summary.frequency_hz,
        trusted: summary.trusted,
    }
}

/// The summary columns of a damping report: zeta0, its interval, its source, the frequency,
/// trusted, the regime.
pub(crate) struct Summary {
    pub zeta0: Option<f64>,
    pub zeta0_low: Option<f64>,
    pub zeta0_high: Option<f64>,
    pub zeta0_source: Option<String>,
    pub frequency_hz: Option<f64>,
    pub trusted: bool,
    pub regime: Option<String>,
}

/// A JSON value as a column: a string as itself, anything else but null as its JSON.
fn text(v: Option<&Value>) -> Option<String> {
    match v? {
        Value::Null => None,
        Value::String(s) => Some(s.clone()),
        other => Some(other.to_string()),
    }
}

impl Summary {
    pub(crate) fn of(damping: &Value) -> Summary {
        let interval = damping.get("zeta0_interval").and_then(Value::as_array);
        let end = |i: usize| interval.and_then(|a| a.get(i)).and_then(Value::as_f64);
        Summary {
            zeta0: damping.get("zeta0").and_then(Value::as_f64),
            zeta0_low: end(0),
            zeta0_high: end(1),
            zeta0_source: text(damping.get("zeta0_source")),
            frequency_hz: damping.get("frequency_hz").and_then(Value::as_f64),
            trusted: damping
                .get("trusted")
                .and_then(Value::as_bool)
                .unwrap_or(false),
            regime: text(damping.get("regime")),
        }
    }
}

/// The damping report as stored: its `zeta_eq_curve` thinned to [`CURVE_STORED_POINTS`] at
/// [`CURVE_STORED_DIGITS`] (see the module); everything else as it is. Idempotent.
pub(crate) fn compact_damping(damping: &Value) -> Value {
    let Some(curve) = damping.get("zeta_eq_curve").and_then(Value::as_array) else {
        return damping.clone();
    };
    let n = curve.len();
    let keep: Vec<Value> = if n > CURVE_STORED_POINTS {
        // evenly spaced indices, both ends kept
        let last = CURVE_STORED_POINTS - 1;
        (0..CURVE_STORED_POINTS)
            .map(|k| curve[(k * (n - 1) + last / 2) / last].clone())
            .collect()
    } else {
        curve.clone()
    };
    let round = |p: Value| match p {
        Value::Array(xs) => Value::Array(
            xs.into_iter()
                .map(|x| match x.as_f64() {
                    Some(f) => serde_json::Number::from_f64(crate::number::round_significant(
                        f,
                        CURVE_STORED_DIGITS,
                    ))
                    .map_or(x, Value::Number),
                    None => x,
                })
                .collect(),
        ),
        other => other,
    };
    let mut out = damping.clone();
    if let Some(obj) = out.as_object_mut() {
        obj.insert(
            "zeta_eq_curve".into(),
            Value::Array(keep.into_iter().map(round).collect()),
        );
    }
    out
}

/// A stored JSON text that does not parse (a file damaged outside gatewatch), kept as a JSON
/// string rather than dropped, so the row survives a migration and the route stays valid
/// JSON.
pub(crate) fn unparsed(text: &str) -> Value {
    Value::String(text.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_curve_keeps_the_analysis_own_points_at_both_ends_rounded() {
        let curve: Vec<Value> = (0..17)
            .map(|i| {
                serde_json::json!([
                    0.1 * f64::from(i) + 1e-9,
                    0.012345678 - 0.001 * f64::from(i)
                ])
            })
            .collect();
        let d = serde_json::json!({"zeta0": 0.012345678901234567, "zeta_eq_curve": curve});
        let c = compact_damping(&d);
        let kept = c["zeta_eq_curve"].as_array().expect("curve");
        assert_eq!(kept.len(), CURVE_STORED_POINTS);
        assert_eq!(kept[0], serde_json::json!([1e-9, 0.01235]));
        // the 9 kept are the 0th, 2nd, ... 16th of the 17
        assert_eq!(kept[8], serde_json::json!([1.6, -0.003654]));
        assert_eq!(kept[4], serde_json::json!([0.8, 0.004346]));
        // the figures are exact
        assert_eq!(c["zeta0"], d["zeta0"]);
        assert_eq!(compact_damping(&c), c, "idempotent");
        // a short curve keeps its points
        let short = serde_json::json!({"zeta_eq_curve": [[1.0, 2.0]]});
        assert_eq!(compact_damping(&short), short);
    }
}
