//! InfluxDB line protocol (`POST /api/v2/write`, `POST /write`, raw TCP).
//!
//! ```text
//! measurement[,tag=value...] field=value[,field=value...] [timestamp]
//! ```
//!
//! Hand-written, and kept on measurement: against the maintained crate `influxdb-line-protocol`
//! (2.0, by InfluxData, nom-based) doing the same work on the daemon's workload (1000-line
//! Telegraf bodies, 4 gates at 200 Hz; `benches/line_protocol.rs`, figures in
//! `docs/benchmarks.md`) this parser with `to_batches` is 1.4-2.1x faster: about 0.6-1.0 us per
//! plain line against 1.2-1.5 us, 1.4-1.5 us per line with extra tags and fields against
//! 2.5-3.2 us. It also names the line and column of every error, which the crate does not.
//! `tests/line_protocol_crate.rs` checks that both read the same (gate, value, time).
//!
//! Escapes: in the measurement `\,` and `\ `; in tag keys, tag values and field keys `\,`, `\=`
//! and `\ `; in string field values `\"` and `\\`. A backslash before any other character is
//! literal. Field values: floats (`1.5`, `-2e3`), integers `12i`, unsigned `12u`, strings
//! `"..."`, booleans `t T true True TRUE f F false False FALSE`. Lines starting with `#` and
//! blank lines are skipped.

use std::fmt;

use super::{excerpt, BadRequest, Batch};
use crate::service::config::{valid_gate_id, Precision, GATE_ID_RULE};

/// The most tags one line may carry. Why a bound: a 4 MiB line of 400 000 tags became
/// 400 000 pairs of strings while parsed, about 100 bytes each (40 MB from a 4 MiB body: the
/// memory bound of `docs/operations.md` assumes less); Telegraf's lines carry a handful.
pub const MAX_TAGS_PER_LINE: usize = 256;
/// The most fields one line may carry (the same reason as [`MAX_TAGS_PER_LINE`]).
pub const MAX_FIELDS_PER_LINE: usize = 256;

/// A field value.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldValue {
    /// Float.
    Float(f64),
    /// `i` suffix.
    Int(i64),
    /// `u` suffix.
    UInt(u64),
    /// Quoted string.
    Str(String),
    /// Boolean.
    Bool(bool),
}

/// One parsed line.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    /// Measurement name.
    pub measurement: String,
    /// Tags in order.
    pub tags: Vec<(String, String)>,
    /// Fields in order (at least one).
    pub fields: Vec<(String, FieldValue)>,
    /// Timestamp in the request's precision.
    pub timestamp: Option<i64>,
}

/// A syntax error at a 1-based line and byte column.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LineError {
    /// 1-based line.
    pub line: usize,
    /// 1-based byte column.
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for LineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "line {} column {}: {}",
            self.line, self.column, self.message
        )
    }
}

impl std::error::Error for LineError {}

impl From<LineError> for BadRequest {
    fn from(e: LineError) -> Self {
        BadRequest {
            error: e.message,
            line: Some(e.line),
            column: Some(e.column),
            field: None,
            index: None,
        }
    }
}

struct Cursor<'a> {
    b: &'a [u8],
    pos: usize,
    line: usize,
}

impl Cursor<'_> {
    fn err(&self, pos: usize, message: impl Into<String>) -> LineError {
        LineError {
            line: self.line,
            column: pos + 1,
            message: message.into(),
        }
    }

    fn peek(&self) -> Option<u8> {
        self.b.get(self.pos).copied()
    }

    /// Reads up to an unescaped byte of `stops` (not consumed); `escapable` are the bytes a
    /// backslash escapes.
    fn read_escaped(&mut self, stops: &[u8], escapable: &[u8]) -> Result<String, LineError> {
        let mut out = Vec::new();
        while let Some(c) = self.peek() {
            if c == b'\\' {
                if let Some(n) = self.b.get(self.pos + 1).copied() {
                    if escapable.contains(&n) {
                        out.push(n);
                        self.pos += 2;
                        continue;
                    }
                }
                out.push(c);
                self.pos += 1;
                continue;
            }
            if stops.contains(&c) {
                break;
            }
            out.push(c);
            self.pos += 1;
        }
        String::from_utf8(out).map_err(|_| self.err(self.pos, "invalid UTF-8"))
    }
}

