//! The notification outbox as the target tasks see it: one entry per alert transition and
//! target, delivered in order, retried until it is acknowledged or too old.
//!
//! The daemon writes each entry to the store *before* handing it to the notifier (see
//! `service::storage`), so a crash or a receiver outage of any length loses nothing: on
//! restart the undelivered entries are read back and delivered. A target task calls the
//! acknowledgement callback with the entry ids once they are settled (delivered, refused with a
//! 4xx, or given up at the maximum age), and the store deletes them.
//!
//! Rules (`docs/alerts.md`, "Outbox"):
//! - Per target, entries go out in the order of the transitions (head of line): a webhook
//!   receiver sees `firing` before `resolved`, even after an outage.
//! - Retries: jittered exponential backoff capped at `max_backoff_ms`, or the receiver's
//!   `Retry-After` (capped the same way), with no limit on attempts while the entry is younger
//!   than the maximum age; then it is given up, counted in `failed` and logged.
//! - Supersession ([`supersedes`]): a newer transition of the same alert (fingerprint)
//!   replaces older undelivered ones when they no longer matter: for Alertmanager any newer
//!   transition (its API takes states, the latest is the truth), for a webhook a new `firing`
//!   (a new episode: the old episode's firing and resolved are dropped). A webhook's `resolved`
//!   does not supersede its `firing`: both are delivered, in order.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use tokio::sync::{mpsc, watch};

use super::dispatch::{aborted, Job};
use super::stats::{DropReason, NotifierStats, TargetType};
use super::target::{body, next_wait, post, Target, WarnLimiter};
use super::NotifyConfig;
use crate::alert::engine::persist::AlertRecord;
use crate::alert::engine::{Alert, AlertEvent};

/// One notification for one target.
#[derive(Debug, Clone, PartialEq)]
pub struct OutboxEntry {
    /// The store's row id; `None` when it could not be persisted (delivered from memory).
    pub id: Option<i64>,
    /// Transitions of one batch are delivered in one request when they are next to each other.
    pub batch: u64,
    /// The transition.
    pub event: AlertEvent,
    /// When it happened: the maximum age counts from here.
    pub created: SystemTime,
}

/// Which targets exist, in the order the notifier numbers them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TargetInfo {
    /// The store's key of the target: `webhook <url>` or `alertmanager <url>`.
    pub key: String,
    /// Alertmanager targets take states; webhooks take transitions.
    pub is_alertmanager: bool,
}

/// Whether a newer transition (`newer_is_firing`) of an alert removes the older undelivered
/// ones of the same alert for a target of this kind. See the module documentation.
pub fn supersedes(is_alertmanager: bool, newer_is_firing: bool) -> bool {
    is_alertmanager || newer_is_firing
}

/// Appends `entry` to a target's pending entries, removing those it supersedes; past `max`
/// entries the oldest leave too and are appended to `evicted`, for the caller to give up
/// (`NotifyConfig::outbox_max_pending`).
pub(super) fn push(
    pending: &mut VecDeque<OutboxEntry>,
    entry: OutboxEntry,
    am: bool,
    max: usize,
    evicted: &mut Vec<OutboxEntry>,
) {
    if supersedes(am, entry.event.is_firing()) {
        let fp = &entry.event.alert().fingerprint;
        pending.retain(|e| &e.event.alert().fingerprint != fp);
    }
    pending.push_back(entry);
    while pending.len() > max.max(1) {
        evicted.extend(pending.pop_front());
    }
}

/// The JSON kept in the store for a transition.
pub fn encode(event: &AlertEvent) -> String {
    serde_json::to_string(&AlertRecord::from(event.alert())).unwrap_or_default()
}

/// An entry back from its stored JSON (`status` says firing or resolved).
pub fn decode(
    id: i64,
    batch: u64,
    status: &str,
    created: f64,
    payload: &str,
) -> Result<OutboxEntry, String> {
    let record: AlertRecord = serde_json::from_str(payload)
        .map_err(|e| format!("outbox row {id}: bad alert JSON: {e}"))?;
    let alert = Alert::from(record);
    let event = match status {
        "firing" => AlertEvent::Firing(alert),
        "resolved" => AlertEvent::Resolved(alert),
        other => return Err(format!("outbox row {id}: unknown status {other:?}")),
    };
    let created = Duration::try_from_secs_f64(created)
        .map(|d| SystemTime::UNIX_EPOCH + d)
        .map_err(|e| format!("outbox row {id}: bad time {created}: {e}"))?;
    Ok(OutboxEntry {
        id: Some(id),
        batch,
        event,
        created,
    })
}

/// Called with the ids of settled entries (delivered, refused, given up) so the store deletes
/// them.
pub type Ack = Arc<dyn Fn(Vec<i64>) + Send + Sync>;

/// What [`drain`] needs from its target task.
pub(super) struct Drain<'a> {
    pub target: &'a Target,
    pub client: Option<&'a reqwest::Client>,
    pub config: &'a NotifyConfig,
    pub stats: &'a NotifierStats,
    pub kind: TargetType,
    pub ack: &'a Ack,
    pub limiter: &'a mut WarnLimiter,
}

