//! Delivery counters and the reasons a batch is dropped.

use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};

/// Delivery counters, shared with the daemon (turn them into Prometheus counters).
///
/// One unit is one batch for one target: a batch of events sent to two webhooks and one
/// Alertmanager that all succeed adds 3 to `delivered`. Re-sends to Alertmanager count too.
#[derive(Debug, Default)]
pub struct NotifierStats {
    /// Batches accepted by a target (2xx).
    pub delivered: AtomicU64,
    /// Batches given up after `max_attempts` (or a non-retryable answer such as 400).
    pub failed: AtomicU64,
    /// Batches dropped: queue full, notify after shutdown, or abandoned at the shutdown
    /// deadline.
    pub dropped: AtomicU64,
}

/// A copy of the counters at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatsSnapshot {
    pub delivered: u64,
    pub failed: u64,
    pub dropped: u64,
}

/// Why a batch was dropped (all count in [`NotifierStats::dropped`]; the reason is logged).
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
    /// Read all counters.
    pub fn snapshot(&self) -> StatsSnapshot {
        StatsSnapshot {
            delivered: self.delivered.load(Ordering::Relaxed),
            failed: self.failed.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
        }
    }

    /// Count one dropped batch and log why.
    pub(super) fn drop_one(&self, why: DropReason<'_>) {
        let n = self.dropped.fetch_add(1, Ordering::Relaxed) + 1;
        // Rate limit: warn on the 1st, 2nd, 4th, 8th... drop.
        if n.is_power_of_two() {
            tracing::warn!(dropped_total = n, "alert notification dropped: {why}");
        } else {
            tracing::debug!(dropped_total = n, "alert notification dropped: {why}");
        }
    }

    pub(super) fn delivered_one(&self) {
        self.delivered.fetch_add(1, Ordering::Relaxed);
    }

    pub(super) fn failed_one(&self) {
        self.failed.fetch_add(1, Ordering::Relaxed);
    }
}
