//! [`NatsStore`]: the distributed store, on a NATS JetStream server, for several daemons that
//! share their gates' state (`docs/design.md`, "The NATS store").
//!
//! The history is a stream, one subject per gate, each message one [`HistoryRow`] as JSON; the
//! stream's own limits (`max_age` = the retention, `max_msgs` = `max_history_rows`) bound it, so
//! the server prunes it without the daemon. The alert states are a stream that keeps the newest
//! message of each subject, one subject per gate (a key-value table). The outbox is a stream
//! whose sequence numbers are the rows' ids, one subject per target and fingerprint, so
//! superseding the older rows of an alert is one purge of a subject.
//! Gate names, targets and fingerprints may hold what a subject or a key refuses (`.`, `*`,
//! `>`, spaces, any UTF-8): they are written as the hex of their bytes ([`encode`]).
//!
//! The [`Store`] trait is blocking and is called from the writer thread and from tokio's
//! blocking threads, where nobody may `block_on` a runtime. So the store owns a small runtime of
//! its own (one worker thread, [`NATS_RUNTIME_THREADS`]) that holds the connection; each call
//! is spawned there and its answer comes back through a channel of one, waited for at most
//! the operation timeout ([`OPERATION_TIMEOUT`] by default): a server that is down or silent
//! gives an error naming its URL, never a hang.
//!
//! JetStream 2.9 has no transaction over several streams: a [`WriteBatch`] is written history
//! first, then the outbox, then the alert states, then the deletions of delivered rows, each
//! history message with a `Nats-Msg-Id` so a retried batch is not stored twice. What a crash
//! between two of them leaves is in `docs/design.md`.
//!
//! One daemon per prefix: `serve` opens the store with an owner lease ([`NatsOptions::owner_lease`]),
//! a record in stream `<PREFIX>_OWNER` that it renews and releases at shutdown; a second daemon
//! on the prefix is refused at start, naming the owner, and a daemon that finds its lease taken
//! writes nothing more ([`Store::check`] fails, `/readyz` and `/healthz` with it). Why and how
//! in `lease` and `docs/design.md`, "The owner lease". A reader beside the daemon
//! (`gatewatch history --nats`) opens the store with [`NatsStore::open_read_only`]: no lease,
//! no stream created or changed, no write.
//!
//! # Layout
//! - this file: [`NatsStore`], its options, its runtime and the [`Store`] methods;
//! - `names`: the streams' and subjects' names, and the reversible encoding of gate names;
//! - `lease`: the owner lease ([`LeaseRecord`]): taken at open, renewed, released;
//! - `ops`: the operations as they run on the runtime: connecting and declaring the streams
//!   (or only finding them, read-only), reading a subject, writing a batch in its order, pruning.

mod lease;
mod names;
mod ops;
mod read;

use std::future::Future;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_nats::jetstream::consumer::DeliverPolicy;
use async_nats::jetstream::{self, stream};
use serde::{Deserialize, Serialize};

use super::row::HistoryRow;
use super::{
    HistoryQuery, NewOutboxRow, OutboxRow, Pruned, Store, StoreError, WriteBatch, MAX_HISTORY_LIMIT,
};
use lease::{lock, Held, HeldState, Taken};
pub use lease::{
    renew_interval, retry_interval, LeaseRecord, LEASE_TTL, RENEWALS_PER_TTL, RETRIES_PER_RENEWAL,
};
use names::Names;
pub use names::{decode, encode, valid_prefix};
pub use ops::{reconnect_delay, RECONNECT_DELAY_MAX};

/// How long one store call (a write, a query, the connection at open) may take before it fails
/// with an error naming the server. The SQLite store waits up to 5 s for a lock. A gate's
/// newest rows are read from the stream's end in milliseconds; a history range reads the
/// gate's subject from the messages stored since its start on (the whole subject when the
/// daemon's gates accept unbounded sample times, about 1.8 s per week of one gate on loopback,
/// `read`), so 10 s is a server that is down or overloaded, or such a range over more than
/// about a month.
pub const OPERATION_TIMEOUT: Duration = Duration::from_secs(10);

