//! The dispatcher task: takes batches from the handle's queue and fans them out to the
//! targets' queues, and every resend interval fans the firing alerts out to the Alertmanager
//! targets.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::outbox::OutboxEntry;
use super::stats::{DropReason, NotifierStats, TargetType};
use crate::alert::engine::{Alert, AlertEvent};

/// Period of the (disabled) resend ticker when there is nothing to re-send: `interval_at`
/// needs a non-zero period even when its branch of the `select!` is off.
const IDLE_TICK: Duration = Duration::from_secs(3600);

/// What a target task is asked to deliver. The payload is shared by all targets (`Arc`);
/// each target formats it its own way.
#[derive(Debug, Clone)]
pub(super) enum Job {
    /// Transitions from the engine (every target).
    Events(Arc<Vec<AlertEvent>>),
    /// Firing alerts re-sent so Alertmanager does not resolve them (Alertmanager targets only).
    Resend(Arc<Vec<Alert>>),
    /// Outbox entries of this target, delivered in order until acknowledged or too old.
    Outbox(Vec<OutboxEntry>),
}

/// What the handle sends to the dispatcher.
#[derive(Debug)]
pub(super) enum Input {
    /// Transitions for every target, kept in memory only.
    Events(Vec<AlertEvent>),
    /// Outbox entries, each for the target of that index.
    Entries(Vec<(usize, OutboxEntry)>),
    /// Re-send the firing alerts to Alertmanager now (after a restart).
    ResendNow,
}

/// The dispatcher's end of one target's queue.
#[derive(Debug)]
pub(super) struct TargetQueue {
    pub sender: mpsc::Sender<Job>,
    /// Alertmanager targets also get the re-sends.
    pub is_alertmanager: bool,
    /// The URL the target posts to (for log lines).
    pub url: String,
}

impl TargetQueue {
    /// The `target` label of the target's counters.
    pub fn target_type(&self) -> TargetType {
        if self.is_alertmanager {
            TargetType::Alertmanager
        } else {
            TargetType::Webhook
        }
    }
}

/// Everything the dispatcher task owns.
pub(super) struct Dispatcher<F> {
    /// Batches from [`NotifierHandle::notify`](super::NotifierHandle::notify).
    pub events: mpsc::Receiver<Input>,
    pub targets: Vec<TargetQueue>,
    /// The target tasks; awaited after their queues are closed.
    pub tasks: Vec<JoinHandle<()>>,
    /// From the configuration; `None`: no re-sends.
    pub resend_interval: Option<Duration>,
    /// The engine's firing alerts.
    pub snapshot: F,
    pub stats: Arc<NotifierStats>,
    /// Set at the shutdown deadline.
    pub abort: watch::Receiver<bool>,
    /// Set once every target task has ended.
    pub done: watch::Sender<bool>,
}

impl<F> Dispatcher<F>
where
    F: Fn() -> Vec<Alert> + Send + Sync + 'static,
{
    /// Runs until the handle's queue is closed (shutdown, or every handle dropped) or the
    /// shutdown deadline passes, then closes the target queues, waits for the target tasks and
    /// sets `done`.
    pub async fn run(self) {
        let Dispatcher {
            mut events,
            targets,
            tasks,
            resend_interval,
            snapshot,
            stats,
            mut abort,
            done,
        } = self;
        let has_am = targets.iter().any(|t| t.is_alertmanager);
        let resend = resend_interval.filter(|_| has_am);
        let period = resend.unwrap_or(IDLE_TICK);
        let mut ticker = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);

        let fan_out = |job: Job, am_only: bool| {
            for t in &targets {
                if am_only && !t.is_alertmanager {
                    continue;
                }
                if t.sender.try_send(job.clone()).is_err() {
                    stats.drop_one(Some(t.target_type()), DropReason::TargetQueueFull(&t.url));
                }
            }
        };

        loop {
            tokio::select! {
                biased;
                _ = aborted(&mut abort) => {
                    // Count what is still queued here as dropped.
                    events.close();
                    while events.try_recv().is_ok() {
                        stats.drop_one(None, DropReason::ShutdownDeadline);
                    }
                    break;
                }
                msg = events.recv() => match msg {
                    Some(Input::Events(batch)) => fan_out(Job::Events(Arc::new(batch)), false),
                    Some(Input::Entries(entries)) => {
                        let mut per_target: Vec<Vec<OutboxEntry>> = vec![Vec::new(); targets.len()];
                        for (i, e) in entries {
                            if let Some(v) = per_target.get_mut(i) {
                                v.push(e);
                            }
                        }
                        for (t, entries) in targets.iter().zip(per_target) {
                            if entries.is_empty() {
                                continue;
                            }
                            // persisted entries are not lost when the queue is full: the next
                            // start delivers them from the store
                            if t.sender.try_send(Job::Outbox(entries)).is_err() {
                                stats.drop_one(Some(t.target_type()), DropReason::TargetQueueFull(&t.url));
                            }
                        }
                    }
                    Some(Input::ResendNow) => {
                        if has_am {
                            let alerts = snapshot();
                            if !alerts.is_empty() {
                                fan_out(Job::Resend(Arc::new(alerts)), true);
                            }
                        }
                    }
                    None => {
                        // Shutting down: nothing is resolved, and the firing alerts are re-sent
                        // once more, so Alertmanager keeps them active for a whole
                        // resolve_timeout from now, the time a restarted daemon has to
                        // re-assert them (docs/alerts.md, "Restarts").
                        if resend.is_some() {
                            let alerts = snapshot();
                            if !alerts.is_empty() {
                                fan_out(Job::Resend(Arc::new(alerts)), true);
                            }
                        }
                        break;
                    }
                },
                _ = ticker.tick(), if resend.is_some() => {
                    let alerts = snapshot();
                    if !alerts.is_empty() {
                        fan_out(Job::Resend(Arc::new(alerts)), true);
                    }
                }
            }
        }
        drop(targets); // closes the target queues: target tasks drain and end
        for t in tasks {
            if let Err(e) = t.await {
                tracing::error!("alert notifier: a target task ended abnormally: {e}");
            }
        }
        done.send_replace(true);
    }
}

/// Resolves when an abort is requested; pends forever if the abort sender is gone.
pub(super) async fn aborted(rx: &mut watch::Receiver<bool>) {
    loop {
        if *rx.borrow_and_update() {
            return;
        }
        if rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}
