//! The maintained `influxdb-line-protocol` crate doing what gatewatch's hand-written parser and
//! `to_batches` do, and the workload both are measured on. Shared by
//! `tests/line_protocol_crate.rs` (they agree) and `benches/line_protocol.rs` (which is faster).
#![allow(dead_code)]

use std::fmt::Write as _;

use gatewatch::service::config::valid_gate_id;
use gatewatch::service::ingest::line_protocol::Mapping;
use gatewatch::service::ingest::Batch;
use influxdb_line_protocol::{parse_lines, FieldValue};

/// `to_batches(parse(text))` with the crate as the parser: the same samples, the same checks
/// (gate tag present and a valid id, a numeric value field from `m.value_fields`, first present
/// wins), the same per-gate grouping and 1-based line numbers. The body is split on `\n` as
/// gatewatch does, so that every sample keeps its line number; the crate parses each line.
/// Errors are plain strings: only whether and where a body fails matters here.
pub fn crate_to_batches(text: &str, m: &Mapping<'_>) -> Result<Vec<Batch>, String> {
    let mut batches: Vec<Batch> = Vec::new();
    for (i, raw) in text.split('\n').enumerate() {
        let line_no = i + 1;
        let trimmed = raw.trim_start();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let Some(parsed) = parse_lines(raw).next() else {
            continue;
        };
        let line = parsed.map_err(|e| format!("line {line_no}: {e}"))?;
        let gate = line
            .tag_value(m.gate_tag)
            .ok_or_else(|| format!("line {line_no}: missing tag `{}`", m.gate_tag))?;
        let gate = gate.as_str();
        if !valid_gate_id(gate) {
            return Err(format!("line {line_no}: invalid gate id"));
        }
        let (name, value) = m
            .value_fields
            .iter()
            .find_map(|f| line.field_value(f).map(|v| (f, v)))
            .ok_or_else(|| format!("line {line_no}: missing field"))?;
        let v = numeric(value).ok_or_else(|| format!("line {line_no}: expected a number"))?;
        let t = match line.timestamp {
            Some(ts) => ts as f64 * m.precision.seconds_per_unit(),
            None => m.now,
        };
        let batch = match batches.iter().position(|b| b.gate == gate) {
            Some(i) => &mut batches[i],
            None => {
                batches.push(Batch {
                    gate: gate.to_string(),
                    samples: Vec::new(),
                    rate: None,
                    values_field: name.clone(),
                    lines: Some(Vec::new()),
                    precision: Some(m.precision),
                });
                batches.last_mut().expect("just pushed")
            }
        };
        batch.samples.push((t, v));
        if let Some(l) = batch.lines.as_mut() {
            l.push(line_no);
        }
    }
    if batches.is_empty() {
        return Err("no lines".into());
    }
    Ok(batches)
}

/// The crate over the whole body in one call (its own line splitter, which also honours
/// newlines inside quoted strings). It yields no line numbers, so samples carry none: less
/// work than gatewatch does, measured as the crate's best case.
pub fn crate_whole_body(text: &str, m: &Mapping<'_>) -> Result<Vec<(String, f64, f64)>, String> {
    let mut out = Vec::new();
    for parsed in parse_lines(text) {
        let line = parsed.map_err(|e| e.to_string())?;
        let gate = line
            .tag_value(m.gate_tag)
            .ok_or_else(|| format!("missing tag `{}`", m.gate_tag))?;
        if !valid_gate_id(gate.as_str()) {
            return Err("invalid gate id".into());
        }
        let value = m
            .value_fields
            .iter()
            .find_map(|f| line.field_value(f))
            .ok_or("missing field")?;
        let v = numeric(value).ok_or("expected a number")?;
        let t = match line.timestamp {
            Some(ts) => ts as f64 * m.precision.seconds_per_unit(),
            None => m.now,
        };
        out.push((gate.to_string(), v, t));
    }
    Ok(out)
}

/// The numeric field kinds gatewatch accepts as a sample.
pub fn numeric(v: &FieldValue<'_>) -> Option<f64> {
    match v {
        FieldValue::F64(x) => Some(*x),
        FieldValue::I64(i) => Some(*i as f64),
        FieldValue::U64(u) => Some(*u as f64),
        FieldValue::String(_) | FieldValue::Boolean(_) => None,
    }
}

/// First timestamp of the generated bodies, in nanoseconds (Telegraf's default precision).
pub const T0_NS: i64 = 1_700_000_000_000_000_000;

/// A Telegraf-like body of `lines` lines: `gates` gates interleaved at `rate_hz` each (one line
/// per gate per sample instant), starting at sample `start`. `extra` adds two tags (one with an
/// escaped space) and three more fields around the value field, as a Telegraf input with
/// global tags and several sensor fields writes them.
pub fn telegraf_body(
    lines: usize,
    gates: usize,
    rate_hz: f64,
    start: usize,
    extra: bool,
) -> String {
    let mut s = String::with_capacity(lines * if extra { 140 } else { 60 });
    let step_ns = (1e9 / rate_hz).round() as i64;
    for i in 0..lines {
        let k = start + i / gates;
        let g = i % gates;
        let ts = T0_NS + k as i64 * step_ns;
        // A deterministic value with three decimals, like a load cell reading.
        let force = ((k * 7919 + g * 104_729) % 1_000_000) as f64 / 1000.0 - 500.0;
        if extra {
            writeln!(
                s,
                "gate_force,gate=g{g:02},site=north,sensor=load\\ cell\\ {g} temp=21.5,force={force:.3},status={}i,ok=t {ts}",
                k % 3
            )
        } else {
            writeln!(s, "m,gate=g{g:02} force={force:.3} {ts}")
        }
        .expect("writing to a String");
    }
    s
}
