//! Raw TCP listener: newline-delimited line protocol, as Telegraf's `socket_writer` sends.
//!
//! Each line is parsed and applied on its own; a bad line is counted
//! (`gatewatch_samples_rejected_total{reason="bad_line"}` and the validation reasons), logged at
//! most once per [`BAD_LINE_LOG_INTERVAL`] per connection, and the connection is kept. Lines
//! longer than `ingest.tcp_max_line_bytes` are skipped up to their newline. At most
//! `server.max_tcp_connections` connections are served; further ones are closed at once.

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use tokio::io::{AsyncBufReadExt, AsyncReadExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};

use super::line_protocol::{self, Mapping};
use crate::service::state::{AppState, IngestError};

/// Bad lines of one connection are logged at most once per this interval (with a count).
pub const BAD_LINE_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// Accepts connections until `shutdown` turns true.
pub async fn serve(
    listener: TcpListener,
    state: Arc<AppState>,
    mut shutdown: watch::Receiver<bool>,
) {
    let limit = Arc::new(Semaphore::new(state.config.server.max_tcp_connections));
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = shutdown.wait_for(|s| *s) => break,
        };
        let (stream, peer) = match accepted {
            Ok(x) => x,
            Err(e) => {
                tracing::warn!(error = %e, "tcp accept failed");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let Ok(permit) = limit.clone().try_acquire_owned() else {
            state.metrics.tcp_connections_rejected.inc();
            tracing::warn!(%peer, "tcp connection limit reached, closing");
            drop(stream);
            continue;
        };
        let state = state.clone();
        let shutdown = shutdown.clone();
        tokio::spawn(async move {
            handle(stream, state, shutdown).await;
            drop(permit);
        });
    }
}

async fn handle(stream: TcpStream, state: Arc<AppState>, mut shutdown: watch::Receiver<bool>) {
    let peer = stream.peer_addr().ok();
    let max = state.config.ingest.tcp_max_line_bytes;
    let mut reader = BufReader::new(stream);
    let mut buf = Vec::with_capacity(1024);
    let mut line_no = 0usize;
    let mut bad = 0u64;
    let mut last_log: Option<Instant> = None;
    loop {
        buf.clear();
        let mut limited = (&mut reader).take(max as u64 + 1);
        let read = tokio::select! {
            r = limited.read_until(b'\n', &mut buf) => r,
            _ = shutdown.wait_for(|s| *s) => break,
        };
        match read {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) => {
                tracing::debug!(?peer, error = %e, "tcp read failed");
                break;
            }
        }
        line_no += 1;
        let error = if buf.len() > max && !buf.ends_with(b"\n") {
            // skip the rest of the over-long line
            let mut sink = Vec::new();
            loop {
                sink.clear();
                match (&mut reader)
                    .take(64 * 1024)
                    .read_until(b'\n', &mut sink)
                    .await
                {
                    Ok(0) => break,
                    Ok(_) if sink.ends_with(b"\n") => break,
                    Ok(_) => continue,
                    Err(_) => break,
                }
            }
            Some(("bad_line", format!("line longer than {max} bytes")))
        } else {
            process(&state, &buf, line_no)
        };
        if let Some((reason, msg)) = error {
            bad += 1;
            if reason != "none" {
                state
                    .metrics
                    .samples_rejected
                    .with_label_values(&[reason])
                    .inc();
            }
            if last_log.is_none_or(|t| t.elapsed() >= BAD_LINE_LOG_INTERVAL) {
                tracing::warn!(?peer, line = line_no, bad_lines = bad, error = %msg, "bad line on tcp listener");
                last_log = Some(Instant::now());
            }
        }
    }
}

/// Parses and applies one line; `Some((reason, message))` when it is refused (`reason` is
/// `"none"` when `AppState::ingest` already counted it).
fn process(state: &AppState, raw: &[u8], line_no: usize) -> Option<(&'static str, String)> {
    let Ok(text) = std::str::from_utf8(raw) else {
        return Some(("bad_line", "invalid UTF-8".into()));
    };
    let text = text.trim_end_matches(['\n', '\r']);
    let line = match line_protocol::parse_line(text, line_no) {
        Ok(Some(l)) => l,
        Ok(None) => return None,
        Err(e) => return Some(("bad_line", e.to_string())),
    };
    let cfg = &state.config.ingest;
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0);
    let mapping = Mapping {
        gate_tag: &cfg.gate_tag,
        value_fields: &cfg.value_fields,
        precision: cfg.tcp_precision,
        now,
    };
    let batches = match line_protocol::to_batches(&[(line_no, line)], &mapping) {
        Ok(b) => b,
        Err(e) => return Some(("bad_line", e.error)),
    };
    // `ingest` counts its own rejection reasons
    match state.ingest(batches) {
        Ok(_) => None,
        Err(IngestError::BadRequest(b)) => Some(("none", b.error)),
        Err(IngestError::UnknownGate(g)) => Some(("none", format!("unknown gate `{g}`"))),
        Err(IngestError::TooManyGates(g)) => {
            Some(("none", format!("gate limit reached, `{g}` refused")))
        }
    }
}
