//! Fuzz targets of the ingestion formats (proptest; see `tests/fuzz_common`): the line-protocol
//! parser and the JSON ingest decoding. Properties: never a panic; every error names where
//! (line and column within the text for line protocol; a line/column, a field, or both for
//! JSON); and round trips: lines formatted from their parts parse back to the same parts, and
//! a JSON batch gives back its samples.

use crate::fuzz_common;

use gatewatch::service::ingest::json;
use gatewatch::service::ingest::line_protocol::{self, FieldValue, Line};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// Bytes a line protocol text is made of, weighted to its syntax.
fn lp_text() -> impl Strategy<Value = String> {
    let piece = prop_oneof![
        Just("m".to_string()),
        Just(",".to_string()),
        Just("=".to_string()),
        Just(" ".to_string()),
        Just("\\".to_string()),
        Just("\"".to_string()),
        Just("\n".to_string()),
        Just("\r".to_string()),
        Just("#".to_string()),
        Just("gate".to_string()),
        Just("force".to_string()),
        Just("1.5".to_string()),
        Just("-2i".to_string()),
        Just("3u".to_string()),
        Just("1e999".to_string()),
        Just("NaN".to_string()),
        Just("true".to_string()),
        Just("1700000000000000000".to_string()),
        Just("99999999999999999999".to_string()),
        Just("é".to_string()),
        any::<char>().prop_map(String::from),
    ];
    proptest::collection::vec(piece, 0..40).prop_map(|v| v.concat())
}

/// An error names a line and a column inside the text (column up to one past the line's end).
fn lp_check(text: &str) -> Result<(), TestCaseError> {
    match line_protocol::parse(text) {
        Ok(lines) => {
            for (n, _) in &lines {
                prop_assert!(*n >= 1 && *n <= text.split('\n').count(), "{text:?}");
            }
        }
        Err(e) => {
            let lines: Vec<&str> = text.split('\n').collect();
            prop_assert!(e.line >= 1 && e.line <= lines.len().max(1), "{text:?}: {e}");
            let len = lines.get(e.line - 1).map_or(0, |l| l.len());
            prop_assert!(e.column >= 1 && e.column <= len + 1, "{text:?}: {e}");
            prop_assert!(!e.message.is_empty());
        }
    }
    Ok(())
}

fn escape(s: &str, special: &[char]) -> String {
    let mut out = String::new();
    for c in s.chars() {
        if special.contains(&c) || c == '\\' {
            out.push('\\');
        }
        out.push(c);
    }
    out
}

fn name() -> impl Strategy<Value = String> {
    // names start with a letter (a leading `#` is a comment); any of , = space inside, escaped
    "[a-z][a-zA-Z0-9_ ,=.é-]{0,12}"
}

fn field_value() -> impl Strategy<Value = FieldValue> {
    prop_oneof![
        any::<f64>()
            .prop_filter("finite", |x| x.is_finite())
            .prop_map(FieldValue::Float),
        any::<i64>().prop_map(FieldValue::Int),
        any::<u64>().prop_map(FieldValue::UInt),
        "[ -~é]{0,12}".prop_map(FieldValue::Str),
        any::<bool>().prop_map(FieldValue::Bool),
    ]
}

fn line() -> impl Strategy<Value = Line> {
    (
        name(),
        proptest::collection::vec((name(), name()), 0..4),
        proptest::collection::vec((name(), field_value()), 1..4),
        proptest::option::of(any::<i64>()),
    )
        .prop_map(|(measurement, mut tags, mut fields, timestamp)| {
            // a key given twice in a line is refused (f76c014): the round trip is of valid
            // lines, so each key keeps its first occurrence
            let mut seen = std::collections::HashSet::new();
            tags.retain(|(k, _)| seen.insert(k.clone()));
            let mut seen = std::collections::HashSet::new();
            fields.retain(|(k, _)| seen.insert(k.clone()));
            Line {
                measurement,
                tags,
                fields,
                timestamp,
            }
        })
}

fn format_line(l: &Line) -> String {
    let mut out = escape(&l.measurement, &[',', ' ']);
    for (k, v) in &l.tags {
        out.push_str(&format!(
            ",{}={}",
            escape(k, &[',', '=', ' ']),
            escape(v, &[',', '=', ' '])
        ));
    }
    let fields: Vec<String> = l
        .fields
        .iter()
        .map(|(k, v)| {
            let v = match v {
                FieldValue::Float(x) => format!("{x:?}"),
                FieldValue::Int(i) => format!("{i}i"),
                FieldValue::UInt(u) => format!("{u}u"),
                FieldValue::Str(s) => format!("\"{}\"", escape(s, &['"'])),
                FieldValue::Bool(b) => b.to_string(),
            };
            format!("{}={v}", escape(k, &[',', '=', ' ']))
        })
        .collect();
    out.push(' ');
    out.push_str(&fields.join(","));
    if let Some(t) = l.timestamp {
        out.push_str(&format!(" {t}"));
    }
    out
}

/// A JSON error names where: a line and column (syntax), or a field.
fn json_check(body: &[u8]) -> Result<(), TestCaseError> {
    if let Err(e) = json::parse(body) {
        prop_assert!(
            e.field.is_some()
                || (e.line.is_some() && e.column.is_some())
                || body_shape_error(&e.error),
            "{:?}: {e:?}",
            String::from_utf8_lossy(body)
        );
        prop_assert!(!e.error.is_empty());
    }
    Ok(())
}

