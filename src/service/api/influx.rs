//! The InfluxDB HTTP surface around the line protocol, so Telegraf and the official clients work
//! as they ship: `/ping`, `/health`, the 1.x `/query` as far as clients call it before writing
//! (`CREATE DATABASE`), gzip request bodies, and errors in InfluxDB 2.x's shape.
//!
//! gatewatch keeps no databases, buckets or retention policies: the `db`, `rp`, `org` and
//! `bucket` parameters are accepted and ignored, and `CREATE DATABASE` succeeds without doing
//! anything (clients such as Telegraf's `outputs.influxdb` and the v1 Python client issue it
//! before their first write and stop when it fails).

use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::FormRejection;
use axum::extract::{Form, RawQuery, Request, State};
use axum::http::{header, HeaderName, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::{json, Map, Value};

use super::HttpError;
use crate::service::ingest::BadRequest;
use crate::service::ingest_checks::{single_param, single_value};
use crate::service::metrics::RejectReason;
use crate::service::state::AppState;

/// What `/ping` answers in `X-Influxdb-Version` and `/health` in `version`: gatewatch's own
/// version, named as such (no client parses it; the 1.x CLI and the v1 client print it).
pub const VERSION: &str = concat!("gatewatch-", env!("CARGO_PKG_VERSION"));

/// The InfluxDB 2.x header that repeats an error's `code`.
const PLATFORM_ERROR_CODE: HeaderName = HeaderName::from_static("x-platform-error-code");

/// Error bodies rewritten by [`v2_errors`] are gatewatch's own small JSON objects; anything
/// longer is cut, so the rewrite never buffers more than this.
const MAX_ERROR_BODY: usize = 64 * 1024;

/// The request decompression of every ingestion route: gzip only (what Telegraf and the Influx
/// clients send). It streams: the body limit (`server.body_limit_bytes`, enforced when the
/// handler buffers the body) counts DECOMPRESSED bytes, so a gzip bomb stops at the limit with
/// 413 instead of inflating into memory. [`content_encoding`] runs first and answers unknown
/// encodings (and leaves `gzip` as the one spelling).
///
/// Every member of the body is decoded: a gzip file may hold several (RFC 1952, section 2.2;
/// `cat a.gz b.gz`, a logger that appends), and `gzip -d`, Go's reader and InfluxDB read them
/// all. tower-http's `RequestDecompressionLayer` stopped after the first and answered 204 for
/// the lot: the lines of the later members were lost without a word. Bytes after the last
/// member that are not gzip fail the body (400), as a broken stream does.
pub async fn gunzip(mut req: Request, next: Next) -> Response {
    use futures_util::StreamExt;
    let gzip = req
        .headers()
        .get(header::CONTENT_ENCODING)
        .is_some_and(|v| v == "gzip");
    if !gzip {
        return next.run(req).await;
    }
    req.headers_mut().remove(header::CONTENT_ENCODING);
    req.headers_mut().remove(header::CONTENT_LENGTH);
    let req = req.map(|body| {
        let raw = body
            .into_data_stream()
            .map(|chunk| chunk.map_err(std::io::Error::other));
        let mut decoder = async_compression::tokio::bufread::GzipDecoder::new(
            tokio_util::io::StreamReader::new(raw),
        );
        decoder.multiple_members(true);
        Body::from_stream(tokio_util::io::ReaderStream::new(decoder))
    });
    next.run(req).await
}

/// Normalises `Content-Encoding` for [`gunzip`] (which matches the exact lowercase
/// token): `gzip` and `x-gzip` in any case become `gzip`, `identity` is dropped, and anything
/// else (`br`, `deflate`, a list of codings) is answered 415 naming the encoding, with
/// `Accept-Encoding: gzip` as RFC 7694 asks, before the body is read.
pub async fn content_encoding(
    State(state): State<Arc<AppState>>,
    mut req: Request,
    next: Next,
) -> Response {
    let lines = req.headers().get_all(header::CONTENT_ENCODING);
    if lines.iter().next().is_some() {
        // header lines repeated are one list (RFC 9110, section 5.3): `gzip` twice on two
        // lines is `gzip, gzip`, refused as such (it was decoded once and read as bad JSON)
        let enc = lines
            .iter()
            .map(|v| {
                String::from_utf8_lossy(v.as_bytes())
                    .trim()
                    .to_ascii_lowercase()
            })
            .collect::<Vec<_>>()
            .join(", ");
        match enc.as_str() {
            "gzip" | "x-gzip" => {
                req.headers_mut()
                    .insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
            }
            "identity" | "" => {
                req.headers_mut().remove(header::CONTENT_ENCODING);
            }
            _ => {
                state.metrics.reject(RejectReason::Invalid, 1);
                return HttpError::UnsupportedEncoding(enc).into_response();
            }
        }
    }
    next.run(req).await
}

/// The `code` of an InfluxDB 2.x error for an HTTP status (the names InfluxDB uses).
fn code_for(status: StatusCode) -> &'static str {
    match status.as_u16() {
        400 => "invalid",
        401 => "unauthorized",
        403 => "forbidden",
        404 => "not found",
        405 => "method not allowed",
        413 => "request too large",
        415 => "unsupported media type",
        422 => "unprocessable entity",
        429 => "too many requests",
        408 | 503 => "unavailable",
        s if s >= 500 => "internal error",
        _ => "invalid",
    }
}

