//! The monitoring daemon: ingestion (JSON, InfluxDB line protocol over HTTP and raw TCP),
//! per-gate sliding windows, identification on a bounded worker pool, Prometheus metrics,
//! alerts, and the `serve`, `check-config` and `simulate` commands.
//!
//! - [`config`]: TOML configuration, environment overrides, validation naming the key.
//! - [`ingest`]: request formats ([`ingest::json`], [`ingest::line_protocol`]) and the raw
//!   TCP listener ([`ingest::tcp`]).
//! - [`window`]: the ring buffer of a gate and the sample-time cadence.
//! - [`worker`]: `WindowAnalyzer`, the worker pool and its replace-don't-queue scheduler.
//! - [`state`]: the shared state; the only user of the alert engine ([`crate::alert`]) and of
//!   its notifier.
//! - [`metrics`]: the Prometheus metrics.
//! - [`api`]: routes, authentication, `HttpError`.
//! - [`server`]: `run`; [`shutdown`]: signals; [`cli`]: command-line entry points.
//! - [`bench`]: `gatewatch bench daemon`, load measurements.
//! - [`demo`]: `gatewatch demo`, daemon + webhook receiver + simulated gate in one process.

pub mod api;
pub mod bench;
pub mod cli;
pub mod config;
pub mod demo;
pub mod ingest;
pub mod metrics;
pub mod server;
pub mod shutdown;
pub mod state;
pub mod window;
pub mod worker;

/// Alert types as the daemon uses them (re-exported for tests and the integrator).
pub mod alerts {
    pub use crate::alert::notify::{NotifyConfig, WebhookTarget};
    pub use crate::alert::{Alert, AlertRules, GateState};
}
