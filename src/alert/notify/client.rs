//! The notifier's HTTP client and the TLS set-up it needs.

use std::sync::Once;
use std::time::Duration;

/// Installs rustls' ring crypto provider as the process default, once.
///
/// reqwest is built with `rustls-no-provider` (see `Cargo.toml`), so a client cannot be built
/// until a provider is installed. Call this before building any `reqwest::Client`;
/// [`spawn_notifier`](super::spawn_notifier) does. Idempotent and cheap after the first call.
pub fn ensure_crypto_provider() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // Err means another provider was installed first (by the embedding program): fine,
        // reqwest uses whichever is the default.
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
}

/// The client shared by all target tasks. `None` (logged) if it cannot be built: then every
/// delivery fails instead of the notifier refusing to start.
pub(super) fn build_client(timeout: Duration) -> Option<reqwest::Client> {
    ensure_crypto_provider();
    reqwest::Client::builder()
        .timeout(timeout)
        .user_agent(concat!("gatewatch/", env!("CARGO_PKG_VERSION")))
        .build()
        .map_err(|e| {
            tracing::error!(
                "alert notifier: cannot build the HTTP client: {e}; every delivery will fail"
            );
        })
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crypto_provider_installed_once_and_client_builds() {
        ensure_crypto_provider();
        ensure_crypto_provider();
        assert!(rustls::crypto::CryptoProvider::get_default().is_some());
        assert!(build_client(Duration::from_secs(1)).is_some());
    }
}
