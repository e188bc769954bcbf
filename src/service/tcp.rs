//! Raw TCP listener: newline-delimited line protocol, as Telegraf's `socket_writer` sends.
//!
//! It sits next to `server.rs`, which runs the HTTP listener, and not in `ingest/`: `ingest/`
//! holds the request formats only (pure parsing, no state), while a listener feeds
//! [`AppState`]; keeping the two apart keeps `ingest` below `state` in the import graph.
//!
//! Each line is parsed and applied on its own; a bad line is counted
//! (`gatewatch_samples_rejected_total{reason="bad_line"}` and the validation reasons), logged at
//! most once per [`BAD_LINE_LOG_INTERVAL`] by the listener (not per connection: a client that
//! reconnects for every line would log every line), and the connection is kept. Lines
//! longer than `ingest.tcp_max_line_bytes` are skipped up to their newline, and so are lines
//! that are not UTF-8. At most `server.max_tcp_connections` connections are served; further ones
//! are closed at once, and so are clients outside `server.tcp_allowed_networks` (loopback by
//! default: this listener has no tokens, see docs/security.md). A connection silent for
//! `server.tcp_idle_timeout_seconds` is closed. Logged client input goes through
//! [`for_log`] (escaped, cut).
//!
//! Framing is tokio-util's [`LinesCodec`] with a maximum length (it discards an over-long line
//! up to its newline and checks UTF-8), read through [`FramedRead`].
//!
//! Same rule as HTTP ingestion: parsing and applying (CPU work proportional to the data) run on
//! the blocking pool, never on the async runtime's threads. Reading and framing stay async; the
//! lines that have already arrived (up to [`MAX_BATCH_BYTES`]) go to the blocking pool together,
//! so a busy connection costs one blocking task per read, not per line. Each connection has at
//! most one such task at a time, so there are at most `server.max_tcp_connections` of them.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use std::io;

use futures_util::StreamExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};
use tokio_util::bytes::BytesMut;
use tokio_util::codec::{Decoder, FramedRead, LinesCodec, LinesCodecError};

use super::clock::now_unix;
use super::ingest::line_protocol::{self, Mapping};
use super::limits::for_log;
use super::log_limit::{LogLimiter, ACCEPT_WARNING_INTERVAL};
use super::metrics::{RejectReason, TCP_CONNECTION_LIMIT, TCP_NOT_ALLOWED};
use super::state::{AppState, IngestError};

