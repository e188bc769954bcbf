//! Daemon configuration: a TOML file, environment overrides, validation naming the key at fault.
//!
//! Per-gate settings are `[defaults]` merged key by key (tables recursively) with `[gates.ID]`.
//! Every table denies unknown keys. See `config/gatewatch.toml` for the documented example.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::alert::notify::NotifyConfig;
use crate::alert::AlertRules;
use crate::analysis::{
    AnalysisError, AnalysisSettings, Analyzer, PoolingSettings, Signal, TrackingPolicy,
};

/// The embedded default configuration (the documented example), used by `serve` without
/// `--config` and by the demo.
pub const EMBEDDED_CONFIG: &str = include_str!("../../config/gatewatch.toml");

/// Default HTTP listen address (the port is gatewatch's, next to node_exporter's 9100 range).
pub const DEFAULT_LISTEN: &str = "0.0.0.0:9464";
/// Default request body limit: 4 MiB, about 500 000 JSON samples; larger bodies get 413.
pub const DEFAULT_BODY_LIMIT_BYTES: usize = 4 * 1024 * 1024;
/// Default number of HTTP requests handled at once; more are shed with 503 + Retry-After.
pub const DEFAULT_MAX_CONCURRENT_REQUESTS: usize = 256;
/// Default number of ingestion requests in progress at once. Each holds its body and parsed
/// form (about 5x the body for JSON), so memory is bounded by about
/// `max_concurrent_ingest * body_limit_bytes * 5` (16 * 4 MiB * 5 = 320 MiB at worst).
pub const DEFAULT_MAX_CONCURRENT_INGEST: usize = 16;
/// Default per-request timeout in seconds (408 after it).
pub const DEFAULT_REQUEST_TIMEOUT_SECONDS: f64 = 30.0;
/// Default bound on the number of gates (bounds memory and metric label cardinality).
pub const DEFAULT_MAX_GATES: usize = 64;
/// Hard upper bound on `max_gates`.
pub const MAX_GATES_LIMIT: usize = 10_000;
/// Hard upper bound on `worker_threads`: each is an OS thread with an identification's
/// memory, and more workers than cores only share them (a typo of 100000 reached the process
/// limit and `serve` exited naming no key).
pub const MAX_WORKER_THREADS: usize = 256;
/// Default bound on one identification's wall time, seconds. A cold window takes 0.1 s to a
/// minute on one core (docs/benchmarks.md); five minutes is far past any window that
/// progresses, and short enough that a stuck worker (a decomposition that never converged, in
/// session 53) is restarted within minutes by the liveness probe.
pub const DEFAULT_IDENTIFICATION_TIMEOUT_SECONDS: f64 = 300.0;
/// Default bound on simultaneous raw TCP connections.
pub const DEFAULT_MAX_TCP_CONNECTIONS: usize = 64;
/// Default seconds given to in-flight jobs and notifications at shutdown.
pub const DEFAULT_SHUTDOWN_GRACE_SECONDS: f64 = 10.0;
/// Default `Retry-After` seconds sent with 429/503.
pub const DEFAULT_RETRY_AFTER_SECONDS: u64 = 1;
/// Default `window_cycles`: 40 cycles lengthen a 2 Hz barrier gate's 10 s window to 20 s and a
/// 1 Hz gate's to 40 s, and leave the lab gate's (104 cycles) and a 5 Hz lock gate's (50) as
/// they are. Why 40: at 20 s the barrier gate's readings scattered less and its pages came
/// earlier (on the slow drift before -1 % on 36 of 40 seeds, 26 at 10 s), though its growth
/// and onset limit-cycle rows covered less (docs/benchmarks.md, "Stop 86"); and a 1 Hz gate at
/// 10 s, 10 cycles, paged 91 times a day.
pub const DEFAULT_WINDOW_CYCLES: f64 = 40.0;
/// Largest `window_cycles` accepted (the history kept bounds the span whatever it is; a larger
/// figure is a typo).
pub const MAX_WINDOW_CYCLES: f64 = 100_000.0;

/// Largest window accepted: bounds the memory of one gate (`window_seconds * rate_hz` samples).
pub const MAX_WINDOW_SAMPLES: usize = 10_000_000;
/// Alertmanager's default `resolve_timeout` (5 min): an alert not re-sent within it is resolved.
pub const ALERTMANAGER_RESOLVE_TIMEOUT_SECONDS: f64 = 300.0;
/// Default bound on how far ahead of the daemon's clock a sample may be: 10 min, as Mimir's
/// `creation_grace_period`; clocks synchronised by NTP are within milliseconds.
pub const DEFAULT_MAX_FUTURE_SECONDS: f64 = 600.0;
/// Default bound on how far behind the daemon's clock a sample may be: 1 h. A monitor acts on
/// live data; older samples are a replay or a broken clock (year 1971).
pub const DEFAULT_MAX_PAST_SECONDS: f64 = 3600.0;
/// Largest value of any setting in seconds (one year). `Duration::from_secs_f64` panics on
/// values past `u64::MAX` seconds and deadlines far past the clock's range overflow; a year is
/// far beyond any sensible timeout, grace period or window.
pub const MAX_SECONDS: f64 = 365.0 * 86_400.0;
/// Largest `ingest.tcp_max_line_bytes` (1 MiB): every TCP connection may buffer one line, so
/// with `max_tcp_connections` (64) the lines alone hold up to 64 MiB (a line of line protocol is
/// about 50 bytes; the default is 64 KiB).
pub const MAX_TCP_LINE_BYTES: usize = 1024 * 1024;
/// Default equation of motion: van der Pol-like damping, known installed stiffness `k`.
pub const DEFAULT_MODEL: &str = "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0";

/// Whether listeners on `a` and `b` would take the same port: the same port (not 0, which the
/// system chooses) on the same address, or with either on every address of its family. As
/// Linux binds them by default (`net.ipv6.bindv6only = 0`; the standard library does not set
/// `IPV6_V6ONLY`): an IPv4-mapped address (`[::ffff:127.0.0.1]`) is its IPv4 address, `[::]`
/// takes the port on every IPv4 address as well, and `0.0.0.0` takes none of IPv6's
/// (`0.0.0.0:8080` and `[::1]:8080` both bind).
fn same_port(a: SocketAddr, b: SocketAddr) -> bool {
    use std::net::IpAddr;
    let canonical = |ip: IpAddr| match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    };
    let (x, y) = (canonical(a.ip()), canonical(b.ip()));
    let overlap = match (x, y) {
        (IpAddr::V4(_), IpAddr::V4(_)) | (IpAddr::V6(_), IpAddr::V6(_)) => {
            x == y || x.is_unspecified() || y.is_unspecified()
        }
        // across families only IPv6's wildcard, which is dual-stack, takes IPv4's port
        (IpAddr::V6(v6), IpAddr::V4(_)) | (IpAddr::V4(_), IpAddr::V6(v6)) => v6.is_unspecified(),
    };
    a.port() != 0 && a.port() == b.port() && overlap
}

