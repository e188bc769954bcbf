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
//! - graceful shutdown: on the stop signal, accepting ends and each connection finishes its
//!   request in progress, then closes; `serve` returns when every connection has ended (the
//!   caller bounds that wait with the shutdown deadline).
//!
//! HTTP/1 only, as before (axum was built without HTTP/2).

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};
use tower::ServiceExt;

/// The bounds of the HTTP listener (from `[server]`).
#[derive(Debug, Clone, Copy)]
pub struct HttpLimits {
    /// Most simultaneous connections (`server.max_http_connections`).
    pub max_connections: usize,
    /// Time to send a request's headers; also the keep-alive idle timeout
    /// (`server.http_header_read_timeout_seconds`).
    pub header_read_timeout: Duration,
}

/// Pause after a failed `accept` (typically EMFILE: out of file descriptors), so the loop does
/// not spin while connections close.
const ACCEPT_ERROR_PAUSE: Duration = Duration::from_millis(50);

/// Serves `router` on `listener` until `stop` turns true, then waits for the open connections
/// to finish. `refused` is called for each connection closed at accept because of the cap.
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: HttpLimits,
    refused: impl Fn() + Send + 'static,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout);
    // every connection task holds a receiver: `closed()` resolves when the last one ends
    let (open_tx, open_rx) = watch::channel(());
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = async { let _ = stop.wait_for(|s| *s).await; } => break,
        };
        let (stream, peer) = match accepted {
            Ok(x) => x,
            Err(e) => {
                tracing::warn!(error = %e, "http accept failed");
                tokio::time::sleep(ACCEPT_ERROR_PAUSE).await;
                continue;
            }
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            refused();
            tracing::warn!(%peer, "http connection limit (server.max_http_connections) reached, closing");
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let router = router.clone();
        let service = hyper::service::service_fn(move |req: hyper::Request<Incoming>| {
            router.clone().oneshot(req)
        });
        let conn = builder.serve_connection(TokioIo::new(stream), service);
        let mut stop = stop.clone();
        let open = open_rx.clone();
        tokio::spawn(async move {
            let mut conn = std::pin::pin!(conn);
            let ended = tokio::select! {
                r = conn.as_mut() => r,
                _ = async { let _ = stop.wait_for(|s| *s).await; } => {
                    conn.as_mut().graceful_shutdown();
                    conn.await
                }
            };
            if let Err(e) = ended {
                tracing::debug!(%peer, error = %e, "http connection ended with an error");
            }
            drop((slot, open));
        });
    }
    drop(open_rx);
    drop(listener);
    open_tx.closed().await;
    Ok(())
}
