//! `[server]` keys of the network limits (issue 12): the body-bytes budget, connection caps
//! and timeouts, the raw TCP allow-list, unknown-gate expiry. Their defaults and validation
//! live here, next to each other, to keep `config.rs` to one screenful per concept.

use super::{ConfigError, ServerConfig};

/// Default bound on the request-body bytes held by ingestion requests at once (16 MiB): each
/// request reserves its `Content-Length` before its body is read (a gzip or chunked body its
/// decompressed bytes as they arrive), and gets 503 + Retry-After when the reservation does not
/// fit. With the measured
/// per-request peak (docs/design.md, bounds) this is what keeps the daemon inside 512 MiB.
pub const DEFAULT_MAX_BODY_BYTES_IN_FLIGHT: usize = 16 * 1024 * 1024;
/// Default bound on simultaneous HTTP connections; further ones are closed at once.
pub const DEFAULT_MAX_HTTP_CONNECTIONS: usize = 512;
/// Most simultaneous connections of the health listener (`server.health_listen`); one more is
/// closed at accept and counted (`gatewatch_health_connections_rejected_total`). Who connects
/// there: the kubelet's two probes, a Prometheus or two, an operator's curl; each probe and
/// scrape is one short request on its own connection, or one kept alive. 16 holds them with
/// room to spare, and the header timeout (`http_header_read_timeout_seconds`, shared with
/// `listen`) frees a slot that a silent client holds. A cap, not a guard: admit only those
/// clients to the port (docs/security.md, "Exhaust connections or file descriptors").
pub const HEALTH_MAX_CONNECTIONS: usize = 16;
/// Default seconds a client has to send a request's headers, counted from the moment the
/// connection waits for them: also the idle timeout of a keep-alive connection.
pub const DEFAULT_HTTP_HEADER_READ_TIMEOUT_SECONDS: f64 = 10.0;
/// Default seconds a raw TCP connection may stay silent before it is closed.
pub const DEFAULT_TCP_IDLE_TIMEOUT_SECONDS: f64 = 300.0;
/// Default seconds after which a gate created by `accept_unknown_gates` that stopped sending
/// is forgotten (its alerts resolved); 0: never.
pub const DEFAULT_UNKNOWN_GATE_EXPIRY_SECONDS: f64 = 600.0;
impl ServerConfig {
    /// `tcp_allowed_networks` parsed; a bare address is a single-host network.
    pub fn tcp_networks(&self) -> Result<Vec<ipnet::IpNet>, String> {
        self.tcp_allowed_networks
            .iter()
            .map(|n| {
                n.parse::<ipnet::IpNet>()
                    .or_else(|_| n.parse::<std::net::IpAddr>().map(ipnet::IpNet::from))
                    .map_err(|_| format!("`{n}` is not a network like 10.0.0.0/8 or an address"))
            })
            .collect()
    }

    /// A warning when the raw TCP listener listens beyond loopback but only loopback clients
    /// may use it: every client from another host (also through a container's published port:
    /// with rootful Docker a remote client keeps its own address, a client on the same host
    /// arrives from the bridge's gateway) is refused at accept, one log line each, and nothing
    /// at start said so (`GATEWATCH_TCP_LISTEN=0.0.0.0:8094` alone in a container).
    pub fn tcp_loopback_only_warning(&self) -> Option<String> {
        let addr = self.tcp_listen.parse::<std::net::SocketAddr>().ok()?;
        let networks = self.tcp_networks().ok()?;
        let loopback_only = networks.iter().all(|n| n.addr().is_loopback());
        (!addr.ip().is_loopback() && loopback_only).then(|| {
            format!(
                "server.tcp_listen = \"{}\" listens beyond loopback, but \
                 server.tcp_allowed_networks ({}) lets in loopback clients only: every other \
                 client is refused (set it, or GATEWATCH_TCP_ALLOWED_NETWORKS, to the clients' \
                 networks; in a container, the remote clients' own networks, and the bridge's \
                 gateway for a client on the same host: docs/security.md)",
                self.tcp_listen,
                if self.tcp_allowed_networks.is_empty() {
                    "empty".to_string()
                } else {
                    self.tcp_allowed_networks.join(", ")
                }
            )
        })
    }

    /// Validates the keys of this module, naming the key at fault.
    pub(super) fn validate_net(&self) -> Result<(), ConfigError> {
        let s = self;
        let err = |key: &str, msg: &str| Err(ConfigError::new(format!("server.{key}: {msg}")));
        if s.max_body_bytes_in_flight < s.body_limit_bytes {
            return err(
                "max_body_bytes_in_flight",
                "must be >= body_limit_bytes (else a body at the limit never fits)",
            );
        }
        if s.max_http_connections == 0 {
            return err("max_http_connections", "must be > 0");
        }
        // a day at most: `Duration::from_secs_f64` panics on huge values
        for (key, v, min) in [
            (
                "http_header_read_timeout_seconds",
                s.http_header_read_timeout_seconds,
                f64::MIN_POSITIVE,
            ),
            (
                "tcp_idle_timeout_seconds",
                s.tcp_idle_timeout_seconds,
                f64::MIN_POSITIVE,
            ),
            (
                "unknown_gate_expiry_seconds",
                s.unknown_gate_expiry_seconds,
                0.0,
            ),
        ] {
            if !(v.is_finite() && v >= min && v <= 86_400.0) {
                let range = if min > 0.0 { "> 0" } else { ">= 0" };
                return err(key, &format!("must be {range} and <= 86400"));
            }
        }
        if let Err(e) = s.tcp_networks() {
            return err("tcp_allowed_networks", &e);
        }
        // An empty list with the listener on refuses every client at accept, one log line
        // each, and nothing at start said so. It is no way to turn the listener off (that is
        // `tcp_listen = ""`), so it is refused; with the listener off the list is not used.
        if !s.tcp_listen.is_empty() && s.tcp_allowed_networks.is_empty() {
            return err(
                "tcp_allowed_networks",
                &format!(
                    "empty, so the raw TCP listener (server.tcp_listen = \"{}\") would refuse \
                     every client: list the clients' networks (e.g. [\"10.20.0.0/16\"]; \
                     loopback only: [\"127.0.0.0/8\", \"::1/128\"]), or turn the listener \
                     off with tcp_listen = \"\"",
                    s.tcp_listen
                ),
            );
        }
        Ok(())
    }
}
