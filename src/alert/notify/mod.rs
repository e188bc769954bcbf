//! Delivery of alert events to webhooks and Alertmanager (tokio + reqwest).
//!
//! Shape of the machinery started by [`spawn_notifier`]:
//!
//! ```text
//!  NotifierHandle::notify(events)      (never blocks: try_send, drop + count when full)
//!        |  bounded mpsc, capacity = queue_capacity
//!        v
//!   dispatcher task ---- every resend_interval: engine_snapshot() -> firing alerts
//!        |  one bounded queue per target (capacity = queue_capacity), try_send, drop when full
//!        +--> webhook target task       POST {webhook payload v4}          retries + backoff
//!        +--> webhook target task       ...
//!        +--> alertmanager target task  POST {base}/api/v2/alerts [array]  retries + backoff
//! ```
//!
//! Each target has its own task and queue, so a dead or hanging receiver only delays itself.
//! Webhooks receive transitions (firing, resolved) only; Alertmanager also receives the
//! re-sends of firing alerts, because it resolves an alert by itself when it has not been
//! re-sent within its `resolve_timeout`.
//!
//! # Layout
//! - `config`: [`NotifyConfig`] and [`WebhookTarget`] (the `[notify]` section), backoff.
//! - `handle`: [`spawn_notifier`] and [`NotifierHandle`] (queue events, shut down).
//! - `dispatch`: the dispatcher task (fan-out to the target queues, periodic re-sends).
//! - `target`: one target task (its queue, formatting, retries with backoff).
//! - `payload`: the bodies, as typed serde structs ([`WebhookPayload`], [`PostableAlert`]).
//! - `client`: the HTTP client and [`ensure_crypto_provider`], the crate's one rustls set-up.
//! - `stats`: [`NotifierStats`] and the reasons a batch is dropped.
//! - [`outbox`]: outbox entries: in-order delivery until acknowledged or too old, supersession.

mod client;
mod config;
mod dispatch;
mod handle;
pub mod outbox;
mod payload;
mod stats;
mod target;

pub use client::ensure_crypto_provider;
pub use config::{
    NotifyConfig, NotifyConfigError, WebhookTarget, DEFAULT_OUTBOX_MAX_PENDING,
    DEFAULT_QUEUE_CAPACITY,
};
pub use handle::{spawn_notifier, spawn_notifier_with_ack, NotifierHandle};
pub use payload::{
    alertmanager_payload, webhook_payload, LabelSet, PostableAlert, WebhookAlert, WebhookPayload,
    ZERO_TIME,
};
pub use stats::{KindSnapshot, NotifierStats, StatsSnapshot, TargetType};