/// Worker threads of the store's own runtime: one holds the connection and runs the calls; the
/// work is waiting on the network.
pub const NATS_RUNTIME_THREADS: usize = 1;

/// How far the clock of a daemon that writes the history may be from the NATS server's
/// (default of [`NatsOptions::clock_margin`]): a history range starts reading this much
/// earlier than its rows could have been stored. An hour of a gate's rows (720 at the default
/// cadence) reads in about 10 ms at the measured 1.8 s per week (docs/benchmarks.md, "History
/// on NATS"); hosts kept by NTP are within milliseconds.
pub const CLOCK_MARGIN: Duration = Duration::from_secs(3600);

/// Messages asked for by one fetch when a subject is read: large enough that a day of a gate
/// (17 280 rows) is a few round trips, small enough that one answer is about a megabyte.
const FETCH_BATCH: usize = 1000;

/// How long the server may hold one fetch that finds fewer messages than the consumer
/// counted. A fetch is a no-wait pull request; without an expiry, nats-server before 2.12
/// does not answer one whose counted messages were deleted after the consumer was made (a
/// gate's alert state replaced, an outbox row delivered, rows pruned) until another message
/// arrives: no `404 No Messages` (nats-server issue 7457, fixed by its pull request 7466;
/// Debian's 2.9.10 has the bug). Seen here as fetches answered only at the writer's next
/// write; with no next write the read would wait out the operation timeout. With an expiry
/// the server ends such a request with `408 Request Timeout` after this long at most, and the
/// read goes on with what it has; a fetch that finds its messages is answered at once.
const FETCH_EXPIRES: Duration = Duration::from_millis(500);

/// Messages [`Store::prune`] reads from the start of the history at most in one call: the
/// writer prunes every hour, so the expired rows of an hour of many gates are removed in one
/// call and a backlog over several; what is older is removed by the stream's `max_age` anyway.
pub const PRUNE_SCAN_MAX: usize = 20_000;

/// Where a [`NatsStore`] connects and what it names its streams.
#[derive(Debug, Clone, PartialEq)]
pub struct NatsOptions {
    /// The server, e.g. `nats://127.0.0.1:4222`.
    pub url: String,
    /// Prefix of the streams and the subjects (`GATEWATCH`: streams `GATEWATCH_HISTORY`,
    /// `GATEWATCH_ALERTS` and `GATEWATCH_OUTBOX`, subjects
    /// `GATEWATCH.history.<gate>`); letters, digits, `-` and `_` ([`valid_prefix`]).
    pub prefix: String,
    /// The history stream's `max_age`: the retention.
    pub retention: Duration,
    /// The history stream's `max_msgs`: `max_history_rows`.
    pub max_history_rows: u64,
    /// How long one call may take ([`OPERATION_TIMEOUT`] by default).
    pub timeout: Duration,
    /// `Some(ttl)`: take the prefix's owner lease at open, refused when another daemon holds
    /// it, and renew it every `ttl / 3` ([`LEASE_TTL`] for `serve`). `None` (the default of
    /// [`NatsOptions::new`]): no lease, for a store that is only read or a test's.
    pub owner_lease: Option<Duration>,
    /// How far ahead of its writer's clock a row's window may end: the largest
    /// `max_future_seconds` of the daemon's gates (`Config::sample_lead_bound`). `Some`: a
    /// history range from `from` reads only the messages the server stored from
    /// `from - sample_lead - clock_margin` on, since a row ending at `from` or later cannot
    /// have been stored before (`range_start`). `None` (the default; a gate without the bound,
    /// or a reader that does not know the daemon's gates): the gate's whole subject.
    pub sample_lead: Option<Duration>,
    /// How far the writers' clocks may be from the server's ([`CLOCK_MARGIN`] by default).
    /// With an owner lease the store measures its own offset at open; an offset beyond half
    /// this margin turns the range's shortcut off (logged).
    pub clock_margin: Duration,
}

