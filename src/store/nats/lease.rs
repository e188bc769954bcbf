//! The owner lease: one daemon per prefix, as the SQLite store's lock is one daemon per file.
//!
//! Why: two daemons on one prefix would both restore the same alert states, both fire
//! `GateDataStale` for gates only the other receives, both write their states back over the
//! other's and both deliver the same outbox. The SQLite lock is the kernel's and dies with the
//! process; a NATS server knows nothing of a client's process, so the claim is a record with
//! an expiry that its owner renews: a lease.
//!
//! The record ([`LeaseRecord`]: instance, host, pid, start and expiry) is the one message of
//! subject `<prefix>.owner` in stream `<PREFIX>_OWNER` (one message kept per subject). Every
//! write of it is conditional: `Nats-Expected-Last-Subject-Sequence` is the sequence the writer
//! last saw (0: none), so of two daemons that read the same record and write theirs, the server
//! stores one and refuses the other (`wrong last sequence`): there is no window in which both
//! believe they won.
//!
//! - At open ([`acquire`]): a live record of another instance refuses the start, naming the
//!   owner and when its lease expires; an expired or released one (or none) is taken.
//! - Every [`renew_interval`] (a third of the TTL, so two renewals may fail before the lease
//!   expires) the owner writes its record again, expected sequence = the one it last wrote
//!   ([`renew`]). A server that does not answer is not a loss: the renewal is retried every
//!   [`retry_interval`] (a fifth of the interval) until one gets through. A refused renewal
//!   means someone else wrote: when it is a live lease of another
//!   instance, this daemon has lost the prefix ([`Renewal::Lost`]); when the record is its own
//!   (an earlier renewal stored whose answer was lost) it goes on from it; when it is expired,
//!   released or gone, the prefix is taken again as at start.
//! - At a clean shutdown ([`release`]) the record is written expired, so the next start does
//!   not wait; after `kill -9` the next start is refused until the TTL has passed.
//!
//! The expiry is the writer's wall clock: the hosts' clocks must agree (NTP) well within the
//! TTL. The lease fences what plays by it: a write already on its way when the lease is lost
//! may still land. The same record and the same conditional write per gate (a subject per gate)
//! is how several daemons will share the gates later.

use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use async_nats::jetstream::context::PublishErrorKind;
use async_nats::jetstream::message::PublishMessage as Publish;
use async_nats::jetstream::stream::LastRawMessageErrorKind;
use async_nats::jetstream::ErrorCode;
use serde::{Deserialize, Serialize};

use super::{Conn, Failure};

/// How long an owner lease lasts without renewal by default (`storage.nats_lease_seconds`):
/// how long a prefix stays refused after its daemon was killed without releasing it. 30 s is
/// the shortest at which a renewal ([`renew_interval`], every 10 s) gets the whole
/// [`OPERATION_TIMEOUT`](super::OPERATION_TIMEOUT) of 10 s, and two in a row that each take all
/// of it still land in time (shorter leases are warned about: `StorageConfig::warnings`); a
/// failed renewal is retried every [`retry_interval`] until the expiry (`docs/design.md`, "The
/// owner lease"). A systemd `Restart=` loop after a `kill -9` gets through within half a minute.
pub const LEASE_TTL: Duration = Duration::from_secs(30);

/// The renewals per TTL: the lease is written again every TTL / 3.
pub const RENEWALS_PER_TTL: u32 = 3;

/// How often an owner renews a lease of `ttl`.
pub fn renew_interval(ttl: Duration) -> Duration {
    (ttl / RENEWALS_PER_TTL).max(Duration::from_millis(100))
}

/// Failed renewals of the lease are retried this many times per [`renew_interval`].
pub const RETRIES_PER_RENEWAL: u32 = 5;

/// How soon a renewal that failed is tried again: a fifth of [`renew_interval`] (2 s at the
/// default 30 s TTL), at least 100 ms. Why not at the next renewal: a server that was away (a
/// restart, an upgrade) for longer than the lease has let it expire, and the store refuses
/// every write until a renewal gets through. Waiting out a whole interval after the server
/// was back lost up to 10 s of writes at the default TTL (session 56); the retries bound that
/// to about 2 s plus the client's reconnection (at most [`super::RECONNECT_DELAY_MAX`] apart).
pub fn retry_interval(ttl: Duration) -> Duration {
    (renew_interval(ttl) / RETRIES_PER_RENEWAL).max(Duration::from_millis(100))
}

/// Who owns a prefix, as its lease message holds it (JSON).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeaseRecord {
    /// Random, drawn at each open of the store: a restarted daemon is a new instance.
    pub instance: String,
    /// The owner's host name.
    pub host: String,
    /// The owner's process id.
    pub pid: u32,
    /// When the owner took the prefix, Unix seconds.
    pub since: f64,
    /// When the lease ends unless renewed, Unix seconds (the owner's clock); a released lease
    /// has ended.
    pub expires: f64,
}