/// Delivers `first` and every outbox entry that arrives meanwhile, in order, until none is
/// left. Other jobs arriving meanwhile are kept in `deferred` (one re-send at most: only the
/// latest matters). Returns `false` when the shutdown deadline aborted it: entries with a row
/// id stay in the store for the next start; those without one are counted as dropped.
pub(super) async fn drain(
    d: Drain<'_>,
    first: Vec<OutboxEntry>,
    jobs: &mut mpsc::Receiver<Job>,
    abort: &mut watch::Receiver<bool>,
    deferred: &mut VecDeque<Job>,
) -> bool {
    let am = d.target.is_alertmanager();
    let cap = d.config.outbox_max_pending;
    let mut pending = VecDeque::new();
    let mut evicted = Vec::new();
    for e in first {
        push(&mut pending, e, am, cap, &mut evicted);
    }
    if let Some(why) = give_up_evicted(d.stats, d.kind, d.ack, cap, &mut evicted) {
        d.limiter.failure_message(&d.target.url, &why);
    }
    let max = d.config.max_backoff();
    let mut closed = false;
    let lost = |pending: &VecDeque<OutboxEntry>| {
        for _ in pending.iter().filter(|e| e.id.is_none()) {
            d.stats.drop_one(Some(d.kind), DropReason::ShutdownDeadline);
        }
    };
    'outer: while let Some(head) = pending.front() {
        let batch = head.batch;
        let n = pending.iter().take_while(|e| e.batch == batch).count();
        let group: Vec<OutboxEntry> = pending.iter().take(n).cloned().collect();
        let settle = |pending: &mut VecDeque<OutboxEntry>| {
            let ids: Vec<i64> = pending.drain(..n).filter_map(|e| e.id).collect();
            if !ids.is_empty() {
                (d.ack)(ids);
            }
        };
        let job = Job::Events(Arc::new(group.iter().map(|e| e.event.clone()).collect()));
        let body = match body(&d.target.kind, &job, &d.config.external_url) {
            Some(Ok(b)) => b,
            Some(Err(e)) => {
                d.stats.failed_one(d.kind);
                tracing::error!(target_url = %d.target.url, "alert delivery: {e}");
                settle(&mut pending);
                continue;
            }
            // every target takes transitions
            None => {
                settle(&mut pending);
                continue;
            }
        };
        let oldest = group
            .iter()
            .map(|e| e.created)
            .min()
            .unwrap_or_else(SystemTime::now);
        let mut backoff = Duration::from_millis(d.config.initial_backoff_ms);
        let mut attempts: u32 = 0;
        loop {
            attempts = attempts.saturating_add(1);
            let result = tokio::select! {
                biased;
                _ = aborted(abort) => { lost(&pending); return false; }
                r = post(d.target, d.client, &body) => r,
            };
            let error = match result {
                Ok(()) => {
                    d.stats.delivered_one(d.kind);
                    settle(&mut pending);
                    continue 'outer;
                }
                Err(e) => e,
            };
            let age = SystemTime::now().duration_since(oldest).unwrap_or_default();
            let expired = match d.config.outbox_max_age {
                Some(max_age) => age >= max_age,
                None => attempts >= d.config.max_attempts.max(1),
            };
            if !error.retryable() || expired {
                d.stats.failed_one(d.kind);
                let why = if error.retryable() {
                    format!("{error}; given up after {attempts} attempts over {age:?}")
                } else {
                    format!("{error} (not retried)")
                };
                d.limiter.failure_message(&d.target.url, &why);
                settle(&mut pending);
                continue 'outer;
            }
            let wait = next_wait(&error, backoff, max, fastrand::f64());
            backoff = backoff.saturating_mul(2).min(max);
            tracing::debug!(target_url = %d.target.url, attempts, ?wait, "alert delivery: {error}, retrying");
            let until = tokio::time::Instant::now() + wait;
            loop {
                tokio::select! {
                    biased;
                    _ = aborted(abort) => { lost(&pending); return false; }
                    _ = tokio::time::sleep_until(until) => break,
                    job = jobs.recv(), if !closed => match job {
                        Some(Job::Outbox(entries)) => {
                            for e in entries {
                                push(&mut pending, e, am, cap, &mut evicted);
                            }
                            if let Some(why) = give_up_evicted(d.stats, d.kind, d.ack, cap, &mut evicted) {
                                d.limiter.failure_message(&d.target.url, &why);
                            }
                            // the entries in flight were superseded: start over with the head
                            if !pending.iter().take(n).eq(group.iter()) {
                                continue 'outer;
                            }
                        }
                        Some(Job::Resend(r)) => {
                            deferred.retain(|j| !matches!(j, Job::Resend(_)));
                            deferred.push_back(Job::Resend(r));
                        }
                        Some(other) => {
                            if deferred.len() < d.config.capacity() {
                                deferred.push_back(other);
                            } else {
                                d.stats.drop_one(Some(d.kind), DropReason::TargetQueueFull(&d.target.url));
                            }
                        }
                        None => closed = true,
                    },
                }
            }
        }
    }
    true
}