impl NatsOptions {
    /// Options for `url` with the default prefix and timeout.
    pub fn new(url: &str, retention: Duration, max_history_rows: u64) -> NatsOptions {
        NatsOptions {
            url: url.to_string(),
            prefix: "GATEWATCH".to_string(),
            retention,
            max_history_rows,
            timeout: OPERATION_TIMEOUT,
            owner_lease: None,
            sample_lead: None,
            clock_margin: CLOCK_MARGIN,
        }
    }
}

/// An outbox row as its message holds it (the id is the message's sequence).
#[derive(Serialize, Deserialize)]
struct StoredOutbox {
    target: String,
    fingerprint: String,
    status: String,
    created: f64,
    batch: u64,
    payload: String,
}

/// What the calls share on the store's runtime.
struct Conn {
    js: jetstream::Context,
    history: stream::Stream,
    outbox: stream::Stream,
    alerts: stream::Stream,
    owner: stream::Stream,
    names: Names,
}

/// An error of the server or the client, as text.
type Failure = String;

/// `e` after what was being done.
fn ctx<E: std::fmt::Display>(what: impl std::fmt::Display) -> impl FnOnce(E) -> Failure {
    move |e| format!("{what}: {e}")
}

/// The store on a NATS JetStream server. See the module.
pub struct NatsStore {
    url: String,
    names: Names,
    timeout: Duration,
    conn: Arc<Conn>,
    /// The owner lease, when the store was opened with one.
    held: Option<Arc<Held>>,
    /// The task that renews it.
    renewal: Mutex<Option<tokio::task::AbortHandle>>,
    /// Opened by [`NatsStore::open_read_only`]: every write and prune is refused.
    read_only: bool,
    /// Seconds before a range's `from` at which its read starts (`sample_lead` plus the
    /// clock margin); `None`: the whole subject.
    range_slack: Option<f64>,
    /// The store's own runtime; `None` only while it is dropped.
    runtime: Option<tokio::runtime::Runtime>,
}

impl std::fmt::Debug for NatsStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NatsStore")
            .field("url", &self.url)
            .field("names", &self.names)
            .finish_non_exhaustive()
    }
}

impl Drop for NatsStore {
    /// Stops the runtime, the lease's renewal with it. The lease is not released here (no
    /// network in a drop): [`NatsStore::release`] does, at a clean shutdown; without it the
    /// prefix stays owned until the lease expires, as after a crash.
    fn drop(&mut self) {
        // `shutdown_background`, not a plain drop: dropping a runtime blocks, which panics when
        // the last handle goes on an async thread.
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

/// The store's own runtime ([`NATS_RUNTIME_THREADS`] worker), or why it cannot start.
fn store_runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(NATS_RUNTIME_THREADS)
        .thread_name("gatewatch-nats")
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the store's runtime: {e}"))
}

/// Runs `fut` on `runtime` and waits for its answer at most `timeout` (and the future itself
/// is cut at `timeout` on the runtime, so nothing is left running). The error is the text.
fn call<T: Send + 'static>(
    runtime: &tokio::runtime::Runtime,
    timeout: Duration,
    fut: impl Future<Output = Result<T, Failure>> + Send + 'static,
) -> Result<T, Failure> {
    // a channel of one: one answer per call, and the sender never waits
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    runtime.spawn(async move {
        let answer = match tokio::time::timeout(timeout, fut).await {
            Ok(r) => r,
            Err(_) => Err(format!("no answer within {} s", timeout.as_secs_f64())),
        };
        let _ = tx.try_send(answer);
    });
    // the runtime's own timeout answers first; this one is for a runtime that cannot run at all
    match rx.recv_timeout(timeout + Duration::from_secs(1)) {
        Ok(r) => r,
        Err(_) => Err(format!(
            "no answer within {} s (the store's runtime did not run the call)",
            timeout.as_secs_f64()
        )),
    }
}

