//! Raw TCP listener: newline-delimited line protocol, as Telegraf's `socket_writer` sends.
//!
//! It sits next to `server.rs`, which runs the HTTP listener, and not in `ingest/`: `ingest/`
//! holds the request formats only (pure parsing, no state), while a listener feeds
//! [`AppState`]; keeping the two apart keeps `ingest` below `state` in the import graph.
//!
//! Each line is parsed and applied on its own; a bad line is counted
//! (`gatewatch_samples_rejected_total{reason="bad_line"}` and the validation reasons), logged at
//! most once per [`BAD_LINE_LOG_INTERVAL`] per connection, and the connection is kept. Lines
//! longer than `ingest.tcp_max_line_bytes` are skipped up to their newline. At most
//! `server.max_tcp_connections` connections are served; further ones are closed at once.
//!
//! Same rule as HTTP ingestion: parsing and applying (CPU work proportional to the data) run on
//! the blocking pool, never on the async runtime's threads. Reading stays async; the lines that
//! have already arrived (up to [`MAX_BATCH_BYTES`]) go to the blocking pool together, so a busy
//! connection costs one blocking task per read, not per line. Each connection has at most one
//! such task at a time, so there are at most `server.max_tcp_connections` of them.

use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncReadExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};

use super::clock::now_unix;
use super::ingest::line_protocol::{self, Mapping};
use super::metrics::RejectReason;
use super::state::{AppState, IngestError};

/// Bad lines of one connection are logged at most once per this interval (with a count).
pub const BAD_LINE_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// Most bytes of complete lines handed to one blocking task: bounds the memory a connection
/// holds and how long its lines wait for one another.
pub const MAX_BATCH_BYTES: usize = 256 * 1024;

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
            handle(stream, peer, state, shutdown).await;
            drop(permit);
        });
    }
}

/// Counts and logs (rate-limited) the bad lines of one connection.
struct BadLines {
    peer: std::net::SocketAddr,
    count: u64,
    last_log: Option<Instant>,
}

impl BadLines {
    fn record(&mut self, line: usize, msg: &str) {
        self.count += 1;
        if self
            .last_log
            .is_none_or(|t| t.elapsed() >= BAD_LINE_LOG_INTERVAL)
        {
            tracing::warn!(peer = %self.peer, line, bad_lines = self.count, error = %msg, "bad line on tcp listener");
            self.last_log = Some(Instant::now());
        }
    }
}

/// Complete lines read but not yet applied: `bytes` holds them, each ending in `\n`, the first
/// being line `first_line` of the connection.
struct Pending {
    bytes: Vec<u8>,
    first_line: usize,
    lines: usize,
}

async fn handle(
    stream: TcpStream,
    peer: std::net::SocketAddr,
    state: Arc<AppState>,
    mut shutdown: watch::Receiver<bool>,
) {
    let max = state.config.ingest.tcp_max_line_bytes;
    let mut bad = BadLines {
        peer,
        count: 0,
        last_log: None,
    };
    let mut reader = BufReader::new(stream);
    let mut pending = Pending {
        bytes: Vec::with_capacity(1024),
        first_line: 1,
        lines: 0,
    };
    loop {
        let start = pending.bytes.len();
        let mut limited = (&mut reader).take(max as u64 + 1);
        let read = tokio::select! {
            r = limited.read_until(b'\n', &mut pending.bytes) => r,
            _ = shutdown.wait_for(|s| *s) => break,
        };
        match read {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) => {
                tracing::debug!(peer = %bad.peer, error = %e, "tcp read failed");
                break;
            }
        }
        let line_no = pending.first_line + pending.lines;
        if pending.bytes.len() - start > max && !pending.bytes.ends_with(b"\n") {
            // apply the lines before it, then skip the rest of the over-long line
            pending.bytes.truncate(start);
            apply(&state, &mut pending, &mut bad).await;
            skip_line(&mut reader).await;
            state.metrics.reject(RejectReason::BadLine, 1);
            bad.record(line_no, &format!("line longer than {max} bytes"));
            pending.first_line = line_no + 1;
            continue;
        }
        if !pending.bytes.ends_with(b"\n") {
            pending.bytes.push(b'\n'); // the last line, ended by the end of the stream
        }
        pending.lines += 1;
        // more complete lines already buffered: read them before going to the blocking pool
        if pending.bytes.len() < MAX_BATCH_BYTES && reader.buffer().contains(&b'\n') {
            continue;
        }
        apply(&state, &mut pending, &mut bad).await;
    }
    apply(&state, &mut pending, &mut bad).await;
}

