//! What the HTTP history route and `gatewatch history` share: the time syntax of `from`/`to`
//! and the CSV columns.

use std::time::UNIX_EPOCH;

use super::IdentificationRecord;

/// The CSV header, one column per field an engineer plots or filters on. Times in Unix
/// seconds (spreadsheets and pandas convert them), the interval as two columns.
pub const HISTORY_CSV_HEADER: [&str; 13] = [
    "gate",
    "time",
    "window_start",
    "window_end",
    "zeta0",
    "zeta0_low",
    "zeta0_high",
    "frequency_hz",
    "trusted",
    "verdict",
    "fit_nmae",
    "path",
    "equation",
];

/// A time given as Unix seconds (`1714564800`, `1714564800.5`) or RFC 3339 in UTC
/// (`2024-05-01T12:00:00Z`, fractions allowed), as Unix seconds. The error says which forms
/// are accepted.
pub fn parse_time(s: &str) -> Result<f64, String> {
    let s = s.trim();
    if let Ok(v) = s.parse::<f64>() {
        if v.is_finite() {
            return Ok(v);
        }
    }
    match humantime::parse_rfc3339_weak(s) {
        Ok(t) => Ok(t
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_secs_f64())
            .unwrap_or(0.0)),
        Err(e) => Err(format!(
            "{s:?} is neither Unix seconds nor an RFC 3339 time like 2024-05-01T12:00:00Z ({e})"
        )),
    }
}

fn opt(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

/// The records as CSV with [`HISTORY_CSV_HEADER`].
pub fn history_csv(records: &[IdentificationRecord]) -> Result<String, String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    let err = |e: csv::Error| format!("cannot write CSV: {e}");
    w.write_record(HISTORY_CSV_HEADER).map_err(err)?;
    for r in records {
        let interval = r.zeta0_interval();
        let trusted = r
            .damping
            .get("trusted")
            .and_then(serde_json::Value::as_bool)
            .unwrap_or(false);
        let frequency = r
            .damping
            .get("frequency_hz")
            .and_then(serde_json::Value::as_f64);
        w.write_record([
            r.gate.clone(),
            r.time.to_string(),
            r.window_start.to_string(),
            r.window_end.to_string(),
            opt(r.zeta0()),
            opt(interval.map(|i| i.0)),
            opt(interval.map(|i| i.1)),
            opt(frequency),
            trusted.to_string(),
            r.verdict.clone(),
            r.fit_nmae.to_string(),
            r.path.clone(),
            r.equation.clone(),
        ])
        .map_err(err)?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| format!("cannot write CSV: {e}"))?;
    String::from_utf8(bytes).map_err(|e| format!("CSV is not UTF-8: {e}"))
}