impl NatsStore {
    /// Connects to the server and creates (or updates to these limits) the history, outbox,
    /// alert-state and owner streams. Fails, within the options' timeout, with an error
    /// naming the URL when the server is down, has no JetStream, or refuses the streams. With
    /// [`NatsOptions::owner_lease`], takes the prefix's owner lease and starts renewing it;
    /// [`StoreError::Owned`], naming the owner and when its lease expires, when another
    /// daemon holds it.
    pub fn open(options: &NatsOptions) -> Result<NatsStore, StoreError> {
        let open_err = |message: String| StoreError::Open {
            path: format!("NATS server {}", options.url),
            message,
        };
        if !valid_prefix(&options.prefix) {
            return Err(open_err(format!(
                "prefix {:?}: letters, digits, '-' and '_' only",
                options.prefix
            )));
        }
        let runtime = store_runtime().map_err(open_err)?;
        let names = Names::new(&options.prefix);
        let conn = call(
            &runtime,
            options.timeout,
            ops::connect(options.clone(), names.clone()),
        );
        let conn = match conn {
            Ok(c) => c,
            Err(e) => {
                runtime.shutdown_background();
                return Err(open_err(e));
            }
        };
        let conn = Arc::new(conn);
        let mut range_slack = options
            .sample_lead
            .map(|lead| (lead + options.clock_margin).as_secs_f64());
        let held = match options.owner_lease {
            None => None,
            Some(ttl) => match take_lease(&runtime, &conn, options, ttl) {
                Ok((held, offset)) => {
                    if range_slack.is_some() && !clock_agrees(offset, options) {
                        range_slack = None;
                    }
                    Some(held)
                }
                Err(e) => {
                    runtime.shutdown_background();
                    return Err(e);
                }
            },
        };
        let renewal = held.as_ref().map(|h| {
            let keep = lease::keep(
                conn.clone(),
                h.clone(),
                options.url.clone(),
                options.timeout,
            );
            runtime.spawn(keep).abort_handle()
        });
        Ok(NatsStore {
            url: options.url.clone(),
            names,
            timeout: options.timeout,
            conn,
            held,
            renewal: Mutex::new(renewal),
            read_only: false,
            range_slack,
            runtime: Some(runtime),
        })
    }

    /// Opens the store of `prefix` on the server at `url` to read it (`gatewatch history`):
    /// the streams are looked up, not created or changed (an [`open`](NatsStore::open) would
    /// set the history stream's limits to its own options, over the daemon's), no owner lease
    /// is taken (the daemon that holds it keeps it) and every write and prune is refused.
    /// Reading a subject still makes an ephemeral consumer on the server, deleted after the
    /// read (and gone by itself a minute later if the reader dies).
    ///
    /// Fails within `timeout`, naming the URL, when the server is down or silent, and naming
    /// the stream and the prefix when nothing was stored under the prefix.
    pub fn open_read_only(
        url: &str,
        prefix: &str,
        timeout: Duration,
    ) -> Result<NatsStore, StoreError> {
        let open_err = |message: String| StoreError::Open {
            path: format!("NATS server {url}"),
            message,
        };
        if !valid_prefix(prefix) {
            return Err(open_err(format!(
                "prefix {prefix:?}: letters, digits, '-' and '_' only"
            )));
        }
        let runtime = store_runtime().map_err(open_err)?;
        let names = Names::new(prefix);
        let conn = match call(
            &runtime,
            timeout,
            ops::look_up(url.to_string(), timeout, names.clone()),
        ) {
            Ok(c) => c,
            Err(e) => {
                runtime.shutdown_background();
                return Err(open_err(e));
            }
        };
        Ok(NatsStore {
            url: url.to_string(),
            names,
            timeout,
            conn: Arc::new(conn),
            held: None,
            renewal: Mutex::new(None),
            read_only: true,
            range_slack: None,
            runtime: Some(runtime),
        })
    }

    /// The prefix's owner lease as stored, with its sequence; `None` when there is none.
    pub fn owner_lease(&self) -> Result<Option<(u64, LeaseRecord)>, StoreError> {
        self.run("read of the owner lease", |c| async move {
            lease::read(&c).await
        })
    }

