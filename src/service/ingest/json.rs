//! `POST /api/v1/samples`: JSON samples.
//!
//! ```json
//! {"gate": "g1", "start": 1700000000.0, "rate_hz": 200, "values": [0.1, 0.2]}
//! {"gate": "g1", "start": "2023-11-14T22:13:20.5Z", "rate_hz": 200, "values": [0.1]}
//! {"gate": "g1", "samples": [[1700000000.0, 0.1], [1700000000.005, 0.2]]}
//! [{"gate": "g1", ...}, {"gate": "g2", ...}]
//! ```
//!
//! Streamed: the body is deserialised straight into the samples (serde visitors), never into a
//! `serde_json::Value` tree (32 bytes and more per number, which made one request cost 27 to 34
//! times its body). A request's peak is its body plus its samples (16 bytes each: at most 8
//! times a body of `0,0,0...`), see docs/design.md. Every error still names its field and
//! index; a field given twice is refused (a JSON object with duplicate keys is ambiguous).

use std::fmt;

use serde::de::{self, DeserializeSeed, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};

use super::{implied_rate, BadRequest, Batch};
use crate::service::config::{valid_gate_id, GATE_ID_RULE};

/// Parses a request body into batches.
pub fn parse(body: &[u8]) -> Result<Vec<Batch>, BadRequest> {
    let mut fault = None;
    let mut de = serde_json::Deserializer::from_slice(body);
    let parsed = Top { fault: &mut fault }
        .deserialize(&mut de)
        .and_then(|b| de.end().map(|()| b));
    parsed.map_err(|e| {
        // a fault found by a visitor is the answer (with where it was found, when the fault
        // does not say); otherwise it is a syntax error
        if let Some(mut b) = fault.take() {
            if b.line.is_none() && b.index.is_none() && e.line() > 0 {
                b.line = Some(e.line());
                b.column = Some(e.column());
            }
            return b;
        }
        fault.take().unwrap_or_else(|| {
            let mut b = BadRequest::new(format!("invalid JSON: {e}"));
            if e.line() > 0 {
                b.line = Some(e.line());
                b.column = Some(e.column());
            }
            b
        })
    })
}

/// Records `b` as the fault and returns the serde error that stops the parse.
fn fail<E: de::Error>(fault: &mut Option<BadRequest>, b: BadRequest) -> E {
    let msg = b.error.clone();
    *fault = Some(b);
    E::custom(msg)
}

/// A JSON value where a scalar is expected: a number, a string, or the name of what it was.
enum Scalar {
    Num(f64),
    Str(String),
    Other(&'static str),
}

impl Scalar {
    fn type_name(&self) -> &'static str {
        match self {
            Scalar::Num(_) => "a number",
            Scalar::Str(_) => "a string",
            Scalar::Other(t) => t,
        }
    }
}

impl<'de> de::Deserialize<'de> for Scalar {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Scalar;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a JSON value")
            }
            fn visit_bool<E>(self, _: bool) -> Result<Scalar, E> {
                Ok(Scalar::Other("a boolean"))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Scalar, E> {
                Ok(Scalar::Num(v as f64))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Scalar, E> {
                Ok(Scalar::Num(v as f64))
            }
            fn visit_f64<E>(self, v: f64) -> Result<Scalar, E> {
                Ok(Scalar::Num(v))
            }
            fn visit_str<E>(self, v: &str) -> Result<Scalar, E> {
                Ok(Scalar::Str(v.to_string()))
            }
            fn visit_unit<E>(self) -> Result<Scalar, E> {
                Ok(Scalar::Other("null"))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Scalar, A::Error> {
                while a.next_element::<IgnoredAny>()?.is_some() {}
                Ok(Scalar::Other("an array"))
            }
            fn visit_map<A: MapAccess<'de>>(self, mut a: A) -> Result<Scalar, A::Error> {
                while a.next_entry::<IgnoredAny, IgnoredAny>()?.is_some() {}
                Ok(Scalar::Other("an object"))
            }
        }
        d.deserialize_any(V)
    }
}

