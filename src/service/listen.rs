//! The HTTP accept loop: hyper's HTTP/1 connection served with the bounds `axum::serve` does
//! not offer (it has no header timeout and no connection cap):
//!
//! - at most `server.max_http_connections` connections; one more is closed at accept and
//!   counted (`gatewatch_http_connections_rejected_total`), as Prometheus'
//!   `--web.max-connections` does. A slot frees when its connection ends, so the cap cannot be
//!   held forever by silent clients: see the next point.
//! - `server.http_header_read_timeout_seconds`: a client must send a request's headers within it,
//!   counted from the moment the connection waits for them. hyper starts this timer whenever the
//!   connection waits for a request head, so it is also the keep-alive idle timeout: a slowloris
//!   or an idle keep-alive connection is closed after it.
//! - a request head of at most [`MAX_REQUEST_HEAD_BYTES`] (hyper's read buffer): a longer one
//!   gets 431, so a connection holds at most that while its client sends a head.
//! - graceful shutdown: on the stop signal, accepting ends and each connection finishes its
//!   request in progress, then closes; `serve` returns when every connection has ended (the
//!   caller bounds that wait with the shutdown deadline).
//!
//! - an answer given before its request's body was read (a refusal: 413, 503 over the body
//!   budget, 401, 415, 404, ...) says `Connection: close` (`TrackedBody`): the unread rest of
//!   the body makes the connection unusable, and a keep-alive client that is not told sees its
//!   next request fail.
//! - lingering close (`linger`), as nginx's `lingering_close`: when a connection ends, its
//!   write side is shut first (the client sees the end of the answer), then what the client
//!   still sends is read and discarded for at most [`LINGER_TIME`], until the client closes.
//!   hyper, left alone, closes the socket with the rest of a refused body unread; the kernel then
//!   answers with a reset, and a reset also discards, on the client's side, the answer the
//!   client had not read yet: a client still writing a 4 MB body saw "broken pipe" or
//!   "connection reset" instead of its 503 and `Retry-After` (issue 12, point 7).
//!
//! - `server.request_timeout_seconds` is also the send timeout (`SendTimeout`): a connection
//!   whose client takes none of its answer for that long is closed. hyper has no write timeout,
//!   and the request timeout (tower's `TimeoutLayer`) ends when the answer's head is ready, not
//!   its body: a client that asked for a day of history and read nothing kept the answer (tens
//!   of megabytes) and its connection for as long as it kept the socket open.
//!
//! - a deadline on the whole transfer of an answer whose handler asks for one
//!   ([`TransferDeadline`], in every request's extensions): when it passes, the connection is
//!   closed and the answer dropped. The send timeout restarts at every write that goes
//!   through, so a client that reads slowly but steadily is not cut by it: four such clients
//!   held the four history places (`history::MAX_CONCURRENT_HISTORY`) for as long as their
//!   transfers lasted (an hour for a day's history at 10 KB/s), and every other history
//!   request got 503 meanwhile. The history route arms it
//!   (`history::HISTORY_TRANSFER_TIMEOUTS`); other routes do not. The connection task, not the
//!   body, watches it: hyper does not poll a body while the socket is full, so a timer in the
//!   body would not fire while the client reads slowly.
//!
//! HTTP/1 only, as before (axum was built without HTTP/2).

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::http::{header, HeaderValue};
use axum::Router;
use hyper::body::{Body, Bytes, Frame, Incoming, SizeHint};
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};
use tower::ServiceExt;

use super::log_limit::{LogLimiter, ACCEPT_WARNING_INTERVAL};

/// The bounds of the HTTP listener (from `[server]`).
#[derive(Debug, Clone, Copy)]
pub struct HttpLimits {
    /// Most simultaneous connections (`server.max_http_connections`).
    pub max_connections: usize,
    /// What sets `max_connections`, for the log line of a refusal: the operator raises that.
    pub cap_name: &'static str,
    /// Time to send a request's headers; also the keep-alive idle timeout
    /// (`server.http_header_read_timeout_seconds`).
    pub header_read_timeout: Duration,
    /// Longest time a write of an answer may wait for the client to take bytes before the
    /// connection is closed (`server.request_timeout_seconds`, [`SendTimeout`]).
    pub send_timeout: Duration,
}