/// Rewrites the error responses of the Influx routes into InfluxDB 2.x's shape, `{"code":
/// "invalid", "message": "..."}` plus the `X-Platform-Error-Code` header, so the clients show
/// the message instead of raw JSON. gatewatch's members stay: `error` (the shape InfluxDB 1.x
/// answers, read by 1.x clients) and `line`, `column`, `field`, `index`. Status and other
/// headers (`Retry-After`, `WWW-Authenticate`, `Accept-Encoding`) are kept. As a middleware it
/// covers every layer's errors (auth, overload, body limit, encoding), not only the handler's.
pub async fn v2_errors(req: Request, next: Next) -> Response {
    let resp = next.run(req).await;
    let status = resp.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return resp;
    }
    let (mut parts, body) = resp.into_parts();
    let bytes = axum::body::to_bytes(body, MAX_ERROR_BODY)
        .await
        .unwrap_or_default();
    let mut obj = match serde_json::from_slice::<Value>(&bytes) {
        Ok(Value::Object(m)) => m,
        _ => Map::new(),
    };
    let error = obj
        .get("error")
        .and_then(Value::as_str)
        .map(str::to_owned)
        .unwrap_or_else(|| {
            status
                .canonical_reason()
                .unwrap_or("error")
                .to_ascii_lowercase()
        });
    // the clients show `message` alone: it carries the location too
    let message = match (
        obj.get("line").and_then(Value::as_u64),
        obj.get("column").and_then(Value::as_u64),
    ) {
        (Some(l), Some(c)) => format!("line {l} column {c}: {error}"),
        (Some(l), None) => format!("line {l}: {error}"),
        _ => error.clone(),
    };
    let code = code_for(status);
    obj.insert("code".into(), code.into());
    obj.insert("message".into(), message.into());
    obj.insert("error".into(), error.into());
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    parts
        .headers
        .insert(PLATFORM_ERROR_CODE, HeaderValue::from_static(code));
    Response::from_parts(parts, Body::from(Value::Object(obj).to_string()))
}

/// `GET`/`HEAD /ping`: 204 with `X-Influxdb-Version`, as InfluxDB 1.8 and 2.x answer; the v1
/// client's `ping()` returns that header, the v2 client's is true on any 2xx, and the 1.x CLI
/// pings on connect.
pub async fn ping() -> Response {
    (
        StatusCode::NO_CONTENT,
        [
            ("x-influxdb-version", VERSION),
            ("x-influxdb-build", "gatewatch"),
        ],
    )
        .into_response()
}

/// `GET /health` in InfluxDB 2.x's shape: 200 `"status": "pass"` when ready (as `/readyz`),
/// otherwise 503 `"status": "fail"` as InfluxDB answers while it starts, the message saying why
/// (as `/readyz`'s body; also as `error`, which [`v2_errors`] makes the 503's `message`).
pub async fn health(State(state): State<Arc<AppState>>) -> Response {
    let (status, verdict, message) = match state.not_ready() {
        None => (StatusCode::OK, "pass", "ready for writes".to_string()),
        Some(why) => (
            StatusCode::SERVICE_UNAVAILABLE,
            "fail",
            format!("not ready: {why}"),
        ),
    };
    let mut body = json!({
        "name": "gatewatch",
        "message": message,
        "status": verdict,
        "checks": [],
        "version": VERSION,
        "commit": "",
    });
    if status != StatusCode::OK {
        body["error"] = message.into();
    }
    (status, Json(body)).into_response()
}