    /// Writes `record` as the prefix's owner lease only if the last one stored is at sequence
    /// `expected` (0: none): the conditional write the lease is made of, so that of two
    /// writers that read the same sequence one is stored and the other refused. `Some(seq)`
    /// when stored, `None` when refused.
    pub fn claim_owner_lease(
        &self,
        expected: u64,
        record: &LeaseRecord,
    ) -> Result<Option<u64>, StoreError> {
        if self.read_only {
            return Err(self.error(
                "write of the owner lease",
                "the store was opened read-only".into(),
            ));
        }
        let record = record.clone();
        self.run("write of the owner lease", move |c| async move {
            Ok(match lease::claim(&c, expected, &record).await? {
                lease::Claim::Won(seq) => Some(seq),
                lease::Claim::Refused => None,
            })
        })
    }

    /// Releases the owner lease (at a clean shutdown, after the last write): its record is
    /// written expired, so the next daemon takes the prefix at once. Nothing is written after
    /// it. A store without a lease, or one that lost it, has nothing to release.
    pub fn release(&self) -> Result<(), StoreError> {
        let Some(held) = &self.held else {
            return Ok(());
        };
        if let Some(task) = lock(&self.renewal).take() {
            task.abort();
        }
        let state = {
            let mut s = lock(&held.state);
            if s.released || s.lost.is_some() {
                return Ok(());
            }
            s.released = true;
            s.clone()
        };
        self.run("release of the owner lease", move |c| async move {
            lease::release(&c, &state).await
        })?;
        tracing::info!(prefix = %self.names.prefix, "owner lease of prefix {} released", self.names.prefix);
        Ok(())
    }

    /// Whether this store may write: not when its lease was lost, released, or has expired
    /// without renewal (the server did not answer the renewals: another daemon may take the
    /// prefix meanwhile).
    fn may_write(&self, operation: &'static str) -> Result<(), StoreError> {
        if self.read_only {
            return Err(self.error(operation, "the store was opened read-only".into()));
        }
        let Some(held) = &self.held else {
            return Ok(());
        };
        let s = lock(&held.state).clone();
        if let Some(why) = s.lost {
            return Err(self.lost(why));
        }
        if s.released {
            return Err(self.error(operation, "the owner lease was released".into()));
        }
        if !s.record.live(lease::unix_now()) {
            return Err(self.error(
                operation,
                format!(
                    "the owner lease of prefix {} expired without renewal (the server did not \
                     answer); writes wait for its renewal",
                    self.names.prefix
                ),
            ));
        }
        Ok(())
    }

    fn lost(&self, message: String) -> StoreError {
        StoreError::Owned {
            url: self.url.clone(),
            prefix: self.names.prefix.clone(),
            message,
        }
    }