/// Longest time a closing connection keeps reading (and discarding) what its client still
/// sends, so that the client reads the answer instead of a reset (see the module
/// documentation). On loopback or a LAN a client sends megabytes in it; a client that keeps
/// sending longer still gets its reset, and meanwhile its connection holds a slot of
/// `max_http_connections`, so the bound also caps what a flood of refused bodies can hold. nginx
/// lingers up to 30 s (`lingering_time`); 5 s is its idle `lingering_timeout`.
pub const LINGER_TIME: Duration = Duration::from_secs(5);

/// Largest request head (request line and headers), and hyper's read buffer: a longer head
/// gets 431 and the connection ends. hyper stops reading a head once the buffer holds this
/// much, and one read adds at most as much again, so a connection holds under 2 x 64 KiB while
/// its client sends a head: 64 MiB over the 512 connections of `server.max_http_connections`.
/// hyper's own default is about 400 KiB (8 KiB + 100 x 4 KiB), which a head of 100 KiB in
/// one header got through, with up to twice that buffered per connection: 400 MiB over 512
/// connections, which the memory bound of docs/design.md did not count. 64 KiB takes a
/// 60 000-character path (the longest the tests send) and every real client's headers; nginx
/// reads at most 4 x 8 KiB, Node.js 16 KiB.
pub const MAX_REQUEST_HEAD_BYTES: usize = 64 * 1024;

/// Buffer of the lingering read: the discarded bytes go through it, on the connection task.
const LINGER_BUF_BYTES: usize = 16 * 1024;

/// Pause after a failed `accept` (typically EMFILE: out of file descriptors), so the loop does
/// not spin while connections close.
const ACCEPT_ERROR_PAUSE: Duration = Duration::from_millis(50);

/// Why the listener closed a connection while it was sending an answer (the `reason` label of
/// `gatewatch_http_connections_cut_total`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cut {
    /// The client took none of the answer for `server.request_timeout_seconds` ([`SendTimeout`]).
    SendTimeout,
    /// The answer was still being sent at its transfer limit ([`TransferDeadline`]).
    TransferLimit,
}

impl Cut {
    /// Every reason, in label order.
    pub const ALL: [Cut; 2] = [Cut::SendTimeout, Cut::TransferLimit];

    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            Cut::SendTimeout => "send_timeout",
            Cut::TransferLimit => "transfer_limit",
        }
    }
}

