//! The notifier's public face: [`spawn_notifier`] wires the tasks together and returns a
//! [`NotifierHandle`], through which the daemon queues events and shuts delivery down.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::client::build_client;
use super::dispatch::{Dispatcher, Input, TargetQueue};
use super::outbox::{Ack, OutboxEntry, TargetInfo};
use super::stats::{DropReason, NotifierStats};
use super::target::{Target, TargetKind, TargetTask};
use super::NotifyConfig;
use crate::alert::engine::{Alert, AlertEvent};

/// The sending side of the notifier. Cheap to clone; all clones feed the same tasks.
#[derive(Clone)]
pub struct NotifierHandle {
    inner: Arc<HandleInner>,
}

struct HandleInner {
    /// `None` after [`NotifierHandle::shutdown`]: dropping the sender closes the queue.
    tx: Mutex<Option<mpsc::Sender<Input>>>,
    stats: Arc<NotifierStats>,
    /// Set by the dispatcher once every target task has ended.
    done: watch::Receiver<bool>,
    /// Set at the shutdown deadline: the tasks abandon what is left.
    abort: watch::Sender<bool>,
    /// The targets, in the order outbox entries are addressed by.
    targets: Vec<TargetInfo>,
}

impl HandleInner {
    /// The sender slot. A poisoned lock is used anyway: the slot is an `Option` that is only
    /// ever taken, so a panic elsewhere cannot leave it half-written.
    fn tx(&self) -> MutexGuard<'_, Option<mpsc::Sender<Input>>> {
        self.tx
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl std::fmt::Debug for NotifierHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NotifierHandle")
            .field("stats", &self.inner.stats.snapshot())
            .finish()
    }
}

impl NotifierHandle {
    /// Queue a batch of events for delivery to every target. Never blocks: when the queue is
    /// full, or after [`NotifierHandle::shutdown`], the batch is dropped and counted in
    /// `dropped`. Returns whether the batch was queued. An empty batch is ignored (`true`).
    pub fn notify(&self, events: Vec<AlertEvent>) -> bool {
        if events.is_empty() {
            return true;
        }
        self.send(Input::Events(events))
    }

    /// Queue outbox entries, each for the target of that index in [`NotifierHandle::targets`]
    /// (the caller persisted them first). Never blocks; a full queue drops the batch, counted
    /// in `dropped` (persisted entries are delivered from the store at the next start).
    pub fn notify_entries(&self, entries: Vec<(usize, OutboxEntry)>) -> bool {
        if entries.is_empty() {
            return true;
        }
        self.send(Input::Entries(entries))
    }

    /// Re-send the firing alerts to the Alertmanager targets now (after a restart, so
    /// Alertmanager does not resolve them while the first windows are identified).
    pub fn resend_now(&self) -> bool {
        self.send(Input::ResendNow)
    }

    /// The targets, in order.
    pub fn targets(&self) -> &[TargetInfo] {
        &self.inner.targets
    }

    /// Queues `input` without blocking; a refusal is counted as one drop, with its reason.
    fn send(&self, input: Input) -> bool {
        let guard = self.inner.tx();
        let Some(tx) = guard.as_ref() else {
            self.inner.stats.drop_one(None, DropReason::ShutDown);
            return false;
        };
        match tx.try_send(input) {
            Ok(()) => true,
            Err(mpsc::error::TrySendError::Full(_)) => {
                self.inner.stats.drop_one(None, DropReason::QueueFull);
                false
            }
            Err(mpsc::error::TrySendError::Closed(_)) => {
                self.inner.stats.drop_one(None, DropReason::Stopped);
                false
            }
        }
    }

    /// The delivery counters.
    pub fn stats(&self) -> Arc<NotifierStats> {
        self.inner.stats.clone()
    }

    /// Stop accepting events, deliver what is queued (with retries) until `deadline` has
    /// passed, then abandon the rest (counted as dropped) and return. Returns `true` if
    /// everything queued was handled (delivered or failed) before the deadline. Idempotent.
    pub async fn shutdown(&self, deadline: Duration) -> bool {
        self.inner.tx().take();
        let mut done = self.inner.done.clone();
        // A dispatcher that ended without saying so (panicked) also counts as finished.
        let finished = tokio::time::timeout(deadline, done.wait_for(|d| *d))
            .await
            .is_ok();
        if !finished {
            tracing::warn!(
                ?deadline,
                "alert notifier: shutdown deadline reached, abandoning undelivered notifications"
            );
            self.inner.abort.send_replace(true);
        }
        finished
    }
}