    /// Runs one operation on the store's runtime; the error names the server and the operation.
    fn run<T, F, Fut>(&self, operation: &'static str, f: F) -> Result<T, StoreError>
    where
        T: Send + 'static,
        F: FnOnce(Arc<Conn>) -> Fut,
        Fut: Future<Output = Result<T, Failure>> + Send + 'static,
    {
        let Some(runtime) = &self.runtime else {
            return Err(self.error(operation, "the store is closed".into()));
        };
        call(runtime, self.timeout, f(self.conn.clone())).map_err(|m| self.error(operation, m))
    }

    fn error(&self, operation: &'static str, message: String) -> StoreError {
        StoreError::Nats {
            url: self.url.clone(),
            operation,
            message,
        }
    }
}

/// History message `seq` of `gate` decoded; the failure names both (a [`StoreError::Decode`]
/// message, not a server's failure).
fn decode_row(gate: &str, seq: u64, payload: &[u8]) -> Result<HistoryRow, String> {
    serde_json::from_slice(payload)
        .map_err(|e| format!("history message {seq} of gate {gate}: {e}"))
}

/// Where a history range from `from` starts reading: at the messages stored from
/// `from - slack` on (Unix seconds of the server's clock); the whole subject without a
/// slack or a lower bound, or when that start lies before 1970 or past year 9999. Why this is sound: the daemon
/// refuses a sample more than `max_future_seconds` ahead of its clock, so a row ending at
/// `from` or later was written at `from - max_future_seconds` or later by its writer's clock,
/// and stored then by the server's, within the clock margin (`NatsOptions::sample_lead`).
/// A row written late (a backfill, a replay of old samples) was stored later still. Why not
/// always the whole subject: it took 5.5 s for a month of one gate, most of it before `from`
/// on a query of the last day (docs/benchmarks.md, "History on NATS").
fn range_start(from: Option<f64>, slack: Option<f64>) -> DeliverPolicy {
    let start = match (from, slack) {
        (Some(from), Some(slack)) if from.is_finite() => from - slack,
        _ => return DeliverPolicy::All,
    };
    // `OffsetDateTime` holds years up to 9999: about 2.5e20 ns after 1970
    let nanos = start * 1e9;
    if !(nanos.is_finite() && nanos > 0.0 && nanos < 2.5e20) {
        return DeliverPolicy::All;
    }
    match time::OffsetDateTime::from_unix_timestamp_nanos(nanos as i128) {
        Ok(start_time) => DeliverPolicy::ByStartTime { start_time },
        Err(_) => DeliverPolicy::All,
    }
}

/// Whether the server's clock, `offset` seconds ahead of this host's (measured at the lease's
/// write, `take_lease`), is within half the clock margin; logged when it is not (or was not
/// measured), and the range's shortcut is then off.
fn clock_agrees(offset: Option<f64>, options: &NatsOptions) -> bool {
    let half = options.clock_margin.as_secs_f64() / 2.0;
    match offset {
        Some(o) if o.abs() <= half => true,
        Some(o) => {
            tracing::warn!(
                url = %options.url,
                offset_seconds = o,
                "the NATS server's clock is {o:.1} s from this host's, more than {half} s: \
                 history ranges read each gate's whole subject (set both clocks by NTP)"
            );
            false
        }
        None => {
            tracing::warn!(
                url = %options.url,
                "the NATS server's clock could not be read at the owner lease's write: \
                 history ranges read each gate's whole subject"
            );
            false
        }
    }
}

/// Takes the owner lease of `options.prefix` at open (see `lease`); with it, how far the
/// server's clock is ahead of this host's, from the time the server stored the lease at
/// (`None` when that read failed).
fn take_lease(
    runtime: &tokio::runtime::Runtime,
    conn: &Arc<Conn>,
    options: &NatsOptions,
    ttl: Duration,
) -> Result<(Arc<Held>, Option<f64>), StoreError> {
    let record = LeaseRecord::this_process(ttl);
    let (c, mine) = (conn.clone(), record.clone());
    let before = lease::unix_now();
    let taken = call(runtime, options.timeout, async move {
        Ok(lease::acquire(&c, &mine).await)
    });
    let after = lease::unix_now();
    let seq = match taken {
        Ok(Ok(seq)) => seq,
        Ok(Err(Taken::Owned(who))) => {
            return Err(StoreError::Owned {
                url: options.url.clone(),
                prefix: options.prefix.clone(),
                message: format!(
                    "another gatewatch owns prefix {} on {}: {who} (one daemon per prefix: \
                     stop the other one, or give this one another storage.nats_prefix)",
                    options.prefix, options.url
                ),
            })
        }
        Ok(Err(Taken::Failed(m))) | Err(m) => {
            return Err(StoreError::Open {
                path: format!("NATS server {}", options.url),
                message: format!("owner lease of prefix {}: {m}", options.prefix),
            })
        }
    };
    let c = conn.clone();
    let stored = call(runtime, options.timeout, async move {
        let m = c
            .owner
            .get_raw_message(seq)
            .await
            .map_err(ctx("owner lease message"))?;
        Ok(m.time.unix_timestamp_nanos() as f64 / 1e9)
    });
    let offset = stored.ok().map(|t| t - (before + after) / 2.0);
    tracing::info!(
        prefix = %options.prefix,
        instance = %record.instance,
        server_clock_ahead_seconds = offset,
        "owner lease of prefix {} taken for {} s",
        options.prefix,
        ttl.as_secs_f64()
    );
    let held = Arc::new(Held {
        ttl,
        state: Mutex::new(HeldState {
            record,
            seq,
            lost: None,
            released: false,
        }),
    });
    Ok((held, offset))
}

impl Store for NatsStore {
    fn location(&self) -> String {
        format!(
            "NATS server {} (streams {}, {} and {})",
            self.url, self.names.history, self.names.alerts, self.names.outbox
        )
    }