/// Serves `router` on `listener` until `stop` turns true, then waits for the open connections
/// to finish. `refused` is called for each connection closed at accept because of the cap,
/// `cut` for each closed while its answer was being sent ([`Cut`]).
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: HttpLimits,
    refused: impl Fn() + Send + 'static,
    cut: impl Fn(Cut) + Send + Sync + 'static,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let cut = Arc::new(cut);
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .max_header_size(MAX_REQUEST_HEAD_BYTES)
        .max_buf_size(MAX_REQUEST_HEAD_BYTES);
    // every connection task holds a receiver: `closed()` resolves when the last one ends
    let (open_tx, open_rx) = watch::channel(());
    let mut refusals = LogLimiter::new(ACCEPT_WARNING_INTERVAL);
    let mut failures = LogLimiter::new(ACCEPT_WARNING_INTERVAL);
    // shared by the connection tasks: a cut is logged once per interval for the listener
    let cuts = Arc::new(Mutex::new(LogLimiter::new(ACCEPT_WARNING_INTERVAL)));
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = async { let _ = stop.wait_for(|s| *s).await; } => break,
        };
        let (stream, peer) = match accepted {
            Ok(x) => x,
            Err(e) => {
                if let Some(held_back) = failures.allow(std::time::Instant::now()) {
                    tracing::warn!(error = %e, held_back, "http accept failed");
                }
                tokio::time::sleep(ACCEPT_ERROR_PAUSE).await;
                continue;
            }
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            refused();
            // counted each (gatewatch_http_connections_rejected_total), logged once per interval
            if let Some(held_back) = refusals.allow(std::time::Instant::now()) {
                tracing::warn!(%peer, held_back, cap = limits.cap_name, "http connection limit reached, closing");
            }
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let router = router.clone();
        let (deadline, mut overdue) = TransferDeadline::new();
        let service = hyper::service::service_fn(move |req: hyper::Request<Incoming>| {
            let router = router.clone();
            let deadline = deadline.clone();
            // boxed: `poll_without_shutdown` (below) wants an `Unpin` future
            Box::pin(async move {
                let (mut req, read) = TrackedBody::wrap(req);
                req.extensions_mut().insert(deadline);
                let mut resp = router.oneshot(req).await?;
                if !read.load(Ordering::Acquire) {
                    resp.headers_mut()
                        .insert(header::CONNECTION, HeaderValue::from_static("close"));
                }
                Ok::<_, std::convert::Infallible>(resp)
            })
        });
        let io = SendTimeout::new(stream, limits.send_timeout);
        let timed_out = io.timed_out.clone();
        let mut conn = builder.serve_connection(TokioIo::new(io), service);
        let mut stop = stop.clone();
        let open = open_rx.clone();
        let cuts = cuts.clone();
        let cut = cut.clone();
        tokio::spawn(async move {
            // without shutdown: the socket comes back to be closed by `linger`
            let served = async {
                tokio::select! {
                    r = std::future::poll_fn(|cx| conn.poll_without_shutdown(cx)) => r,
                    _ = async { let _ = stop.wait_for(|s| *s).await; } => {
                        Pin::new(&mut conn).graceful_shutdown();
                        std::future::poll_fn(|cx| conn.poll_without_shutdown(cx)).await
                    }
                }
            };
            let ended = tokio::select! {
                r = served => Ok(r),
                limit = overdue.passed() => Err(limit),
            };
            match ended {
                Ok(Ok(())) => linger(conn.into_parts().io.into_inner().stream, stop).await,
                // a malformed request, a header timeout, a reset: nothing worth lingering for
                Ok(Err(e)) if timed_out.load(Ordering::Acquire) => {
                    cut(Cut::SendTimeout);
                    log_cut(&cuts, peer, Cut::SendTimeout, limits.send_timeout, &e);
                }
                // a head over the bound or with too many header lines: hyper has answered 431,
                // and the client is still sending its head; closing at once reset the
                // connection before it read the answer (a 200 KB head, or 1000 header lines)
                Ok(Err(e)) if e.is_parse_too_large() => {
                    linger(conn.into_parts().io.into_inner().stream, stop).await
                }
                Ok(Err(e)) => {
                    tracing::debug!(%peer, error = %e, "http connection ended with an error")
                }
                // dropping the connection drops the answer (and what it holds); no linger: the
                // client is still reading, not sending
                Err(limit) => {
                    cut(Cut::TransferLimit);
                    log_cut(&cuts, peer, Cut::TransferLimit, limit, &"");
                }
            }
            drop((slot, open));
        });
    }
    drop(open_rx);
    drop(listener);
    open_tx.closed().await;
    Ok(())
}

/// Logs a connection cut at its answer's transfer deadline, at most once per
/// [`ACCEPT_WARNING_INTERVAL`] for the listener (a slow client per answer would otherwise log at
/// its own pace), with the number of cuts held back.
fn log_cut(
    cuts: &Mutex<LogLimiter>,
    peer: std::net::SocketAddr,
    why: Cut,
    limit: Duration,
    error: &dyn std::fmt::Display,
) {
    let allowed = cuts
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .allow(std::time::Instant::now());
    let Some(held_back) = allowed else {
        return;
    };
    match why {
        Cut::TransferLimit => {
            tracing::warn!(%peer, ?limit, held_back, "an answer was still being sent at its transfer limit (the client reads too slowly), connection closed")
        }
        Cut::SendTimeout => {
            tracing::warn!(%peer, ?limit, held_back, %error, "the client took none of its answer for server.request_timeout_seconds, connection closed")
        }
    }
}

/// A connection's deadline on the transfer of the answer it is sending, in every request's
/// extensions (put there by [`serve`]; a request built without the listener has none, and its
/// answer no deadline). A handler whose answer must not hold its resources for long, however
/// steadily the client reads, arms it for its answer ([`TransferDeadline::arm`]) and puts the
/// guard into the answer's body, which clears it when dropped (sent to the end, or dropped with
/// the connection). When the deadline passes first, the connection task closes the
/// connection, which drops the answer.
#[derive(Clone)]
pub struct TransferDeadline {
    slot: Arc<watch::Sender<Option<Armed>>>,
}

/// A deadline set, and the limit it was set with (for the log).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Armed {
    at: tokio::time::Instant,
    limit: Duration,
}