/// `expected a number, got ...` for `field` (at `index`).
fn not_a_number(s: &Scalar, field: &str, index: Option<usize>) -> BadRequest {
    let mut b = BadRequest::new(format!("expected a number, got {}", s.type_name())).field(field);
    b.index = index;
    b
}

/// The body: one object or a non-empty array of objects.
struct Top<'f> {
    fault: &'f mut Option<BadRequest>,
}

impl<'de> DeserializeSeed<'de> for Top<'_> {
    type Value = Vec<Batch>;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Vec<Batch>, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Top<'_> {
    type Value = Vec<Batch>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("an object or an array of objects")
    }
    fn visit_map<A: MapAccess<'de>>(self, a: A) -> Result<Vec<Batch>, A::Error> {
        Ok(vec![Object {
            prefix: String::new(),
            fault: self.fault,
        }
        .visit_map(a)?])
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Vec<Batch>, A::Error> {
        let mut out = Vec::new();
        loop {
            let seed = Object {
                prefix: format!("[{}].", out.len()),
                fault: &mut *self.fault,
            };
            match a.next_element_seed(seed)? {
                Some(b) => out.push(b),
                None => break,
            }
        }
        if out.is_empty() {
            return Err(fail(self.fault, BadRequest::new("empty batch array")));
        }
        Ok(out)
    }
    fn visit_bool<E: de::Error>(self, _: bool) -> Result<Vec<Batch>, E> {
        Err(self.wrong())
    }
    fn visit_i64<E: de::Error>(self, _: i64) -> Result<Vec<Batch>, E> {
        Err(self.wrong())
    }
    fn visit_u64<E: de::Error>(self, _: u64) -> Result<Vec<Batch>, E> {
        Err(self.wrong())
    }
    fn visit_f64<E: de::Error>(self, _: f64) -> Result<Vec<Batch>, E> {
        Err(self.wrong())
    }
    fn visit_str<E: de::Error>(self, _: &str) -> Result<Vec<Batch>, E> {
        Err(self.wrong())
    }
    fn visit_unit<E: de::Error>(self) -> Result<Vec<Batch>, E> {
        Err(self.wrong())
    }
}

impl Top<'_> {
    fn wrong<E: de::Error>(self) -> E {
        fail(
            self.fault,
            BadRequest::new("expected an object or an array of objects"),
        )
    }
}

/// One batch object; `prefix` is `""` or `"[i]."` for errors.
struct Object<'f> {
    prefix: String,
    fault: &'f mut Option<BadRequest>,
}

impl<'de> DeserializeSeed<'de> for Object<'_> {
    type Value = Batch;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Batch, D::Error> {
        d.deserialize_any(self)
    }
}

/// Which of `values` and `samples` was given, parsed.
enum Data {
    /// `values`: `(index, value)`; the times are set once `start` and `rate_hz` are known
    /// (they may come after `values`), in place, so no second vector is needed.
    Values(Vec<(f64, f64)>),
    /// `samples`: `(time, value)`.
    Samples(Vec<(f64, f64)>),
}

impl Object<'_> {
    /// An array item that is not an object: 400 naming the item (`[i]`).
    fn not_an_object<E: de::Error>(self, got: &str) -> E {
        let field = self.prefix.trim_end_matches('.').to_string();
        let b = BadRequest::new(format!("expected an object, got {got}"));
        fail(
            self.fault,
            if field.is_empty() { b } else { b.field(field) },
        )
    }
}