/// `GET`/`POST /query` (InfluxDB 1.x): `q` from the URL or a form body. Only `CREATE DATABASE`
/// statements are answered, with success and no effect; anything else is 400 saying that
/// gatewatch stores nothing to query (its data is at `/api/v1/gates` and `/metrics`).
///
/// `q` given twice is a 400 naming it, as `precision` on `/write`: twice in the URL, twice in
/// the body, or once in each (which one wins is a guess: InfluxDB's Go server takes the body's,
/// most frameworks the URL's). Other parameters are accepted and ignored, as InfluxDB's clients
/// send their own (`db`, `epoch`, `pretty`, `chunked`, `u`, `p`) and InfluxDB ignores the ones
/// it does not use.
pub async fn query(
    State(state): State<Arc<AppState>>,
    method: Method,
    RawQuery(raw): RawQuery,
    form: Result<Form<Vec<(String, String)>>, FormRejection>,
) -> Result<Response, HttpError> {
    let in_url = single_param(raw.as_deref(), "q").map_err(HttpError::BadRequest)?;
    // a GET's form is its query string again: only a POST has a body to read. A body that
    // could not be read as a form is said as such, not as a missing `q` (a 5 MB form was
    // "missing required parameter `q`", a 400 instead of 413)
    let mut unread = None;
    let in_body = match form {
        Ok(Form(pairs)) if method == Method::POST => {
            single_value(pairs, "q").map_err(HttpError::BadRequest)?
        }
        Err(r) if method == Method::POST => {
            if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
                return Err(HttpError::PayloadTooLarge(
                    state.config.server.body_limit_bytes,
                ));
            }
            unread = Some(r.body_text());
            None
        }
        _ => None,
    };
    let q = match (in_url, in_body) {
        (Some(u), Some(b)) => {
            return Err(HttpError::BadRequest(
                BadRequest::new(format!(
                    "parameter `q` given in both the URL (`{u}`) and the body (`{b}`)"
                ))
                .field("q"),
            ))
        }
        (Some(q), None) | (None, Some(q)) => q,
        (None, None) => {
            let why = unread.map_or(String::new(), |r| {
                format!(" (in the URL, or in a form body: this body was not read as one: {r})")
            });
            return Err(HttpError::BadRequest(
                BadRequest::new(format!("missing required parameter `q`{why}")).field("q"),
            ));
        }
    };
    let results = create_database_statements(&q)
        .map_err(HttpError::BadRequest)?
        .into_iter()
        .map(|i| json!({ "statement_id": i }))
        .collect::<Vec<_>>();
    Ok(Json(json!({ "results": results })).into_response())
}

/// The statement ids of `q` when every statement is `CREATE DATABASE ...`; otherwise a 400
/// naming the first other statement.
fn create_database_statements(q: &str) -> Result<Vec<usize>, BadRequest> {
    let statements: Vec<&str> = q
        .split(';')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    if statements.is_empty() {
        return Err(BadRequest::new("empty query").field("q"));
    }
    for s in &statements {
        let mut words = s.split_whitespace();
        let create_db = words
            .next()
            .is_some_and(|w| w.eq_ignore_ascii_case("create"))
            && words
                .next()
                .is_some_and(|w| w.eq_ignore_ascii_case("database"))
            && words.next().is_some();
        if !create_db {
            return Err(BadRequest::new(format!(
                "gatewatch keeps no databases and answers no queries (only CREATE DATABASE, \
                 as a no-op): `{s}`; read the gates at /api/v1/gates and /metrics"
            ))
            .field("q"));
        }
    }
    Ok((0..statements.len()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn create_database_is_accepted_and_other_statements_refused() {
        assert_eq!(
            create_database_statements("CREATE DATABASE \"telegraf\""),
            Ok(vec![0])
        );
        assert_eq!(
            create_database_statements("create  database x; CREATE DATABASE y;"),
            Ok(vec![0, 1])
        );
        for bad in [
            "",
            ";",
            "SHOW DATABASES",
            "CREATE DATABASE",
            "DROP DATABASE x",
        ] {
            let e = create_database_statements(bad).unwrap_err();
            assert_eq!(e.field.as_deref(), Some("q"), "{bad}");
        }
    }

    #[test]
    fn codes_follow_influxdb() {
        assert_eq!(code_for(StatusCode::BAD_REQUEST), "invalid");
        assert_eq!(code_for(StatusCode::PAYLOAD_TOO_LARGE), "request too large");
        assert_eq!(code_for(StatusCode::SERVICE_UNAVAILABLE), "unavailable");
        assert_eq!(
            code_for(StatusCode::INTERNAL_SERVER_ERROR),
            "internal error"
        );
    }
}
