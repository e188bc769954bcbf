//! The monitoring daemon: ingestion (JSON, InfluxDB line protocol over HTTP and raw TCP),
//! per-gate sliding windows, identification on a bounded worker pool, Prometheus metrics,
//! alerts, and the `serve`, `check-config` and `simulate` commands.
//!
//! - [`config`]: TOML configuration, environment overrides, validation naming the key.
//! - [`ingest`]: request formats ([`ingest::json`], [`ingest::line_protocol`]), pure parsing.
//! - [`ingest_checks`]: sample times against the daemon's clock, repeated query parameters.
//! - [`window`]: the ring buffer of a gate and the sample-time cadence; [`window_span`]: how
//!   much of it an identification reads (`window_cycles` of the gate's frequency).
//! - [`worker`]: `WindowAnalyzer`, the worker pool and its replace-don't-queue scheduler.
//! - [`state`]: the shared state; the only user of the alert engine ([`crate::alert`]) and of
//!   its notifier.
//! - [`metrics`]: the Prometheus metrics and the rejection reasons.
//! - [`limits`]: the body-bytes budget, refusals before the body is read, log escaping.
//! - [`api`]: routes, authentication, `HttpError`, and (in `api::influx`) the InfluxDB surface:
//!   `/ping`, `/health`, `/query`, gzip bodies, v2-shaped errors.
//! - [`server`]: `run` and the one-deadline shutdown; [`listen`]: the HTTP accept loop with its
//!   connection cap and header timeout; [`tcp`]: the raw TCP listener; [`shutdown`]: signals;
//!   [`log_limit`]: the accept loops' warnings, once per interval, and the per-gate lines of
//!   one sweep, at most ten and a summary; [`malloc`]: large buffers back to the OS.
//! - [`cli`]: command-line entry points; [`client`]: the simulate client (talks to a daemon
//!   over the network only, and installs the TLS crypto provider its HTTP client needs).
//! - [`bench`](mod@bench): `gatewatch bench daemon`, load measurements.
//! - [`bench_history`]: `gatewatch bench history`, a day of history: file size, route time.
//! - [`bench_warning`]: `gatewatch bench warning`, the scenarios streamed through [`state`] in
//!   sample time and scored against the simulator's truth.
//! - [`demo`]: `gatewatch demo`, daemon + webhook receiver + simulated gate in one process.
//! - [`storage`]: the daemon's side of the store ([`crate::store`]): restore at start, writes
//!   of the history, the alert states and the outbox; [`history`]: `GET .../history`;
//!   [`resume`]: each gate's analysis memory (trend, ambient level, tracking model) rebuilt
//!   from its latest stored windows at start.
//! - [`clock`], [`sync`]: Unix seconds and the poison-tolerant lock, shared by the above;
//!   [`stdout`]: command output that ends quietly when its reader goes away; [`rust_log`]:
//!   `RUST_LOG` read and checked (an invalid one is reported and `log.level` used).
//!
//! Imports go one way (no circle): `cli` -> `server`, `demo`, `client`, `shutdown`; `demo`,
//! `bench` -> `server`, `client`; `bench_warning` -> `state`, `worker`, `ingest`, `config`;
//! `server` -> `api`, `listen`, `tcp`, `state`, `worker`; `api`, `tcp` -> `state`, `ingest`,
//! `metrics`, `limits`; `state` -> `worker`, `window`, `window_span`, `ingest`, `ingest_checks`, `metrics`,
//! `config`, `resume`, `log_limit`; `resume` -> `worker`, `config`; `ingest_checks` -> `ingest`, `metrics`, `config`;
//! `ingest`, `worker` -> `config`; and `config`, `window`, `window_span`, `clock`, `sync`, `stdout`,
//! `rust_log` import nothing of the service.

pub mod api;
pub mod bench;
pub mod bench_history;
pub mod bench_soak;
pub mod bench_warning;
pub mod cli;
pub mod client;
pub mod clock;
pub mod config;
pub mod demo;
pub mod history;
pub mod ingest;
pub mod ingest_checks;
pub mod limits;
pub mod listen;
pub mod log_limit;
pub mod malloc;
pub mod metrics;
pub mod resume;
pub mod rust_log;
pub mod server;
pub mod shutdown;
pub mod state;
pub mod stdout;
pub mod storage;
pub mod sync;
pub mod tcp;
pub mod window;
pub mod window_span;
pub mod worker;

/// Alert types as the daemon uses them (re-exported for tests and the integrator).
pub mod alerts {
    pub use crate::alert::notify::{NotifyConfig, WebhookTarget};
    pub use crate::alert::{Alert, AlertRules, GateState};
}
