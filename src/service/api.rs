//! HTTP routes, bearer-token authentication, request metrics and the one error type.

/// The InfluxDB surface of the API (ping, health, query, gzip, v2 errors): a child of this
/// module because it answers with this module's [`HttpError`].
mod influx;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Bytes;
use axum::error_handling::HandleErrorLayer;
use axum::extract::path::ErrorKind;
use axum::extract::rejection::{BytesRejection, PathRejection, QueryRejection};
use axum::extract::{
    DefaultBodyLimit, Extension, MatchedPath, Path, Query, RawQuery, Request, State,
};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::StreamExt;
use subtle::{Choice, ConstantTimeEq};
use tokio::sync::OwnedSemaphorePermit;
use tower::ServiceBuilder;

use super::clock::now_unix;
use super::config::{Precision, DEFAULT_RETRY_AFTER_SECONDS};
use super::history::{query_pairs, query_params};
use super::ingest::{excerpt, implied_rate, json, line_protocol, BadRequest};
use super::ingest_checks::single_param;
use super::limits::{close_connection, for_log, BodyBudget, BodyMeter, BudgetExceeded};
use super::metrics::RejectReason;
use super::state::{AppState, ForgetError, IngestError, IngestSummary};

/// The one error type of the HTTP API: 4xx precise, 5xx generic (detail logged).
#[derive(Debug)]
pub enum HttpError {
    /// 400 with details.
    BadRequest(BadRequest),
    /// 401: missing or wrong bearer token.
    Unauthorized,
    /// 404 naming what is missing.
    NotFound(String),
    /// 409 naming what the request conflicts with and what to do instead.
    Conflict(String),
    /// 413.
    PayloadTooLarge(usize),
    /// 415: a request body in a `Content-Encoding` other than gzip or identity (named).
    UnsupportedEncoding(String),
    /// 503 + Retry-After: overloaded.
    Overloaded,
    /// 500: detail logged, not shown.
    Internal(String),
}

impl From<IngestError> for HttpError {
    fn from(e: IngestError) -> Self {
        match e {
            IngestError::BadRequest(b) => HttpError::BadRequest(b),
            IngestError::UnknownGate(g) => HttpError::NotFound(format!("unknown gate `{g}`")),
            IngestError::TooManyGates(r) => {
                let e = BadRequest::new(format!(
                    "gate limit (server.max_gates) reached: gate `{}` refused",
                    r.gate
                ));
                // where the refused gate is: its first line, or its element of a JSON array
                HttpError::BadRequest(match r.line {
                    Some(line) => e.line(line).field("gate"),
                    None if r.batches > 1 => e.field(format!("[{}].gate", r.batch)),
                    None => e.field("gate"),
                })
            }
        }
    }
}

impl IntoResponse for HttpError {
    fn into_response(self) -> Response {
        let (status, body) = match self {
            HttpError::BadRequest(b) => (StatusCode::BAD_REQUEST, b.clipped()),
            HttpError::Unauthorized => {
                let mut r = (
                    StatusCode::UNAUTHORIZED,
                    Json(BadRequest::new("missing or invalid bearer token")),
                )
                    .into_response();
                r.headers_mut()
                    .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
                return r;
            }
            HttpError::NotFound(m) => (StatusCode::NOT_FOUND, BadRequest::new(m).clipped()),
            HttpError::Conflict(m) => (StatusCode::CONFLICT, BadRequest::new(m).clipped()),
            HttpError::PayloadTooLarge(limit) => {
                // the body is left unread: the connection ends (`limits::close_connection`)
                return close_connection(
                    (
                        StatusCode::PAYLOAD_TOO_LARGE,
                        Json(BadRequest::new(format!(
                            "request body larger than {limit} bytes"
                        ))),
                    )
                        .into_response(),
                );
            }
            HttpError::UnsupportedEncoding(enc) => {
                let mut r = (
                    StatusCode::UNSUPPORTED_MEDIA_TYPE,
                    Json(BadRequest::new(format!(
                        "unsupported Content-Encoding `{enc}`: gatewatch accepts gzip or identity"
                    ))),
                )
                    .into_response();
                // RFC 7694: the codings the server accepts in requests
                r.headers_mut()
                    .insert(header::ACCEPT_ENCODING, HeaderValue::from_static("gzip"));
                return r;
            }
            HttpError::Overloaded => {
                let mut r = (
                    StatusCode::SERVICE_UNAVAILABLE,
                    Json(BadRequest::new("overloaded, retry later")),
                )
                    .into_response();
                r.headers_mut().insert(
                    header::RETRY_AFTER,
                    HeaderValue::from(DEFAULT_RETRY_AFTER_SECONDS),
                );
                // refused before the body is read: the connection ends
                return close_connection(r);
            }
            HttpError::Internal(detail) => {
                tracing::error!(%detail, "internal error");
                (
                    StatusCode::INTERNAL_SERVER_ERROR,
                    BadRequest::new("internal error"),
                )
            }
        };
        (status, Json(body)).into_response()
    }
}

