//! Ingestion: the request formats, parsed into [`Batch`]es that are validated WHOLE before any
//! is applied (see `service::state::AppState::ingest`), so a rejected request changed nothing
//! and can be retried.

pub mod json;
pub mod line_protocol;

use std::borrow::Cow;

use serde::Serialize;

use super::config::Precision;

/// The longest piece of a client's input an error quotes (`excerpt`), in characters.
pub const EXCERPT_CHARS: usize = 64;
/// The longest `error` message of a 400, in characters ([`BadRequest::clipped`]).
pub const MAX_ERROR_CHARS: usize = 1024;

/// `s` as an error quotes it: whole up to [`EXCERPT_CHARS`] characters, else its start and a
/// note of its length. Why: a 3 MB key or a 65 536-digit value was echoed whole (a 6 MB answer;
/// on the Influx routes an inner body over 64 KiB lost its line and column altogether).
pub fn excerpt(s: &str) -> Cow<'_, str> {
    match s.char_indices().nth(EXCERPT_CHARS) {
        None => Cow::Borrowed(s),
        Some((cut, _)) => Cow::Owned(format!("{}... ({} bytes)", &s[..cut], s.len())),
    }
}

/// `s` cut to `max` characters in the middle, keeping its start and its end (where a parser's
/// message says what it expected), with a note of what was left out.
fn clip_middle(s: &str, max: usize) -> Cow<'_, str> {
    let n = s.chars().count();
    if n <= max {
        return Cow::Borrowed(s);
    }
    let head: String = s.chars().take(max * 2 / 3).collect();
    let tail: String = s.chars().skip(n - max / 3).collect();
    Cow::Owned(format!(
        "{head} ...({} characters left out)... {tail}",
        n - head.chars().count() - tail.chars().count()
    ))
}

/// Samples of one gate from one request, oldest first.
#[derive(Debug, Clone, PartialEq)]
pub struct Batch {
    /// Gate id.
    pub gate: String,
    /// `(unix seconds, value)`.
    pub samples: Vec<(f64, f64)>,
    /// The sample rate the client declared or that its timestamps imply, checked against the
    /// gate's `rate_hz` (1 % tolerance); with the name of the field to blame.
    pub rate: Option<(f64, String)>,
    /// Field holding the values (for errors naming a non-finite value).
    pub values_field: String,
    /// For line protocol: the 1-based line of each sample (errors name the line).
    pub lines: Option<Vec<usize>>,
    /// For line protocol: the unit its timestamps were read in (`None` for JSON, whose times
    /// are seconds). A time out of the gate's bounds that would be plausible in another unit
    /// gets a hint naming that unit (`ingest_checks`).
    pub precision: Option<Precision>,
}

/// A precise 400 answer: `{"error": "...", "line": N, "field": "...", "index": N}`.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct BadRequest {
    /// What is wrong.
    pub error: String,
    /// 1-based line (JSON syntax errors, line protocol).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub line: Option<usize>,
    /// 1-based column (JSON syntax errors, line protocol).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub column: Option<usize>,
    /// The field at fault (`values`, `[2].rate_hz`, `force`, ...).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
    /// 0-based index of the element at fault in the field's array.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub index: Option<usize>,
}

impl BadRequest {
    /// A message only.
    pub fn new(error: impl Into<String>) -> Self {
        BadRequest {
            error: error.into(),
            ..Default::default()
        }
    }

    /// Names the field.
    pub fn field(mut self, field: impl Into<String>) -> Self {
        self.field = Some(field.into());
        self
    }

    /// Names the index.
    pub fn index(mut self, index: usize) -> Self {
        self.index = Some(index);
        self
    }

    /// Names the line.
    pub fn line(mut self, line: usize) -> Self {
        self.line = Some(line);
        self
    }

    /// The answer as sent: the message at most [`MAX_ERROR_CHARS`] characters and the field an
    /// [`excerpt`], whatever input a parser's message quoted (serde names an unknown member
    /// whole).
    pub fn clipped(mut self) -> Self {
        if let Cow::Owned(e) = clip_middle(&self.error, MAX_ERROR_CHARS) {
            self.error = e;
        }
        if let Some(Cow::Owned(f)) = self.field.as_deref().map(excerpt) {
            self.field = Some(f);
        }
        self
    }
}

/// Median spacing of increasing timestamps implies a rate (`None` with fewer than 3 samples).
pub fn implied_rate(samples: &[(f64, f64)]) -> Option<f64> {
    if samples.len() < 3 {
        return None;
    }
    let mut dts: Vec<f64> = samples
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .filter(|d| *d > 0.0)
        .collect();
    if dts.len() < 2 {
        return None;
    }
    dts.sort_by(f64::total_cmp);
    let median = dts[dts.len() / 2];
    Some(1.0 / median)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_excerpt_keeps_short_input_and_cuts_long_input_on_a_character() {
        assert_eq!(excerpt("force"), "force");
        let exact = "é".repeat(EXCERPT_CHARS);
        assert_eq!(excerpt(&exact), exact);
        let long = "é".repeat(EXCERPT_CHARS + 1);
        let e = excerpt(&long);
        assert!(e.starts_with(&exact), "{e}");
        assert!(e.ends_with(&format!("... ({} bytes)", long.len())), "{e}");
    }

    #[test]
    fn a_clipped_answer_keeps_start_and_end_of_its_message() {
        let short = BadRequest::new("unknown field `x`").field("x");
        assert_eq!(short.clone().clipped(), short);
        let message = format!(
            "unknown field `{}`, expected one of `gate`",
            "y".repeat(5000)
        );
        let b = BadRequest::new(message).field("z".repeat(5000)).clipped();
        assert!(
            b.error.chars().count() < MAX_ERROR_CHARS + 60,
            "{}",
            b.error.len()
        );
        assert!(b.error.starts_with("unknown field `yyy"), "{}", b.error);
        assert!(b.error.ends_with("expected one of `gate`"), "{}", b.error);
        assert!(b.error.contains("characters left out"), "{}", b.error);
        assert!(b.field.as_deref().is_some_and(|f| f.len() < 100));
    }
}