    /// An error once the owner lease is lost to another daemon: nothing this daemon writes
    /// may land any more (the writer refuses every write, `/readyz` and `/healthz` fail).
    fn check(&self) -> Result<(), StoreError> {
        match self.held.as_ref().and_then(|h| lock(&h.state).lost.clone()) {
            Some(why) => Err(self.lost(why)),
            None => Ok(()),
        }
    }

    fn write(&self, batch: &WriteBatch) -> Result<Vec<i64>, StoreError> {
        self.may_write("write")?;
        let batch = batch.clone();
        self.run("write", move |c| ops::write_batch(c, batch))
    }

    fn history_rows(&self, q: &HistoryQuery) -> Result<Vec<HistoryRow>, StoreError> {
        let (from, to) = (q.from.unwrap_or(f64::MIN), q.to.unwrap_or(f64::MAX));
        let limit = q.limit.min(MAX_HISTORY_LIMIT);
        let (gate, subject) = (q.gate.clone(), self.names.history_subject(&q.gate));
        let start = range_start(q.from, self.range_slack);
        // the subject streams by from `start`; at most `limit` rows are kept (`read`)
        let rows = self.run("history", move |c| async move {
            let mut first = read::FirstRows::new(limit);
            let mut bad = None;
            read::read_each(&c.history, subject, start, |seq, _, payload| {
                match decode_row(&gate, seq, payload) {
                    Ok(row) if row.window_end >= from && row.window_end <= to => {
                        first.offer(seq, row)
                    }
                    Ok(_) => {}
                    Err(e) => bad = Some(e),
                }
                Ok(bad.is_none())
            })
            .await?;
            Ok(bad.map_or_else(|| Ok(first.into_rows()), Err))
        })?;
        rows.map_err(|message| StoreError::Decode {
            operation: "history",
            message,
        })
    }

    /// The last `n` rows stored for the gate, oldest window first: read from the stream's end
    /// (`read::read_last`), so a restart does not read a month of history per gate. The last
    /// stored are the newest windows because the daemon writes a gate's windows in their order
    /// (one job per gate in flight, one writer); rows written out of order (a replay started
    /// again) come as stored, where SQLite would take the largest window ends.
    fn latest_history_rows(&self, gate: &str, n: usize) -> Result<Vec<HistoryRow>, StoreError> {
        let n = n.min(MAX_HISTORY_LIMIT);
        let subject = self.names.history_subject(gate);
        let messages = self.run("latest history", move |c| async move {
            read::read_last(&c.history, subject, n).await
        })?;
        let mut rows = messages
            .into_iter()
            .map(|(seq, payload)| decode_row(gate, seq, &payload))
            .collect::<Result<Vec<_>, String>>()
            .map_err(|message| StoreError::Decode {
                operation: "latest history",
                message,
            })?;
        // oldest window first; equal ends in the order stored (a stable sort)
        rows.sort_by(|a, b| a.window_end.total_cmp(&b.window_end));
        Ok(rows)
    }

    fn history_gates(&self, limit: usize) -> Result<Vec<String>, StoreError> {
        let mut gates = self.run("history gates", ops::read_history_gates)?;
        gates.truncate(limit);
        Ok(gates)
    }

    fn alert_states(&self) -> Result<Vec<(String, String)>, StoreError> {
        self.run("read of the alert states", ops::read_alert_states)
    }