impl LeaseRecord {
    /// A record of this process, taken now, expiring after `ttl`.
    pub fn this_process(ttl: Duration) -> LeaseRecord {
        let now = unix_now();
        LeaseRecord {
            instance: format!("{:016x}", fastrand::u64(..)),
            host: host_name(),
            pid: std::process::id(),
            since: now,
            expires: now + ttl.as_secs_f64(),
        }
    }

    /// Whether the lease is still running at `now` (Unix seconds).
    pub fn live(&self, now: f64) -> bool {
        self.expires > now
    }

    /// `host H pid P since T; its lease expires in N s`, for the messages.
    pub fn describe(&self, now: f64) -> String {
        format!(
            "host {} pid {} since {}; its lease expires in {:.0} s",
            self.host,
            self.pid,
            rfc3339(self.since),
            (self.expires - now).max(0.0).ceil()
        )
    }
}

/// Unix seconds now.
pub(super) fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

fn rfc3339(t: f64) -> String {
    let t = UNIX_EPOCH + Duration::try_from_secs_f64(t.max(0.0)).unwrap_or_default();
    humantime::format_rfc3339_seconds(t).to_string()
}

/// The kernel's host name (no `unsafe` call to `gethostname`), `$HOSTNAME`, or `unknown`.
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "unknown".to_string())
}

/// The lease this store holds: its record and the sequence it was last stored at.
#[derive(Debug)]
pub(super) struct Held {
    pub(super) ttl: Duration,
    pub(super) state: Mutex<HeldState>,
}

/// What changes while the lease is held.
#[derive(Debug, Clone)]
pub(super) struct HeldState {
    pub(super) record: LeaseRecord,
    pub(super) seq: u64,
    /// Why the prefix was lost (another owner), once it was: every write is refused from then.
    pub(super) lost: Option<String>,
    /// Released at shutdown: no renewal any more.
    pub(super) released: bool,
}

/// The outcome of a conditional write of the record.
pub(super) enum Claim {
    /// Stored at this sequence.
    Won(u64),
    /// The subject's last sequence was not the expected one: someone else wrote.
    Refused,
}

/// The last lease record of the prefix and its sequence, `None` when there is none.
pub(super) async fn read(c: &Conn) -> Result<Option<(u64, LeaseRecord)>, Failure> {
    let subject = c.names.owner_subject();
    match c.owner.get_last_raw_message_by_subject(&subject).await {
        Ok(m) => {
            let record = serde_json::from_slice(&m.payload)
                .map_err(|e| format!("owner lease message {} of {subject}: {e}", m.sequence))?;
            Ok(Some((m.sequence, record)))
        }
        Err(e) => {
            let none = match e.kind() {
                LastRawMessageErrorKind::NoMessageFound => true,
                LastRawMessageErrorKind::JetStream(j) => {
                    j.error_code() == ErrorCode::NO_MESSAGE_FOUND
                }
                _ => false,
            };
            if none {
                Ok(None)
            } else {
                Err(format!("read of the owner lease {subject}: {e}"))
            }
        }
    }
}

/// Writes `record` as the lease, only if the subject's last sequence is `expected` (0: the
/// subject has no message).
pub(super) async fn claim(c: &Conn, expected: u64, record: &LeaseRecord) -> Result<Claim, Failure> {
    let subject = c.names.owner_subject();
    let payload = serde_json::to_vec(record).map_err(|e| format!("owner lease: {e}"))?;
    let publish = Publish::build()
        .payload(payload.into())
        .expected_last_subject_sequence(expected);
    let ack =
        c.js.send_publish(subject.clone(), publish)
            .await
            .map_err(|e| format!("write of the owner lease {subject}: {e}"))?
            .await;
    match ack {
        Ok(ack) => Ok(Claim::Won(ack.sequence)),
        Err(e) if e.kind() == PublishErrorKind::WrongLastSequence => Ok(Claim::Refused),
        Err(e) => Err(format!("write of the owner lease {subject}: {e}")),
    }
}

/// Why a lease could not be taken.
pub(super) enum Taken {
    /// Another instance's live lease: the message for the refusal (without the prefix).
    Owned(String),
    /// The server failed or did not answer.
    Failed(Failure),
}

impl From<Failure> for Taken {
    fn from(f: Failure) -> Taken {
        Taken::Failed(f)
    }
}

/// Takes the lease for `mine` as at start: refused when another instance's lease is live,
/// taken over an expired, released or missing one with the sequence read as the expected one.
/// Returns the sequence stored.
pub(super) async fn acquire(c: &Conn, mine: &LeaseRecord) -> Result<u64, Taken> {
    let now = unix_now();
    let expected = match read(c).await? {
        Some((_, other)) if other.instance != mine.instance && other.live(now) => {
            return Err(Taken::Owned(other.describe(now)));
        }
        Some((seq, _)) => seq,
        None => 0,
    };
    match claim(c, expected, mine).await? {
        Claim::Won(seq) => Ok(seq),
        // another daemon wrote between the read and the write: it won the race
        Claim::Refused => Err(Taken::Owned(match read(c).await? {
            Some((_, other)) => other.describe(unix_now()),
            None => "a daemon that took it at the same time and let it go".to_string(),
        })),
    }
}