impl<'de> Visitor<'de> for Object<'_> {
    type Value = Batch;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("an object")
    }
    fn visit_bool<E: de::Error>(self, _: bool) -> Result<Batch, E> {
        Err(self.not_an_object("a boolean"))
    }
    fn visit_i64<E: de::Error>(self, _: i64) -> Result<Batch, E> {
        Err(self.not_an_object("a number"))
    }
    fn visit_u64<E: de::Error>(self, _: u64) -> Result<Batch, E> {
        Err(self.not_an_object("a number"))
    }
    fn visit_f64<E: de::Error>(self, _: f64) -> Result<Batch, E> {
        Err(self.not_an_object("a number"))
    }
    fn visit_str<E: de::Error>(self, _: &str) -> Result<Batch, E> {
        Err(self.not_an_object("a string"))
    }
    fn visit_unit<E: de::Error>(self) -> Result<Batch, E> {
        Err(self.not_an_object("null"))
    }
    fn visit_seq<A: SeqAccess<'de>>(self, _: A) -> Result<Batch, A::Error> {
        Err(self.not_an_object("an array"))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut a: A) -> Result<Batch, A::Error> {
        let p = self.prefix;
        let fault = self.fault;
        let mut seen: Vec<&'static str> = Vec::new();
        let (mut gate, mut start, mut rate) = (None, None, None);
        let mut values: Option<Vec<(f64, f64)>> = None;
        let mut samples: Option<Vec<(f64, f64)>> = None;
        while let Some(key) = a.next_key::<std::borrow::Cow<'de, str>>()? {
            let known = match key.as_ref() {
                "gate" => "gate",
                "start" => "start",
                "rate_hz" => "rate_hz",
                "values" => "values",
                "samples" => "samples",
                other => {
                    let b = BadRequest::new(format!("unknown field `{other}`"))
                        .field(format!("{p}{other}"));
                    return Err(fail(fault, b));
                }
            };
            if seen.contains(&known) {
                let b = BadRequest::new(format!("duplicate field `{known}`"))
                    .field(format!("{p}{known}"));
                return Err(fail(fault, b));
            }
            seen.push(known);
            match known {
                "gate" => gate = Some(a.next_value::<Scalar>()?),
                "start" => start = Some(a.next_value::<Scalar>()?),
                "rate_hz" => rate = Some(a.next_value::<Scalar>()?),
                "values" => {
                    let field = format!("{p}values");
                    let seed = Numbers {
                        field: &field,
                        fault: &mut *fault,
                    };
                    values = Some(a.next_value_seed(seed)?);
                }
                _ => {
                    let field = format!("{p}samples");
                    let seed = Pairs {
                        field: &field,
                        fault: &mut *fault,
                    };
                    samples = Some(a.next_value_seed(seed)?);
                }
            }
        }
        let data =
            match (values, samples) {
                (Some(_), Some(_)) => Err(BadRequest::new(
                    "give either `values` or `samples`, not both",
                )
                .field(format!("{p}samples"))),
                (Some(v), None) => Ok(Data::Values(v)),
                (None, Some(s)) => Ok(Data::Samples(s)),
                (None, None) => Err(BadRequest::new("missing field `values` or `samples`")
                    .field(format!("{p}values"))),
            };
        build(&p, gate, start, rate, data).map_err(|b| fail(fault, b))
    }
}