impl TransferDeadline {
    /// A connection's deadline, not armed, and the receiver its connection task watches.
    fn new() -> (TransferDeadline, Overdue) {
        let (tx, rx) = watch::channel(None);
        (TransferDeadline { slot: Arc::new(tx) }, Overdue(rx))
    }

    /// Bounds the transfer of the answer about to be sent to `limit` from now, until the guard
    /// is dropped. A limit too far to be represented sets no deadline.
    pub fn arm(&self, limit: Duration) -> TransferGuard {
        let armed = tokio::time::Instant::now()
            .checked_add(limit)
            .map(|at| Armed { at, limit });
        self.slot.send_replace(armed);
        TransferGuard {
            slot: self.slot.clone(),
            armed,
        }
    }
}

/// Clears the deadline it set when dropped; put into the answer's body.
pub struct TransferGuard {
    slot: Arc<watch::Sender<Option<Armed>>>,
    armed: Option<Armed>,
}

impl Drop for TransferGuard {
    fn drop(&mut self) {
        // only its own: an HTTP/1 connection sends one answer at a time, but a guard dropped
        // late must not clear the next answer's deadline
        let armed = self.armed;
        self.slot.send_if_modified(|d| {
            let own = *d == armed && armed.is_some();
            if own {
                *d = None;
            }
            own
        });
    }
}

/// The connection task's side of a [`TransferDeadline`].
struct Overdue(watch::Receiver<Option<Armed>>);

impl Overdue {
    /// Resolves with the limit when an armed deadline passes before it is cleared; never while
    /// none is armed.
    async fn passed(&mut self) -> Duration {
        loop {
            let armed = *self.0.borrow_and_update();
            let changed = async {
                if self.0.changed().await.is_err() {
                    // every sender is gone with the connection's service: nothing will arm it
                    std::future::pending::<()>().await;
                }
            };
            match armed {
                Some(a) => tokio::select! {
                    _ = tokio::time::sleep_until(a.at) => return a.limit,
                    _ = changed => {}
                },
                None => changed.await,
            }
        }
    }
}

/// Closes `stream` after its HTTP exchange ended: shuts the write side (the client reads the
/// whole answer and then end-of-file), then reads and discards what the client still sends
/// until it closes, for at most [`LINGER_TIME`], and not past the stop signal (a connection
/// closed by the shutdown has nothing unread). Closing a socket with unread data sends a reset
/// instead of a clean end, and the reset destroys the answer not yet read by the client.
async fn linger(mut stream: TcpStream, mut stop: watch::Receiver<bool>) {
    if stream.shutdown().await.is_err() {
        return;
    }
    let mut buf = vec![0u8; LINGER_BUF_BYTES];
    let drain = async {
        // end-of-file (the client closed) or an error ends it
        while matches!(stream.read(&mut buf).await, Ok(n) if n > 0) {}
    };
    tokio::select! {
        _ = tokio::time::timeout(LINGER_TIME, drain) => {}
        _ = async { let _ = stop.wait_for(|s| *s).await; } => {}
    }
}

/// A connection's socket whose writes fail with [`io::ErrorKind::TimedOut`] once one has
/// waited `limit` for the client to take bytes (its receive window stays full): hyper then ends
/// the connection and drops the answer it was sending. The timer starts when a write finds the
/// socket full and stops at the next write that goes through, so a client that reads, however
/// slowly, is not cut; one that stopped reading is, after `limit`. Reads are untouched (their
/// bound is the header read timeout). "Reads" is as the kernel sees it: Linux wakes a write
/// blocked on a full send buffer once a third of that buffer is free, so a client must take
/// that much within `limit` (a client on loopback, whose 64 KiB segments grow the buffer to
/// 4 MiB, was cut by a 1 s limit while taking 740 KB/s; tests/service_memory.rs,
/// `ask_as_a_network_client`). A slow reader's whole transfer is bounded by
/// [`TransferDeadline`] where a route asks for it.
pub struct SendTimeout {
    stream: TcpStream,
    limit: Duration,
    /// Set while a write waits for room in the socket.
    stalled: Option<Pin<Box<tokio::time::Sleep>>>,
    /// Set once a write has failed for want of room: the connection task tells this cut from
    /// the other ends of a connection (a reset, a malformed request) by it.
    pub timed_out: Arc<AtomicBool>,
}