fn body(state: &AppState, b: Result<Bytes, BytesRejection>) -> Result<Bytes, HttpError> {
    b.map_err(|r| {
        if budget_exceeded(&r) {
            state.metrics.reject(RejectReason::Overloaded, 1);
            HttpError::Overloaded
        } else if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            state.metrics.reject(RejectReason::BodyTooLarge, 1);
            HttpError::PayloadTooLarge(state.config.server.body_limit_bytes)
        } else {
            // a body that cannot be read (a broken gzip stream) is as invalid as one that
            // cannot be parsed, and counted the same
            invalid(state, BadRequest::new(format!("cannot read body: {r}")))
        }
    })
}

/// A request body that cannot be parsed: counted once (no sample could be read), answered 400.
fn invalid(state: &AppState, e: BadRequest) -> HttpError {
    state.metrics.reject(RejectReason::Invalid, 1);
    HttpError::BadRequest(e)
}

/// Runs parsing and ingestion (CPU work proportional to the body, up to the body limit) on the
/// blocking pool, off the async runtime's threads; their number is bounded by
/// `server.max_concurrent_ingest`.
async fn blocking(
    f: impl FnOnce() -> Result<Response, HttpError> + Send + 'static,
) -> Result<Response, HttpError> {
    tokio::task::spawn_blocking(f)
        .await
        .unwrap_or_else(|e| Err(HttpError::Internal(format!("ingestion task failed: {e}"))))
}

/// What [`admit_ingest`] needs: the state and the body budget.
#[derive(Debug, Clone)]
struct Admission {
    /// The shared state (configuration, metrics, `ingest_permits`).
    state: Arc<AppState>,
    /// The body bytes in flight.
    budget: BodyBudget,
}

