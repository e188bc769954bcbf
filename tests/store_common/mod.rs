//! What the store's process-level tests (`store_outage`, `store_restart`) share: a free port,
//! the daemon's outbox read from its file, and a webhook receiver.
#![allow(dead_code)]

use std::net::TcpListener as StdListener;
use std::path::Path;
use std::time::Instant;

use serde_json::Value;
use tokio::sync::mpsc;

use gatewatch::store::{SqliteStore, Store, WriteBatch};

pub mod brim;

/// A port nobody listens on now (the receiver is bound to it later, or never).
pub fn free_port() -> u16 {
    StdListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

/// `(status, payload)` of the persisted outbox rows, oldest first, read from the daemon's file
/// read-only while it runs (WAL); empty while the file or its table does not exist yet.
pub fn outbox_rows(db: &Path) -> Vec<(String, Value)> {
    let Ok(c) =
        rusqlite::Connection::open_with_flags(db, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
    else {
        return Vec::new();
    };
    let Ok(mut s) = c.prepare("SELECT status, payload FROM outbox ORDER BY id") else {
        return Vec::new();
    };
    s.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?)))
        .map(|rows| {
            rows.filter_map(Result::ok)
                .map(|(status, payload)| {
                    (
                        status,
                        serde_json::from_str(&payload).unwrap_or(Value::Null),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// A webhook receiver on `port` (`POST /hook`): every payload with the instant it arrived,
/// through a bounded queue (a full queue answers 503, which the daemon retries).
pub async fn receiver(port: u16) -> mpsc::Receiver<(Instant, Value)> {
    let (tx, rx) = mpsc::channel::<(Instant, Value)>(256);
    let app = axum::Router::new()
        .route(
            "/hook",
            axum::routing::post(
                |axum::extract::State(tx): axum::extract::State<mpsc::Sender<(Instant, Value)>>,
                 axum::Json(v): axum::Json<Value>| async move {
                    match tx.try_send((Instant::now(), v)) {
                        Ok(()) => axum::http::StatusCode::OK,
                        Err(_) => axum::http::StatusCode::SERVICE_UNAVAILABLE,
                    }
                },
            ),
        )
        .with_state(tx);
    let l = tokio::net::TcpListener::bind(("127.0.0.1", port))
        .await
        .expect("bind the receiver");
    tokio::spawn(async move {
        let _ = axum::serve(l, app).await;
    });
    rx
}

/// One metric's value at the daemon at `url` (the first line starting with `line_start`),
/// `None` while the daemon does not answer.
pub async fn metric(client: &reqwest::Client, url: &str, line_start: &str) -> Option<f64> {
    let text = client
        .get(format!("{url}/metrics"))
        .send()
        .await
        .ok()?
        .text()
        .await
        .ok()?;
    text.lines()
        .find(|l| l.starts_with(line_start))
        .and_then(|l| l.split_whitespace().last())
        .and_then(|v| v.parse().ok())
}