/// Checks the fields of one object (in the order the Value-based parser did) and builds it.
fn build(
    p: &str,
    gate: Option<Scalar>,
    start: Option<Scalar>,
    rate: Option<Scalar>,
    data: Result<Data, BadRequest>,
) -> Result<Batch, BadRequest> {
    let gate = match gate {
        Some(Scalar::Str(g)) if valid_gate_id(&g) => g,
        Some(Scalar::Str(_)) => return Err(BadRequest::new(GATE_ID_RULE).field(format!("{p}gate"))),
        Some(v) => {
            return Err(
                BadRequest::new(format!("expected a string, got {}", v.type_name()))
                    .field(format!("{p}gate")),
            )
        }
        None => return Err(BadRequest::new("missing field `gate`").field(format!("{p}gate"))),
    };
    match data? {
        Data::Values(mut samples) => {
            let field = format!("{p}values");
            if samples.is_empty() {
                return Err(BadRequest::new("must not be empty").field(field));
            }
            let start_field = format!("{p}start");
            let start = start_time(
                start.ok_or_else(|| {
                    BadRequest::new("missing field `start`").field(start_field.clone())
                })?,
                &start_field,
            )?;
            let rate_field = format!("{p}rate_hz");
            let rate = match rate {
                Some(Scalar::Num(r)) => r,
                Some(other) => return Err(not_a_number(&other, &rate_field, None)),
                None => return Err(BadRequest::new("missing field `rate_hz`").field(rate_field)),
            };
            if !(rate.is_finite() && rate > 0.0) {
                return Err(BadRequest::new("must be > 0").field(rate_field));
            }
            // the first member holds the index until now
            for (i, s) in samples.iter_mut().enumerate() {
                s.0 = start + i as f64 / rate;
            }
            Ok(Batch {
                gate,
                samples,
                rate: Some((rate, rate_field)),
                values_field: field,
                lines: None,
                precision: None,
            })
        }
        Data::Samples(samples) => {
            let field = format!("{p}samples");
            for (key, given) in [("start", start.is_some()), ("rate_hz", rate.is_some())] {
                if given {
                    return Err(BadRequest::new(format!(
                        "`{key}` goes with `values`, not `samples`"
                    ))
                    .field(format!("{p}{key}")));
                }
            }
            if samples.is_empty() {
                return Err(BadRequest::new("must not be empty").field(field));
            }
            let rate = implied_rate(&samples).map(|r| (r, field.clone()));
            Ok(Batch {
                gate,
                samples,
                rate,
                values_field: field,
                lines: None,
                precision: None,
            })
        }
    }
}

/// Parses `start`: Unix seconds, or an RFC 3339 UTC string (`Z` suffix). A time without an
/// offset is refused rather than taken as UTC: it is local time somewhere, and guessing wrong
/// shifts every sample by hours (RFC 3339 section 4.3 wants an explicit offset).
fn start_time(v: Scalar, field: &str) -> Result<f64, BadRequest> {
    match v {
        Scalar::Str(s) => {
            if !s.ends_with(['Z', 'z']) {
                return Err(BadRequest::new(format!(
                    "RFC 3339 time `{s}` must be in UTC and end with `Z` (a time without an offset \
                     is ambiguous; numeric offsets are not accepted)"
                ))
                .field(field));
            }
            // RFC 3339 (section 5.6) allows a lowercase `t` and `z`; humantime reads uppercase
            let t = humantime::parse_rfc3339_weak(&s.to_ascii_uppercase())
                .map_err(|e| BadRequest::new(format!("invalid RFC 3339 time: {e}")).field(field))?;
            t.duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs_f64())
                .map_err(|_| BadRequest::new("time before 1970").field(field))
        }
        Scalar::Num(x) => Ok(x),
        other => Err(not_a_number(&other, field, None)),
    }
}

/// The visits of everything but an array, shared by the array visitors ([`Numbers`],
/// [`Pairs`]): each refuses naming the field and what it got (an object is read to its end
/// first, so the error is the visitor's, not the parser's).
macro_rules! refuse_all_but_arrays {
    ($de:lifetime) => {
        fn visit_map<A: MapAccess<$de>>(self, mut a: A) -> Result<Self::Value, A::Error> {
            while a.next_entry::<IgnoredAny, IgnoredAny>()?.is_some() {}
            Err(not_array(self.fault, self.field, "an object"))
        }
        fn visit_bool<E: de::Error>(self, _: bool) -> Result<Self::Value, E> {
            Err(not_array(self.fault, self.field, "a boolean"))
        }
        fn visit_i64<E: de::Error>(self, _: i64) -> Result<Self::Value, E> {
            Err(not_array(self.fault, self.field, "a number"))
        }
        fn visit_u64<E: de::Error>(self, _: u64) -> Result<Self::Value, E> {
            Err(not_array(self.fault, self.field, "a number"))
        }
        fn visit_f64<E: de::Error>(self, _: f64) -> Result<Self::Value, E> {
            Err(not_array(self.fault, self.field, "a number"))
        }
        fn visit_str<E: de::Error>(self, _: &str) -> Result<Self::Value, E> {
            Err(not_array(self.fault, self.field, "a string"))
        }
        fn visit_unit<E: de::Error>(self) -> Result<Self::Value, E> {
            Err(not_array(self.fault, self.field, "null"))
        }
    };
}