/// The declared body length, if any and well-formed.
fn content_length(req: &Request) -> Option<usize> {
    req.headers()
        .get(header::CONTENT_LENGTH)?
        .to_str()
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// Admits an ingestion request or refuses it before its body is read: 413 when its
/// `Content-Length` is over `body_limit_bytes`; 503 + Retry-After when its body does not fit
/// the budget or `max_concurrent_ingest` requests are in progress. A body of known size
/// reserves it here; a gzip or chunked body, whose decompressed size is known only once read,
/// is metered as it arrives ([`BodyMeter`], through [`meter_body`]) and answered 503 when the
/// budget runs out part-way.
async fn admit_ingest(State(adm): State<Admission>, mut req: Request, next: Next) -> Response {
    let state = &adm.state;
    let limit = state.config.server.body_limit_bytes;
    let declared = content_length(&req);
    if declared.is_some_and(|n| n > limit) {
        state.metrics.reject(RejectReason::BodyTooLarge, 1);
        return close_connection(HttpError::PayloadTooLarge(limit).into_response());
    }
    // every header line: a second one is part of the list (RFC 9110, section 5.3)
    let encoded = req
        .headers()
        .get_all(header::CONTENT_ENCODING)
        .iter()
        .any(|v| !v.as_bytes().eq_ignore_ascii_case(b"identity"));
    let reservation = match declared {
        Some(n) if !encoded => adm
            .budget
            .try_reserve(n)
            .map(|p| Reservation::Fixed { _permit: p }),
        _ => BodyMeter::start(&adm.budget).map(Reservation::Metered),
    };
    let (Some(bytes), Ok(slot)) = (
        reservation,
        state.ingest_permits.clone().try_acquire_owned(),
    ) else {
        state.metrics.reject(RejectReason::Overloaded, 1);
        return close_connection(HttpError::Overloaded.into_response());
    };
    if let Reservation::Metered(m) = &bytes {
        req.extensions_mut().insert(m.clone());
    }
    // the handler's blocking work takes a share (`Admitted`): a client that disconnects while
    // its body is parsed drops this future, and the work must not leave the bounds with it
    let admitted = Admitted {
        _held: Arc::new((bytes, slot)),
    };
    req.extensions_mut().insert(admitted.clone());
    let resp = next.run(req).await;
    drop(admitted);
    resp
}

/// What an admitted request holds of the ingestion bounds (its body's bytes in
/// `max_body_bytes_in_flight`, its place in `max_concurrent_ingest`), until the last of its
/// middleware and its blocking work lets go: the parsing and applying on the blocking pool
/// cannot be cancelled, so a handler dropped mid-way (its client gone) must not free them.
#[derive(Clone)]
struct Admitted {
    _held: Arc<(Reservation, OwnedSemaphorePermit)>,
}

/// What an admitted request holds of the body budget until it is answered.
enum Reservation {
    /// Its `Content-Length`, reserved before the body is read (held, never read).
    Fixed { _permit: OwnedSemaphorePermit },
    /// Its decompressed bytes, reserved as they arrive.
    Metered(BodyMeter),
}

/// Innermost on the ingestion routes (after decompression): a body that [`admit_ingest`]
/// meters is charged chunk by chunk as the handler reads it; the chunk that does not fit
/// ends the body with [`BudgetExceeded`], which [`body`] answers 503.
async fn meter_body(req: Request, next: Next) -> Response {
    let Some(meter) = req.extensions().get::<BodyMeter>().cloned() else {
        return next.run(req).await;
    };
    let req = req.map(|b| {
        let chunks = b.into_data_stream().map(move |chunk| {
            let chunk = chunk.map_err(tower::BoxError::from)?;
            meter.charge(chunk.len())?;
            Ok::<_, tower::BoxError>(chunk)
        });
        axum::body::Body::from_stream(chunks)
    });
    next.run(req).await
}

/// Whether `e` or an error it wraps is the body budget running out part-way.
fn budget_exceeded(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cur = Some(e);
    while let Some(c) = cur {
        if c.is::<BudgetExceeded>() {
            return true;
        }
        cur = c.source();
    }
    false
}

async fn post_samples(
    State(state): State<Arc<AppState>>,
    admitted: Option<Extension<Admitted>>,
    b: Result<Bytes, BytesRejection>,
) -> Result<Response, HttpError> {
    let bytes = body(&state, b)?;
    blocking(move || {
        let _admitted = admitted;
        let batches = json::parse(&bytes).map_err(|e| invalid(&state, e))?;
        let summary = state.ingest(batches)?;
        Ok(accepted(summary, false))
    })
    .await
}

/// The answer to an applied request. 204 only when every sample went into its window; samples
/// dropped as duplicates or out of order are said so: gatewatch's own route answers 200 with
/// the counts, the Influx routes (`influx = true`) keep 204, which Telegraf's InfluxDB outputs
/// require (any other 2xx is an error to them, and they would resend the batch), and carry the
/// counts in `X-Gatewatch-Dropped`.
fn accepted(summary: IngestSummary, influx: bool) -> Response {
    let dropped = summary.duplicate + summary.out_of_order;
    if dropped == 0 {
        return StatusCode::NO_CONTENT.into_response();
    }
    if influx {
        let counts = format!(
            "duplicate={}, out_of_order={}",
            summary.duplicate, summary.out_of_order
        );
        let mut r = StatusCode::NO_CONTENT.into_response();
        if let Ok(v) = HeaderValue::from_str(&counts) {
            r.headers_mut().insert(DROPPED_HEADER, v);
        }
        return r;
    }
    (
        StatusCode::OK,
        Json(serde_json::json!({
            "accepted": summary.accepted,
            "dropped": { "duplicate": summary.duplicate, "out_of_order": summary.out_of_order },
        })),
    )
        .into_response()
}

/// The header of a 204 from an Influx route that dropped samples: `duplicate=N, out_of_order=M`.
pub const DROPPED_HEADER: header::HeaderName =
    header::HeaderName::from_static("x-gatewatch-dropped");

async fn post_write(
    State(state): State<Arc<AppState>>,
    RawQuery(query): RawQuery,
    admitted: Option<Extension<Admitted>>,
    b: Result<Bytes, BytesRejection>,
) -> Result<Response, HttpError> {
    // other InfluxDB parameters (db, org, bucket, rp) are accepted and ignored; `m` and `h`
    // are InfluxDB 1.x precisions (2.x has only ns, us, ms, s); `precision` twice is a 400
    // a refused parameter refuses the whole request: counted as `invalid` like a bad body
    let precision = single_param(query.as_deref(), "precision").map_err(|e| invalid(&state, e))?;
    let precision = match precision.as_deref() {
        None => Precision::Ns,
        Some(s) => Precision::parse(s).ok_or_else(|| {
            invalid(
                &state,
                BadRequest::new(format!(
                    "invalid precision `{}`, expected ns, us, ms, s (or n, u, m, h)",
                    excerpt(s)
                ))
                .field("precision"),
            )
        })?,
    };
    let bytes = body(&state, b)?;
    blocking(move || {
        let _admitted = admitted;
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            // where, as every other line-protocol error says it: the line and column of
            // the first byte that is not UTF-8
            let good = &bytes[..e.valid_up_to()];
            let line = good.iter().filter(|&&b| b == b'\n').count() + 1;
            let start = good.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            let column = std::str::from_utf8(&good[start..]).map_or(1, |s| s.chars().count() + 1);
            let mut b = BadRequest::new(format!("body is not UTF-8: {e}")).line(line);
            b.column = Some(column);
            invalid(&state, b)
        })?;
        let cfg = &state.config.ingest;
        let now = now_unix();
        // one pass, line by line: no parsed `Line` per line of the body is held
        let batches = line_protocol::parse_to_batches(
            text,
            &line_protocol::Mapping {
                gate_tag: &cfg.gate_tag,
                value_fields: &cfg.value_fields,
                precision,
                now,
                max_gates: state.config.server.max_gates,
            },
        )
        .map_err(|e| invalid(&state, e))?;
        // the rate its timestamps imply (3 or more lines of a gate), checked for the whole
        // request as JSON `samples` pairs are: a 250 Hz source on a 200 Hz gate was answered
        // 204 and its samples never identified (docs/api.md, "Defined handling of bad data")
        let batches = batches
            .into_iter()
            .map(|mut b| {
                b.rate = implied_rate(&b.samples).map(|r| (r, b.values_field.clone()));
                b
            })
            .collect();
        let summary = state.ingest(batches)?;
        Ok(accepted(summary, true))
    })
    .await
}

