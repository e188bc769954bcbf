//! `GET /api/v1/gates/{id}/history?from=&to=&limit=`: a gate's identifications from the store,
//! JSON, or CSV with `format=csv` or `Accept: text/csv` (`docs/api.md`).

use std::sync::Arc;
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{Extension, Path, Query, State};
use axum::http::{header, HeaderMap};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use tokio::sync::{Semaphore, SemaphorePermit};

use super::api::{path_param, HttpError};
use super::ingest::{excerpt, BadRequest};
use super::listen::{TransferDeadline, TransferGuard};
use super::state::AppState;
use crate::store::{
    history_csv_rows, history_json_rows, parse_time, HistoryQuery, HistoryRow, MAX_HISTORY_LIMIT,
};

/// Rows per chunk of a streamed answer: about 0.4 MB of JSON, so a day of one gate is sent
/// in about 35 chunks and the daemon never holds the whole body (`docs/api.md`).
pub const HISTORY_CHUNK_ROWS: usize = 512;

/// History answers at once at most this many, from the query to the last byte sent: each
/// holds a blocking thread and the store's read connection while it reads, then its rows
/// (up to [`MAX_HISTORY_LIMIT`], about 37 MB for a day's 20 000 rows) until the client has
/// taken the body. More wait for none and get 503 (the client retries). Before, the permit
/// ended with the read: sixteen clients that asked for a day and read nothing held 600 MB (a
/// client that takes nothing is cut after `server.request_timeout_seconds`, `listen::SendTimeout`).
pub const MAX_CONCURRENT_HISTORY: usize = 4;

static PERMITS: Semaphore = Semaphore::const_new(MAX_CONCURRENT_HISTORY);

/// The whole transfer of a history answer, from its head to its last byte, may last at most
/// this many `server.request_timeout_seconds` (300 s at the default 30 s); then the connection
/// is closed (`listen::TransferDeadline`), which frees the answer's place of
/// [`MAX_CONCURRENT_HISTORY`] and its rows. Why a bound on the whole: the send timeout
/// (`listen::SendTimeout`) restarts at every write that goes through, so four clients reading
/// slowly but steadily held the four places for as long as their transfers lasted (an hour at
/// 10 KB/s for a day) and the route answered 503 to everyone else meanwhile. Why 10 timeouts:
/// the largest answer (a day, about 37 MB) then needs about 125 KB/s (1 Mbit/s) at the
/// default, far below what a client on a LAN or a notebook's `pandas.read_csv` takes, and a
/// slower client can page with `from`/`to`/`limit`. Derived from the request timeout rather
/// than a key of its own: an operator who lengthens that timeout for slow clients wants this
/// bound to follow.
pub const HISTORY_TRANSFER_TIMEOUTS: u32 = 10;

/// The transfer limit of a history answer for a request timeout of `request_timeout_seconds`
/// ([`HISTORY_TRANSFER_TIMEOUTS`] of it).
pub fn history_transfer_limit(request_timeout_seconds: f64) -> Duration {
    Duration::from_secs_f64(request_timeout_seconds) * HISTORY_TRANSFER_TIMEOUTS
}

/// The query string.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistoryParams {
    /// RFC 3339 or Unix seconds (inclusive, on the window end).
    pub from: Option<String>,
    /// RFC 3339 or Unix seconds (inclusive, on the window end).
    pub to: Option<String>,
    /// At most this many rows, 1..=[`MAX_HISTORY_LIMIT`] (default: the maximum).
    pub limit: Option<usize>,
    /// `csv` or `json`; overrides the `Accept` header. A URL alone then names the format, as
    /// `pandas.read_csv(url)` and a browser's address bar need (`docs/notebooks.md`).
    pub format: Option<String>,
}

/// Longest parameter name echoed in an error's `field` (an unknown one is the client's text).
const MAX_FIELD_ECHO: usize = 64;

/// The values of the query parameters `names`, in their order, from the query string's
/// `(name, value)` pairs; or a 400 naming the parameter: a name not in `names` (`takes` says
/// which the route takes), or one given twice, since which one wins is a guess (InfluxDB takes
/// the first, most frameworks the last). Every `/api/v1` route with query parameters reads them
/// here: `?limt=2` used to list every gate with a 200.
pub fn query_params<const N: usize>(
    pairs: Vec<(String, String)>,
    names: [&str; N],
    takes: &str,
) -> Result<[Option<String>; N], HttpError> {
    let mut values: [Option<String>; N] = std::array::from_fn(|_| None);
    for (name, value) in pairs {
        let Some(k) = names.iter().position(|n| *n == name) else {
            let shown: String = name.chars().take(MAX_FIELD_ECHO).collect();
            return Err(bad(format!("unknown parameter `{shown}`: {takes}"), &shown));
        };
        if values[k].is_some() {
            return Err(bad(format!("{name} given more than once"), &name));
        }
        values[k] = Some(value);
    }
    Ok(values)
}