    fn outbox(&self) -> Result<Vec<OutboxRow>, StoreError> {
        let filter = format!("{}.outbox.*.*", self.names.prefix);
        let messages = self.run("read of the outbox", move |c| async move {
            let all = read::read_from(&c.outbox, filter, usize::MAX).await?;
            Ok(all
                .into_iter()
                .map(|(seq, _, p)| (seq, p))
                .collect::<Vec<_>>())
        })?;
        messages
            .into_iter()
            .map(|(seq, payload)| {
                let r: StoredOutbox =
                    serde_json::from_slice(&payload).map_err(|e| StoreError::Decode {
                        operation: "read of the outbox",
                        message: format!("outbox message {seq}: {e}"),
                    })?;
                Ok(OutboxRow {
                    id: i64::try_from(seq).unwrap_or(i64::MAX),
                    row: NewOutboxRow {
                        target: r.target,
                        fingerprint: r.fingerprint,
                        status: r.status,
                        created: r.created,
                        batch: r.batch,
                        payload: r.payload,
                        supersedes: false,
                    },
                })
            })
            .collect()
    }

    /// The stream's `max_age` and `max_msgs` already bound the history; this removes, as the
    /// SQLite store does, the rows whose window ended before `cutoff` (a prefix of the stream,
    /// at most [`PRUNE_SCAN_MAX`] rows read per call) and the oldest beyond `max_rows`.
    fn prune(&self, cutoff: f64, max_rows: u64) -> Result<Pruned, StoreError> {
        self.may_write("prune")?;
        self.run("prune", move |c| ops::prune(c, cutoff, max_rows))
    }

    // `make_room` is the trait's no-op: the size of the history is bounded by the stream's own
    // limits (`max_age`, `max_msgs`), which the server keeps.
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_range_starts_at_from_less_the_slack_or_reads_everything() {
        let from = 1_714_564_800.0; // 2024-05-01T12:00:00Z
        match range_start(Some(from), Some(4200.0)) {
            DeliverPolicy::ByStartTime { start_time } => {
                assert_eq!(start_time.unix_timestamp(), 1_714_564_800 - 4200)
            }
            other => panic!("{other:?}"),
        }
        // no bound on the samples' lead, no lower bound, or a start outside the clock's range
        for (from, slack) in [
            (Some(from), None),
            (None, Some(4200.0)),
            (Some(f64::MIN), Some(4200.0)),
            (Some(f64::NEG_INFINITY), Some(4200.0)),
            (Some(f64::NAN), Some(4200.0)),
            (Some(3.0), Some(4200.0)),
            (Some(f64::MAX), Some(4200.0)),
        ] {
            assert_eq!(
                range_start(from, slack),
                DeliverPolicy::All,
                "{from:?} {slack:?}"
            );
        }
    }

    #[test]
    fn a_server_clock_off_by_more_than_half_the_margin_turns_the_shortcut_off() {
        let o = NatsOptions::new("nats://127.0.0.1:1", Duration::from_secs(60), 10);
        assert!(clock_agrees(Some(0.003), &o));
        assert!(clock_agrees(Some(-1799.0), &o));
        assert!(!clock_agrees(Some(1801.0), &o));
        assert!(!clock_agrees(Some(-7200.0), &o));
        assert!(!clock_agrees(None, &o));
    }

    #[test]
    fn reconnection_starts_at_once_and_never_waits_more_than_a_second() {
        assert_eq!(reconnect_delay(0), Duration::ZERO);
        assert_eq!(reconnect_delay(1), Duration::ZERO);
        assert_eq!(reconnect_delay(2), Duration::from_millis(2));
        assert_eq!(reconnect_delay(5), Duration::from_millis(16));
        assert_eq!(reconnect_delay(10), Duration::from_millis(512));
        for attempts in [11, 64, 65, usize::MAX] {
            assert_eq!(reconnect_delay(attempts), RECONNECT_DELAY_MAX, "{attempts}");
        }
    }

    #[test]
    fn a_failed_renewal_is_retried_five_times_an_interval() {
        assert_eq!(retry_interval(LEASE_TTL), Duration::from_secs(2));
        assert_eq!(
            retry_interval(Duration::from_secs(12)),
            Duration::from_millis(800)
        );
        // never busier than ten tries a second, however short the lease
        assert_eq!(
            retry_interval(Duration::from_millis(30)),
            Duration::from_millis(100)
        );
    }
}
