//! JSON parsing that refuses a duplicate key in an object.
//!
//! `serde_json::Value` keeps the last of two equal keys, so `{"gate": "g1", ..., "gate": "g2"}`
//! went to `g2` silently. RFC 8259 leaves duplicate names undefined and parsers disagree (first
//! wins, last wins, error); a sample going to the wrong gate is worse than a 400, so the body is
//! read into a `Value` through a visitor that refuses a repeated key, naming it.

use std::fmt;

use serde::de::{self, Deserialize, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};

use super::BadRequest;

/// The message prefix of a duplicate key (the key follows in backquotes).
const DUPLICATE: &str = "duplicate key `";

/// Parses `body` into a `Value`; a syntax error names its line and column, a duplicate key also
/// the key (as `field`).
pub fn parse(body: &[u8]) -> Result<Value, BadRequest> {
    serde_json::from_slice::<Strict>(body)
        .map(|s| s.0)
        .map_err(|e| {
            let msg = e.to_string();
            let mut b = BadRequest::new(format!("invalid JSON: {e}"));
            if let Some(rest) = msg.strip_prefix(DUPLICATE) {
                if let Some((key, _)) = rest.split_once('`') {
                    b.field = Some(key.to_string());
                }
            }
            if e.line() > 0 {
                b.line = Some(e.line());
                b.column = Some(e.column());
            }
            b
        })
}

/// A `Value` read without duplicate keys.
struct Strict(Value);

impl<'de> Deserialize<'de> for Strict {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(StrictVisitor).map(Strict)
    }
}

struct StrictVisitor;

impl<'de> Visitor<'de> for StrictVisitor {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any JSON value")
    }
    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }
    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }
    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }
    fn visit_f64<E>(self, v: f64) -> Result<Value, E> {
        // JSON numbers are finite: serde_json never hands over NaN or infinity
        Ok(Number::from_f64(v).map_or(Value::Null, Value::Number))
    }
    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_owned()))
    }
    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }
    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }
    fn visit_none<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }
    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        Strict::deserialize(d).map(|s| s.0)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(4096));
        while let Some(Strict(v)) = seq.next_element()? {
            out.push(v);
        }
        Ok(Value::Array(out))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut out = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if out.contains_key(&key) {
                return Err(de::Error::custom(format!("{DUPLICATE}{key}`")));
            }
            let Strict(v) = map.next_value()?;
            out.insert(key, v);
        }
        Ok(Value::Object(out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_values_as_serde_json() {
        let text = br#"{"a": [1, -2, 3.5, 1e300, 18446744073709551615], "b": {"c": null, "d": true}, "e": "\u00e9"}"#;
        let strict = parse(text).unwrap();
        let plain: Value = serde_json::from_slice(text).unwrap();
        assert_eq!(strict, plain);
    }

    #[test]
    fn duplicate_key_is_named_with_its_line() {
        let e = parse(b"{\"gate\": \"g1\",\n \"gate\": \"g2\"}").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("gate"));
        assert_eq!(e.line, Some(2));
        assert!(e.error.contains("duplicate key `gate`"), "{}", e.error);
        // nested, in an array
        let e = parse(br#"[{"gate": "g1", "values": [1], "values": [2]}]"#).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("values"));
    }

    #[test]
    fn syntax_errors_keep_line_and_column() {
        let e = parse(b"[1,\n]").unwrap_err();
        assert_eq!((e.line, e.field), (Some(2), None));
    }
}