/// Discards the rest of an over-long line, up to and including its newline.
async fn skip_line(reader: &mut BufReader<TcpStream>) {
    let mut sink = Vec::new();
    loop {
        sink.clear();
        match (&mut *reader)
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
}

/// Parses and applies the pending lines on the blocking pool, then records the refused ones;
/// `pending` is left empty (its buffer reused), starting after the lines applied.
async fn apply(state: &Arc<AppState>, pending: &mut Pending, bad: &mut BadLines) {
    if pending.lines == 0 {
        return;
    }
    let bytes = std::mem::take(&mut pending.bytes);
    let first = pending.first_line;
    let st = state.clone();
    let done = tokio::task::spawn_blocking(move || {
        let refused = process_lines(&st, &bytes, first);
        (bytes, refused)
    })
    .await;
    match done {
        Ok((mut bytes, refused)) => {
            for (line, msg) in refused {
                bad.record(line, &msg);
            }
            bytes.clear();
            pending.bytes = bytes;
        }
        Err(e) => tracing::error!(error = %e, "tcp ingestion task failed"),
    }
    pending.first_line += pending.lines;
    pending.lines = 0;
}

/// Applies each `\n`-terminated line of `bytes` (the first is line `first_line`) on its own;
/// returns the refused lines with their messages (already counted).
fn process_lines(state: &AppState, bytes: &[u8], first_line: usize) -> Vec<(usize, String)> {
    let mut refused = Vec::new();
    for (i, raw) in bytes.split_inclusive(|b| *b == b'\n').enumerate() {
        let line_no = first_line + i;
        if let Some((reason, msg)) = process(state, raw, line_no) {
            if let Some(r) = reason {
                state.metrics.reject(r, 1);
            }
            refused.push((line_no, msg));
        }
    }
    refused
}

/// Parses and applies one line; `Some((reason, message))` when it is refused (`reason` is
/// `None` when `AppState::ingest` already counted it).
fn process(state: &AppState, raw: &[u8], line_no: usize) -> Option<(Option<RejectReason>, String)> {
    let bad_line = |msg: String| Some((Some(RejectReason::BadLine), msg));
    let Ok(text) = std::str::from_utf8(raw) else {
        return bad_line("invalid UTF-8".into());
    };
    let text = text.trim_end_matches(['\n', '\r']);
    let line = match line_protocol::parse_line(text, line_no) {
        Ok(Some(l)) => l,
        Ok(None) => return None,
        Err(e) => return bad_line(e.to_string()),
    };
    let cfg = &state.config.ingest;
    let mapping = Mapping {
        gate_tag: &cfg.gate_tag,
        value_fields: &cfg.value_fields,
        precision: cfg.tcp_precision,
        now: now_unix(),
    };
    let batches = match line_protocol::to_batches(&[(line_no, line)], &mapping) {
        Ok(b) => b,
        Err(e) => return bad_line(e.error),
    };
    // `ingest` counts its own rejection reasons
    match state.ingest(batches) {
        Ok(_) => None,
        Err(IngestError::BadRequest(b)) => Some((None, b.error)),
        Err(IngestError::UnknownGate(g)) => Some((None, format!("unknown gate `{g}`"))),
        Err(IngestError::TooManyGates(g)) => {
            Some((None, format!("gate limit reached, `{g}` refused")))
        }
    }
}