/// Parses one line (`line_no` is 1-based); `Ok(None)` for blank and comment lines.
pub fn parse_line(text: &str, line_no: usize) -> Result<Option<Line>, LineError> {
    let text = text.strip_suffix('\r').unwrap_or(text);
    let trimmed = text.trim_start();
    if trimmed.is_empty() || trimmed.starts_with('#') {
        return Ok(None);
    }
    let mut c = Cursor {
        b: text.as_bytes(),
        pos: text.len() - trimmed.len(),
        line: line_no,
    };
    let start = c.pos;
    let measurement = c.read_escaped(b", ", b", ")?;
    if measurement.is_empty() {
        return Err(c.err(start, "missing measurement"));
    }
    let mut tags = Vec::new();
    while c.peek() == Some(b',') {
        c.pos += 1;
        let kpos = c.pos;
        let key = c.read_escaped(b",= ", b",= ")?;
        if key.is_empty() {
            return Err(c.err(kpos, "missing tag key"));
        }
        if c.peek() != Some(b'=') {
            return Err(c.err(
                c.pos,
                format!("expected '=' after tag key `{}`", excerpt(&key)),
            ));
        }
        // a tag twice is refused, as InfluxDB does: which one names the gate would be a guess
        if tags.iter().any(|(k, _)| *k == key) {
            return Err(c.err(kpos, format!("tag `{}` given twice", excerpt(&key))));
        }
        if tags.len() == MAX_TAGS_PER_LINE {
            return Err(c.err(kpos, format!("more than {MAX_TAGS_PER_LINE} tags")));
        }
        c.pos += 1;
        let vpos = c.pos;
        let value = c.read_escaped(b", ", b",= ")?;
        if value.is_empty() {
            return Err(c.err(vpos, format!("missing value of tag `{}`", excerpt(&key))));
        }
        tags.push((key, value));
    }
    if c.peek() != Some(b' ') {
        return Err(c.err(c.pos, "expected a space before the fields"));
    }
    while c.peek() == Some(b' ') {
        c.pos += 1;
    }
    let mut fields = Vec::new();
    loop {
        let kpos = c.pos;
        let key = c.read_escaped(b",= ", b",= ")?;
        if key.is_empty() {
            return Err(c.err(kpos, "missing field key"));
        }
        if c.peek() != Some(b'=') {
            return Err(c.err(
                c.pos,
                format!("expected '=' after field key `{}`", excerpt(&key)),
            ));
        }
        // a field twice is refused (InfluxDB keeps the last silently): which value is the
        // sample would be a guess
        if fields.iter().any(|(k, _): &(String, FieldValue)| *k == key) {
            return Err(c.err(kpos, format!("field `{}` given twice", excerpt(&key))));
        }
        if fields.len() == MAX_FIELDS_PER_LINE {
            return Err(c.err(kpos, format!("more than {MAX_FIELDS_PER_LINE} fields")));
        }
        c.pos += 1;
        let vpos = c.pos;
        let value = if c.peek() == Some(b'"') {
            c.pos += 1;
            let mut out = Vec::new();
            loop {
                match c.peek() {
                    None => {
                        return Err(c.err(
                            vpos,
                            format!("unterminated string in field `{}`", excerpt(&key)),
                        ))
                    }
                    Some(b'\\') if matches!(c.b.get(c.pos + 1), Some(b'"') | Some(b'\\')) => {
                        out.push(c.b[c.pos + 1]);
                        c.pos += 2;
                    }
                    Some(b'"') => {
                        c.pos += 1;
                        break;
                    }
                    Some(ch) => {
                        out.push(ch);
                        c.pos += 1;
                    }
                }
            }
            FieldValue::Str(String::from_utf8(out).map_err(|_| c.err(vpos, "invalid UTF-8"))?)
        } else {
            let raw = c.read_escaped(b", ", b"")?;
            parse_scalar(&raw).ok_or_else(|| {
                c.err(
                    vpos,
                    format!(
                        "invalid value `{}` of field `{}`",
                        excerpt(&raw),
                        excerpt(&key)
                    ),
                )
            })?
        };
        fields.push((key, value));
        match c.peek() {
            Some(b',') => c.pos += 1,
            _ => break,
        }
    }
    let mut timestamp = None;
    if c.peek() == Some(b' ') {
        while c.peek() == Some(b' ') {
            c.pos += 1;
        }
        let tpos = c.pos;
        let rest = &text[tpos..];
        let rest_trim = rest.trim_end();
        if !rest_trim.is_empty() {
            timestamp =
                Some(rest_trim.parse::<i64>().map_err(|_| {
                    c.err(tpos, format!("invalid timestamp `{}`", excerpt(rest_trim)))
                })?);
        }
        c.pos = text.len();
    }
    if c.pos != text.len() {
        return Err(c.err(c.pos, "unexpected character after the fields"));
    }
    Ok(Some(Line {
        measurement,
        tags,
        fields,
        timestamp,
    }))
}

