//! Delivery counters and the reasons a batch is dropped.

use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};

/// The kind of a delivery target: the `target` label of `gatewatch_notifications_total`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TargetType {
    /// A webhook receiving Alertmanager's webhook format.
    Webhook,
    /// Alertmanager's `POST /api/v2/alerts`.
    Alertmanager,
}

impl TargetType {
    /// Every kind, in label order.
    pub const ALL: [TargetType; 2] = [TargetType::Webhook, TargetType::Alertmanager];

    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            TargetType::Webhook => "webhook",
            TargetType::Alertmanager => "alertmanager",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// One kind's counters.
#[derive(Debug, Default)]
struct Counters {
    delivered: AtomicU64,
    failed: AtomicU64,
    dropped: AtomicU64,
}

/// Delivery counters, shared with the daemon (turn them into Prometheus counters).
///
/// One unit is one batch for one target, counted by target kind: a batch of events sent to
/// two webhooks and one Alertmanager that all succeed adds 2 to the webhooks' `delivered` and
/// 1 to Alertmanager's. Re-sends to Alertmanager count too. A batch dropped before it reached
/// the targets' queues (the notifier's own queue full, or shut down) counts once per target,
/// since each of them missed it.
#[derive(Debug, Default)]
pub struct NotifierStats {
    counters: [Counters; 2],
    /// Targets of each kind (for the drops before the fan-out).
    targets: [u64; 2],
}

/// A copy of one kind's counters at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct KindSnapshot {
    /// Batches accepted by a target of this kind.
    pub delivered: u64,
    /// Batches given up for a target of this kind.
    pub failed: u64,
    /// Batches dropped for a target of this kind.
    pub dropped: u64,
}

/// A copy of the counters at one instant: totals over every target, and per kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatsSnapshot {
    /// Batches accepted by a target (2xx).
    pub delivered: u64,
    /// Batches given up after `max_attempts` (or a non-retryable answer such as 400).
    pub failed: u64,
    /// Batches dropped: queue full, notify after shutdown, or abandoned at the shutdown
    /// deadline.
    pub dropped: u64,
    /// Webhook targets only.
    pub webhook: KindSnapshot,
    /// Alertmanager targets only.
    pub alertmanager: KindSnapshot,
}

impl StatsSnapshot {
    /// The counters of one kind.
    pub fn of(&self, kind: TargetType) -> KindSnapshot {
        match kind {
            TargetType::Webhook => self.webhook,
            TargetType::Alertmanager => self.alertmanager,
        }
    }
}

/// Why a batch was dropped (all count in `dropped`; the reason is logged).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum DropReason<'a> {
    /// `notify` after [`NotifierHandle::shutdown`](super::NotifierHandle::shutdown).
    ShutDown,
    /// The handle's queue is full.
    QueueFull,
    /// The dispatcher has ended (it panicked, or every receiver is gone).
    Stopped,
    /// The queue of the target with this URL is full.
    TargetQueueFull(&'a str),
    /// Still queued or in flight when the shutdown deadline passed.
    ShutdownDeadline,
}

impl fmt::Display for DropReason<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DropReason::ShutDown => f.write_str("notifier shut down"),
            DropReason::QueueFull => f.write_str("notifier queue full"),
            DropReason::Stopped => f.write_str("notifier stopped"),
            DropReason::TargetQueueFull(url) => write!(f, "queue of {url} full"),
            DropReason::ShutdownDeadline => f.write_str("shutdown deadline"),
        }
    }
}

impl NotifierStats {
    /// Counters for `webhooks` webhook targets and `alertmanagers` Alertmanager targets.
    pub fn new(webhooks: usize, alertmanagers: usize) -> Self {
        NotifierStats {
            counters: Default::default(),
            targets: [webhooks as u64, alertmanagers as u64],
        }
    }

    /// Read all counters.
    pub fn snapshot(&self) -> StatsSnapshot {
        let kind = |k: TargetType| {
            let c = &self.counters[k.index()];
            KindSnapshot {
                delivered: c.delivered.load(Ordering::Relaxed),
                failed: c.failed.load(Ordering::Relaxed),
                dropped: c.dropped.load(Ordering::Relaxed),
            }
        };
        let (webhook, alertmanager) = (kind(TargetType::Webhook), kind(TargetType::Alertmanager));
        StatsSnapshot {
            delivered: webhook.delivered + alertmanager.delivered,
            failed: webhook.failed + alertmanager.failed,
            dropped: webhook.dropped + alertmanager.dropped,
            webhook,
            alertmanager,
        }
    }

    /// Count one batch dropped for one target of kind `target` (`None`: before the fan-out,
    /// so once for every target) and log why.
    pub(super) fn drop_one(&self, target: Option<TargetType>, why: DropReason<'_>) {
        let before = self.snapshot().dropped;
        match target {
            Some(t) => {
                self.counters[t.index()]
                    .dropped
                    .fetch_add(1, Ordering::Relaxed);
            }
            None => {
                for t in TargetType::ALL {
                    self.counters[t.index()]
                        .dropped
                        .fetch_add(self.targets[t.index()], Ordering::Relaxed);
                }
            }
        }
        let n = self.snapshot().dropped;
        // Rate limit: warn when the total crosses a power of two (1st, 2nd, 4th, 8th... drop).
        if n > before && (before + 1..=n).any(u64::is_power_of_two) {
            tracing::warn!(dropped_total = n, "alert notification dropped: {why}");
        } else {
            tracing::debug!(dropped_total = n, "alert notification dropped: {why}");
        }
    }

    pub(super) fn delivered_one(&self, target: TargetType) {
        self.counters[target.index()]
            .delivered
            .fetch_add(1, Ordering::Relaxed);
    }

    pub(super) fn failed_one(&self, target: TargetType) {
        self.counters[target.index()]
            .failed
            .fetch_add(1, Ordering::Relaxed);
    }
}
