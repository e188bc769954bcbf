//! What the HTTP history route and `gatewatch history` share: the time syntax of `from`/`to`
//! and the CSV columns.

use std::time::UNIX_EPOCH;

use super::{HistoryRow, IdentificationRecord};

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

/// A time given as Unix seconds (`1714564800`, `1714564800.5`) or RFC 3339 (`2024-05-01T12:00:00Z`,
/// fractions allowed, or with an offset: `2024-05-01T14:00:00+02:00` is the same instant), as
/// Unix seconds. The error says which forms are accepted.
pub fn parse_time(s: &str) -> Result<f64, String> {
    let given = s.trim();
    // RFC 3339 (section 5.6) allows a lowercase `t` and `z`, which humantime does not read
    let upper = given.to_ascii_uppercase();
    let s = upper.as_str();
    if let Ok(v) = s.parse::<f64>() {
        if v.is_finite() {
            return Ok(v);
        }
    }
    // humantime reads UTC only: an offset `+HH:MM` / `-HH:MM` is taken off and applied after
    let (utc, offset) = match split_offset(s) {
        Some((base, offset)) => (format!("{base}Z"), offset),
        None => (s.to_string(), 0.0),
    };
    // A time without `Z` or an offset is local time somewhere: read as UTC it shifted the
    // range by hours without a word (ingest refuses it too; RFC 3339 section 4.3)
    if !utc.ends_with('Z') && s.contains(':') {
        return Err(format!(
            "{given:?} has no offset: end an RFC 3339 time with Z (UTC) or +HH:MM/-HH:MM, like \
             2024-05-01T12:00:00Z or 2024-05-01T14:00:00+02:00 (a time without one is \
             ambiguous)"
        ));
    }
    match humantime::parse_rfc3339_weak(&utc) {
        // the parser refuses years before 1970; should it ever take one, it is negative seconds
        Ok(t) => Ok(match t.duration_since(UNIX_EPOCH) {
            Ok(d) => d.as_secs_f64(),
            Err(before) => -before.duration().as_secs_f64(),
        } - offset),
        Err(e) => Err(format!(
            "{given:?} is neither Unix seconds nor an RFC 3339 time like 2024-05-01T12:00:00Z or \
             2024-05-01T14:00:00+02:00 ({e})"
        )),
    }
}

/// `(time without offset, offset in seconds)` when `s` ends in an RFC 3339 offset `+HH:MM` or
/// `-HH:MM` after a time of day.
fn split_offset(s: &str) -> Option<(&str, f64)> {
    let at = s.len().checked_sub(6)?;
    let (base, tail) = (s.get(..at)?, s.get(at..)?);
    let b = tail.as_bytes();
    let sign = match b[0] {
        b'+' => 1.0,
        b'-' => -1.0,
        _ => return None,
    };
    if b[3] != b':' || !base.contains(['T', 't', ' ']) {
        return None;
    }
    let hours: u8 = tail.get(1..3)?.parse().ok()?;
    let minutes: u8 = tail.get(4..6)?.parse().ok()?;
    if hours > 23 || minutes > 59 {
        return None;
    }
    Some((
        base,
        sign * (f64::from(hours) * 3600.0 + f64::from(minutes) * 60.0),
    ))
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

/// Appends `rows` as CSV (with the header when `header`) to `out`, from the summary columns:
/// no JSON parsed. The same text as [`history_csv`] for the same records.
pub fn history_csv_rows(
    rows: &[HistoryRow],
    header: bool,
    out: &mut Vec<u8>,
) -> Result<(), String> {
    let err = |e: csv::Error| format!("cannot write CSV: {e}");
    let mut w = csv::Writer::from_writer(out);
    if header {
        w.write_record(HISTORY_CSV_HEADER).map_err(err)?;
    }
    for r in rows {
        w.write_record([
            r.gate.as_str(),
            &r.time.to_string(),
            &r.window_start.to_string(),
            &r.window_end.to_string(),
            &opt(r.zeta0),
            &opt(r.zeta0_interval.map(|i| i.0)),
            &opt(r.zeta0_interval.map(|i| i.1)),
            &opt(r.frequency_hz),
            if r.trusted { "true" } else { "false" },
            &r.verdict,
            &r.fit_nmae.to_string(),
            &r.path,
            &r.equation,
        ])
        .map_err(err)?;
    }
    w.flush().map_err(|e| format!("cannot write CSV: {e}"))
}

/// Appends `rows` to `out` as the JSON objects of [`IdentificationRecord`] (keys in the order
/// `serde_json::Value` gives them), each preceded by a comma unless `first` and it is the
/// first. The stored JSON (damping report, coefficients) is copied as it is, never parsed:
/// the store wrote it with `serde_json`, so it is valid JSON.
pub fn history_json_rows(rows: &[HistoryRow], first: bool, out: &mut Vec<u8>) {
    // serde_json never fails to write a string or a number into a Vec
    fn put<T: serde::Serialize + ?Sized>(out: &mut Vec<u8>, key: &str, v: &T) {
        out.extend_from_slice(b",\"");
        out.extend_from_slice(key.as_bytes());
        out.extend_from_slice(b"\":");
        let _ = serde_json::to_writer(&mut *out, v);
    }
    for (i, r) in rows.iter().enumerate() {
        if i > 0 || !first {
            out.push(b',');
        }
        out.extend_from_slice(b"{\"coefficients\":");
        out.extend_from_slice(r.coefficients.as_bytes());
        out.extend_from_slice(b",\"damping\":");
        out.extend_from_slice(r.damping.as_bytes());
        put(out, "equation", &r.equation);
        put(out, "fit_nmae", &r.fit_nmae);
        put(out, "gate", &r.gate);
        put(out, "path", &r.path);
        put(out, "time", &r.time);
        put(out, "verdict", &r.verdict);
        put(out, "window_end", &r.window_end);
        put(out, "window_start", &r.window_start);
        out.push(b'}');
    }
}