/// The whole configuration.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Listeners and limits.
    pub server: ServerConfig,
    /// Logging.
    pub log: LogConfig,
    /// Ingestion mapping.
    pub ingest: IngestConfig,
    /// Where alerts go (webhooks, Alertmanager; see `docs/alerts.md`). Never serialized: it
    /// holds bearer tokens.
    #[serde(skip_serializing)]
    pub notify: NotifyConfig,
    /// The store: history, alert state, outbox (`crate::store`, `docs/operations.md`).
    pub storage: crate::store::StorageConfig,
    /// Settings for every gate (resolved; the raw table is merged into each gate).
    #[serde(skip)]
    pub defaults: GateConfig,
    /// Configured gates, resolved.
    #[serde(skip)]
    pub gates: BTreeMap<String, GateConfig>,
}

/// `[server]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    /// HTTP listen address.
    pub listen: String,
    /// Raw TCP line-protocol listen address; empty: off.
    pub tcp_listen: String,
    /// Health listen address: `/healthz`, `/readyz` and `/metrics` on a port of their own, with
    /// a connection cap of its own ([`HEALTH_MAX_CONNECTIONS`]), so that clients holding every
    /// connection of `listen` cannot get the probes refused; empty: off (the probes are on
    /// `listen` only).
    pub health_listen: String,
    /// Bearer tokens; empty: no authentication (decided in the file only: a
    /// `GATEWATCH_AUTH_TOKENS` holding no token is refused, [`Config::apply_env`]).
    pub auth_tokens: Vec<String>,
    /// Whether /metrics also needs a token (when tokens are configured).
    pub metrics_auth: bool,
    /// Request body limit in bytes.
    pub body_limit_bytes: usize,
    /// Requests handled at once.
    pub max_concurrent_requests: usize,
    /// Ingestion requests handled at once (bounds their memory).
    pub max_concurrent_ingest: usize,
    /// Per-request timeout, seconds; also how long a client may take no byte of an answer.
    pub request_timeout_seconds: f64,
    /// Identification worker threads; 0: cores - 1, at least 1.
    pub worker_threads: usize,
    /// Most gates tracked at once.
    pub max_gates: usize,
    /// Most identification jobs waiting (one per gate at most); 0: `max_gates`.
    pub job_queue: usize,
    /// Seconds one identification may run before the daemon counts its worker as stuck:
    /// logged, and `/healthz` fails (503) while it runs, so that a liveness probe restarts the
    /// daemon (a thread cannot be stopped from outside; see `worker.rs`).
    pub identification_timeout_seconds: f64,
    /// Most simultaneous raw TCP connections.
    pub max_tcp_connections: usize,
    /// Seconds from the stop signal to the end of the shutdown: open requests, in-flight jobs and
    /// pending notifications share this one deadline (see `server.rs`).
    pub shutdown_grace_seconds: f64,
    /// Unknown gates get `[defaults]` (true) or are refused with 404 (false).
    pub accept_unknown_gates: bool,
    /// Request-body bytes held by ingestion requests at once (see
    /// [`DEFAULT_MAX_BODY_BYTES_IN_FLIGHT`]); at least `body_limit_bytes`.
    pub max_body_bytes_in_flight: usize,
    /// Most simultaneous HTTP connections.
    pub max_http_connections: usize,
    /// Seconds to send a request's headers; also the keep-alive idle timeout.
    pub http_header_read_timeout_seconds: f64,
    /// Seconds a raw TCP connection may stay silent.
    pub tcp_idle_timeout_seconds: f64,
    /// Client networks (CIDR) allowed on the raw TCP listener; others are closed at accept.
    pub tcp_allowed_networks: Vec<String>,
    /// Seconds after which a silent gate created by `accept_unknown_gates` is forgotten; 0: never.
    pub unknown_gate_expiry_seconds: f64,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            listen: DEFAULT_LISTEN.into(),
            tcp_listen: String::new(),
            health_listen: String::new(),
            auth_tokens: Vec::new(),
            metrics_auth: false,
            body_limit_bytes: DEFAULT_BODY_LIMIT_BYTES,
            max_concurrent_requests: DEFAULT_MAX_CONCURRENT_REQUESTS,
            max_concurrent_ingest: DEFAULT_MAX_CONCURRENT_INGEST,
            request_timeout_seconds: DEFAULT_REQUEST_TIMEOUT_SECONDS,
            worker_threads: 0,
            max_gates: DEFAULT_MAX_GATES,
            job_queue: 0,
            identification_timeout_seconds: DEFAULT_IDENTIFICATION_TIMEOUT_SECONDS,
            max_tcp_connections: DEFAULT_MAX_TCP_CONNECTIONS,
            shutdown_grace_seconds: DEFAULT_SHUTDOWN_GRACE_SECONDS,
            accept_unknown_gates: true,
            max_body_bytes_in_flight: DEFAULT_MAX_BODY_BYTES_IN_FLIGHT,
            max_http_connections: DEFAULT_MAX_HTTP_CONNECTIONS,
            http_header_read_timeout_seconds: DEFAULT_HTTP_HEADER_READ_TIMEOUT_SECONDS,
            tcp_idle_timeout_seconds: DEFAULT_TCP_IDLE_TIMEOUT_SECONDS,
            tcp_allowed_networks: vec!["127.0.0.0/8".into(), "::1/128".into()],
            unknown_gate_expiry_seconds: DEFAULT_UNKNOWN_GATE_EXPIRY_SECONDS,
        }
    }
}

impl ServerConfig {
    /// Worker threads to start: configured, or cores - 1 (at least 1).
    pub fn effective_worker_threads(&self) -> usize {
        if self.worker_threads > 0 {
            self.worker_threads
        } else {
            std::thread::available_parallelism()
                .map(|n| n.get().saturating_sub(1))
                .unwrap_or(1)
                .max(1)
        }
    }

    /// [`ServerConfig::identification_timeout_seconds`] as a duration (the default's where the
    /// value was not validated and is no duration).
    pub fn identification_timeout(&self) -> std::time::Duration {
        std::time::Duration::try_from_secs_f64(self.identification_timeout_seconds).unwrap_or(
            std::time::Duration::from_secs_f64(DEFAULT_IDENTIFICATION_TIMEOUT_SECONDS),
        )
    }