/// `values`: an array of numbers, read as `(index, value)`.
struct Numbers<'a> {
    field: &'a str,
    fault: &'a mut Option<BadRequest>,
}

impl<'de> DeserializeSeed<'de> for Numbers<'_> {
    type Value = Vec<(f64, f64)>;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Numbers<'_> {
    type Value = Vec<(f64, f64)>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("an array of numbers")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Self::Value, A::Error> {
        let mut out = Vec::new();
        while let Some(v) = a.next_element::<Scalar>()? {
            match v {
                Scalar::Num(x) => out.push((out.len() as f64, x)),
                other => {
                    let b = not_a_number(&other, self.field, Some(out.len()));
                    return Err(fail(self.fault, b));
                }
            }
        }
        Ok(out)
    }
    refuse_all_but_arrays!('de);
}

fn not_array<E: de::Error>(fault: &mut Option<BadRequest>, field: &str, got: &str) -> E {
    fail(
        fault,
        BadRequest::new(format!("expected an array, got {got}")).field(field),
    )
}

/// `samples`: an array of `[time, value]` pairs.
struct Pairs<'a> {
    field: &'a str,
    fault: &'a mut Option<BadRequest>,
}

impl<'de> DeserializeSeed<'de> for Pairs<'_> {
    type Value = Vec<(f64, f64)>;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        d.deserialize_any(self)
    }
}

/// One element of `samples`: a pair of numbers, or what is wrong with it.
enum Pair {
    Ok(f64, f64),
    NotANumber(Scalar),
    /// Not an array of two numbers.
    Malformed,
}

