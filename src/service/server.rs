//! The daemon: HTTP server, raw TCP listener, stale-data ticker, worker pool; graceful shutdown.
//!
//! Shutdown: ONE deadline, `server.shutdown_grace_seconds` after the stop signal, bounds the
//! whole drain. Stop accepting (HTTP and TCP); in-flight requests and TCP connections finish
//! until the deadline; pending identification jobs are abandoned and in-flight ones get until
//! [`NOTIFY_RESERVE`] before the deadline; the notifier flushes until the deadline. Each drain
//! takes what is left, never a grace period of its own, so the process exits one grace period
//! after SIGTERM whatever is stuck (the systemd unit's `TimeoutStopSec` relies on it).

use std::future::Future;
use std::sync::atomic::Ordering;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, SystemTime};

use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::time::Instant;

use super::api;
use super::config::{Config, HEALTH_MAX_CONNECTIONS};
use super::listen::{self, HttpLimits};
use super::state::AppState;
use super::storage::Persistence;
use super::tcp;
use super::worker::{AnalyzerMap, WindowAnalyzer};

/// Interval of the stale-data check.
pub const STALE_CHECK_INTERVAL: Duration = Duration::from_secs(1);

/// Part of the grace period (at most a quarter of it) the workers leave to the notifier, so an
/// alert raised by the last identification still goes out before the deadline.
pub const NOTIFY_RESERVE: Duration = Duration::from_secs(1);

/// Bound listeners (bound by the caller, so tests can use port 0).
#[derive(Debug)]
pub struct Listeners {
    /// HTTP.
    pub http: TcpListener,
    /// Raw TCP line protocol, if enabled.
    pub tcp: Option<TcpListener>,
    /// The probes' own port (`server.health_listen`), if enabled.
    pub health: Option<TcpListener>,
}

impl Listeners {
    /// Binds `server.listen`, and `server.tcp_listen` and `server.health_listen` when set. An
    /// error names the key and the address (`server.listen 0.0.0.0:9464: cannot bind: Address
    /// already in use`): the OS's message alone did not say which of the ports clashed.
    pub async fn bind(config: &Config) -> anyhow::Result<Listeners> {
        let http = bind_named("server.listen", &config.server.listen).await?;
        let tcp = if config.server.tcp_listen.is_empty() {
            None
        } else {
            Some(bind_named("server.tcp_listen", &config.server.tcp_listen).await?)
        };
        let health = if config.server.health_listen.is_empty() {
            None
        } else {
            Some(bind_named("server.health_listen", &config.server.health_listen).await?)
        };
        Ok(Listeners { http, tcp, health })
    }

    /// The HTTP listener alone (no raw TCP, no health port): the demo's, the benches' and most
    /// tests'.
    pub fn http_only(http: TcpListener) -> Listeners {
        Listeners {
            http,
            tcp: None,
            health: None,
        }
    }
}

/// Binds `addr`, the value of the configuration key `key`; an error names both, with the OS's
/// reason without its code (`(os error 98)` tells an operator nothing more).
async fn bind_named(key: &str, addr: &str) -> anyhow::Result<TcpListener> {
    TcpListener::bind(addr).await.map_err(|e| {
        let reason = e.to_string();
        let reason = match reason.rfind(" (os error ") {
            Some(i) if reason.ends_with(')') => &reason[..i],
            _ => &reason,
        };
        anyhow::anyhow!("{key} {addr}: cannot bind: {reason}")
    })
}

/// Builds the state and the router without serving (for tests with `oneshot`).
pub fn build_app(
    config: Config,
    analyzer: Arc<dyn WindowAnalyzer>,
) -> anyhow::Result<(axum::Router, Arc<AppState>)> {
    let state = AppState::new(config, analyzer)?;
    Ok((api::router(state.clone()), state))
}

/// Runs the daemon with the real analyzers and the store of `[storage]` (`storage.path` as
/// given: the caller resolves a relative one) until `shutdown` resolves. A store that cannot
/// be opened is an error naming the file: no silent in-memory fallback.
pub async fn run(
    config: Config,
    listeners: Listeners,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let analyzer = Arc::new(AnalyzerMap::from_config(&config)?);
    let (storage, lead) = (config.storage.clone(), config.sample_lead_bound());
    let persistence = tokio::task::spawn_blocking(move || {
        Persistence::open(std::path::Path::new(&storage.path), &storage, lead)
    })
    .await
    .map_err(|e| anyhow::anyhow!("opening the store: {e}"))??;
    run_with_persistence(config, listeners, analyzer, Some(persistence), shutdown).await
}

/// Runs the daemon with the given analyzer and no store until `shutdown` resolves.
pub async fn run_with_analyzer(
    config: Config,
    listeners: Listeners,
    analyzer: Arc<dyn WindowAnalyzer>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    run_with_persistence(config, listeners, analyzer, None, shutdown).await
}