    /// Bound on waiting jobs.
    pub fn effective_job_queue(&self) -> usize {
        if self.job_queue > 0 {
            self.job_queue
        } else {
            self.max_gates
        }
    }
}

/// Log output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Text,
    /// One JSON object per line.
    Json,
}

/// `[log]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogConfig {
    /// text | json.
    pub format: LogFormat,
    /// An `EnvFilter` directive (`RUST_LOG` wins when set).
    pub level: String,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            format: LogFormat::Text,
            level: "info".into(),
        }
    }
}

/// What `log.level` accepts, for its error message.
const LOG_LEVEL_HELP: &str = "valid levels are off, error, warn, info, debug and trace; or \
     comma-separated tracing EnvFilter directives target=level, e.g. \"info,gatewatch::service=debug\"";

/// Checks a `log.level` value with the parser `serve` gives it to (tracing's `EnvFilter`), and
/// refuses a bare word that is not a level: `EnvFilter` reads `debugg` as "everything of the
/// target `debugg`", which no event has, so a typo used to silence every log without a word.
pub fn check_log_level(level: &str) -> Result<(), String> {
    if level.trim().is_empty() {
        return Err(format!("must not be empty: {LOG_LEVEL_HELP}"));
    }
    for directive in level.split(',').map(str::trim).filter(|d| !d.is_empty()) {
        let bare = !directive.contains('=') && !directive.contains('[');
        if bare
            && directive
                .parse::<tracing::level_filters::LevelFilter>()
                .is_err()
        {
            return Err(format!(
                "`{directive}` is not a level ({LOG_LEVEL_HELP}; a target alone needs its \
                 level: `{directive}=trace`)"
            ));
        }
    }
    tracing_subscriber::EnvFilter::builder()
        .parse(level)
        .map(drop)
        .map_err(|e| format!("`{level}`: {e} ({LOG_LEVEL_HELP})"))
}

/// Checks a key gatewatch looks for in line protocol (`ingest.gate_tag`, each of
/// `ingest.value_fields`): refuses what no line can carry as a key, so that the daemon does not
/// start and refuse every write (`value_fields = [""]` passed, and then every line got
/// `missing field, expected one of [""]`). A line carries a tag or field key of at least one
/// character; it cannot hold a newline, which ends the line; and it cannot end with a
/// backslash, which escapes the `=` after it (`service::ingest::line_protocol`: `\,`, `\=` and
/// `\ ` are escapes in keys, so a comma, an equals sign or a space can be carried, escaped).
fn check_line_protocol_key(key: &str) -> Result<(), String> {
    if key.is_empty() {
        return Err("must not be empty: a line-protocol key has at least one character".into());
    }
    if key.contains('\n') {
        return Err(format!(
            "{key:?} holds a newline, which ends a line of line protocol: no line can carry \
             this key"
        ));
    }
    if key.ends_with('\\') {
        return Err(format!(
            "{key:?} ends with a backslash, which escapes the '=' after the key in line \
             protocol: no line can carry this key"
        ));
    }
    Ok(())
}

/// Timestamp precision of line protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// Nanoseconds.
    #[default]
    Ns,
    /// Microseconds.
    Us,
    /// Milliseconds.
    Ms,
    /// Seconds.
    S,
    /// Minutes (InfluxDB 1.x `/write?precision=m`).
    M,
    /// Hours (InfluxDB 1.x `/write?precision=h`).
    H,
}

impl Precision {
    /// Parses `ns|us|ms|s` (also `n`, `u`, `m`, `h` as InfluxDB 1.x accepts).
    pub fn parse(s: &str) -> Option<Precision> {
        match s {
            "ns" | "n" => Some(Precision::Ns),
            "us" | "u" => Some(Precision::Us),
            "ms" => Some(Precision::Ms),
            "s" => Some(Precision::S),
            "m" => Some(Precision::M),
            "h" => Some(Precision::H),
            _ => None,
        }
    }

    /// Seconds per unit.
    pub fn seconds_per_unit(self) -> f64 {
        match self {
            Precision::Ns => 1e-9,
            Precision::Us => 1e-6,
            Precision::Ms => 1e-3,
            Precision::S => 1.0,
            Precision::M => 60.0,
            Precision::H => 3600.0,
        }
    }
}

/// `[ingest]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    /// Line protocol tag that names the gate.
    pub gate_tag: String,
    /// Line protocol fields holding the sample, first present wins.
    pub value_fields: Vec<String>,
    /// Timestamp precision of the raw TCP listener.
    pub tcp_precision: Precision,
    /// Longest line accepted on the TCP listener, bytes.
    pub tcp_max_line_bytes: usize,
}

impl Default for IngestConfig {
    fn default() -> Self {
        IngestConfig {
            gate_tag: "gate".into(),
            value_fields: vec!["force".into(), "value".into()],
            tcp_precision: Precision::Ns,
            tcp_max_line_bytes: 64 * 1024,
        }
    }
}

/// Settings of one gate (`[defaults]` merged with `[gates.ID]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GateConfig {
    /// force | displacement.
    pub signal: Signal,
    /// What a force signal holds: all (damping plus stiffness force) | stiffness.
    pub force_terms: crate::analysis::ForceTerms,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Installed stiffness, N/m (needed for `signal = "force"`).
    pub stiffness: Option<f64>,
    /// Equation of motion.
    pub model: String,
    /// Known constants of the equation.
    pub params: BTreeMap<String, f64>,
    /// DE population.
    pub population: usize,
    /// DE generations.
    pub generations: usize,
    /// Amplitude whose time of reach is predicted.
    pub amplitude_limit: Option<f64>,
    /// Windows fitting worse than this NMAE are not trusted.
    pub max_fit_nmae: f64,
    /// Relative tolerance of the full search's polish integrations (Dormand-Prince).
    pub polish_rtol: f64,
    /// Solver of the polish and the tracked refinement: rk4 | dopri5.
    pub polish_solver: crate::analysis::PolishSolver,
    /// How a model-based zeta0 gets its interval: newey-west | forcing.
    pub model_interval: crate::analysis::ModelInterval,
    /// Which reference instants the ambient SSI-COV correlations use: lagged | common.
    pub ssi_reference: crate::analysis::SsiReference,
    /// Window length, seconds of sample time: the shortest record an identification reads.
    pub window_seconds: f64,
    /// Cycles of the gate's dominant frequency an identification reads at least, once the
    /// frequency is known: the window is lengthened up to the history kept (six windows;
    /// `service::window_span`). 0: `window_seconds` always.
    pub window_cycles: f64,
    /// Identification cadence, seconds of new sample time.
    pub identify_every_seconds: f64,
    /// Whether a gate's first window waits a fraction of the cadence fixed by its ID, so that
    /// gates starting together are identified spread over the cadence (`service::window`).
    pub stagger: bool,
    /// Samples more than this many seconds ahead of the daemon's clock refuse their request
    /// (400); 0: no bound. See `service::ingest_checks` for why.
    pub max_future_seconds: f64,
    /// Samples more than this many seconds behind the daemon's clock refuse their request
    /// (400); 0: no bound (replaying recorded data).
    pub max_past_seconds: f64,
    /// Alert rules.
    pub alert: AlertRules,
    /// When a window may refine the previous window's model instead of searching
    /// (`docs/design.md`, "Tracking between windows").
    pub tracking: TrackingPolicy,
    /// Pooling of consecutive model-free estimates (`docs/damping.md`, "Pooling windows").
    pub pooling: PoolingSettings,
}