/// Gives up the entries `push` evicted at the target's bound (`cap`), as an entry at its
/// maximum age: each counted in `failed`, their store rows acknowledged (deleted). The warning
/// to log, when there were some (the caller logs it through the target's limiter).
fn give_up_evicted(
    stats: &NotifierStats,
    kind: TargetType,
    ack: &Ack,
    cap: usize,
    evicted: &mut Vec<OutboxEntry>,
) -> Option<String> {
    if evicted.is_empty() {
        return None;
    }
    for _ in evicted.iter() {
        stats.failed_one(kind);
    }
    let ids: Vec<i64> = evicted.iter().filter_map(|e| e.id).collect();
    if !ids.is_empty() {
        ack(ids);
    }
    let why = format!(
        "{} undelivered notifications queued for this target (the bound, while its oldest is \
         retried): the {} oldest given up",
        cap.max(1),
        evicted.len()
    );
    evicted.clear();
    Some(why)
}

#[cfg(test)]
mod tests {
    use std::collections::{BTreeMap, VecDeque};

    use super::*;

    fn event(fp: &str, firing: bool) -> AlertEvent {
        let a = Alert {
            name: "GateNegativeDamping".into(),
            labels: BTreeMap::new(),
            annotations: BTreeMap::new(),
            starts_at: SystemTime::UNIX_EPOCH + Duration::from_secs(5),
            ends_at: (!firing).then(|| SystemTime::UNIX_EPOCH + Duration::from_secs(9)),
            fingerprint: fp.into(),
        };
        if firing {
            AlertEvent::Firing(a)
        } else {
            AlertEvent::Resolved(a)
        }
    }

    fn entry(n: i64, fp: &str, firing: bool) -> OutboxEntry {
        OutboxEntry {
            id: Some(n),
            batch: n as u64,
            event: event(fp, firing),
            created: SystemTime::UNIX_EPOCH,
        }
    }

    /// [`push`] with no bound.
    fn push_all(p: &mut VecDeque<OutboxEntry>, e: OutboxEntry, am: bool) {
        let mut evicted = Vec::new();
        push(p, e, am, usize::MAX, &mut evicted);
        assert!(evicted.is_empty());
    }

    #[test]
    fn past_the_bound_the_oldest_entries_leave_after_supersession() {
        let mut p = VecDeque::new();
        let mut evicted = Vec::new();
        for (n, fp) in [(1, "a"), (2, "b"), (3, "c")] {
            push(&mut p, entry(n, fp, true), false, 3, &mut evicted);
        }
        assert!(evicted.is_empty(), "at the bound, not past it");
        // a re-fire of `a` supersedes its old episode first: nothing to evict
        push(&mut p, entry(4, "a", true), false, 3, &mut evicted);
        assert_eq!(ids(&p), [2, 3, 4]);
        assert!(evicted.is_empty());
        push(&mut p, entry(5, "d", true), false, 3, &mut evicted);
        assert_eq!(ids(&p), [3, 4, 5]);
        assert_eq!(evicted.iter().filter_map(|e| e.id).collect::<Vec<_>>(), [2]);
        // a bound of 0 acts as 1
        push(&mut p, entry(6, "e", true), false, 0, &mut evicted);
        assert_eq!(ids(&p), [6]);
        assert_eq!(evicted.len(), 4);
    }

    fn ids(p: &VecDeque<OutboxEntry>) -> Vec<i64> {
        p.iter().filter_map(|e| e.id).collect()
    }

    #[test]
    fn webhooks_keep_firing_then_resolved_and_a_new_episode_replaces_the_old() {
        let mut p = VecDeque::new();
        push_all(&mut p, entry(1, "a", true), false);
        push_all(&mut p, entry(2, "b", true), false);
        push_all(&mut p, entry(3, "a", false), false);
        assert_eq!(ids(&p), [1, 2, 3], "resolved does not supersede firing");
        push_all(&mut p, entry(4, "a", true), false);
        assert_eq!(ids(&p), [2, 4], "a re-fire replaces the old episode");
    }

    #[test]
    fn alertmanager_keeps_only_the_latest_state_of_an_alert() {
        let mut p = VecDeque::new();
        push_all(&mut p, entry(1, "a", true), true);
        push_all(&mut p, entry(2, "b", true), true);
        push_all(&mut p, entry(3, "a", false), true);
        assert_eq!(ids(&p), [2, 3]);
    }

    #[test]
    fn entries_round_trip_through_their_json() {
        let e = event("a", false);
        let back = decode(7, 3, "resolved", 12.5, &encode(&e)).expect("decode");
        assert_eq!(back.event, e);
        assert_eq!(back.id, Some(7));
        assert_eq!(
            back.created,
            SystemTime::UNIX_EPOCH + Duration::from_millis(12_500)
        );
        assert!(decode(7, 3, "weird", 1.0, &encode(&e)).is_err());
        assert!(decode(7, 3, "firing", 1.0, "{").is_err());
    }
}