fn parse_scalar(raw: &str) -> Option<FieldValue> {
    match raw {
        "t" | "T" | "true" | "True" | "TRUE" => return Some(FieldValue::Bool(true)),
        "f" | "F" | "false" | "False" | "FALSE" => return Some(FieldValue::Bool(false)),
        "" => return None,
        _ => {}
    }
    if let Some(i) = raw.strip_suffix('i') {
        return i.parse().ok().map(FieldValue::Int);
    }
    if let Some(u) = raw.strip_suffix('u') {
        return u.parse().ok().map(FieldValue::UInt);
    }
    // Rust also reads `NaN`, `inf`: kept so that the batch is rejected naming the sample.
    raw.parse::<f64>().ok().map(FieldValue::Float)
}

/// Parses every line; the first error stops.
pub fn parse(text: &str) -> Result<Vec<(usize, Line)>, LineError> {
    let mut out = Vec::new();
    for (i, l) in text.split('\n').enumerate() {
        if let Some(line) = parse_line(l, i + 1)? {
            out.push((i + 1, line));
        }
    }
    Ok(out)
}

/// How lines map to gate samples.
#[derive(Debug, Clone)]
pub struct Mapping<'a> {
    /// Tag naming the gate.
    pub gate_tag: &'a str,
    /// Fields holding the value, first present wins.
    pub value_fields: &'a [String],
    /// Timestamp unit.
    pub precision: Precision,
    /// Time of lines without timestamp (unix seconds, the receive time).
    pub now: f64,
    /// Gates a request may name (`server.max_gates`): [`parse_to_batches`] stops at the first
    /// line of one more, a request the daemon refuses whole (`usize::MAX`: no bound).
    pub max_gates: usize,
}

/// Turns parsed lines into per-gate batches (in order of first appearance).
pub fn to_batches(lines: &[(usize, Line)], m: &Mapping<'_>) -> Result<Vec<Batch>, BadRequest> {
    let mut batches = Batches::default();
    for (line_no, line) in lines {
        push_line(&mut batches, *line_no, line, m)?;
    }
    batches.finish()
}

/// The batches of a request being built, with each gate's batch found by its id.
///
/// Why the index: a request whose every line names another gate (95 000 gates in a 4 MiB
/// body) searched the batches line by line, a quadratic 30 s and more of a core after the
/// client had its 408; a request can carry at most `server.max_gates` gates, but that is
/// checked once the body is parsed.
#[derive(Default)]
struct Batches {
    batches: Vec<Batch>,
    index: std::collections::HashMap<String, usize>,
}

impl Batches {
    /// The batch of `gate`, created (with `field` as its values field) on its first line.
    fn of(&mut self, gate: &str, field: &str, precision: Precision) -> &mut Batch {
        // consecutive lines of one gate, the usual body, need no lookup
        let i = match self.batches.last() {
            Some(b) if b.gate == gate => self.batches.len() - 1,
            _ => match self.index.get(gate) {
                Some(&i) => i,
                None => {
                    self.index.insert(gate.to_string(), self.batches.len());
                    self.batches.push(Batch {
                        gate: gate.to_string(),
                        samples: Vec::new(),
                        rate: None,
                        values_field: field.to_string(),
                        lines: Some(Vec::new()),
                        precision: Some(precision),
                    });
                    self.batches.len() - 1
                }
            },
        };
        &mut self.batches[i]
    }

    fn finish(self) -> Result<Vec<Batch>, BadRequest> {
        if self.batches.is_empty() {
            return Err(BadRequest::new("no lines"));
        }
        Ok(self.batches)
    }
}