impl Default for GateConfig {
    fn default() -> Self {
        GateConfig {
            signal: Signal::Force,
            force_terms: crate::analysis::ForceTerms::All,
            rate_hz: 200.0,
            stiffness: Some(81_360.0),
            model: DEFAULT_MODEL.into(),
            params: BTreeMap::new(),
            population: 20,
            generations: 40,
            amplitude_limit: None,
            max_fit_nmae: 0.2,
            polish_rtol: crate::analysis::DEFAULT_POLISH_RTOL,
            polish_solver: crate::analysis::PolishSolver::default(),
            model_interval: crate::analysis::ModelInterval::default(),
            ssi_reference: crate::analysis::SsiReference::default(),
            window_seconds: 10.0,
            window_cycles: DEFAULT_WINDOW_CYCLES,
            identify_every_seconds: 5.0,
            stagger: true,
            max_future_seconds: DEFAULT_MAX_FUTURE_SECONDS,
            max_past_seconds: DEFAULT_MAX_PAST_SECONDS,
            alert: AlertRules::default(),
            tracking: TrackingPolicy::default(),
            pooling: PoolingSettings::default(),
        }
    }
}

/// A configuration error; the message names the key (`gates.g1.rate_hz: must be > 0`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ConfigError {
    /// One line.
    pub message: String,
    /// Whether the message already names the file (it could not be read), or names the
    /// environment variable the bad value came from, so a caller that prefixes the file's name
    /// does not say it twice or blame the file.
    names_file: bool,
    /// Other keys the fault may lie in (a rule on two settings: `window_seconds * rate_hz`),
    /// full dotted paths. When the file does not write the named key but writes one of these,
    /// the error names that one and its line: `rate_hz = 1e-300` was reported as
    /// `defaults.window_seconds`, a key the file did not have, at the table's header.
    also: Vec<String>,
}

/// Every `GATEWATCH_*` variable `serve` reads, with the key it sets (`None`: no key of the file;
/// `GATEWATCH_JIT` is read by the model compiler, `GATEWATCH_TOKEN` by `simulate`).
pub const ENV_KEYS: &[(&str, &str)] = &[
    ("GATEWATCH_LISTEN", "server.listen"),
    ("GATEWATCH_TCP_LISTEN", "server.tcp_listen"),
    ("GATEWATCH_HEALTH_LISTEN", "server.health_listen"),
    (
        "GATEWATCH_TCP_ALLOWED_NETWORKS",
        "server.tcp_allowed_networks",
    ),
    ("GATEWATCH_AUTH_TOKENS", "server.auth_tokens"),
    ("GATEWATCH_LOG_FORMAT", "log.format"),
    ("GATEWATCH_LOG_LEVEL", "log.level"),
    ("GATEWATCH_JIT", "(the model compiler)"),
    ("GATEWATCH_STORAGE_PATH", "storage.path"),
    ("GATEWATCH_STORAGE_BACKEND", "storage.backend"),
    ("GATEWATCH_NATS_URL", "storage.nats_url"),
    ("GATEWATCH_NATS_PREFIX", "storage.nats_prefix"),
    ("GATEWATCH_NATS_LEASE_SECONDS", "storage.nats_lease_seconds"),
    ("GATEWATCH_WORKER_THREADS", "server.worker_threads"),
    ("GATEWATCH_MAX_GATES", "server.max_gates"),
    (
        "GATEWATCH_ACCEPT_UNKNOWN_GATES",
        "server.accept_unknown_gates",
    ),
    ("GATEWATCH_TOKEN", "(simulate's token)"),
    ("GATEWATCH_CONFIG", "(the configuration file)"),
];

