//! Shutdown signals.

/// What the log says when SIGHUP arrives. Many daemons reload their configuration on SIGHUP;
/// gatewatch does not (its gates, workers, listeners and store are built once from it), and
/// SIGHUP's default action would kill the process with no flush of the store (exit 129).
pub const SIGHUP_IGNORED: &str =
    "SIGHUP received and ignored: gatewatch does not reload its configuration; restart it to \
     apply changes";

/// Resolves on SIGINT (Ctrl-C) or SIGTERM. SIGHUP is logged as a warning ([`SIGHUP_IGNORED`])
/// and otherwise ignored: the daemon keeps running.
///
/// SIGTERM and SIGHUP are taken over when this is CALLED (inside the runtime), not when the
/// future is first polled. Why: the daemon polls it in a task of its own, and until that task
/// first ran a SIGHUP took the default action and killed the daemon, which already answered
/// `/readyz` (`store_restart::sighup_is_logged_...` failed so once in a CI rehearsal under load,
/// stop 67).
///
/// # Panics
/// Outside a Tokio runtime with I/O enabled (as every `tokio::signal` call).
pub fn signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    #[cfg(unix)]
    let term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate());
    #[cfg(unix)]
    let hangup = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::hangup());
    async move {
        let ctrl_c = async {
            if let Err(e) = tokio::signal::ctrl_c().await {
                tracing::error!(error = %e, "cannot listen for SIGINT");
                std::future::pending::<()>().await;
            }
        };
        #[cfg(unix)]
        let term = async {
            match term {
                Ok(mut s) => {
                    s.recv().await;
                }
                Err(e) => {
                    tracing::error!(error = %e, "cannot listen for SIGTERM");
                    std::future::pending::<()>().await;
                }
            }
        };
        #[cfg(not(unix))]
        let term = std::future::pending::<()>();
        // never resolves: each SIGHUP is logged and the wait goes on
        #[cfg(unix)]
        let hup = async {
            match hangup {
                Ok(mut s) => {
                    while s.recv().await.is_some() {
                        tracing::warn!("{SIGHUP_IGNORED}");
                    }
                }
                Err(e) => {
                    tracing::error!(error = %e, "cannot listen for SIGHUP (it would stop the daemon)")
                }
            }
            std::future::pending::<()>().await;
        };
        #[cfg(not(unix))]
        let hup = std::future::pending::<()>();
        tokio::select! {
            _ = ctrl_c => tracing::info!("SIGINT received, shutting down"),
            _ = term => tracing::info!("SIGTERM received, shutting down"),
            _ = hup => {}
        }
    }
}