/// Gates per page of `GET /api/v1/gates` when `limit` is not given.
pub const GATES_PAGE_DEFAULT: usize = 100;
/// Largest `limit` of `GET /api/v1/gates` (`MAX_GATES_LIMIT` gates take ten pages).
pub const GATES_PAGE_MAX: usize = 1000;

/// `GET /api/v1/gates?limit=N&after=ID`: one page of gate summaries in id order, and `next`,
/// the `after` of the next page (null on the last). Serialised after the state's lock is
/// released ([`AppState::gate_page`]).
async fn list_gates(
    State(state): State<Arc<AppState>>,
    pairs: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, HttpError> {
    let [limit, after, cursor] = query_params(
        query_pairs(pairs)?,
        ["limit", "after", "cursor"],
        "the gate list takes limit and after (or cursor)",
    )?;
    let limit = match limit {
        None => GATES_PAGE_DEFAULT,
        Some(s) => s
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=GATES_PAGE_MAX).contains(n))
            .ok_or_else(|| {
                HttpError::BadRequest(
                    BadRequest::new(format!(
                        "invalid limit `{}`: expected 1..={GATES_PAGE_MAX}",
                        for_log(&s)
                    ))
                    .field("limit"),
                )
            })?,
    };
    // `cursor` is accepted as a synonym of `after`; both at once is a parameter given twice
    let after = match (after, cursor) {
        (Some(_), Some(_)) => {
            return Err(HttpError::BadRequest(
                BadRequest::new("after and cursor are the same parameter; give one")
                    .field("cursor"),
            ))
        }
        (a, c) => a.or(c),
    };
    // a cursor is a gate id (`next`): one that cannot be (`%ff` decodes to U+FFFD) ended the
    // paging with an empty page, as if there were no more gates
    if let Some(a) = after
        .as_deref()
        .filter(|a| !super::config::valid_gate_id(a))
    {
        return Err(HttpError::BadRequest(
            BadRequest::new(format!(
                "invalid after `{}`: a gate id, as `next` gives it",
                for_log(a)
            ))
            .field("after"),
        ));
    }
    let (gates, next) = state.gate_page(after.as_deref(), limit);
    Ok(Json(serde_json::json!({ "gates": gates, "next": next })).into_response())
}