/// A warning for each variable named `GATEWATCH_*` that gatewatch does not read: a mistyped
/// `GATEWATCH_LISTEN_ADDR` was ignored without a word and the daemon listened elsewhere.
pub fn unknown_env_warnings(names: impl Iterator<Item = String>) -> Vec<String> {
    let mut unknown: Vec<String> = names
        .filter(|n| n.starts_with("GATEWATCH_") && !ENV_KEYS.iter().any(|(k, _)| k == n))
        .collect();
    unknown.sort();
    unknown
        .into_iter()
        .map(|n| {
            format!(
                "environment variable {n} is not one gatewatch reads (ignored); it reads {}",
                ENV_KEYS
                    .iter()
                    .map(|(k, _)| *k)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })
        .collect()
}

impl ConfigError {
    fn new(message: impl Into<String>) -> Self {
        ConfigError {
            message: message.into().replace('\n', " "),
            names_file: false,
            also: Vec::new(),
        }
    }

    /// The error of a rule on two settings: it names `key` and, when the file writes `other`
    /// but not `key`, `with_line` names `other` instead (both full dotted paths).
    fn on_pair(key: &str, other: &str, message: &str) -> Self {
        ConfigError {
            also: vec![other.to_string()],
            ..ConfigError::new(format!("{key}: {message}"))
        }
    }

    /// Whether [`Self::message`] already names the configuration file.
    pub fn names_file(&self) -> bool {
        self.names_file
    }
}

/// An I/O error's reason without the OS's code: `No such file or directory`, not `... (os
/// error 2)`, which tells the user nothing more.
fn io_reason(e: &std::io::Error) -> String {
    let s = e.to_string();
    match s.rfind(" (os error ") {
        Some(i) if s.ends_with(')') => s[..i].to_string(),
        _ => s,
    }
}

/// Where a file stops being UTF-8, told as its line and column (TOML is UTF-8 by its
/// specification; the io error said only "stream did not contain valid UTF-8").
fn not_utf8(bytes: &[u8], valid_up_to: usize) -> String {
    let before = &bytes[..valid_up_to.min(bytes.len())];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let line_start = before
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    // the valid prefix is UTF-8, so its characters count the column
    let column = String::from_utf8_lossy(&before[line_start..])
        .chars()
        .count()
        + 1;
    format!(
        "line {line}, column {column}: not valid UTF-8 (byte 0x{:02x}); save the file as UTF-8",
        bytes.get(valid_up_to).copied().unwrap_or(0)
    )
}

/// A TOML syntax error (or duplicate key) with what toml's span points at and its line:
/// `server.max_gates: duplicate key, line 3` or `line 1: unclosed table, expected `]`: `[server``.
fn toml_error(text: &str, e: toml::de::Error) -> ConfigError {
    let msg = e.message().trim().to_string();
    let Some(span) = e.span() else {
        return ConfigError::new(msg);
    };
    let start = span.start.min(text.len());
    // an error at the end of the text (an unclosed `"""`) points past its final newline and
    // any blank lines: name the last line that has text, which is what a user can fix
    let line = if start >= text.trim_end().len() {
        text.trim_end().lines().count().max(1)
    } else {
        text[..start].matches('\n').count() + 1
    };
    // the key a duplicate-key error points at, or the text of the line at fault
    let at = text.get(span.clone()).map(str::trim).unwrap_or("");
    if msg.starts_with("duplicate key") && !at.is_empty() && !at.contains('\n') {
        // name the key by its full path (`defaults.alert.for_windows`), as every other error
        // does: the leaf alone is ambiguous in a file where each gate's table has the same keys
        let key = match table_header_before(text, start) {
            Some(header) if !at.starts_with('[') => format!("{header}.{at}"),
            _ => at.trim_matches(|c| c == '[' || c == ']').trim().to_string(),
        };
        return ConfigError::new(format!("{key}: duplicate key, line {line}"));
    }
    let line_text = text.lines().nth(line - 1).unwrap_or("").trim();
    let line_text: String = line_text.chars().take(80).collect();
    ConfigError::new(format!("line {line}: {msg}: `{line_text}`"))
}

/// The header of the table (`defaults.alert` of `[defaults.alert]`, or of `[[notify.webhooks]]`)
/// that the byte `at` of `text` lies in, `None` at the top level. A line-by-line reading, which
/// is enough for the position of a key that toml has already parsed: a header is a line that
/// starts with `[`, and no key line does (a multi-line array's continuation lines hold values,
/// not keys, so a duplicate key is never inside one).
fn table_header_before(text: &str, at: usize) -> Option<String> {
    let before = text.get(..at)?;
    let upto = before.rfind('\n').map_or(0, |i| i);
    // a duplicate table (`[server]` twice) is named by its header alone
    let own = text[upto..].trim_start_matches('\n').trim_start();
    if own.starts_with('[') {
        return None;
    }
    text[..upto].lines().rev().find_map(|l| {
        let l = l.trim();
        let (inner, rest) = match l.strip_prefix("[[") {
            Some(r) => r.split_once("]]")?,
            None => l.strip_prefix('[')?.split_once(']')?,
        };
        // `[1, 2],` in a multi-line array is a value, not a header
        let rest = rest.trim();
        if inner.contains(',') || !(rest.is_empty() || rest.starts_with('#')) {
            return None;
        }
        let parts: Vec<String> = inner
            .split('.')
            .map(|p| p.trim().trim_matches('"').to_string())
            .collect();
        Some(parts.join("."))
    })
}

/// `err` with the line of the key it names (`server.max_gates: must be ...`), when the text
/// has that key. Validation works on merged values, so the line is looked up afterwards;
/// a gate's key inherited from `[defaults]` is found there.
fn with_line(text: &str, err: ConfigError) -> ConfigError {
    if err.message.contains(", line ") {
        return err;
    }
    let Some((key, rest)) = err.message.split_once(": ") else {
        return err;
    };
    // a rule on two settings names the one the file writes
    if written_line(text, key).is_none() {
        if let Some((other, line)) = err
            .also
            .iter()
            .find_map(|other| written_line(text, other).map(|line| (other, line)))
        {
            return ConfigError::new(format!("{other}: {rest}, line {line}"));
        }
    }
    let path = locate::key_path(key);
    let line = locate::line_of(text, &path)
        .filter(|_| path.len() > 1)
        .or_else(|| locate::line_of(text, &inherited_from(&path)?));
    match line {
        Some(l) => ConfigError::new(format!("{}, line {l}", err.message)),
        None => err,
    }
}

/// The line of `key` (a full dotted path) when the file writes that very key, under its gate or
/// (a gate's) under `[defaults]`; `None` when only a table above it is written.
fn written_line(text: &str, key: &str) -> Option<usize> {
    let path = locate::key_path(key);
    locate::exact_line_of(text, &path)
        .or_else(|| locate::exact_line_of(text, &inherited_from(&path)?))
}

/// Where a gate's key (`gates.ID.KEY...`) is inherited from: `defaults.KEY...`.
fn inherited_from(path: &[String]) -> Option<Vec<String>> {
    (path.len() > 2 && path[0] == "gates").then(|| {
        std::iter::once("defaults".to_string())
            .chain(path[2..].iter().cloned())
            .collect()
    })
}

fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// `table` (in `text` at the key path `path`, e.g. `gates.g1`) as a gate's settings.
fn gate_from_table(
    text: &str,
    path: &[&str],
    table: toml::Table,
) -> Result<GateConfig, ConfigError> {
    let gate: GateConfig =
        locate::deserialize(toml::Value::Table(table), text, path, &["defaults"])?;
    gate.validate(&path.join("."))?;
    Ok(gate)
}

/// What [`valid_gate_id`] requires, as the errors refusing an id say it.
pub const GATE_ID_RULE: &str =
    "gate id must be 1..=64 characters of A-Z a-z 0-9 _ - ., not only dots";

/// A valid gate id: 1..=64 characters of `[A-Za-z0-9_.-]` (bounded metric labels, safe paths),
/// not only dots. Why not `.` or `..`: clients (curl, browsers, HTTP libraries) normalise them
/// as path segments, so `/api/v1/gates/..` never reaches the gate: it would be ingested and
/// listed but not readable by its URL.
pub fn valid_gate_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 64
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
        && !id.bytes().all(|b| b == b'.')
}

/// Every top-level table of the file. `[defaults]` and `[gates.*]` are taken out before serde
/// reads the rest (they are merged first), so serde's "expected one of" for an unknown table
/// named neither, and `[defualts]` or `[gate.g1]` got a hint without the table meant; the
/// check in [`Config::from_toml`] names them all (a test keeps the list to `Config`'s fields).
pub const TOP_LEVEL_TABLES: [&str; 7] = [
    "server", "log", "ingest", "notify", "storage", "defaults", "gates",
];