/// Start the notifier: a dispatcher task and one task per target. Must be called inside a
/// tokio runtime (it spawns tasks).
///
/// `engine_snapshot` returns the alerts currently firing (normally
/// `engine.lock().firing()`); it is called every `resend_interval_seconds` when Alertmanager
/// targets are configured, from the dispatcher task, so it must be quick and must not block on
/// anything that waits for the notifier.
///
/// # Panics
/// When called outside a tokio runtime (like `tokio::spawn`).
///
/// Returns the handle and the dispatcher's join handle, which completes after
/// [`NotifierHandle::shutdown`] (or once every handle is dropped) when all target tasks have
/// ended.
pub fn spawn_notifier<F>(
    config: NotifyConfig,
    engine_snapshot: F,
) -> (NotifierHandle, JoinHandle<()>)
where
    F: Fn() -> Vec<Alert> + Send + Sync + 'static,
{
    spawn_notifier_with_ack(config, engine_snapshot, Arc::new(|_| {}))
}

/// [`spawn_notifier`] for a daemon with an outbox: `ack` is called (on a target task) with the
/// ids of outbox entries once they are settled, so the store deletes them.
pub fn spawn_notifier_with_ack<F>(
    config: NotifyConfig,
    engine_snapshot: F,
    ack: Ack,
) -> (NotifierHandle, JoinHandle<()>)
where
    F: Fn() -> Vec<Alert> + Send + Sync + 'static,
{
    let client = build_client(config.timeout());
    let stats = Arc::new(NotifierStats::new(
        config.webhooks.len(),
        config.alertmanager_urls.len(),
    ));
    let (tx, rx) = mpsc::channel(config.capacity());
    let (done_tx, done_rx) = watch::channel(false);
    let (abort_tx, abort_rx) = watch::channel(false);
    let config = Arc::new(config);

    let webhooks = config.webhooks.iter().map(|w| Target {
        url: w.url.clone(),
        kind: TargetKind::Webhook {
            receiver: w.receiver.clone(),
            bearer_token: w.bearer_token.clone(),
        },
    });
    let alertmanagers = config.alertmanager_urls.iter().map(|base| Target {
        url: format!("{}/api/v2/alerts", base.trim_end_matches('/')),
        kind: TargetKind::Alertmanager,
    });
    let mut targets = Vec::new();
    let mut infos = Vec::new();
    let mut tasks = Vec::new();
    for target in webhooks.chain(alertmanagers) {
        let is_alertmanager = target.is_alertmanager();
        infos.push(TargetInfo {
            key: format!(
                "{} {}",
                if is_alertmanager {
                    "alertmanager"
                } else {
                    "webhook"
                },
                target.url
            ),
            is_alertmanager,
        });
        let (sender, jobs) = mpsc::channel(config.capacity());
        targets.push(TargetQueue {
            sender,
            is_alertmanager: matches!(target.kind, TargetKind::Alertmanager),
            url: target.url.clone(),
        });
        let task = TargetTask {
            target,
            jobs,
            client: client.clone(),
            config: config.clone(),
            stats: stats.clone(),
            abort: abort_rx.clone(),
            ack: ack.clone(),
        };
        tasks.push(tokio::spawn(task.run()));
    }

    let dispatcher = Dispatcher {
        events: rx,
        targets,
        tasks,
        resend_interval: config.resend_interval(),
        snapshot: engine_snapshot,
        stats: stats.clone(),
        abort: abort_rx,
        done: done_tx,
    };
    let dispatcher = tokio::spawn(dispatcher.run());
    let handle = NotifierHandle {
        inner: Arc::new(HandleInner {
            tx: Mutex::new(Some(tx)),
            stats,
            done: done_rx,
            abort: abort_tx,
            targets: infos,
        }),
    };
    (handle, dispatcher)
}
