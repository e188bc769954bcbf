//! gatewatch: early warning of self-excited vibrations of hydraulic gates.
//!
//! The library identifies a gate's equation of motion, a second-order ODE such as
//! `ydd + (c1 + c2*yd^2)*yd + c3*y = 0`, from a sampled signal with a self-adaptive differential
//! evolution, and turns the identified model into damping figures an engineer can act on.
//! The `gatewatch` binary wraps it as a command-line tool and a monitoring daemon.
//!
//! # Layout
//!
//! Numerical core (no tokio, axum or prometheus below this line):
//! - [`model`]: the model language: parse an equation, check it is linear in `ydd`, compile it
//!   (to an accumulator program, and to machine code with Cranelift where it can: `model::jit`).
//! - [`linalg`]: nalgebra's eigen- and singular-value decompositions with an iteration cap, so
//!   that no matrix can keep a worker spinning.
//! - [`ode`]: integrators (Dormand-Prince 5(4), fixed-step RK4, Rosenbrock) with failure reports.
//! - [`de`]: the Cauchy differential evolution, generic over any objective, parallel and seeded.
//! - [`data`]: time series and their CSV loading, with errors that name line and column.
//! - [`identify`]: fitness, train/test split, DE + local refinement + restarts: the identification.
//! - [`cases`]: the chapter's seed cases (Table 8.1), generated in code.
//! - [`analysis`]: the early-warning analysis of a window: damping figures and a verdict.
//! - [`spectral`]: model-free analysis: dominant frequency, Hilbert envelope growth, ambient AR and
//!   SSI-COV damping, a limit cycle's zeta0 from its envelope, pooling of a gate's windows.
//! - [`simulate`]: synthetic gate signals: noise-driven gate with a damping scenario, worked example.
//! - [`bench`](mod@bench): `gatewatch bench seed-cases`: the chapter's protocol and its
//!   comparison table.
//! - [`stability`]: the stability map (Figure 8.13): Monte Carlo over a plane of two coefficients,
//!   each point simulated and classified stable (the free vibration decays) or unstable.
//! - [`number`]: numbers in messages: plain when moderate, `1e300` when not ([`number::Num`]).
//!
//! Service (tokio, axum, prometheus; nothing in the numerical core depends on it):
//! - [`alert`]: per-gate alert state machine (negative damping, stale data), delivery to
//!   webhooks in Alertmanager's format and to Alertmanager's API.
//! - [`service`]: the monitoring daemon (`gatewatch serve`): configuration, ingestion (JSON,
//!   InfluxDB line protocol over HTTP and TCP), per-gate windows, the identification worker pool,
//!   Prometheus metrics, alert wiring, HTTP API, graceful shutdown, and the `check-config` and
//!   `simulate` commands.
//! - [`store`]: the daemon's persistence behind one trait: the SQLite file (history, alert
//!   state, notification outbox), its writer thread, its size bound, and its lock; the same on
//!   NATS JetStream streams (`store::NatsStore`), for daemons that share their gates.
//!
//! Front ends:
//! - [`cli`]: the command-line interface behind `src/main.rs`.
//! - [`plot`]: engineers' pictures (SVG or PNG): data with the fitted model, phase plane,
//!   hysteresis loop, DE convergence, stability map.

pub mod alert;
pub mod analysis;
pub mod bench;
pub mod cases;
pub mod cli;
pub mod data;
pub mod de;
pub mod identify;
pub mod linalg;
pub mod model;
pub mod number;
pub mod ode;
pub mod plot;
pub mod service;
pub mod simulate;
pub mod spectral;
pub mod stability;
pub mod store;