/// `KEY: must be a table` for a top-level key given a value (`gates = 5`), with its line.
fn not_a_table(text: &str, key: &str) -> ConfigError {
    let mut message = format!("{key}: must be a table");
    if let Some(line) = locate::line_of(text, &[key.to_string()]) {
        message.push_str(&format!(", line {line}"));
    }
    ConfigError::new(message)
}

/// The error for a top-level key that is no table of [`TOP_LEVEL_TABLES`], with its line.
fn unknown_top_level(text: &str, key: &str) -> ConfigError {
    let expected: Vec<String> = TOP_LEVEL_TABLES.iter().map(|t| format!("`{t}`")).collect();
    let mut message = format!(
        "{key}: unknown field `{key}`, expected one of {}",
        expected.join(", ")
    );
    if let Some(line) = locate::line_of(text, &[key.to_string()]) {
        message.push_str(&format!(", line {line}"));
    }
    ConfigError::new(message)
}

impl Config {
    /// Parses and validates TOML text (no environment overrides).
    pub fn from_toml(text: &str) -> Result<Config, ConfigError> {
        Config::from_toml_unlocated(text).map_err(|e| with_line(text, e))
    }

    fn from_toml_unlocated(text: &str) -> Result<Config, ConfigError> {
        let mut doc: toml::Table = text
            .parse::<toml::Table>()
            .map_err(|e| toml_error(text, e))?;
        let defaults = match doc.remove("defaults") {
            None => toml::Table::new(),
            Some(toml::Value::Table(t)) => t,
            Some(_) => return Err(not_a_table(text, "defaults")),
        };
        let gates = match doc.remove("gates") {
            None => toml::Table::new(),
            Some(toml::Value::Table(t)) => t,
            Some(_) => return Err(not_a_table(text, "gates")),
        };
        if let Some(key) = doc.keys().find(|k| !TOP_LEVEL_TABLES.contains(&k.as_str())) {
            return Err(unknown_top_level(text, key));
        }
        let mut config: Config = locate::deserialize(toml::Value::Table(doc), text, &[], &[])?;
        config.defaults = gate_from_table(text, &["defaults"], defaults.clone())?;
        for (id, table) in gates {
            let prefix = format!("gates.{id}");
            if !valid_gate_id(&id) {
                return Err(ConfigError::new(format!("{prefix}: {GATE_ID_RULE}")));
            }
            let toml::Value::Table(table) = table else {
                return Err(ConfigError::new(format!("{prefix}: must be a table")));
            };
            let mut merged = defaults.clone();
            merge(&mut merged, table);
            let gate = gate_from_table(text, &["gates", &id], merged)?;
            config.gates.insert(id, gate);
        }
        config.validate()?;
        Ok(config)
    }

    /// Reads, parses and validates a file.
    pub fn from_file(path: &Path) -> Result<Config, ConfigError> {
        let bytes = std::fs::read(path).map_err(|e| ConfigError {
            names_file: true,
            ..ConfigError::new(format!("{}: {}", path.display(), io_reason(&e)))
        })?;
        let text = String::from_utf8(bytes).map_err(|e| ConfigError {
            names_file: true,
            ..ConfigError::new(format!(
                "{}: {}",
                path.display(),
                not_utf8(e.as_bytes(), e.utf8_error().valid_up_to())
            ))
        })?;
        Config::from_toml(&text)
    }

    /// The embedded example configuration.
    pub fn embedded() -> Config {
        Config::from_toml(EMBEDDED_CONFIG).expect("embedded config is valid (tested)")
    }

    /// Applies `GATEWATCH_*` overrides read through `get` (`std::env::var` in production).
    /// An error about a value a variable set names the variable, not the file (which may say
    /// something else: `GATEWATCH_LISTEN=foo` was reported as the file's `server.listen`), and
    /// is printed without the file's name.
    pub fn apply_env(&mut self, get: impl Fn(&str) -> Option<String>) -> Result<(), ConfigError> {
        self.apply_env_values(&get).map_err(|mut e| {
            if let Some((var, key)) = ENV_KEYS
                .iter()
                .find(|(var, key)| get(var).is_some() && e.message.starts_with(&format!("{key}:")))
            {
                e.message = format!("{var} (sets {key}){}", &e.message[key.len()..]);
            }
            if e.message.starts_with("GATEWATCH_") {
                e.names_file = true;
            }
            e
        })
    }

    /// Whether `serve` can open the store where this configuration puts it, as
    /// [`crate::store::check_location`] tells (a SQLite store only: a NATS store has no file,
    /// its server is reached at start). `storage.path` is resolved against `base` (the file's
    /// directory) as `serve` resolves it. `get` reads the environment, as for
    /// [`Config::apply_env`]: a path `GATEWATCH_STORAGE_PATH` set is refused naming the variable
    /// and not the file (`GATEWATCH_STORAGE_PATH=/nonexist/x.db` was reported as the file's
    /// `storage.path`), as every other bad value from the environment is.
    pub fn check_store_location(
        &self,
        base: Option<&Path>,
        get: impl Fn(&str) -> Option<String>,
    ) -> Result<(), ConfigError> {
        if self.storage.backend != crate::store::StorageBackend::Sqlite {
            return Ok(());
        }
        let store = self.storage.resolve(base);
        crate::store::check_location(&store).map_err(|reason| {
            if get("GATEWATCH_STORAGE_PATH").is_some() {
                ConfigError {
                    names_file: true,
                    ..ConfigError::new(format!(
                        "GATEWATCH_STORAGE_PATH (sets storage.path) {}: {reason}",
                        store.display()
                    ))
                }
            } else {
                ConfigError::new(format!("storage.path {}: {reason}", store.display()))
            }
        })
    }