/// The value of a route's path parameter as axum's extractor gives it, or a 400 in the JSON
/// shape of every other answer, naming the parameter in `field` and quoting the value as an
/// [`excerpt`]: axum's own rejection is a text/plain ``Invalid URL: Invalid UTF-8 in `id` ``
/// (`/api/v1/gates/%ff`). A rejection that is the route's own fault (a parameter the route
/// does not have) is a 500, as axum has it. Every `/api/v1` route with a path parameter reads it
/// here, as it reads its query string with `history::query_pairs`.
pub fn path_param<T>(p: Result<Path<T>, PathRejection>) -> Result<T, HttpError> {
    let e = match p {
        Ok(Path(v)) => return Ok(v),
        Err(e) => e,
    };
    if e.status().is_server_error() {
        return Err(HttpError::Internal(format!(
            "path parameters: {}",
            e.body_text()
        )));
    }
    let PathRejection::FailedToDeserializePathParams(failed) = &e else {
        return Err(HttpError::BadRequest(BadRequest::new(e.body_text())));
    };
    let cannot =
        |value: &str, expected: &str| format!("cannot read `{}` as {expected}", excerpt(value));
    let (key, why) = match failed.kind() {
        ErrorKind::InvalidUtf8InPathParam { key } => {
            (Some(key), "not UTF-8 once percent-decoded".to_string())
        }
        ErrorKind::ParseErrorAtKey {
            key,
            value,
            expected_type,
        } => (Some(key), cannot(value, expected_type)),
        ErrorKind::DeserializeError {
            key,
            value,
            message,
        } => (Some(key), format!("`{}`: {message}", excerpt(value))),
        ErrorKind::ParseError {
            value,
            expected_type,
        }
        | ErrorKind::ParseErrorAtIndex {
            value,
            expected_type,
            ..
        } => (None, cannot(value, expected_type)),
        other => (None, other.to_string()),
    };
    Err(HttpError::BadRequest(match key {
        Some(key) => BadRequest::new(format!("path parameter `{key}`: {why}")).field(key.clone()),
        None => BadRequest::new(format!("path parameter: {why}")),
    }))
}