impl<'de> de::Deserialize<'de> for Pair {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Pair;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a [time, value] pair")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Pair, A::Error> {
                let t = a.next_element::<Scalar>()?;
                let v = a.next_element::<Scalar>()?;
                let more = a.next_element::<IgnoredAny>()?.is_some();
                while a.next_element::<IgnoredAny>()?.is_some() {}
                Ok(match (t, v, more) {
                    (Some(Scalar::Num(t)), Some(Scalar::Num(v)), false) => Pair::Ok(t, v),
                    (Some(t), Some(v), false) => Pair::NotANumber(match t {
                        Scalar::Num(_) => v,
                        t => t,
                    }),
                    _ => Pair::Malformed,
                })
            }
            fn visit_map<A: MapAccess<'de>>(self, mut a: A) -> Result<Pair, A::Error> {
                while a.next_entry::<IgnoredAny, IgnoredAny>()?.is_some() {}
                Ok(Pair::Malformed)
            }
            fn visit_bool<E>(self, _: bool) -> Result<Pair, E> {
                Ok(Pair::Malformed)
            }
            fn visit_i64<E>(self, _: i64) -> Result<Pair, E> {
                Ok(Pair::Malformed)
            }
            fn visit_u64<E>(self, _: u64) -> Result<Pair, E> {
                Ok(Pair::Malformed)
            }
            fn visit_f64<E>(self, _: f64) -> Result<Pair, E> {
                Ok(Pair::Malformed)
            }
            fn visit_str<E>(self, _: &str) -> Result<Pair, E> {
                Ok(Pair::Malformed)
            }
            fn visit_unit<E>(self) -> Result<Pair, E> {
                Ok(Pair::Malformed)
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Visitor<'de> for Pairs<'_> {
    type Value = Vec<(f64, f64)>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("an array of [time, value] pairs")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Self::Value, A::Error> {
        let mut out = Vec::new();
        while let Some(p) = a.next_element::<Pair>()? {
            let i = out.len();
            match p {
                Pair::Ok(t, v) => out.push((t, v)),
                Pair::NotANumber(s) => {
                    return Err(fail(self.fault, not_a_number(&s, self.field, Some(i))))
                }
                Pair::Malformed => {
                    let b = BadRequest::new("expected a [time, value] pair")
                        .field(self.field)
                        .index(i);
                    return Err(fail(self.fault, b));
                }
            }
        }
        Ok(out)
    }
    refuse_all_but_arrays!('de);
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        // seeded: the same cases on every run (the long fuzz runs draw new ones)
        #![proptest_config(proptest::test_runner::Config { rng_seed: proptest::test_runner::RngSeed::Fixed(12), ..proptest::test_runner::Config::default() })]

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
    fn errors_name_field_and_index_and_duplicates_are_refused() {
        let e = parse(br#"{"gate":"g","start":1,"rate_hz":4,"values":[1,"x",3]}"#).unwrap_err();
        assert_eq!((e.field.as_deref(), e.index), (Some("values"), Some(1)));
        assert!(e.error.contains("got a string"), "{}", e.error);
        let e = parse(br#"[{"gate":"g","samples":[[1,2]]},{"gate":"g","samples":[[1,2,3]]}]"#)
            .unwrap_err();
        assert_eq!(
            (e.field.as_deref(), e.index),
            (Some("[1].samples"), Some(0))
        );
        let e = parse(br#"{"gate":"g","gate":"h","samples":[[1,2]]}"#).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("gate"));
        assert!(e.error.contains("duplicate"), "{}", e.error);
        let e = parse(br#"{"gate":"g","samples":[[1,2]]"#).unwrap_err();
        assert!(
            e.line.is_some() && e.error.starts_with("invalid JSON"),
            "{e:?}"
        );
        // `values` before `start` and `rate_hz`: the times are set afterwards
        let b = parse(br#"{"values":[5,6],"rate_hz":2,"gate":"g","start":10}"#).unwrap();
        assert_eq!(b[0].samples, vec![(10.0, 5.0), (10.5, 6.0)]);
    }

    /// `values` and `samples` that are not arrays are refused naming the field and what came
    /// instead, for each kind of JSON value (the shared visits of both array visitors), and a
    /// later batch's field carries its index.
    #[test]
    fn a_field_that_is_not_an_array_is_refused_naming_what_it_is() {
        for (value, got) in [
            (r#"{"a":[1,2]}"#, "an object"),
            ("true", "a boolean"),
            ("-3", "a number"),
            ("7", "a number"),
            ("2.5", "a number"),
            (r#""1,2,3""#, "a string"),
            ("null", "null"),
        ] {
            for (field, rest) in [("values", r#""start":1,"rate_hz":4"#), ("samples", "")] {
                let sep = if rest.is_empty() { "" } else { "," };
                let body = format!(
                    r#"[{{"gate":"g","samples":[[1,2]]}},{{"gate":"g"{sep}{rest},"{field}":{value}}}]"#
                );
                let e = parse(body.as_bytes()).expect_err(&body);
                assert_eq!(e.field, Some(format!("[1].{field}")), "{body}");
                assert_eq!(e.error, format!("expected an array, got {got}"), "{body}");
            }
        }
    }

    #[test]
    fn uniform_times() {
        let b = parse(br#"{"gate":"g","start":10,"rate_hz":4,"values":[1,2,3]}"#).unwrap();
        assert_eq!(b[0].samples, vec![(10.0, 1.0), (10.25, 2.0), (10.5, 3.0)]);
        assert_eq!(b[0].rate, Some((4.0, "rate_hz".to_string())));
    }
}