    fn apply_env_values(
        &mut self,
        get: impl Fn(&str) -> Option<String>,
    ) -> Result<(), ConfigError> {
        if let Some(v) = get("GATEWATCH_LISTEN") {
            self.server.listen = v;
        }
        if let Some(v) = get("GATEWATCH_TCP_LISTEN") {
            self.server.tcp_listen = v;
        }
        if let Some(v) = get("GATEWATCH_HEALTH_LISTEN") {
            self.server.health_listen = v;
        }
        // a list from the environment: comma-separated, blanks around and empty items dropped
        let list = |v: String| -> Vec<String> {
            v.split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(String::from)
                .collect()
        };
        if let Some(v) = get("GATEWATCH_TCP_ALLOWED_NETWORKS") {
            // what a container started with GATEWATCH_TCP_LISTEN needs (its clients' networks:
            // docs/security.md, "How the raw TCP ingest is protected"). A variable set to
            // nothing (`GATEWATCH_TCP_ALLOWED_NETWORKS=`, an empty ConfigMap value, `,`) was
            // taken as an empty allow-list: every TCP client was refused at accept, and
            // `check-config` said ok. As for GATEWATCH_AUTH_TOKENS, no network in the variable
            // is taken as a mistake.
            let networks = list(v.clone());
            if networks.is_empty() {
                return Err(ConfigError::new(format!(
                    "server.tcp_allowed_networks: {v:?} holds no network, and would let no \
                     client in on the raw TCP listener: give comma-separated networks or \
                     addresses (e.g. 10.20.0.0/16,172.17.0.1), or unset the variable to keep \
                     the file's server.tcp_allowed_networks"
                )));
            }
            self.server.tcp_allowed_networks = networks;
        }
        if let Some(v) = get("GATEWATCH_AUTH_TOKENS") {
            // A variable set to nothing (`GATEWATCH_AUTH_TOKENS=`, an empty Secret, `,`) used
            // to replace the file's tokens with none, which is no authentication at all, and
            // `check-config` said ok. No token in the variable is taken as a mistake, never as
            // a wish: a daemon without authentication is configured in the file, where it is
            // written down (`auth_tokens = []`).
            let tokens = list(v.clone());
            if tokens.is_empty() {
                return Err(ConfigError::new(format!(
                    "server.auth_tokens: {v:?} holds no token, and would turn authentication \
                     off: give comma-separated tokens of at least 16 characters, or unset the \
                     variable to keep the file's server.auth_tokens (to run without \
                     authentication, unset it and set server.auth_tokens = [] in the file)"
                )));
            }
            self.server.auth_tokens = tokens;
        }
        if let Some(v) = get("GATEWATCH_LOG_FORMAT") {
            self.log.format = match v.as_str() {
                "text" => LogFormat::Text,
                "json" => LogFormat::Json,
                _ => {
                    return Err(ConfigError::new(
                        "GATEWATCH_LOG_FORMAT: must be \"text\" or \"json\"",
                    ))
                }
            };
        }
        if let Some(v) = get("GATEWATCH_JIT") {
            // Read by the model compiler itself (`model::jit_enabled`); checked here so that a
            // typo is an error at start-up rather than a silent default.
            if crate::model::jit_setting(&v).is_none() {
                return Err(ConfigError::new(format!(
                    "GATEWATCH_JIT: must be on or off (or true/false, 1/0), not {v:?}"
                )));
            }
        }
        if let Some(v) = get("GATEWATCH_STORAGE_PATH") {
            self.storage.path = v;
        }
        // the store without a file (a Kubernetes pod on NATS: docs/operations.md, "The store");
        // each checked here so that the message names the variable, not the key it sets
        if let Some(v) = get("GATEWATCH_STORAGE_BACKEND") {
            self.storage.backend = match v.as_str() {
                "sqlite" => crate::store::StorageBackend::Sqlite,
                "nats" => crate::store::StorageBackend::Nats,
                _ => {
                    return Err(ConfigError::new(format!(
                        "GATEWATCH_STORAGE_BACKEND: must be \"sqlite\" or \"nats\", not {v:?}"
                    )))
                }
            };
        }
        if let Some(v) = get("GATEWATCH_NATS_URL") {
            if v.trim().is_empty() || v.contains(char::is_whitespace) {
                return Err(ConfigError::new(format!(
                    "GATEWATCH_NATS_URL: {v:?} is not a server URL (e.g. nats://127.0.0.1:4222)"
                )));
            }
            self.storage.nats_url = v;
        }
        if let Some(v) = get("GATEWATCH_NATS_PREFIX") {
            if !crate::store::valid_nats_prefix(&v) {
                return Err(ConfigError::new(format!(
                    "GATEWATCH_NATS_PREFIX: {v:?}: letters, digits, '-' and '_' only, not empty"
                )));
            }
            self.storage.nats_prefix = v;
        }
        if let Some(v) = get("GATEWATCH_NATS_LEASE_SECONDS") {
            match v.trim().parse::<f64>() {
                Ok(t) if t.is_finite() && (1.0..=MAX_SECONDS).contains(&t) => {
                    self.storage.nats_lease_seconds = t
                }
                _ => {
                    return Err(ConfigError::new(format!(
                        "GATEWATCH_NATS_LEASE_SECONDS: {v:?} is not a number of seconds \
                         from 1 to {MAX_SECONDS}"
                    )))
                }
            }
        }
        if let Some(v) = get("GATEWATCH_LOG_LEVEL") {
            check_log_level(&v)
                .map_err(|e| ConfigError::new(format!("GATEWATCH_LOG_LEVEL: {e}")))?;
            self.log.level = v;
        }
        let parse_usize = |name: &str, v: String| {
            v.trim()
                .parse::<usize>()
                .map_err(|_| ConfigError::new(format!("{name}: must be a non-negative integer")))
        };
        if let Some(v) = get("GATEWATCH_WORKER_THREADS") {
            self.server.worker_threads = parse_usize("GATEWATCH_WORKER_THREADS", v)?;
        }
        if let Some(v) = get("GATEWATCH_MAX_GATES") {
            self.server.max_gates = parse_usize("GATEWATCH_MAX_GATES", v)?;
        }
        if let Some(v) = get("GATEWATCH_ACCEPT_UNKNOWN_GATES") {
            self.server.accept_unknown_gates = match v.as_str() {
                "true" | "1" => true,
                "false" | "0" => false,
                _ => {
                    return Err(ConfigError::new(
                        "GATEWATCH_ACCEPT_UNKNOWN_GATES: must be true or false",
                    ))
                }
            };
        }
        self.validate()
    }