/// `GET /api/v1/gates/{id}`: the gate's view. It takes no parameter, and refuses one as the
/// list does (`?format=csv` would otherwise answer JSON as if it had been read). The probes,
/// `/metrics` and the Influx routes are left lenient: a scrape config or a client may add its
/// own parameters.
async fn get_gate(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
    pairs: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, HttpError> {
    let id = path_param(id)?;
    let [] = query_params(
        query_pairs(pairs)?,
        [],
        "the gate view takes none (its history is /api/v1/gates/{id}/history)",
    )?;
    state
        .gate_view(&id)
        .map(|v| Json(v).into_response())
        .ok_or_else(|| HttpError::NotFound(format!("unknown gate `{}`", excerpt(&id))))
}

/// `DELETE /api/v1/gates/{id}`: forgets an auto-accepted gate now, as its expiry would
/// ([`AppState::forget_gate`]), and answers 200 `{"gate": ID, "resolved": [ALERT...]}`. The
/// operator's way to retire a gate whose sensor was taken out of service: a silent gate with a
/// firing `GateNegativeDamping` is never expired. 404 for a gate the daemon does not know, 409
/// for a configured one. Like the gate view it takes no query parameter.
async fn delete_gate(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
    pairs: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, HttpError> {
    let id = path_param(id)?;
    let [] = query_params(query_pairs(pairs)?, [], "deleting a gate takes none")?;
    match state.forget_gate(&id) {
        Ok(forgotten) => Ok(Json(forgotten).into_response()),
        Err(ForgetError::Unknown) => Err(HttpError::NotFound(format!(
            "unknown gate `{}`: no gate and no alert state of that name",
            excerpt(&id)
        ))),
        Err(ForgetError::Configured) => Err(HttpError::Conflict(format!(
            "gate `{0}` is configured ([gates.{0}]): remove it from the configuration and \
             restart gatewatch to forget it",
            excerpt(&id)
        ))),
    }
}

/// Liveness: 200 `ok` unless the daemon is in a state only a restart ends
/// ([`AppState::unrecoverable`]), then 503 naming it.
async fn healthz(State(state): State<Arc<AppState>>) -> Response {
    let why = state.unrecoverable();
    if why.is_empty() {
        (StatusCode::OK, "ok\n").into_response()
    } else {
        let body = format!("unhealthy: {}\n", why.join("; "));
        (StatusCode::SERVICE_UNAVAILABLE, body).into_response()
    }
}

/// Readiness: 200 `ready`, or 503 `not ready: ` and why ([`AppState::not_ready`]).
async fn readyz(State(state): State<Arc<AppState>>) -> Response {
    match state.not_ready() {
        None => (StatusCode::OK, "ready\n").into_response(),
        Some(why) => (
            StatusCode::SERVICE_UNAVAILABLE,
            format!("not ready: {why}\n"),
        )
            .into_response(),
    }
}

async fn metrics(State(state): State<Arc<AppState>>) -> Response {
    (
        [(header::CONTENT_TYPE, state.metrics.content_type())],
        state.render_metrics(),
    )
        .into_response()
}

/// The token of an `Authorization` header: the `Bearer` scheme (RFC 6750) or InfluxDB 2.x's
/// `Token` scheme (what Telegraf's `outputs.influxdb_v2` and the Influx clients send), the
/// scheme matched case-insensitively as RFC 7235 says.
fn token_of(header: &str) -> Option<&str> {
    let (scheme, token) = header.trim_start().split_once(' ')?;
    (scheme.eq_ignore_ascii_case("bearer") || scheme.eq_ignore_ascii_case("token"))
        .then(|| token.trim())
}

async fn auth(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let tokens = &state.config.server.auth_tokens;
    if tokens.is_empty() {
        return next.run(req).await;
    }
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(token_of);
    // Every token is compared, in constant time, with no early exit on a match: the time taken
    // tells neither which token matched nor how much of one did. (`ct_eq` of slices of
    // different lengths returns false at once: the lengths are not secret.)
    let ok = given.is_some_and(|g| {
        tokens
            .iter()
            .fold(Choice::from(0), |acc, t| {
                acc | t.as_bytes().ct_eq(g.as_bytes())
            })
            .into()
    });
    if ok {
        next.run(req).await
    } else {
        HttpError::Unauthorized.into_response()
    }
}

async fn track(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_string())
        .unwrap_or_else(|| "unmatched".into());
    let start = Instant::now();
    let resp = next.run(req).await;
    let m = &state.metrics;
    m.http_requests
        .with_label_values(&[route.as_str(), resp.status().as_str()])
        .inc();
    m.http_duration
        .with_label_values(&[route.as_str()])
        .observe(start.elapsed().as_secs_f64());
    resp
}

/// What the probes and the scrapers ask for: `/healthz`, `/readyz` (open) and `/metrics` (with a
/// token when `server.metrics_auth`), on `server.listen` and on `server.health_listen`.
fn probes(state: &Arc<AppState>) -> Router<Arc<AppState>> {
    let metrics_route = Router::new().route("/metrics", get(metrics));
    let metrics_route = if state.config.server.metrics_auth {
        metrics_route.route_layer(middleware::from_fn_with_state(state.clone(), auth))
    } else {
        metrics_route
    };
    metrics_route
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
}

/// The router of the health listener (`server.health_listen`): the probes alone, with the
/// request timeout and the request metrics of the main router. No concurrency limit of its
/// own: each of its connections (at most [`HEALTH_MAX_CONNECTIONS`]) has one request at a time.
///
/// [`HEALTH_MAX_CONNECTIONS`]: super::config::HEALTH_MAX_CONNECTIONS
pub fn health_router(state: Arc<AppState>) -> Router {
    let timeout = Duration::from_secs_f64(state.config.server.request_timeout_seconds);
    probes(&state)
        .fallback(fallback)
        .layer(tower_http::timeout::TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            timeout,
        ))
        .layer(middleware::from_fn_with_state(state.clone(), track))
        .with_state(state)
}

async fn fallback() -> HttpError {
    HttpError::NotFound("no such route".into())
}