/// The errors about the whole body (not an object, an empty array): nothing narrower to name.
fn body_shape_error(msg: &str) -> bool {
    msg == "empty batch array" || msg == "expected an object or an array of objects"
}

/// JSON values shaped like sample batches, with wrong types, duplicates and extremes mixed in.
fn json_value() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        Just("null".to_string()),
        Just("true".to_string()),
        any::<f64>()
            .prop_filter("finite", |x| x.is_finite())
            .prop_map(|x| format!("{x:?}")),
        any::<i64>().prop_map(|x| x.to_string()),
        Just("1e999".to_string()),
        Just("18446744073709551616".to_string()),
        "[ -~é]{0,8}".prop_map(|s| serde_json::to_string(&s).unwrap()),
        Just("\"2026-11-23T03:00:00Z\"".to_string()),
        Just("\"2026-11-23T03:00:00\"".to_string()),
        Just("\"g1\"".to_string()),
    ];
    leaf.prop_recursive(4, 64, 6, |inner| {
        let key = prop_oneof![
            Just("gate"),
            Just("start"),
            Just("rate_hz"),
            Just("values"),
            Just("samples"),
            Just("x"),
        ];
        prop_oneof![
            proptest::collection::vec(inner.clone(), 0..6)
                .prop_map(|v| format!("[{}]", v.join(","))),
            proptest::collection::vec((key, inner), 0..6).prop_map(|kv| {
                let members: Vec<String> = kv
                    .into_iter()
                    .map(|(k, v)| format!("\"{k}\":{v}"))
                    .collect();
                format!("{{{}}}", members.join(","))
            }),
        ]
    })
}

/// How many representable doubles lie between `a` and `b` (0: equal, also for 0.0 and -0.0); a
/// relative tolerance would refuse a one-ULP difference between subnormals.
fn ulps_apart(a: f64, b: f64) -> u64 {
    if a == b {
        return 0;
    }
    if a.is_sign_negative() != b.is_sign_negative() {
        return u64::MAX;
    }
    a.to_bits().abs_diff(b.to_bits())
}

proptest! {
    #[test]
    fn line_protocol_never_panics_and_errors_name_line_and_column(text in lp_text()) {
        lp_check(&text)?;
    }

    #[test]
    fn line_protocol_arbitrary_strings(text in any::<String>()) {
        lp_check(&text)?;
    }

    #[test]
    fn line_protocol_round_trips(l in line()) {
        let text = format_line(&l);
        let parsed = line_protocol::parse(&text);
        prop_assert_eq!(parsed, Ok(vec![(1, l)]), "{}", text);
    }

    #[test]
    fn json_never_panics_and_errors_name_where(body in json_value()) {
        json_check(body.as_bytes())?;
    }

    #[test]
    fn json_arbitrary_bytes(body in proptest::collection::vec(any::<u8>(), 0..200)) {
        json_check(&body)?;
    }

    #[test]
    fn json_round_trips(
        start in 0.0f64..4e9,
        rate in 1.0f64..10_000.0,
        values in proptest::collection::vec(any::<f64>().prop_filter("finite", |x| x.is_finite()), 1..50),
    ) {
        let body = serde_json::json!({"gate": "g1", "start": start, "rate_hz": rate, "values": values});
        let b = json::parse(body.to_string().as_bytes()).unwrap();
        prop_assert_eq!(b.len(), 1);
        prop_assert_eq!(b[0].samples.len(), values.len());
        // serde_json without its `float_roundtrip` feature may be one ULP off (a known
        // trade-off of its fast float parser); anything more is a bug
        for (got, want) in b[0].samples.iter().map(|s| s.1).zip(&values) {
            prop_assert!(ulps_apart(got, *want) <= 2, "{got} vs {want}");
        }
        for (i, (t, _)) in b[0].samples.iter().enumerate() {
            let want = start + i as f64 / rate;
            prop_assert!((t - want).abs() <= want.abs() * 4.0 * f64::EPSILON, "{t} vs {want}");
        }
        let pairs: Vec<(f64, f64)> = b[0].samples.clone();
        let body = serde_json::json!({"gate": "g1", "samples": pairs});
        let b2 = json::parse(body.to_string().as_bytes()).unwrap();
        prop_assert_eq!(b2.len(), 1);
        prop_assert_eq!(b2[0].samples.len(), pairs.len());
        for (got, want) in b2[0].samples.iter().zip(&pairs) {
            prop_assert!(ulps_apart(got.0, want.0) <= 2, "t {} vs {}", got.0, want.0);
            prop_assert!(ulps_apart(got.1, want.1) <= 2, "value {} vs {}", got.1, want.1);
        }
    }
}

#[test]
#[ignore = "long fuzz run: FUZZ_SECONDS (600) per target"]
fn fuzz_long_line_protocol() {
    fuzz_common::long_run("line protocol", lp_text(), |t| lp_check(&t));
    fuzz_common::long_run("line protocol round trip", line(), |l| {
        let text = format_line(&l);
        prop_assert_eq!(line_protocol::parse(&text), Ok(vec![(1, l)]), "{}", text);
        Ok(())
    });
}

#[test]
#[ignore = "long fuzz run: FUZZ_SECONDS (600) per target"]
fn fuzz_long_json() {
    fuzz_common::long_run("JSON ingest", json_value(), |b| json_check(b.as_bytes()));
}