impl SendTimeout {
    /// `stream`, its writes given `limit` each to find room.
    pub fn new(stream: TcpStream, limit: Duration) -> SendTimeout {
        SendTimeout {
            stream,
            limit,
            stalled: None,
            timed_out: Arc::new(AtomicBool::new(false)),
        }
    }

    /// What a write that returned `polled` means: its result, or, when it waits for room, an
    /// error once the wait has lasted `limit` (the timer's wake-up brings hyper back here).
    fn timed<T>(
        &mut self,
        cx: &mut Context<'_>,
        polled: Poll<io::Result<T>>,
    ) -> Poll<io::Result<T>> {
        if polled.is_ready() {
            self.stalled = None;
            return polled;
        }
        let limit = self.limit;
        let timer = self
            .stalled
            .get_or_insert_with(|| Box::pin(tokio::time::sleep(limit)));
        if timer.as_mut().poll(cx).is_ready() {
            self.stalled = None;
            self.timed_out.store(true, Ordering::Release);
            return Poll::Ready(Err(io::Error::new(
                io::ErrorKind::TimedOut,
                format!(
                    "the client took none of the answer for {:?} (server.request_timeout_seconds)",
                    limit
                ),
            )));
        }
        Poll::Pending
    }
}

impl AsyncRead for SendTimeout {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for SendTimeout {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.stream).poll_write(cx, buf);
        self.timed(cx, polled)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.stream).poll_write_vectored(cx, bufs);
        self.timed(cx, polled)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}

/// A request body that records whether it was read to its end, so that an answer given before
/// that says `Connection: close` (see the module documentation).
struct TrackedBody {
    inner: Incoming,
    /// Set once the body has reached its end (at once for a request without a body).
    read: Arc<AtomicBool>,
}

impl TrackedBody {
    fn wrap(req: hyper::Request<Incoming>) -> (hyper::Request<TrackedBody>, Arc<AtomicBool>) {
        let read = Arc::new(AtomicBool::new(req.body().is_end_stream()));
        let flag = read.clone();
        (req.map(|inner| TrackedBody { inner, read }), flag)
    }
}

impl Body for TrackedBody {
    type Data = Bytes;
    type Error = hyper::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, hyper::Error>>> {
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        if matches!(polled, Poll::Ready(None)) || self.inner.is_end_stream() {
            self.read.store(true, Ordering::Release);
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deadline armed and not cleared passes, with its limit.
    #[tokio::test(start_paused = true)]
    async fn an_armed_deadline_passes_with_its_limit() {
        let (deadline, mut overdue) = TransferDeadline::new();
        let _guard = deadline.arm(Duration::from_secs(300));
        let passed = tokio::time::timeout(Duration::from_secs(301), overdue.passed()).await;
        assert_eq!(passed.ok(), Some(Duration::from_secs(300)));
    }

    /// An answer sent (its guard dropped) before the deadline leaves the connection alone, and
    /// so does a connection that never armed one.
    #[tokio::test(start_paused = true)]
    async fn a_cleared_or_unarmed_deadline_never_passes() {
        let (deadline, mut overdue) = TransferDeadline::new();
        drop(deadline.arm(Duration::from_secs(1)));
        let waited = tokio::time::timeout(Duration::from_secs(3600), overdue.passed()).await;
        assert!(waited.is_err(), "a cleared deadline passed");
        let (_deadline, mut overdue) = TransferDeadline::new();
        let waited = tokio::time::timeout(Duration::from_secs(3600), overdue.passed()).await;
        assert!(waited.is_err(), "a deadline never armed passed");
    }

    /// A guard dropped after the next answer armed the deadline does not clear that answer's.
    #[tokio::test(start_paused = true)]
    async fn a_late_guard_does_not_clear_the_next_answers_deadline() {
        let (deadline, mut overdue) = TransferDeadline::new();
        let first = deadline.arm(Duration::from_secs(10));
        tokio::time::advance(Duration::from_secs(1)).await;
        let _second = deadline.arm(Duration::from_secs(20));
        drop(first);
        let passed = tokio::time::timeout(Duration::from_secs(30), overdue.passed()).await;
        assert_eq!(passed.ok(), Some(Duration::from_secs(20)));
    }
}
