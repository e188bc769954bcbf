//! The daemon: HTTP server, raw TCP listener, stale-data ticker, worker pool; graceful shutdown.
//!
//! Shutdown order: stop accepting (HTTP and TCP), let in-flight requests finish, abandon pending
//! identification jobs and give in-flight ones `server.shutdown_grace_seconds`, then flush the
//! notifier within the rest of the grace period.

use std::future::{Future, IntoFuture};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use tokio::net::TcpListener;
use tokio::sync::watch;

use super::api;
use super::config::Config;
use super::ingest::tcp;
use super::state::AppState;
use super::worker::{AnalyzerMap, WindowAnalyzer};

/// Interval of the stale-data check.
pub const STALE_CHECK_INTERVAL: Duration = Duration::from_secs(1);

/// Bound listeners (bound by the caller, so tests can use port 0).
#[derive(Debug)]
pub struct Listeners {
    /// HTTP.
    pub http: TcpListener,
    /// Raw TCP line protocol, if enabled.
    pub tcp: Option<TcpListener>,
}

impl Listeners {
    /// Binds `server.listen` and `server.tcp_listen` (when set).
    pub async fn bind(config: &Config) -> std::io::Result<Listeners> {
        let http = TcpListener::bind(&config.server.listen).await?;
        let tcp = if config.server.tcp_listen.is_empty() {
            None
        } else {
            Some(TcpListener::bind(&config.server.tcp_listen).await?)
        };
        Ok(Listeners { http, tcp })
    }
}

/// Builds the state and the router without serving (for tests with `oneshot`).
pub fn build_app(
    config: Config,
    analyzer: Arc<dyn WindowAnalyzer>,
) -> anyhow::Result<(axum::Router, Arc<AppState>)> {
    let state = AppState::new(config, analyzer)?;
    Ok((api::router(state.clone()), state))
}

/// Runs the daemon with the real analyzers until `shutdown` resolves.
pub async fn run(
    config: Config,
    listeners: Listeners,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let analyzer = Arc::new(AnalyzerMap::from_config(&config)?);
    run_with_analyzer(config, listeners, analyzer, shutdown).await
}

/// Runs the daemon with the given analyzer until `shutdown` resolves.
pub async fn run_with_analyzer(
    config: Config,
    listeners: Listeners,
    analyzer: Arc<dyn WindowAnalyzer>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let grace = Duration::from_secs_f64(config.server.shutdown_grace_seconds);
    let (router, state) = build_app(config, analyzer)?;
    let (stop_tx, stop_rx) = watch::channel(false);
    tokio::spawn(async move {
        shutdown.await;
        let _ = stop_tx.send(true);
    });

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
    }
    state.listeners_up.store(true, Ordering::SeqCst);
    let mut stop = stop_rx.clone();
    let mut serve_task = tokio::spawn(
        axum::serve(listeners.http, router.into_make_service())
            .with_graceful_shutdown(async move {
                let _ = stop.wait_for(|s| *s).await;
            })
            .into_future(),
    );
    // In-flight requests get the grace period; a client that never finishes its request must
    // not hold the shutdown forever.
    let mut stop = stop_rx.clone();
    let served: std::io::Result<()> = tokio::select! {
        r = &mut serve_task => r.unwrap_or_else(|e| Err(std::io::Error::other(e))),
        _ = async {
            let _ = stop.wait_for(|s| *s).await;
            tokio::time::sleep(grace).await;
        } => {
            tracing::warn!("HTTP connections still open after the grace period, closing them");
            serve_task.abort();
            Ok(())
        }
    };
    state.listeners_up.store(false, Ordering::SeqCst);
    let deadline = Instant::now() + grace;
    if let Some(t) = tcp_task {
        let _ = tokio::time::timeout(grace, t).await;
    }
    let _ = ticker.await;
    let (abandoned, clean) = state
        .pool()
        .shutdown(deadline.saturating_duration_since(Instant::now()))
        .await;
    tracing::info!(
        abandoned_jobs = abandoned,
        workers_stopped = clean,
        "worker pool stopped"
    );
    // pending notifications get the rest of the grace period (and at least a second, so that
    // an alert raised by the last identification still goes out)
    let rest = deadline
        .saturating_duration_since(Instant::now())
        .max(Duration::from_secs(1).min(grace));
    let flushed = state.shutdown_notifier(rest).await;
    tracing::info!(flushed, "alert notifier stopped");
    tracing::info!("shut down");
    served.map_err(|e| anyhow::anyhow!("HTTP server failed: {e}"))
}