    /// Checks the server-wide values.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let s = &self.server;
        let err = |key: &str, msg: &str| Err(ConfigError::new(format!("server.{key}: {msg}")));
        if s.listen.parse::<SocketAddr>().is_err() {
            return err("listen", "must be an address like 0.0.0.0:9464");
        }
        if !s.tcp_listen.is_empty() && s.tcp_listen.parse::<SocketAddr>().is_err() {
            return err(
                "tcp_listen",
                "must be empty or an address like 0.0.0.0:8094",
            );
        }
        if !s.health_listen.is_empty() && s.health_listen.parse::<SocketAddr>().is_err() {
            return err(
                "health_listen",
                "must be empty or an address like 0.0.0.0:9465",
            );
        }
        // one port for two listeners: `serve` bound the first and then failed on its own
        // port ("Address already in use") where check-config had said ok
        let http = s.listen.parse::<SocketAddr>().ok();
        let tcp = s.tcp_listen.parse::<SocketAddr>().ok();
        let health = s.health_listen.parse::<SocketAddr>().ok();
        if let Some((tcp, http)) = tcp.zip(http).filter(|(t, h)| same_port(*t, *h)) {
            return err(
                "tcp_listen",
                &format!("{tcp} takes the port of server.listen ({http}): give the line-protocol listener its own port, such as 8094"),
            );
        }
        for (other_key, other) in [("listen", http), ("tcp_listen", tcp)] {
            if let Some((health, other)) = health.zip(other).filter(|(h, o)| same_port(*h, *o)) {
                return err(
                    "health_listen",
                    &format!("{health} takes the port of server.{other_key} ({other}): give the health listener its own port, such as 9465"),
                );
            }
        }
        if s.worker_threads > MAX_WORKER_THREADS {
            return err(
                "worker_threads",
                &format!("must be at most {MAX_WORKER_THREADS} (0: the cores - 1)"),
            );
        }
        if s.auth_tokens.iter().any(|t| t.len() < 16) {
            return err(
                "auth_tokens",
                "every token must have at least 16 characters",
            );
        }
        if s.body_limit_bytes < 1024 {
            return err("body_limit_bytes", "must be >= 1024");
        }
        if s.max_concurrent_requests == 0 {
            return err("max_concurrent_requests", "must be > 0");
        }
        if s.max_concurrent_ingest == 0 {
            return err("max_concurrent_ingest", "must be > 0");
        }
        // every setting that becomes a `Duration` is bounded here: `from_secs_f64` panics on
        // values past u64::MAX seconds (1e300 once made `serve` exit 101)
        if !(s.request_timeout_seconds.is_finite()
            && s.request_timeout_seconds > 0.0
            && s.request_timeout_seconds <= MAX_SECONDS)
        {
            return err(
                "request_timeout_seconds",
                &format!("must be > 0 and <= {MAX_SECONDS} (one year)"),
            );
        }
        if !(s.identification_timeout_seconds.is_finite()
            && s.identification_timeout_seconds > 0.0
            && s.identification_timeout_seconds <= MAX_SECONDS)
        {
            return err(
                "identification_timeout_seconds",
                &format!("must be > 0 and <= {MAX_SECONDS} (one year)"),
            );
        }
        if s.max_gates == 0 || s.max_gates > MAX_GATES_LIMIT {
            return err("max_gates", &format!("must be in 1..={MAX_GATES_LIMIT}"));
        }
        if self.gates.len() > s.max_gates {
            return err(
                "max_gates",
                "is smaller than the number of [gates.*] tables",
            );
        }
        if s.max_tcp_connections == 0 {
            return err("max_tcp_connections", "must be > 0");
        }
        if !(s.shutdown_grace_seconds.is_finite()
            && (0.0..=MAX_SECONDS).contains(&s.shutdown_grace_seconds))
        {
            return err(
                "shutdown_grace_seconds",
                &format!("must be >= 0 and <= {MAX_SECONDS} (one year)"),
            );
        }
        s.validate_net()?;
        if let Err(e) = check_log_level(&self.log.level) {
            return Err(ConfigError::new(format!("log.level: {e}")));
        }
        if let Err(e) = check_line_protocol_key(&self.ingest.gate_tag) {
            return Err(ConfigError::new(format!("ingest.gate_tag: {e}")));
        }
        if self.ingest.value_fields.is_empty() {
            return Err(ConfigError::new("ingest.value_fields: must not be empty"));
        }
        for (i, field) in self.ingest.value_fields.iter().enumerate() {
            if let Err(e) = check_line_protocol_key(field) {
                return Err(ConfigError::new(format!("ingest.value_fields[{i}]: {e}")));
            }
        }
        // each connection buffers up to one line: at most `max_tcp_connections` of them
        if !(64..=MAX_TCP_LINE_BYTES).contains(&self.ingest.tcp_max_line_bytes) {
            return Err(ConfigError::new(format!(
                "ingest.tcp_max_line_bytes: must be from 64 to {MAX_TCP_LINE_BYTES}"
            )));
        }
        if let Err(e) = self.notify.validate() {
            return Err(ConfigError::new(format!("notify.{}: {e}", e.key())));
        }
        for (key, v) in [
            ("timeout_seconds", self.notify.timeout_seconds),
            (
                "resend_interval_seconds",
                self.notify.resend_interval_seconds,
            ),
        ] {
            if v > MAX_SECONDS {
                return Err(ConfigError::new(format!(
                    "notify.{key}: must be <= {MAX_SECONDS} (one year)"
                )));
            }
        }
        if let Err(e) = self.storage.validate() {
            return Err(ConfigError::new(e));
        }
        Ok(())
    }

    /// Settings that are accepted but probably wrong, one line each (`check-config` and `serve`
    /// print them on stderr).
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        let resend = self.notify.resend_interval_seconds;
        if !self.notify.alertmanager_urls.is_empty()
            && resend.is_finite()
            && resend > ALERTMANAGER_RESOLVE_TIMEOUT_SECONDS
        {
            out.push(format!(
                "notify.resend_interval_seconds = {resend} is longer than Alertmanager's default \
                 resolve_timeout ({ALERTMANAGER_RESOLVE_TIMEOUT_SECONDS} s): unless its \
                 resolve_timeout is raised, Alertmanager resolves firing alerts between re-sends"
            ));
        }
        if !self.server.accept_unknown_gates && self.gates.is_empty() {
            out.push(
                "server.accept_unknown_gates = false and no [gates.*] table: every sample is \
                 refused (404, unknown gate); configure the gates or accept unknown ones"
                    .to_string(),
            );
        }
        if let Some(w) = self.server.tcp_loopback_only_warning() {
            out.push(w);
        }
        out.extend(self.storage.warnings());
        out
    }

    /// How far ahead of the daemon's clock a gate's samples may be: the largest
    /// `max_future_seconds` of the defaults and the configured gates, `None` when one of them
    /// has no bound (0). The NATS store starts a history range's read from it
    /// (`NatsOptions::sample_lead`).
    pub fn sample_lead_bound(&self) -> Option<std::time::Duration> {
        std::iter::once(&self.defaults)
            .chain(self.gates.values())
            .map(|g| (g.max_future_seconds > 0.0).then_some(g.max_future_seconds))
            .try_fold(0.0_f64, |lead, g| g.map(|s| lead.max(s)))
            .and_then(|s| std::time::Duration::try_from_secs_f64(s).ok())
    }

    /// The settings of `gate`: its own table, or the defaults (`None` when unknown gates are
    /// refused and `gate` is not configured).
    pub fn gate(&self, gate: &str) -> Option<&GateConfig> {
        match self.gates.get(gate) {
            Some(g) => Some(g),
            None if self.server.accept_unknown_gates => Some(&self.defaults),
            None => None,
        }
    }
}

mod gate;
mod locate;
mod net;
pub use net::*;
#[cfg(test)]
mod tests;