/// What a renewal found.
pub(super) enum Renewal {
    /// Renewed (or taken again): the new record and sequence.
    Renewed(LeaseRecord, u64),
    /// Another instance owns the prefix now: who.
    Lost(String),
}

/// Renews `held` (the record and the sequence it was last stored at), see the module.
pub(super) async fn renew(c: &Conn, held: &HeldState, ttl: Duration) -> Result<Renewal, Failure> {
    let now = unix_now();
    let mut next = held.record.clone();
    next.expires = now + ttl.as_secs_f64();
    if let Claim::Won(seq) = claim(c, held.seq, &next).await? {
        return Ok(Renewal::Renewed(next, seq));
    }
    // someone wrote since: who?
    let expected = match read(c).await? {
        // our own record at another sequence: a renewal stored whose answer was lost
        Some((seq, r)) if r.instance == next.instance => seq,
        Some((_, other)) if other.live(now) => return Ok(Renewal::Lost(other.describe(now))),
        Some((seq, _)) => seq,
        None => 0,
    };
    match claim(c, expected, &next).await? {
        Claim::Won(seq) => Ok(Renewal::Renewed(next, seq)),
        Claim::Refused => Ok(Renewal::Lost(match read(c).await? {
            Some((_, other)) => other.describe(unix_now()),
            None => "a daemon that took it at the same time and let it go".to_string(),
        })),
    }
}

/// Writes `held`'s record expired, so the prefix can be taken at once. A lease lost meanwhile
/// is left to its new owner (the write is conditional too); our own record at another sequence
/// (a renewal stored as it was being stopped) is released all the same.
pub(super) async fn release(c: &Conn, held: &HeldState) -> Result<(), Failure> {
    let mut last = held.record.clone();
    last.expires = unix_now();
    if let Claim::Won(_) = claim(c, held.seq, &last).await? {
        return Ok(());
    }
    match read(c).await? {
        Some((seq, r)) if r.instance == last.instance => {
            claim(c, seq, &last).await?;
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Renews `held` every [`renew_interval`] until it is released or lost (the task is aborted
/// with the store's runtime), each renewal given at most `timeout` and the interval. A failed
/// renewal is logged once per run of failures and retried after [`retry_interval`]; a lost
/// lease is logged as an error naming the new owner and remembered,
/// which refuses every later write and fails `Store::check`.
pub(super) async fn keep(c: Arc<Conn>, held: Arc<Held>, url: String, timeout: Duration) {
    let prefix = c.names.prefix.clone();
    let every = renew_interval(held.ttl);
    // a renewal slower than the interval is given up and tried again: with a short TTL, one
    // renewal waiting out the whole operation timeout would let the lease expire
    let timeout = timeout.min(every);
    let (mut failing, mut expired_told) = (false, false);
    loop {
        let pause = if failing {
            retry_interval(held.ttl)
        } else {
            every
        };
        tokio::time::sleep(pause).await;
        let state = lock(&held.state).clone();
        if state.released || state.lost.is_some() {
            return;
        }
        let result = tokio::time::timeout(timeout, renew(&c, &state, held.ttl))
            .await
            .unwrap_or_else(|_| Err(format!("no answer within {} s", timeout.as_secs_f64())));
        match result {
            Ok(Renewal::Renewed(record, seq)) => {
                let mut s = lock(&held.state);
                if s.released {
                    return;
                }
                s.record = record;
                s.seq = seq;
                if failing {
                    tracing::warn!(%prefix, "owner lease of prefix {prefix} on {url} renewed again");
                }
                (failing, expired_told) = (false, false);
            }
            Ok(Renewal::Lost(who)) => {
                let message = format!(
                    "another gatewatch took prefix {prefix} on {url}: {who}; this daemon lost \
                     the prefix and writes nothing more to the store: restart it once the \
                     other one is stopped"
                );
                tracing::error!(%prefix, "{message}");
                lock(&held.state).lost = Some(message);
                return;
            }
            Err(f) => {
                let expired = !state.record.live(unix_now());
                if !failing {
                    tracing::warn!(
                        %prefix,
                        "renewal of the owner lease of prefix {prefix} on {url} failed, retried \
                         every {:.1} s: {f}",
                        retry_interval(held.ttl).as_secs_f64()
                    );
                }
                if expired && !expired_told {
                    expired_told = true;
                    tracing::error!(
                        %prefix,
                        "owner lease of prefix {prefix} on {url} expired without renewal: \
                         writes are refused until it is renewed (or lost to another daemon)"
                    );
                }
                failing = true;
            }
        }
    }
}

/// `m` locked, a poisoned lock taken as it is (its data is plain values).
pub(super) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
