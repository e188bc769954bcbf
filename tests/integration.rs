//! The integration tests, one crate: every file in `tests/` is a module of this binary, except
//! `service_ordering.rs`, which installs a process-global tracing subscriber and so keeps a
//! process of its own (both are listed in Cargo.toml, which turns `autotests` off).
//!
//! Why one binary: cargo runs test binaries one after another, so with 49 of them a test that
//! mostly waits (a Prometheus evaluation, a NATS reconnect) left CI's cores idle. In one
//! binary libtest's two threads overlap it with the others: the tests' run fell from 423 to
//! 269-309 s, and the shared helpers (`service_common`, ...) compile once instead of once per
//! file (docs/benchmarks.md, "CI time with one integration-test binary"). A test runs as
//! `cargo test --release --test integration MODULE::NAME`. `docs_match_code` checks that every
//! file in `tests/` is either a module here or its own target, so none is silently left out.

// shared helpers
mod cli_common;
mod fuzz_common;
mod history_common;
mod lp_common;
mod nats_common;
mod ode_common;
mod python_common;
mod service_common;
mod store_common;
mod store_conformance;
mod stream_common;

// the tests, one module per former binary
mod alert_notify;
mod ambient_estimators;
mod ambient_pooling;
mod analysis;
mod bad_input;
mod cli_ambient;
mod cli_identify;
mod cli_plot;
mod cli_usage;
mod damping_regimes;
mod deploy;
mod deploy_manifests;
mod docs_match_code;
mod e2e;
mod early_refusal;
mod fuzz_config;
mod fuzz_ingest;
mod grafana_dashboard;
mod identification;
mod influx_clients;
mod influx_compat;
mod lanes;
mod linalg_capped;
mod line_protocol_crate;
mod machine_code;
mod model_fuzz;
mod observability;
mod ode_accuracy;
mod ode_failures;
mod pem_exploration;
mod python_notebooks;
mod real_alerting;
mod restart_memory;
mod service_alerts;
mod service_memory;
mod service_net;
mod service_requests;
mod service_server;
mod service_workers;
mod soak;
mod store_history;
mod store_nats;
mod store_nats_busy;
mod store_nats_history;
mod store_nats_lease;
mod store_nats_serve;
mod store_outage;
mod store_restart;
mod tracking;