/// [`parse`] then [`to_batches`] in one pass, line by line: each line is parsed and turned
/// into its sample at once, so a request's peak memory is its body plus its samples (24 bytes
/// a line: time, value, line number), never a parsed `Line` (a few hundred bytes of strings
/// and vectors) per line of the body. Same answers, same errors as the two steps.
///
/// It stops at the first line of a gate beyond `m.max_gates`, keeping that line: no daemon can
/// hold more gates than that, so the request is refused whole, naming the first gate over
/// ([`crate::service::state`]'s check), and parsing the rest only cost memory. A body whose
/// every line names another gate built a batch, a gate id and an index entry per line (80 MB
/// for a 4 MiB body, twenty times it) before that check.
pub fn parse_to_batches(text: &str, m: &Mapping<'_>) -> Result<Vec<Batch>, BadRequest> {
    let mut batches = Batches::default();
    for (i, l) in text.split('\n').enumerate() {
        if let Some(line) = parse_line(l, i + 1)? {
            push_line(&mut batches, i + 1, &line, m)?;
            if batches.batches.len() > m.max_gates {
                break;
            }
        }
    }
    batches.finish()
}

/// Adds the sample of one parsed line to its gate's batch.
fn push_line(
    batches: &mut Batches,
    line_no: usize,
    line: &Line,
    m: &Mapping<'_>,
) -> Result<(), BadRequest> {
    let gate = line
        .tags
        .iter()
        .find(|(k, _)| k == m.gate_tag)
        .map(|(_, v)| v.as_str())
        .ok_or_else(|| {
            BadRequest::new(format!("missing tag `{}`", m.gate_tag))
                .line(line_no)
                .field(m.gate_tag)
        })?;
    if !valid_gate_id(gate) {
        return Err(BadRequest::new(GATE_ID_RULE)
            .line(line_no)
            .field(m.gate_tag));
    }
    let (name, value) = m
        .value_fields
        .iter()
        .find_map(|f| line.fields.iter().find(|(k, _)| k == f))
        .ok_or_else(|| {
            BadRequest::new(format!(
                "missing field, expected one of {:?}",
                m.value_fields
            ))
            .line(line_no)
            .field(m.value_fields[0].clone())
        })?;
    let v = match value {
        FieldValue::Float(x) => *x,
        FieldValue::Int(i) => *i as f64,
        FieldValue::UInt(u) => *u as f64,
        FieldValue::Str(_) | FieldValue::Bool(_) => {
            return Err(BadRequest::new("expected a numeric field")
                .line(line_no)
                .field(name.clone()))
        }
    };
    let t = match line.timestamp {
        Some(ts) => ts as f64 * m.precision.seconds_per_unit(),
        None => m.now,
    };
    let batch = batches.of(gate, name, m.precision);
    batch.samples.push((t, v));
    if let Some(l) = batch.lines.as_mut() {
        l.push(line_no);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(s: &str) -> Line {
        parse_line(s, 1).unwrap().unwrap()
    }

    #[test]
    fn parses_tags_fields_timestamp() {
        let l =
            one("gate,gate=g1,site=north force=1.5,n=3i,u=4u,ok=t,s=\"a b\" 1700000000000000000");
        assert_eq!(l.measurement, "gate");
        assert_eq!(
            l.tags,
            vec![
                ("gate".into(), "g1".into()),
                ("site".into(), "north".into())
            ]
        );
        assert_eq!(l.fields[0], ("force".into(), FieldValue::Float(1.5)));
        assert_eq!(l.fields[1].1, FieldValue::Int(3));
        assert_eq!(l.fields[2].1, FieldValue::UInt(4));
        assert_eq!(l.fields[3].1, FieldValue::Bool(true));
        assert_eq!(l.fields[4].1, FieldValue::Str("a b".into()));
        assert_eq!(l.timestamp, Some(1_700_000_000_000_000_000));
    }

    #[test]
    fn escapes() {
        let l = one(r#"my\ meas\,x,ta\=g=v\ 1\,2 f\ k=-2e3,s="q\"uote\\" -5"#);
        assert_eq!(l.measurement, "my meas,x");
        assert_eq!(l.tags, vec![("ta=g".into(), "v 1,2".into())]);
        assert_eq!(l.fields[0], ("f k".into(), FieldValue::Float(-2000.0)));
        assert_eq!(l.fields[1].1, FieldValue::Str("q\"uote\\".into()));
        assert_eq!(l.timestamp, Some(-5));
    }

    #[test]
    fn no_timestamp_comments_blank() {
        assert_eq!(one("m force=1").timestamp, None);
        assert_eq!(parse_line("# comment", 1).unwrap(), None);
        assert_eq!(parse_line("   ", 1).unwrap(), None);
        assert_eq!(
            parse("m,gate=a force=1\n\n# c\nm,gate=a force=2 5\n")
                .unwrap()
                .len(),
            2
        );
    }

    #[test]
    fn errors_name_line_and_column() {
        let e = parse("m force=1\nm,gate=a force=abc 1\n").unwrap_err();
        assert_eq!((e.line, e.column), (2, 16));
        assert!(e.message.contains("force"), "{e}");
        let e = parse_line("m,gate force=1", 3).unwrap_err();
        assert_eq!((e.line, e.column), (3, 7));
        let e = parse_line("m", 1).unwrap_err();
        assert!(e.message.contains("space"));
        let e = parse_line("m f=\"open", 1).unwrap_err();
        assert!(e.message.contains("unterminated"));
        let e = parse_line("m f=1 12x", 1).unwrap_err();
        assert!(e.message.contains("timestamp"));
        let e = parse_line("m f=1,", 1).unwrap_err();
        assert!(e.message.contains("field key"));
        let e = parse_line(",gate=a f=1", 1).unwrap_err();
        assert!(e.message.contains("measurement"));
        assert!(parse_line("m f=", 1).is_err());
        assert!(parse_line("m f=1i2", 1).is_err());
    }

    /// A tag or field twice is refused at the second one: the first tag used to win, so
    /// `gate=a,gate=b` went to gate `a` without a word, and `force=1,force=NaN` was accepted.
    #[test]
    fn a_key_twice_is_refused_where_it_repeats() {
        let e = parse_line("m,gate=a,gate=b force=1 5", 4).unwrap_err();
        assert_eq!((e.line, e.column), (4, 10), "{e}");
        assert!(e.message.contains("tag `gate` given twice"), "{e}");
        let e = parse_line("m,gate=a force=1,value=2,force=NaN", 1).unwrap_err();
        assert_eq!(e.column, 26, "{e}");
        assert!(e.message.contains("field `force` given twice"), "{e}");
        // the same name as a tag and as a field is two different keys
        assert!(parse_line("m,force=a force=1", 1).is_ok());
        assert!(parse_line("m,a=1,b=1 a=1,b=2", 1).is_ok());
    }

    /// At most `MAX_TAGS_PER_LINE` tags and `MAX_FIELDS_PER_LINE` fields, named at the first
    /// one over.
    #[test]
    fn tags_and_fields_per_line_are_bounded() {
        let tags = |n: usize| (0..n).map(|i| format!(",t{i}=v")).collect::<String>();
        let fields = |n: usize| {
            (0..n)
                .map(|i| format!("f{i}=1"))
                .collect::<Vec<_>>()
                .join(",")
        };
        let ok = format!(
            "m{} {}",
            tags(MAX_TAGS_PER_LINE),
            fields(MAX_FIELDS_PER_LINE)
        );
        let l = parse_line(&ok, 1).unwrap().unwrap();
        assert_eq!(
            (l.tags.len(), l.fields.len()),
            (MAX_TAGS_PER_LINE, MAX_FIELDS_PER_LINE)
        );
        let e = parse_line(&format!("m{} f=1", tags(MAX_TAGS_PER_LINE + 1)), 2).unwrap_err();
        assert!(e.message.contains("more than 256 tags"), "{e}");
        assert_eq!(e.column, 2 + tags(MAX_TAGS_PER_LINE).len() + 1, "{e}");
        let e = parse_line(&format!("m {}", fields(MAX_FIELDS_PER_LINE + 1)), 1).unwrap_err();
        assert!(e.message.contains("more than 256 fields"), "{e}");
    }

    /// An error quotes at most `EXCERPT_CHARS` characters of the input, whatever its size.
    #[test]
    fn errors_quote_an_excerpt_of_long_input() {
        let long = "9".repeat(65_537);
        for line in [
            format!("m,gate=a force={long}x 1"),
            format!("m,gate=a force=1 {long}x"),
            format!("m,gate=a {long}x"),
            format!("m,gate=a,{long}=1,{long}=2 f=1"),
        ] {
            let e = parse_line(&line, 7).unwrap_err();
            assert!(
                e.message.len() < 200,
                "{} bytes: {}",
                e.message.len(),
                &e.message[..200]
            );
            assert!(e.message.contains("bytes)"), "{e}");
            assert_eq!(e.line, 7);
        }
    }

    /// Past `max_gates` the body is not read on: the first line of one gate more is kept (the
    /// daemon refuses the request naming it), nothing after it, not even a bad line.
    #[test]
    fn parsing_stops_at_the_first_gate_past_the_bound() {
        let fields = vec!["force".to_string()];
        let m = Mapping {
            gate_tag: "gate",
            value_fields: &fields,
            precision: Precision::Ns,
            now: 0.0,
            max_gates: 3,
        };
        let mut body: String = (0..10)
            .map(|i| format!("m,gate=g{i} force=1 {i}\n"))
            .collect();
        body.push_str("not a line\n");
        let b = parse_to_batches(&body, &m).unwrap();
        let gates: Vec<&str> = b.iter().map(|b| b.gate.as_str()).collect();
        assert_eq!(gates, ["g0", "g1", "g2", "g3"]);
        assert_eq!(b[3].lines, Some(vec![4]));
        // within the bound, repeated gates: the whole body, and its bad line
        let within = "m,gate=a force=1 1\nm,gate=b force=1 2\nm,gate=a force=1 3\nbad\n";
        assert_eq!(parse_to_batches(within, &m).unwrap_err().line, Some(4));
    }

    #[test]
    fn mapping_to_batches() {
        let lines =
            parse("m,gate=a force=1 1000\nm,gate=b value=2i 2000\nm,gate=a force=3 3000").unwrap();
        let fields = vec!["force".to_string(), "value".to_string()];
        let m = Mapping {
            gate_tag: "gate",
            value_fields: &fields,
            precision: Precision::Ms,
            now: 0.0,
            max_gates: usize::MAX,
        };
        let b = to_batches(&lines, &m).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[0].samples, vec![(1.0, 1.0), (3.0, 3.0)]);
        assert_eq!(b[0].lines, Some(vec![1, 3]));
        assert_eq!(b[1].samples, vec![(2.0, 2.0)]);
        let lines = parse("m force=1 1").unwrap();
        assert_eq!(
            to_batches(&lines, &m).unwrap_err().field.as_deref(),
            Some("gate")
        );
        let lines = parse("m,gate=a force=\"x\" 1").unwrap();
        assert_eq!(
            to_batches(&lines, &m).unwrap_err().field.as_deref(),
            Some("force")
        );
    }

    proptest::proptest! {
        // seeded: the same cases on every run (the long fuzz runs draw new ones)
        #![proptest_config(proptest::test_runner::Config { rng_seed: proptest::test_runner::RngSeed::Fixed(12), ..proptest::test_runner::Config::default() })]

        #[test]
        fn never_panics(s in "[a-z,= \\\"0-9.ie#-]{0,40}") {
            let _ = parse(&s);
        }

        #[test]
        fn escaped_names_round_trip(tag in "[a-z ,=]{1,12}", value in "[a-z ,=]{1,12}") {
            let esc = |x: &str| x.replace(',', "\\,").replace('=', "\\=").replace(' ', "\\ ");
            let line = format!("m,{}={} f=1 1", esc(&tag), esc(&value));
            let l = parse_line(&line, 1).unwrap().unwrap();
            proptest::prop_assert_eq!(&l.tags[0].0, &tag);
            proptest::prop_assert_eq!(&l.tags[0].1, &value);
        }
    }

    #[test]
    fn never_panics_on_junk() {
        for s in [
            "\\",
            "m\\",
            "m,\\",
            "m,a=\\",
            "m a=\"\\",
            "m a=1 \\",
            "é,é=é é=1",
            "m,a=b a=1    ",
            "m  a=1",
        ] {
            let _ = parse_line(s, 1);
        }
    }
}