/// The `(name, value)` pairs of a query string as axum's extractor gives them, or a 400 in the
/// JSON shape of every other (pairs of strings: only a query string that is not URL-encoding
/// at all is refused here).
pub fn query_pairs(
    pairs: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Vec<(String, String)>, HttpError> {
    pairs.map(|Query(p)| p).map_err(|e| {
        HttpError::BadRequest(BadRequest::new(format!(
            "bad query string: {}",
            e.body_text()
        )))
    })
}

impl HistoryParams {
    /// The parameters from the query string's `(name, value)` pairs, or a 400 naming the
    /// parameter: an unknown name, a name given twice, a `limit` that is not a non-negative
    /// integer. Why not axum's `Query<HistoryParams>`: its rejection is a text/plain "Failed to
    /// deserialize query string" where docs/api.md promises the JSON `{"error", "field"}` of
    /// every other 400.
    pub fn from_pairs(pairs: Vec<(String, String)>) -> Result<HistoryParams, HttpError> {
        let [from, to, limit, format] = query_params(
            pairs,
            ["from", "to", "limit", "format"],
            "the history takes from, to, limit and format",
        )?;
        let mut p = HistoryParams {
            from,
            to,
            limit: None,
            format,
        };
        if let Some(v) = limit {
            p.limit = Some(v.trim().parse::<usize>().map_err(|_| {
                let shown: String = v.chars().take(MAX_FIELD_ECHO).collect();
                bad(
                    format!("limit must be an integer in 1..={MAX_HISTORY_LIMIT}, got `{shown}`"),
                    "limit",
                )
            })?);
        }
        Ok(p)
    }
}

/// Whether the answer is CSV: `format` when given (`csv` or `json`, else a 400 naming it),
/// otherwise `Accept` containing `text/csv`.
pub fn wants_csv(format: Option<&str>, accept: Option<&str>) -> Result<bool, HttpError> {
    match format {
        Some("csv") => Ok(true),
        Some("json") => Ok(false),
        Some(other) => Err(bad(
            format!("format must be `csv` or `json`, got `{other}`"),
            "format",
        )),
        None => Ok(accept.is_some_and(|v| v.contains("text/csv"))),
    }
}

/// The query a request asks for, or a 400 naming the parameter.
pub fn query(gate: &str, p: &HistoryParams) -> Result<HistoryQuery, HttpError> {
    let time = |name: &str, v: &Option<String>| -> Result<Option<f64>, HttpError> {
        v.as_deref()
            .map(|s| parse_time(s).map_err(|e| bad(format!("{name}: {e}"), name)))
            .transpose()
    };
    let from = time("from", &p.from)?;
    let to = time("to", &p.to)?;
    if let (Some(f), Some(t)) = (from, to) {
        if f > t {
            let (f, t) = (crate::number::Num(f), crate::number::Num(t));
            return Err(bad(format!("from ({f}) is after to ({t})"), "from"));
        }
    }
    let limit = p.limit.unwrap_or(MAX_HISTORY_LIMIT);
    if limit == 0 || limit > MAX_HISTORY_LIMIT {
        return Err(bad(
            format!("limit must be in 1..={MAX_HISTORY_LIMIT}, got {limit}"),
            "limit",
        ));
    }
    Ok(HistoryQuery {
        gate: gate.to_string(),
        from,
        to,
        limit,
    })
}

fn bad(message: String, field: &str) -> HttpError {
    HttpError::BadRequest(BadRequest::new(message).field(field.to_string()))
}

/// Whether the store has any row of `gate` (one indexed lookup).
async fn has_history(p: &Arc<super::storage::Persistence>, gate: &str) -> Result<bool, HttpError> {
    let p = p.clone();
    let q = HistoryQuery {
        gate: gate.to_string(),
        from: None,
        to: None,
        limit: 1,
    };
    let rows = tokio::task::spawn_blocking(move || p.store.history_rows(&q))
        .await
        .map_err(|e| HttpError::Internal(format!("history task failed: {e}")))?
        .map_err(|e| HttpError::Internal(e.to_string()))?;
    Ok(!rows.is_empty())
}

/// The handler.
pub async fn get_history(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
    pairs: Result<Query<Vec<(String, String)>>, QueryRejection>,
    deadline: Option<Extension<TransferDeadline>>,
    headers: HeaderMap,
) -> Result<Response, HttpError> {
    let id = path_param(id)?;
    let params = HistoryParams::from_pairs(query_pairs(pairs)?)?;
    let Some(p) = state.persistence.clone() else {
        return Err(HttpError::NotFound(
            "no history: this daemon runs without a store".into(),
        ));
    };
    // A gate is known when it is configured, live, or has stored rows (an expired gate of
    // `accept_unknown_gates` keeps its history); an empty answer is reserved for known gates
    // with nothing in the range, so a typo in the id is a 404, not an empty day.
    let known = state.config.gates.contains_key(&id) || state.gate_ids().contains(&id);
    if !known && state.config.gate(&id).is_none() {
        return Err(HttpError::NotFound(format!(
            "unknown gate `{}`",
            excerpt(&id)
        )));
    }
    let q = query(&id, &params)?;
    let csv = wants_csv(
        params.format.as_deref(),
        headers.get(header::ACCEPT).and_then(|v| v.to_str().ok()),
    )?;
    let Ok(permit) = PERMITS.try_acquire() else {
        return Err(HttpError::Overloaded);
    };
    let reader = p.clone();
    let rows = tokio::task::spawn_blocking(move || reader.store.history_rows(&q))
        .await
        .map_err(|e| HttpError::Internal(format!("history task failed: {e}")))?
        .map_err(|e| HttpError::Internal(e.to_string()))?;
    // (the lookup holds the same permit)
    if rows.is_empty() && !known && !has_history(&p, &id).await? {
        return Err(HttpError::NotFound(format!(
            "unknown gate `{}`: not configured, not live, and nothing stored",
            excerpt(&id)
        )));
    }
    // the permit goes with the body: the rows stay in memory until the client has them, or
    // until the transfer limit cuts the connection (no deadline without the listener: a request
    // sent to the router alone, as in the tests, has no connection to cut)
    let limit = params.limit.unwrap_or(MAX_HISTORY_LIMIT);
    let transfer_limit = history_transfer_limit(state.config.server.request_timeout_seconds);
    let held = Held {
        _permit: permit,
        _transfer: deadline.map(|Extension(d)| d.arm(transfer_limit)),
    };
    if csv {
        return Ok((
            [(header::CONTENT_TYPE, "text/csv; charset=utf-8")],
            stream(rows, csv_chunk, Vec::new(), held),
        )
            .into_response());
    }
    // the keys in the order serde_json's map gives them, as before the body was streamed
    let head = format!(
        "{{\"count\":{},\"gate\":{},\"identifications\":[",
        rows.len(),
        serde_json::to_string(&id).map_err(|e| HttpError::Internal(e.to_string()))?
    );
    let tail = format!("],\"limit\":{limit}}}");
    Ok((
        [(header::CONTENT_TYPE, "application/json")],
        stream(rows, json_chunk, head.into_bytes(), held).with_tail(tail),
    )
        .into_response())
}

fn json_chunk(rows: &[HistoryRow], first: bool, out: &mut Vec<u8>) -> Result<(), String> {
    history_json_rows(rows, first, out);
    Ok(())
}

fn csv_chunk(rows: &[HistoryRow], first: bool, out: &mut Vec<u8>) -> Result<(), String> {
    history_csv_rows(rows, first, out)
}

/// Writes a chunk of rows (`true`: the first chunk) into the buffer.
type Render = fn(&[HistoryRow], bool, &mut Vec<u8>) -> Result<(), String>;

/// What a history answer holds until its body is sent or dropped: its place of
/// [`MAX_CONCURRENT_HISTORY`], and its connection's transfer deadline (cleared when dropped).
struct Held {
    _permit: SemaphorePermit<'static>,
    _transfer: Option<TransferGuard>,
}

/// A body streamed in chunks of [`HISTORY_CHUNK_ROWS`] rows, each written when the client
/// takes it (the rows are read and the read connection released before: a slow client holds
/// no lock), after `head` and before the tail. It holds its permit of
/// [`MAX_CONCURRENT_HISTORY`] until the body is sent or dropped (the client went away, took
/// nothing for `server.request_timeout_seconds`, or was still reading at the transfer limit,
/// [`HISTORY_TRANSFER_TIMEOUTS`]): the rows it holds count against the bound.
struct Streamed {
    rows: Arc<Vec<HistoryRow>>,
    render: Render,
    head: Vec<u8>,
    tail: Vec<u8>,
    held: Held,
}

fn stream(rows: Vec<HistoryRow>, render: Render, head: Vec<u8>, held: Held) -> Streamed {
    Streamed {
        rows: Arc::new(rows),
        render,
        head,
        tail: Vec::new(),
        held,
    }
}

impl Streamed {
    fn with_tail(mut self, tail: String) -> Streamed {
        self.tail = tail.into_bytes();
        self
    }
}

impl IntoResponse for Streamed {
    fn into_response(self) -> Response {
        let Streamed {
            rows,
            render,
            head,
            tail,
            held,
        } = self;
        let n = rows.len().div_ceil(HISTORY_CHUNK_ROWS);
        let chunks = (0..n.max(1)).map(move |i| {
            // moved in: released when the stream is dropped, after its last chunk or with the
            // connection
            let _held = &held;
            let mut out = if i == 0 { head.clone() } else { Vec::new() };
            let from = (i * HISTORY_CHUNK_ROWS).min(rows.len());
            let to = (from + HISTORY_CHUNK_ROWS).min(rows.len());
            if let Err(e) = render(&rows[from..to], i == 0, &mut out) {
                // the status is sent already: the client sees a cut body, the log says why
                tracing::error!("history: {e}");
                return Err(std::io::Error::other(e));
            }
            if i + 1 >= n.max(1) {
                out.extend_from_slice(&tail);
            }
            Ok(Bytes::from(out))
        });
        Body::from_stream(futures_util::stream::iter(chunks)).into_response()
    }
}