/// Bad lines are logged at most once per this interval by the whole listener, each line saying
/// how many were held back since the last and how many its connection sent.
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
    // validated with the configuration; an empty list (impossible after validation) allows none
    let allowed = state.config.server.tcp_networks().unwrap_or_default();
    let bad_line_log = Arc::new(Mutex::new(LogLimiter::new(BAD_LINE_LOG_INTERVAL)));
    let (mut refusals, mut outsiders, mut failures) = (
        LogLimiter::new(ACCEPT_WARNING_INTERVAL),
        LogLimiter::new(ACCEPT_WARNING_INTERVAL),
        LogLimiter::new(ACCEPT_WARNING_INTERVAL),
    );
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = shutdown.wait_for(|s| *s) => break,
        };
        let (stream, peer) = match accepted {
            Ok(x) => x,
            Err(e) => {
                if let Some(held_back) = failures.allow(Instant::now()) {
                    tracing::warn!(error = %e, held_back, "tcp accept failed");
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        if !allowed
            .iter()
            .any(|n| n.contains(&peer.ip().to_canonical()))
        {
            state
                .metrics
                .tcp_connections_rejected
                .with_label_values(&[TCP_NOT_ALLOWED])
                .inc();
            if let Some(held_back) = outsiders.allow(Instant::now()) {
                tracing::warn!(%peer, held_back, "tcp client outside server.tcp_allowed_networks, closing");
            }
            drop(stream);
            continue;
        }
        let Ok(permit) = limit.clone().try_acquire_owned() else {
            state
                .metrics
                .tcp_connections_rejected
                .with_label_values(&[TCP_CONNECTION_LIMIT])
                .inc();
            if let Some(held_back) = refusals.allow(Instant::now()) {
                tracing::warn!(%peer, held_back, "tcp connection limit reached, closing");
            }
            drop(stream);
            continue;
        };
        let state = state.clone();
        let shutdown = shutdown.clone();
        let bad = BadLines {
            peer,
            count: 0,
            log: bad_line_log.clone(),
        };
        tokio::spawn(async move {
            handle(stream, bad, state, shutdown).await;
            drop(permit);
        });
    }
}

/// Counts the bad lines of one connection and logs them through the listener's limiter.
struct BadLines {
    peer: std::net::SocketAddr,
    /// Bad lines of this connection so far.
    count: u64,
    /// The listener's limiter, shared by its connections ([`BAD_LINE_LOG_INTERVAL`]).
    log: Arc<Mutex<LogLimiter>>,
}

impl BadLines {
    fn record(&mut self, line: usize, msg: &str) {
        self.count += 1;
        let allowed = self
            .log
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .allow(Instant::now());
        if let Some(held_back) = allowed {
            // the message may quote the client's line: escaped and cut (`limits::for_log`)
            let error = for_log(msg);
            tracing::warn!(peer = %self.peer, line, bad_lines = self.count, held_back, error = %error, "bad line on tcp listener");
        }
    }
}

/// One frame of the connection: a line, or a line that is refused before it is parsed.
#[derive(Debug, PartialEq)]
enum Frame {
    /// A complete line without its `\n` (and `\r`).
    Line(String),
    /// A line longer than `ingest.tcp_max_line_bytes`; the codec discards it up to its newline.
    TooLong,
    /// A line that is not UTF-8; it has been consumed.
    NotUtf8,
}

/// [`LinesCodec`] with a maximum length, its two refusals turned into frames: `FramedRead`
/// ends the stream after a decoder error, but a bad line must not end the connection. The
/// error type is left for the reads from the socket, which do end it.
struct Lines(LinesCodec, usize);

impl Lines {
    /// Lines of at most `max` bytes, not counting the line end: the codec's bound counts a
    /// CRLF line's `\r`, so it is one byte more, and the line it gives (without the `\r`) is
    /// held to `max` here (a CRLF line of exactly `max` bytes was refused as longer).
    fn new(max: usize) -> Lines {
        Lines(LinesCodec::new_with_max_length(max.saturating_add(1)), max)
    }

    fn frame(
        &self,
        r: Result<Option<String>, LinesCodecError>,
    ) -> Result<Option<Frame>, io::Error> {
        match r {
            Ok(Some(line)) if line.len() > self.1 => Ok(Some(Frame::TooLong)),
            Ok(line) => Ok(line.map(Frame::Line)),
            Err(LinesCodecError::MaxLineLengthExceeded) => Ok(Some(Frame::TooLong)),
            // the codec does no I/O of its own: its only I/O error is the UTF-8 check, made
            // after the line was taken out of the buffer
            Err(LinesCodecError::Io(_)) => Ok(Some(Frame::NotUtf8)),
        }
    }
}

impl Decoder for Lines {
    type Item = Frame;
    type Error = io::Error;

    fn decode(&mut self, buf: &mut BytesMut) -> Result<Option<Frame>, io::Error> {
        let r = self.0.decode(buf);
        self.frame(r)
    }

    fn decode_eof(&mut self, buf: &mut BytesMut) -> Result<Option<Frame>, io::Error> {
        let r = self.0.decode_eof(buf);
        self.frame(r)
    }
}

/// The connection's reader, with the instant it last read a byte (or was accepted): what
/// `tcp_idle_timeout_seconds` counts from.
struct LastRead {
    stream: TcpStream,
    last: Instant,
}

impl LastRead {
    fn new(stream: TcpStream) -> LastRead {
        LastRead {
            stream,
            last: Instant::now(),
        }
    }
}

impl tokio::io::AsyncRead for LastRead {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<io::Result<()>> {
        let before = buf.filled().len();
        let this = &mut *self;
        let poll = std::pin::Pin::new(&mut this.stream).poll_read(cx, buf);
        if buf.filled().len() > before {
            this.last = Instant::now();
        }
        poll
    }
}

/// Complete lines read but not yet applied: `text` holds them, each ending in `\n`, the first
/// being line `first_line` of the connection.
struct Pending {
    text: String,
    first_line: usize,
    lines: usize,
}

async fn handle(
    stream: TcpStream,
    mut bad: BadLines,
    state: Arc<AppState>,
    mut shutdown: watch::Receiver<bool>,
) {
    let max = state.config.ingest.tcp_max_line_bytes;
    let idle = Duration::from_secs_f64(state.config.server.tcp_idle_timeout_seconds);
    let mut frames = FramedRead::new(LastRead::new(stream), Lines::new(max));
    let mut pending = Pending {
        text: String::with_capacity(1024),
        first_line: 1,
        lines: 0,
    };
    loop {
        // a connection that sends nothing for `tcp_idle_timeout_seconds` is closed: silent
        // sockets must not hold connection slots forever. Nothing means no byte: a client
        // still sending its line (a byte at a time) is not idle, so the wait runs from the
        // last byte read (it timed whole lines, and cut such a client; then it restarted a
        // whole timeout when the buffer had changed at any time during the last, and a half
        // line sent once held its slot for up to twice the timeout).
        // `FramedRead::next` is cancel safe: what it read stays in the buffer.
        let frame = loop {
            let deadline = tokio::time::Instant::from_std(frames.get_ref().last + idle);
            tokio::select! {
                f = tokio::time::timeout_at(deadline, frames.next()) => match f {
                    Ok(f) => break Some(f),
                    Err(_) if frames.get_ref().last.elapsed() < idle => {}
                    Err(_) => {
                        tracing::debug!(peer = %bad.peer, "tcp connection idle, closing");
                        break None;
                    }
                },
                _ = shutdown.wait_for(|s| *s) => break None,
            }
        };
        let Some(frame) = frame else {
            // a line begun but never ended (idle, or the daemon stopping) is refused and
            // counted, not dropped without a word; at the end of the stream it is applied
            if frames
                .read_buffer()
                .iter()
                .any(|b| !b.is_ascii_whitespace())
            {
                apply(&state, &mut pending, &mut bad).await;
                state.metrics.reject(RejectReason::BadLine, 1);
                let line_no = pending.first_line + pending.lines;
                bad.record(line_no, "line cut off: the connection went idle (or the daemon stopped) before its newline");
            }
            break;
        };
        let frame = match frame {
            None => break,
            Some(Ok(f)) => f,
            Some(Err(e)) => {
                tracing::debug!(peer = %bad.peer, error = %e, "tcp read failed");
                break;
            }
        };
        let line_no = pending.first_line + pending.lines;
        let refused = match frame {
            Frame::Line(line) => {
                pending.text.push_str(&line);
                pending.text.push('\n');
                pending.lines += 1;
                // More complete lines already buffered: take them before going to the blocking
                // pool. (After a `Line` the codec is not discarding, so a newline in its buffer
                // means the next frame needs no read.)
                if pending.text.len() < MAX_BATCH_BYTES && frames.read_buffer().contains(&b'\n') {
                    continue;
                }
                apply(&state, &mut pending, &mut bad).await;
                continue;
            }
            Frame::TooLong => format!("line longer than {max} bytes"),
            Frame::NotUtf8 => "invalid UTF-8".to_string(),
        };
        // apply the lines before it, so the pending lines stay consecutive
        apply(&state, &mut pending, &mut bad).await;
        state.metrics.reject(RejectReason::BadLine, 1);
        bad.record(line_no, &refused);
        pending.first_line = line_no + 1;
    }
    apply(&state, &mut pending, &mut bad).await;
}

/// Parses and applies the pending lines on the blocking pool, then records the refused ones;
/// `pending` is left empty (its buffer reused), starting after the lines applied.
async fn apply(state: &Arc<AppState>, pending: &mut Pending, bad: &mut BadLines) {
    if pending.lines == 0 {
        return;
    }
    let text = std::mem::take(&mut pending.text);
    let first = pending.first_line;
    let st = state.clone();
    let done = tokio::task::spawn_blocking(move || {
        let refused = process_lines(&st, &text, first);
        (text, refused)
    })
    .await;
    match done {
        Ok((mut text, refused)) => {
            for (line, msg) in refused {
                bad.record(line, &msg);
            }
            text.clear();
            pending.text = text;
        }
        Err(e) => tracing::error!(error = %e, "tcp ingestion task failed"),
    }
    pending.first_line += pending.lines;
    pending.lines = 0;
}

/// Applies each `\n`-terminated line of `text` (the first is line `first_line`) on its own;
/// returns the refused lines with their messages (already counted).
fn process_lines(state: &AppState, text: &str, first_line: usize) -> Vec<(usize, String)> {
    let mut refused = Vec::new();
    for (i, raw) in text.split_terminator('\n').enumerate() {
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
fn process(state: &AppState, text: &str, line_no: usize) -> Option<(Option<RejectReason>, String)> {
    let bad_line = |msg: String| Some((Some(RejectReason::BadLine), msg));
    // the codec took off one `\r`; more are trimmed as before the codec was used
    let text = text.trim_end_matches('\r');
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
        // one line, one gate
        max_gates: usize::MAX,
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
        Err(IngestError::TooManyGates(r)) => {
            Some((None, format!("gate limit reached, `{}` refused", r.gate)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every frame of `input` as [`FramedRead`] would decode it, the end of the stream included.
    fn frames(input: &[u8], max: usize) -> Vec<Frame> {
        let mut codec = Lines::new(max);
        let mut buf = BytesMut::from(input);
        let mut out = Vec::new();
        while let Some(f) = codec.decode(&mut buf).unwrap() {
            out.push(f);
        }
        while let Some(f) = codec.decode_eof(&mut buf).unwrap() {
            out.push(f);
        }
        out
    }

    /// A log sink for the test's subscriber.
    #[derive(Clone, Default)]
    struct Sink(Arc<std::sync::Mutex<Vec<u8>>>);

    impl io::Write for Sink {
        fn write(&mut self, b: &[u8]) -> io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    fn listener_log() -> Arc<Mutex<LogLimiter>> {
        Arc::new(Mutex::new(LogLimiter::new(BAD_LINE_LOG_INTERVAL)))
    }

    fn connection(log: &Arc<Mutex<LogLimiter>>, port: u16) -> BadLines {
        BadLines {
            peer: std::net::SocketAddr::from(([127, 0, 0, 1], port)),
            count: 0,
            log: log.clone(),
        }
    }

    /// What `f` logs, as text without colours.
    fn logged(f: impl FnOnce()) -> String {
        let sink = Sink::default();
        let w = sink.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(move || w.clone())
            .with_ansi(false)
            .finish();
        tracing::subscriber::with_default(subscriber, f);
        let out = sink.0.lock().unwrap().clone();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn a_client_that_reconnects_for_every_bad_line_logs_once_per_interval() {
        let log = listener_log();
        let out = logged(|| {
            // 100 connections of one bad line each, within one interval
            for port in 0..100 {
                connection(&log, 1000 + port).record(1, "invalid line `x`");
            }
        });
        assert_eq!(out.trim_end().lines().count(), 1, "{out}");
        // the next line logged says how many were held back
        assert_eq!(
            log.lock()
                .unwrap()
                .allow(Instant::now() + BAD_LINE_LOG_INTERVAL),
            Some(99)
        );
    }

    #[test]
    fn a_bad_line_reaches_the_log_escaped_and_cut() {
        let raw = format!("m,gate=g1 force=1\r\x1b[2KFAKE{}", "y".repeat(1000));
        let out = logged(|| {
            connection(&listener_log(), 9).record(1, &format!("invalid line `{raw}`"));
        });
        assert!(out.contains("bad line on tcp listener"), "{out}");
        assert!(!out.contains('\r') && !out.contains('\x1b'), "{out:?}");
        assert!(out.contains("\\r\\u{1b}[2KFAKE"), "{out}");
        // one line, the client's part cut
        assert_eq!(out.trim_end().lines().count(), 1, "{out}");
        assert!(out.len() < 600, "{}", out.len());
    }

    #[test]
    fn refused_lines_become_frames_and_framing_goes_on() {
        let mut input = b"ok\r\n".to_vec();
        input.extend(vec![b'x'; 10]); // exactly the maximum: kept
        input.push(b'\n');
        input.extend(vec![b'y'; 25]); // over it: discarded up to its newline
        input.extend(b"\nnext\n\xff\xfe\nlast");
        let line = |s: &str| Frame::Line(s.to_string());
        assert_eq!(
            frames(&input, 10),
            vec![
                line("ok"),
                line("xxxxxxxxxx"),
                Frame::TooLong,
                line("next"),
                Frame::NotUtf8,
                line("last"),
            ]
        );
    }

    /// The bound counts the line, not its end: a CRLF line of exactly the maximum is kept (it
    /// was refused, its `\r` counted), one byte more is refused with or without the `\r`.
    #[test]
    fn the_line_bound_does_not_count_a_crlf_line_end() {
        let mut input = vec![b'x'; 10];
        input.extend(b"\r\n");
        input.extend(vec![b'y'; 11]);
        input.extend(b"\r\n");
        input.extend(vec![b'z'; 11]);
        input.extend(b"\nend\r\n");
        assert_eq!(
            frames(&input, 10),
            vec![
                Frame::Line("xxxxxxxxxx".into()),
                Frame::TooLong,
                Frame::TooLong,
                Frame::Line("end".into()),
            ]
        );
    }

    #[test]
    fn an_over_long_line_cut_by_the_end_of_the_stream_is_dropped() {
        let mut input = b"ok\n".to_vec();
        input.extend(vec![b'z'; 30]);
        assert_eq!(
            frames(&input, 10),
            vec![Frame::Line("ok".into()), Frame::TooLong]
        );
    }
}