/// Runs the daemon with the given analyzer and store until `shutdown` resolves. At shutdown
/// the store is flushed (the notifier's last acknowledgements and alert states included) and
/// checkpointed within the same deadline; an error when either did not complete (the `.db`
/// file alone then does not hold every write: `serve` exits 1).
pub async fn run_with_persistence(
    config: Config,
    listeners: Listeners,
    analyzer: Arc<dyn WindowAnalyzer>,
    persistence: Option<Persistence>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let grace = Duration::from_secs_f64(config.server.shutdown_grace_seconds);
    // restoring reads the store: off the executor
    let state = tokio::task::spawn_blocking(move || {
        AppState::with_persistence(config, analyzer, persistence)
    })
    .await
    .map_err(|e| anyhow::anyhow!("starting: {e}"))??;
    let router = api::router(state.clone());
    let (stop_tx, stop_rx) = watch::channel(false);
    // when the stop signal came: the one shutdown deadline is counted from it
    let stopped_at = Arc::new(OnceLock::new());
    // the store's failed writes when it came: those after it are lost at the shutdown
    let failed_at_stop = Arc::new(OnceLock::new());
    {
        let stopped_at = stopped_at.clone();
        let failed_at_stop = failed_at_stop.clone();
        let persistence = state.persistence.clone();
        tokio::spawn(async move {
            shutdown.await;
            if let Some(p) = persistence {
                let _ = failed_at_stop.set(p.writer.failed_writes());
            }
            let _ = stopped_at.set(Instant::now());
            let _ = stop_tx.send(true);
        });
    }

    let ticker = {
        let state = state.clone();
        let mut stop = stop_rx.clone();
        tokio::spawn(async move {
            let mut interval = tokio::time::interval(STALE_CHECK_INTERVAL);
            interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tokio::select! {
                    _ = interval.tick() => state.tick(SystemTime::now()),
                    _ = stop.wait_for(|s| *s) => break,
                }
            }
        })
    };
    let tcp_task = listeners.tcp.map(|l| {
        if let Ok(a) = l.local_addr() {
            tracing::info!(addr = %a, "line protocol TCP listener up");
        }
        tokio::spawn(tcp::serve(l, state.clone(), stop_rx.clone()))
    });
    if let Ok(a) = listeners.http.local_addr() {
        tracing::info!(addr = %a, "HTTP listener up");
        if !a.ip().is_loopback() {
            tracing::warn!(
                addr = %a,
                "plain HTTP on a non-loopback address: bearer tokens and data cross the network \
                 in clear; put a TLS reverse proxy in front (docs/security.md) or listen on 127.0.0.1"
            );
            if state.config.server.auth_tokens.is_empty() {
                let gates = if state.config.server.accept_unknown_gates {
                    ", create gates"
                } else {
                    ""
                };
                tracing::warn!(
                    addr = %a,
                    "no authentication on a non-loopback address: server.auth_tokens is empty, \
                     so anyone who reaches this port can ingest samples{gates} and read the API; \
                     set server.auth_tokens (or GATEWATCH_AUTH_TOKENS), or set server.listen \
                     to 127.0.0.1 (docs/security.md)"
                );
            }
        }
    }
    state.listeners_up.store(true, Ordering::SeqCst);
    let limits = HttpLimits {
        max_connections: state.config.server.max_http_connections,
        cap_name: "server.max_http_connections",
        header_read_timeout: Duration::from_secs_f64(
            state.config.server.http_header_read_timeout_seconds,
        ),
        send_timeout: Duration::from_secs_f64(state.config.server.request_timeout_seconds),
    };
    let refused = {
        let state = state.clone();
        move || state.metrics.http_connections_rejected.inc()
    };
    let cut = |listener: &'static str| {
        let state = state.clone();
        move |why: listen::Cut| {
            state
                .metrics
                .http_connections_cut
                .with_label_values(&[listener, why.as_str()])
                .inc()
        }
    };
    let health_task = listeners.health.map(|l| {
        if let Ok(a) = l.local_addr() {
            tracing::info!(addr = %a, "health listener up (/healthz, /readyz, /metrics)");
        }
        let limits = HttpLimits {
            max_connections: HEALTH_MAX_CONNECTIONS,
            cap_name: "HEALTH_MAX_CONNECTIONS of server.health_listen",
            ..limits
        };
        let refused = {
            let state = state.clone();
            move || state.metrics.health_connections_rejected.inc()
        };
        let router = api::health_router(state.clone());
        let serve = listen::serve(l, router, limits, refused, cut("health"), stop_rx.clone());
        tokio::spawn(async move {
            // nothing else watches it: a health port gone dead says so (the probes then fail)
            if let Err(e) = serve.await {
                tracing::error!(error = %e, "health listener (server.health_listen) failed");
            }
        })
    });
    let mut serve_task = tokio::spawn(listen::serve(
        listeners.http,
        router,
        limits,
        refused,
        cut("http"),
        stop_rx.clone(),
    ));
    // In-flight requests get until the deadline; a client that never finishes its request must
    // not hold the shutdown forever.
    let mut stop = stop_rx.clone();
    let joined = |r: Result<std::io::Result<()>, tokio::task::JoinError>| {
        r.unwrap_or_else(|e| Err(std::io::Error::other(e)))
    };
    let deadline = || stopped_at.get().copied().unwrap_or_else(Instant::now) + grace;
    let served = tokio::select! {
        // drained quickly after the stop signal, or failed before any
        r = &mut serve_task => joined(r),
        // (the watch guard is dropped at once: it must not live across the awaits below)
        _ = async { let _ = stop.wait_for(|s| *s).await; } => {
            match tokio::time::timeout_at(deadline(), &mut serve_task).await {
                Ok(r) => joined(r),
                Err(_) => {
                    tracing::warn!("HTTP connections still open at the shutdown deadline, closing them");
                    serve_task.abort();
                    Ok(())
                }
            }
        }
    };
    let deadline = deadline();
    state.listeners_up.store(false, Ordering::SeqCst);
    if let Some(t) = tcp_task {
        let _ = tokio::time::timeout_at(deadline, t).await;
    }
    if let Some(mut t) = health_task {
        // a probe or a scrape is one short request: what is still open at the deadline goes
        if tokio::time::timeout_at(deadline, &mut t).await.is_err() {
            t.abort();
        }
    }
    let _ = ticker.await;
    let workers_until = deadline - NOTIFY_RESERVE.min(grace / 4);
    let (abandoned, clean) = state
        .pool()
        .shutdown(workers_until.saturating_duration_since(Instant::now()))
        .await;
    tracing::info!(
        abandoned_jobs = abandoned,
        workers_stopped = clean,
        "worker pool stopped"
    );
    let flushed = state
        .shutdown_notifier(deadline.saturating_duration_since(Instant::now()))
        .await;
    tracing::info!(flushed, "alert notifier stopped");
    // Exit 0 promises that the .db file alone holds every identification counted before the
    // signal (docs/operations.md, "Shutdown"): a flush cut by the deadline or a checkpoint
    // that did not complete (full disk, a reader on the WAL, the file deleted) breaks that
    // promise, so it is an error (exit 1), not a warning under an exit 0.
    let mut store_result = Ok(());
    if let Some(p) = state.persistence.clone() {
        // at least a second for the last commit, even when the grace period is used up
        let within = deadline
            .saturating_duration_since(Instant::now())
            .max(Duration::from_secs(1));
        let location = p.store.location();
        let until = std::time::Instant::now() + within;
        let failed_before = failed_at_stop.get().copied().unwrap_or(0);
        // The flush and the checkpoint share what is left of the deadline. When writes were
        // lost (still queued at the deadline, or failed since the stop signal) the checkpoint
        // is skipped: whatever failed them (a lock another process holds, a stalled or full
        // disk) would hold the checkpoint too, which waited for the writer's connection and
        // then SQLite's 5 s busy timeout, past the deadline by tens of seconds.
        let flushed = tokio::task::spawn_blocking(move || {
            let flushed = p.writer.close(within);
            // the writer is closed: nothing is written after the lease is released
            p.release();
            let failed = p.writer.failed_writes().saturating_sub(failed_before);
            if !flushed || failed > 0 {
                return Err((p.writer.pending(), failed));
            }
            let left = until
                .saturating_duration_since(std::time::Instant::now())
                .max(Duration::from_millis(100));
            Ok(p.checkpoint(left))
        })
        .await;
        store_result = match flushed {
            Ok(Ok(Ok(()))) => {
                tracing::info!("store flushed and checkpointed");
                Ok(())
            }
            Ok(Err((pending, failed))) => Err(anyhow::anyhow!(
                "store {location}: {} writes not committed at shutdown ({failed} failed since \
                 the stop signal, {pending} still queued when the {:.1} s left for the store \
                 ran out; another process holding the database's lock, or a stalled or full \
                 disk: see the errors above): they are lost; checkpoint skipped, keep the -wal \
                 file with the .db",
                pending + failed,
                within.as_secs_f64()
            )),
            // SQLite's own words ("database or disk is full") do not name the file
            Ok(Ok(Err(e))) if !e.to_string().contains(location.as_str()) => {
                Err(anyhow::anyhow!("store {location}: at shutdown: {e}"))
            }
            Ok(Ok(Err(e))) => Err(anyhow::anyhow!("at shutdown: {e}")),
            Err(e) => Err(anyhow::anyhow!("store {location}: flush failed: {e}")),
        };
        if let Err(e) = &store_result {
            tracing::error!("{e:#}");
        }
    }
    tracing::info!("shut down");
    served.map_err(|e| anyhow::anyhow!("HTTP server failed: {e}"))?;
    store_result
}
