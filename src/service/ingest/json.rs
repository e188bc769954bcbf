//! `POST /api/v1/samples`: JSON samples.
//!
//! ```json
//! {"gate": "g1", "start": 1700000000.0, "rate_hz": 200, "values": [0.1, 0.2]}
//! {"gate": "g1", "start": "2023-11-14T22:13:20.5Z", "rate_hz": 200, "values": [0.1]}
//! {"gate": "g1", "samples": [[1700000000.0, 0.1], [1700000000.005, 0.2]]}
//! [{"gate": "g1", ...}, {"gate": "g2", ...}]
//! ```
//!
//! Parsed by hand from a `serde_json::Value` so that every error names its field and index.

use serde_json::{Map, Value};

use super::{implied_rate, BadRequest, Batch};
use crate::service::config::valid_gate_id;

/// Parses a request body into batches.
pub fn parse(body: &[u8]) -> Result<Vec<Batch>, BadRequest> {
    // duplicate keys are refused, naming the key (see `strict_json`)
    let value: Value = super::strict_json::parse(body)?;
    match value {
        Value::Object(o) => Ok(vec![parse_object(&o, "")?]),
        Value::Array(items) => {
            if items.is_empty() {
                return Err(BadRequest::new("empty batch array"));
            }
            items
                .iter()
                .enumerate()
                .map(|(i, item)| match item {
                    Value::Object(o) => parse_object(o, &format!("[{i}].")),
                    _ => Err(BadRequest::new("expected an object").field(format!("[{i}]"))),
                })
                .collect()
        }
        _ => Err(BadRequest::new("expected an object or an array of objects")),
    }
}

fn number(v: &Value, field: &str, index: Option<usize>) -> Result<f64, BadRequest> {
    let err = || {
        let mut b =
            BadRequest::new(format!("expected a number, got {}", type_name(v))).field(field);
        b.index = index;
        b
    };
    let x = v.as_f64().ok_or_else(err)?;
    Ok(x)
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// Parses `start`: Unix seconds, or an RFC 3339 UTC string (`Z` suffix). A time without an
/// offset is refused rather than taken as UTC: it is local time somewhere, and guessing wrong
/// shifts every sample by hours (RFC 3339 section 4.3 wants an explicit offset).
fn start_time(v: &Value, field: &str) -> Result<f64, BadRequest> {
    match v {
        Value::String(s) => {
            if !s.ends_with(['Z', 'z']) {
                return Err(BadRequest::new(format!(
                    "RFC 3339 time `{s}` must be in UTC and end with `Z` (a time without an offset \
                     is ambiguous; numeric offsets are not accepted)"
                ))
                .field(field));
            }
            let t = humantime::parse_rfc3339_weak(s)
                .map_err(|e| BadRequest::new(format!("invalid RFC 3339 time: {e}")).field(field))?;
            t.duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs_f64())
                .map_err(|_| BadRequest::new("time before 1970").field(field))
        }
        _ => number(v, field, None),
    }
}

fn parse_object(o: &Map<String, Value>, p: &str) -> Result<Batch, BadRequest> {
    for key in o.keys() {
        if !matches!(
            key.as_str(),
            "gate" | "start" | "rate_hz" | "values" | "samples"
        ) {
            return Err(
                BadRequest::new(format!("unknown field `{key}`")).field(format!("{p}{key}"))
            );
        }
    }
    let gate = match o.get("gate") {
        Some(Value::String(g)) if valid_gate_id(g) => g.clone(),
        Some(Value::String(_)) => {
            return Err(
                BadRequest::new("gate id must be 1..=64 characters of A-Z a-z 0-9 _ - .")
                    .field(format!("{p}gate")),
            )
        }
        Some(v) => {
            return Err(
                BadRequest::new(format!("expected a string, got {}", type_name(v)))
                    .field(format!("{p}gate")),
            )
        }
        None => return Err(BadRequest::new("missing field `gate`").field(format!("{p}gate"))),
    };
    match (o.get("values"), o.get("samples")) {
        (Some(_), Some(_)) => Err(
            BadRequest::new("give either `values` or `samples`, not both")
                .field(format!("{p}samples")),
        ),
        (Some(values), None) => {
            let field = format!("{p}values");
            let Value::Array(values) = values else {
                return Err(BadRequest::new(format!(
                    "expected an array, got {}",
                    type_name(values)
                ))
                .field(field));
            };
            if values.is_empty() {
                return Err(BadRequest::new("must not be empty").field(field));
            }
            let start = start_time(
                o.get("start").ok_or_else(|| {
                    BadRequest::new("missing field `start`").field(format!("{p}start"))
                })?,
                &format!("{p}start"),
            )?;
            let rate_field = format!("{p}rate_hz");
            let rate = number(
                o.get("rate_hz").ok_or_else(|| {
                    BadRequest::new("missing field `rate_hz`").field(rate_field.clone())
                })?,
                &rate_field,
                None,
            )?;
            if !(rate.is_finite() && rate > 0.0) {
                return Err(BadRequest::new("must be > 0").field(rate_field));
            }
            let mut samples = Vec::with_capacity(values.len());
            for (i, v) in values.iter().enumerate() {
                samples.push((start + i as f64 / rate, number(v, &field, Some(i))?));
            }
            Ok(Batch {
                gate,
                samples,
                rate: Some((rate, rate_field)),
                values_field: field,
                lines: None,
            })
        }
        (None, Some(samples)) => {
            let field = format!("{p}samples");
            for key in ["start", "rate_hz"] {
                if o.contains_key(key) {
                    return Err(BadRequest::new(format!(
                        "`{key}` goes with `values`, not `samples`"
                    ))
                    .field(format!("{p}{key}")));
                }
            }
            let Value::Array(items) = samples else {
                return Err(BadRequest::new(format!(
                    "expected an array, got {}",
                    type_name(samples)
                ))
                .field(field));
            };
            if items.is_empty() {
                return Err(BadRequest::new("must not be empty").field(field));
            }
            let mut out = Vec::with_capacity(items.len());
            for (i, item) in items.iter().enumerate() {
                match item {
                    Value::Array(pair) if pair.len() == 2 => {
                        let t = number(&pair[0], &field, Some(i))?;
                        let v = number(&pair[1], &field, Some(i))?;
                        out.push((t, v));
                    }
                    _ => {
                        return Err(BadRequest::new("expected a [time, value] pair")
                            .field(field)
                            .index(i))
                    }
                }
            }
            let rate = implied_rate(&out).map(|r| (r, field.clone()));
            Ok(Batch {
                gate,
                samples: out,
                rate,
                values_field: field,
                lines: None,
            })
        }
        (None, None) => {
            Err(BadRequest::new("missing field `values` or `samples`").field(format!("{p}values")))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        #[test]
        fn never_panics(body in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200)) {
            let _ = parse(&body);
        }

        #[test]
        fn never_panics_on_json_shapes(s in "[\\[\\]{}\":,0-9a-z.eE+-]{0,60}") {
            let _ = parse(s.as_bytes());
        }
    }

    #[test]
    fn uniform_times() {
        let b = parse(br#"{"gate":"g","start":10,"rate_hz":4,"values":[1,2,3]}"#).unwrap();
        assert_eq!(b[0].samples, vec![(10.0, 1.0), (10.25, 2.0), (10.5, 3.0)]);
        assert_eq!(b[0].rate, Some((4.0, "rate_hz".to_string())));
    }
}