/// The router with every layer.
///
/// Ingestion routes, innermost first: the body meter of gzip and chunked bodies
/// (`meter_body`), gzip decompression (the body limit then counts decompressed bytes),
/// `Content-Encoding` check (415), admission before the body is read (413 on
/// `Content-Length`, 503 on the body budget or the ingestion bound: `admit_ingest`), bearer
/// auth.
/// The Influx routes (`/api/v2/write`, `/write`, `/query`, `/ping`, `/health`) answer errors in
/// InfluxDB 2.x's shape (`influx::v2_errors`); `/ping` and `/health` are open, as in InfluxDB.
pub fn router(state: Arc<AppState>) -> Router {
    let s = &state.config.server;
    let admission = Admission {
        state: state.clone(),
        budget: BodyBudget::new(s.max_body_bytes_in_flight),
    };
    let decoded = |r: Router<Arc<AppState>>| {
        r.route_layer(middleware::from_fn(meter_body))
            .route_layer(middleware::from_fn(influx::gunzip))
            .route_layer(middleware::from_fn_with_state(
                state.clone(),
                influx::content_encoding,
            ))
            .route_layer(middleware::from_fn_with_state(
                admission.clone(),
                admit_ingest,
            ))
    };
    let protected = decoded(Router::new().route("/api/v1/samples", post(post_samples)))
        .route("/api/v1/gates", get(list_gates))
        .route("/api/v1/gates/{id}", get(get_gate).delete(delete_gate))
        .route(
            "/api/v1/gates/{id}/history",
            get(super::history::get_history),
        )
        .route_layer(middleware::from_fn_with_state(state.clone(), auth));
    let influx_routes = decoded(
        Router::new()
            .route("/api/v2/write", post(post_write))
            .route("/write", post(post_write)),
    )
    .route("/query", get(influx::query).post(influx::query))
    .route_layer(middleware::from_fn_with_state(state.clone(), auth))
    .route("/ping", get(influx::ping))
    .route("/health", get(influx::health))
    .route_layer(middleware::from_fn(influx::v2_errors));
    let timeout = Duration::from_secs_f64(s.request_timeout_seconds);
    Router::new()
        .merge(protected)
        .merge(influx_routes)
        .merge(probes(&state))
        .fallback(fallback)
        .layer(DefaultBodyLimit::max(s.body_limit_bytes))
        .layer(
            ServiceBuilder::new()
                .layer(HandleErrorLayer::new(|_: tower::BoxError| async {
                    HttpError::Overloaded
                }))
                .load_shed()
                .layer(tower::limit::GlobalConcurrencyLimitLayer::new(
                    s.max_concurrent_requests,
                )),
        )
        .layer(middleware::from_fn_with_state(timeout, deadline))
        .layer(middleware::from_fn_with_state(state.clone(), track))
        .with_state(state)
}

/// `server.request_timeout_seconds` of the main router: 408 to a request not answered in
/// time, unless its body was wholly read by then. A request whose body has arrived is the
/// daemon's to finish (parsing and applying a body is bounded work, at most
/// `body_limit_bytes`), and it answers what it did.
///
/// Why not `tower_http`'s `TimeoutLayer`, as until stop 97 (the health listener keeps it: its
/// probes read no body): it dropped the handler at the deadline, but the parsing and applying
/// the handler awaited run on the blocking pool and cannot be cancelled. A body whose last
/// bytes came just before the deadline was answered 408 ("the request changed nothing, retry
/// it", docs/api.md) while its samples were applied, and the request's place in
/// `max_concurrent_ingest` and its bytes in `max_body_bytes_in_flight` were freed while it
/// still held its body and parsed it: a review pushed the peak to 701 MB against the 224 MiB
/// bound that way. A request whose body has not wholly arrived never reached its handler's
/// work, so its 408 is still true.
async fn deadline(State(timeout): State<Duration>, req: Request, next: Next) -> Response {
    let read = Arc::new(AtomicBool::new(false));
    let req = req.map(|body| {
        axum::body::Body::from_stream(EndFlag {
            inner: body.into_data_stream(),
            ended: read.clone(),
        })
    });
    let handler = next.run(req);
    tokio::pin!(handler);
    tokio::select! {
        response = &mut handler => response,
        () = tokio::time::sleep(timeout) => {
            if read.load(Ordering::Acquire) {
                handler.await
            } else {
                StatusCode::REQUEST_TIMEOUT.into_response()
            }
        }
    }
}

/// A request body that says when it has been read to its end ([`deadline`]).
struct EndFlag {
    inner: axum::body::BodyDataStream,
    ended: Arc<AtomicBool>,
}

impl futures_util::Stream for EndFlag {
    type Item = Result<Bytes, axum::Error>;

    fn poll_next(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Self::Item>> {
        let next = self.inner.poll_next_unpin(cx);
        if let std::task::Poll::Ready(None) = next {
            self.ended.store(true, Ordering::Release);
        }
        next
    }
}
