//! Ingestion: the request formats, parsed into [`Batch`]es that are validated WHOLE before any
//! is applied (see `service::state::AppState::ingest`), so a rejected request changed nothing
//! and can be retried.

pub mod json;
pub mod line_protocol;

use serde::Serialize;

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
