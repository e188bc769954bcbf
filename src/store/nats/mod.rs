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
//! # Layout
//! - this file: [`NatsStore`], its options, its runtime and the [`Store`] methods;
//! - `names`: the streams' and subjects' names, and the reversible encoding of gate names;
//! - `ops`: the operations as they run on the runtime: connecting and declaring the streams,
//!   reading a subject, writing a batch in its order, pruning.

mod names;
mod ops;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use async_nats::jetstream::{self, stream};
use serde::{Deserialize, Serialize};

use super::row::HistoryRow;
use super::{
    HistoryQuery, NewOutboxRow, OutboxRow, Pruned, Store, StoreError, WriteBatch, MAX_HISTORY_LIMIT,
};
use names::Names;
pub use names::{decode, encode, valid_prefix};

/// How long one store call (a write, a query, the connection at open) may take before it fails
/// with an error naming the server. The SQLite store waits up to 5 s for a lock; a read of a
/// gate's whole history (up to [`MAX_HISTORY_LIMIT`] rows in ~1 000-message fetches) takes
/// well under a second on loopback, so 10 s is a server that is down or overloaded, not a
/// slow query.
pub const OPERATION_TIMEOUT: Duration = Duration::from_secs(10);

/// Worker threads of the store's own runtime: one holds the connection and runs the calls; the
/// work is waiting on the network.
pub const NATS_RUNTIME_THREADS: usize = 1;

/// Messages asked for by one fetch when a subject is read: large enough that a day of a gate
/// (17 280 rows) is a few round trips, small enough that one answer is about a megabyte.
const FETCH_BATCH: usize = 1000;

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
    fn drop(&mut self) {
        // `shutdown_background`, not a plain drop: dropping a runtime blocks, which panics when
        // the last handle goes on an async thread.
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
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
    /// Connects to the server and creates (or updates to these limits) the history and outbox
    /// alert-state streams. Fails, within the options' timeout, with an error
    /// naming the URL when the server is down, has no JetStream, or refuses the streams.
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
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(NATS_RUNTIME_THREADS)
            .thread_name("gatewatch-nats")
            .enable_all()
            .build()
            .map_err(|e| open_err(format!("cannot start the store's runtime: {e}")))?;
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
        Ok(NatsStore {
            url: options.url.clone(),
            names,
            timeout: options.timeout,
            conn: Arc::new(conn),
            runtime: Some(runtime),
        })
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

    /// Every row of one gate, in the order it was stored.
    fn gate_rows(
        &self,
        operation: &'static str,
        gate: &str,
    ) -> Result<Vec<HistoryRow>, StoreError> {
        let subject = self.names.history_subject(gate);
        let messages = self.run(operation, move |c| async move {
            ops::read_subject(&c.history, subject).await
        })?;
        let mut rows = Vec::with_capacity(messages.len());
        for (seq, payload) in messages {
            let row: HistoryRow =
                serde_json::from_slice(&payload).map_err(|e| StoreError::Decode {
                    operation,
                    message: format!("history message {seq} of gate {gate}: {e}"),
                })?;
            rows.push(row);
        }
        // oldest window first; equal ends in the order stored (a stable sort), as SQLite's
        // (window_end, seq)
        rows.sort_by(|a, b| a.window_end.total_cmp(&b.window_end));
        Ok(rows)
    }
}

impl Store for NatsStore {
    fn location(&self) -> String {
        format!(
            "NATS server {} (streams {}, {} and {})",
            self.url, self.names.history, self.names.alerts, self.names.outbox
        )
    }

    fn write(&self, batch: &WriteBatch) -> Result<Vec<i64>, StoreError> {
        let batch = batch.clone();
        self.run("write", move |c| ops::write_batch(c, batch))
    }

    fn history_rows(&self, q: &HistoryQuery) -> Result<Vec<HistoryRow>, StoreError> {
        let from = q.from.unwrap_or(f64::MIN);
        let to = q.to.unwrap_or(f64::MAX);
        Ok(self
            .gate_rows("history", &q.gate)?
            .into_iter()
            .filter(|r| r.window_end >= from && r.window_end <= to)
            .take(q.limit.min(MAX_HISTORY_LIMIT))
            .collect())
    }

    fn latest_history_rows(&self, gate: &str, n: usize) -> Result<Vec<HistoryRow>, StoreError> {
        let mut rows = self.gate_rows("latest history", gate)?;
        let n = n.min(MAX_HISTORY_LIMIT);
        Ok(rows.split_off(rows.len().saturating_sub(n)))
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
            ops::read_subject(&c.outbox, filter).await
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
        self.run("prune", move |c| ops::prune(c, cutoff, max_rows))
    }

    // `make_room` is the trait's no-op: the size of the history is bounded by the stream's own
    // limits (`max_age`, `max_msgs`), which the server keeps.
}
