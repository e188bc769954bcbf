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

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use async_nats::jetstream;
use async_nats::jetstream::consumer::{pull, AckPolicy, DeliverPolicy};
use async_nats::jetstream::message::PublishMessage as Publish;
use async_nats::jetstream::stream::{
    self, DeleteMessageErrorKind, DiscardPolicy, LastRawMessageErrorKind, StorageType,
};
use async_nats::jetstream::ErrorCode;
use futures_util::StreamExt;
use serde::{Deserialize, Serialize};

use super::row::{stored_row, HistoryRow};
use super::{
    HistoryQuery, NewOutboxRow, OutboxRow, Pruned, Store, StoreError, WriteBatch, MAX_HISTORY_LIMIT,
};

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

/// Whether `prefix` can name a stream and a subject token: not empty, letters,
/// digits, `-` and `_` only.
pub fn valid_prefix(prefix: &str) -> bool {
    !prefix.is_empty()
        && prefix
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

/// A name as a subject token or a key: the lowercase hex of its UTF-8 bytes, `_` for the empty
/// name (hex never holds `_`, so the encoding is reversible, [`decode`]).
pub fn encode(name: &str) -> String {
    if name.is_empty() {
        return "_".to_string();
    }
    name.bytes().map(|b| format!("{b:02x}")).collect()
}

/// The name an [`encode`]d token stands for; `None` when it is not one.
pub fn decode(token: &str) -> Option<String> {
    if token == "_" {
        return Some(String::new());
    }
    if token.is_empty() || token.len() % 2 != 0 {
        return None;
    }
    let bytes = (0..token.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(token.get(i..i + 2)?, 16).ok())
        .collect::<Option<Vec<u8>>>()?;
    String::from_utf8(bytes).ok()
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

/// The names the store uses, from the prefix.
#[derive(Debug, Clone)]
struct Names {
    history: String,
    outbox: String,
    alerts: String,
    prefix: String,
}

impl Names {
    fn new(prefix: &str) -> Names {
        Names {
            history: format!("{prefix}_HISTORY"),
            outbox: format!("{prefix}_OUTBOX"),
            alerts: format!("{prefix}_ALERTS"),
            prefix: prefix.to_string(),
        }
    }
    fn history_subject(&self, gate: &str) -> String {
        format!("{}.history.{}", self.prefix, encode(gate))
    }
    fn alert_subject(&self, gate: &str) -> String {
        format!("{}.alert.{}", self.prefix, encode(gate))
    }
    fn outbox_subject(&self, target: &str, fingerprint: &str) -> String {
        format!(
            "{}.outbox.{}.{}",
            self.prefix,
            encode(target),
            encode(fingerprint)
        )
    }
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
            connect(options.clone(), names.clone()),
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
            read_subject(&c.history, subject).await
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

/// Connects and makes sure the three streams exist with the options' limits.
async fn connect(o: NatsOptions, names: Names) -> Result<Conn, Failure> {
    let client = async_nats::ConnectOptions::new()
        .name("gatewatch")
        .connection_timeout(o.timeout)
        .connect(o.url.as_str())
        .await
        .map_err(|e| format!("cannot connect: {e}"))?;
    let mut js = jetstream::new(client);
    js.set_timeout(o.timeout);
    let history = js
        .create_or_update_stream(stream::Config {
            name: names.history.clone(),
            description: Some("gatewatch: identification history, one subject per gate".into()),
            subjects: vec![format!("{}.history.*", names.prefix)],
            max_age: o.retention,
            max_messages: i64::try_from(o.max_history_rows).unwrap_or(i64::MAX),
            discard: DiscardPolicy::Old,
            storage: StorageType::File,
            ..Default::default()
        })
        .await
        .map_err(|e| format!("stream {}: {e}", names.history))?;
    let outbox = js
        .create_or_update_stream(stream::Config {
            name: names.outbox.clone(),
            description: Some("gatewatch: undelivered notifications".into()),
            subjects: vec![format!("{}.outbox.*.*", names.prefix)],
            storage: StorageType::File,
            ..Default::default()
        })
        .await
        .map_err(|e| format!("stream {}: {e}", names.outbox))?;
    // A key-value table as JetStream's KV buckets are underneath: one subject per key, the
    // newest message of each kept. Not the client's KV API: its bucket creation (0.46) does not
    // read nats-server 2.9's answer.
    let alerts = js
        .create_or_update_stream(stream::Config {
            name: names.alerts.clone(),
            description: Some("gatewatch: each gate's alert state, one subject per gate".into()),
            subjects: vec![format!("{}.alert.*", names.prefix)],
            max_messages_per_subject: 1,
            storage: StorageType::File,
            ..Default::default()
        })
        .await
        .map_err(|e| format!("stream {}: {e}", names.alerts))?;
    let history = js
        .get_stream(&history.config.name)
        .await
        .map_err(|e| format!("stream {}: {e}", names.history))?;
    let outbox = js
        .get_stream(&outbox.config.name)
        .await
        .map_err(|e| format!("stream {}: {e}", names.outbox))?;
    let alerts = js
        .get_stream(&alerts.config.name)
        .await
        .map_err(|e| format!("stream {}: {e}", names.alerts))?;
    Ok(Conn {
        js,
        history,
        outbox,
        alerts,
        names,
    })
}

/// Every message of `subject` in `stream`, `(sequence, payload)` in stream order.
async fn read_subject(
    stream: &stream::Stream,
    subject: String,
) -> Result<Vec<(u64, Vec<u8>)>, Failure> {
    let all = read_from(stream, subject, usize::MAX).await?;
    Ok(all.into_iter().map(|(seq, _, p)| (seq, p)).collect())
}

/// Every message of `subject` (a filter) in `stream`, `(subject, payload)` in stream order.
async fn read_messages(
    stream: &stream::Stream,
    subject: String,
) -> Result<Vec<(String, Vec<u8>)>, Failure> {
    let all = read_from(stream, subject, usize::MAX).await?;
    Ok(all.into_iter().map(|(_, s, p)| (s, p)).collect())
}

/// The first `max` messages of `subject` (a filter) in `stream`, `(sequence, subject,
/// payload)` in stream order: an ephemeral consumer without acks, fetched [`FETCH_BATCH`] at a
/// time until none is pending.
async fn read_from(
    stream: &stream::Stream,
    subject: String,
    max: usize,
) -> Result<Vec<(u64, String, Vec<u8>)>, Failure> {
    let mut consumer = stream
        .create_consumer(pull::Config {
            filter_subject: subject.clone(),
            deliver_policy: DeliverPolicy::All,
            ack_policy: AckPolicy::None,
            // an abandoned reader's consumer goes away by itself
            inactive_threshold: Duration::from_secs(60),
            memory_storage: true,
            ..Default::default()
        })
        .await
        .map_err(|e| format!("reader of {subject}: {e}"))?;
    let info = consumer
        .info()
        .await
        .map_err(|e| format!("reader of {subject}: {e}"))?;
    let name = info.name.clone();
    let mut pending = info.num_pending;
    let mut out = Vec::new();
    let result: Result<(), Failure> = async {
        while pending > 0 && out.len() < max {
            let want = (max - out.len()).min(FETCH_BATCH);
            let mut batch = consumer
                .fetch()
                .max_messages(want)
                .messages()
                .await
                .map_err(|e| format!("read of {subject}: {e}"))?;
            let before = out.len();
            while let Some(m) = batch.next().await {
                let m = m.map_err(|e| format!("read of {subject}: {e}"))?;
                let info = m.info().map_err(|e| format!("read of {subject}: {e}"))?;
                pending = info.pending;
                out.push((
                    info.stream_sequence,
                    m.message.subject.to_string(),
                    m.message.payload.to_vec(),
                ));
            }
            if out.len() == before {
                break; // nothing more came: the rest was deleted meanwhile
            }
        }
        Ok(())
    }
    .await;
    // the consumer is not needed any more (and expires by itself if this fails)
    let _ = stream.delete_consumer(&name).await;
    result.map(|()| out)
}

/// Deletes outbox row `seq`; a row that is already gone (delivered twice, or an id the stream
/// never had) is no error, as a `DELETE` of a missing row is none in SQLite. The server says so
/// in more than one way (`no message found`; `stream store EOF` past the last sequence), so a
/// refused deletion is checked by reading the row.
async fn delete_outbox_row(c: &Conn, seq: u64) -> Result<(), Failure> {
    let Err(e) = c.outbox.delete_message(seq).await else {
        return Ok(());
    };
    // the server answered (it is up): is the row there?
    if matches!(e.kind(), DeleteMessageErrorKind::JetStream(_)) {
        let gone = match c.outbox.get_raw_message(seq).await {
            Err(g) => match g.kind() {
                LastRawMessageErrorKind::NoMessageFound => true,
                LastRawMessageErrorKind::JetStream(j) => {
                    j.error_code() == ErrorCode::NO_MESSAGE_FOUND
                }
                _ => false,
            },
            Ok(_) => false,
        };
        if gone {
            return Ok(());
        }
    }
    Err(format!("deletion of outbox row {seq}: {e}"))
}

/// Publishes one message and waits for the server to store it; its stream sequence.
async fn publish(c: &Conn, subject: String, publish: Publish) -> Result<u64, Failure> {
    let ack =
        c.js.send_publish(subject.clone(), publish)
            .await
            .map_err(ctx(format!("publish to {subject}")))?
            .await
            .map_err(ctx(format!("publish to {subject}")))?;
    Ok(ack.sequence)
}

/// [`Store::write`] on the runtime, in the order the module gives.
async fn write_batch(c: Arc<Conn>, batch: WriteBatch) -> Result<Vec<i64>, Failure> {
    for r in &batch.identifications {
        let row = stored_row(r);
        let payload = serde_json::to_vec(&row).map_err(ctx(format!("history of {}", r.gate)))?;
        // the same window of the same gate is one message even when a batch is retried
        let id = format!(
            "{}-{:016x}-{:016x}",
            encode(&r.gate),
            r.window_end.to_bits(),
            r.time.to_bits()
        );
        publish(
            &c,
            c.names.history_subject(&r.gate),
            Publish::build().payload(payload.into()).message_id(id),
        )
        .await?;
    }
    let mut ids = Vec::with_capacity(batch.outbox.len());
    for r in &batch.outbox {
        let subject = c.names.outbox_subject(&r.target, &r.fingerprint);
        let stored = StoredOutbox {
            target: r.target.clone(),
            fingerprint: r.fingerprint.clone(),
            status: r.status.clone(),
            created: r.created,
            batch: r.batch,
            payload: r.payload.clone(),
        };
        let payload = serde_json::to_vec(&stored).map_err(ctx("outbox row"))?;
        let seq = publish(
            &c,
            subject.clone(),
            Publish::build().payload(payload.into()),
        )
        .await?;
        if r.supersedes {
            // the older rows of the same target and fingerprint: all but the newest message
            // of the subject (published first, so a crash here leaves one row too many, sent
            // twice, never one too few)
            c.outbox
                .purge()
                .filter(subject.clone())
                .keep(1)
                .await
                .map_err(ctx(format!("purge of {subject}")))?;
        }
        ids.push(i64::try_from(seq).map_err(ctx("outbox sequence"))?);
    }
    for (gate, state) in &batch.alert_states {
        // the stream keeps the newest message of a subject: this replaces the stored state
        publish(
            &c,
            c.names.alert_subject(gate),
            Publish::build().payload(state.clone().into_bytes().into()),
        )
        .await?;
    }
    for gate in &batch.forget_gates {
        c.alerts
            .purge()
            .filter(c.names.alert_subject(gate))
            .await
            .map_err(ctx(format!("deletion of the alert state of gate {gate}")))?;
    }
    for id in &batch.delivered {
        // a negative id is no row
        if let Ok(seq) = u64::try_from(*id) {
            delete_outbox_row(&c, seq).await?;
        }
    }
    Ok(ids)
}

/// The alert states, sorted by gate: every message of the alert stream (one per gate).
async fn read_alert_states(c: Arc<Conn>) -> Result<Vec<(String, String)>, Failure> {
    let filter = format!("{}.alert.*", c.names.prefix);
    let messages = read_messages(&c.alerts, filter).await?;
    let mut out = Vec::with_capacity(messages.len());
    for (subject, payload) in messages {
        let token = subject.rsplit('.').next().unwrap_or_default();
        let gate = decode(token)
            .ok_or_else(|| format!("alert state subject {subject:?} is not a gate"))?;
        let state =
            String::from_utf8(payload).map_err(ctx(format!("alert state of gate {gate}")))?;
        out.push((gate, state));
    }
    out.sort();
    Ok(out)
}

/// The gates of the history stream's subjects, sorted.
async fn read_history_gates(c: Arc<Conn>) -> Result<Vec<String>, Failure> {
    let filter = format!("{}.history.*", c.names.prefix);
    let mut info = c
        .history
        .info_with_subjects(&filter)
        .await
        .map_err(ctx("subjects of the history"))?;
    let mut gates = Vec::new();
    while let Some(s) = info.next().await {
        let (subject, count) = s.map_err(ctx("subjects of the history"))?;
        let token = subject.rsplit('.').next().unwrap_or_default();
        let gate =
            decode(token).ok_or_else(|| format!("history subject {subject:?} is not a gate"))?;
        if count > 0 {
            gates.push(gate);
        }
    }
    gates.sort();
    Ok(gates)
}

/// [`Store::prune`] on the runtime: the expired rows at the start of the stream, then the
/// oldest beyond `max_rows`.
async fn prune(c: Arc<Conn>, cutoff: f64, max_rows: u64) -> Result<Pruned, Failure> {
    let filter = format!("{}.history.*", c.names.prefix);
    // The stream is in the order of publication, which is the order of the windows' ends
    // except for a late window: the expired rows are a prefix of it. Its end is the first row
    // that has not expired; what expired behind it goes with `max_age`.
    let head = read_from(&c.history, filter, PRUNE_SCAN_MAX).await?;
    let mut expired = 0;
    let mut keep_from = None;
    for (seq, _, payload) in &head {
        let row: HistoryRow =
            serde_json::from_slice(payload).map_err(ctx(format!("history message {seq}")))?;
        if row.window_end >= cutoff {
            keep_from = Some(*seq);
            break;
        }
        expired += 1;
    }
    if expired > 0 {
        let purge = c.history.purge();
        let purged = match keep_from {
            Some(seq) => purge.sequence(seq).await,
            // everything read expired: up to the last one read
            None => {
                purge
                    .sequence(head.last().map_or(0, |(s, _, _)| s + 1))
                    .await
            }
        }
        .map_err(ctx("purge of the expired history"))?;
        expired = purged.purged;
    }
    let info = c.history.get_info().await.map_err(ctx("history info"))?;
    let mut over_size = 0;
    if info.state.messages > max_rows {
        over_size = c
            .history
            .purge()
            .keep(max_rows)
            .await
            .map_err(ctx("purge of the history beyond max_history_rows"))?
            .purged;
    }
    Ok(Pruned { expired, over_size })
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
        self.run("write", move |c| write_batch(c, batch))
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
        let mut gates = self.run("history gates", read_history_gates)?;
        gates.truncate(limit);
        Ok(gates)
    }

    fn alert_states(&self) -> Result<Vec<(String, String)>, StoreError> {
        self.run("read of the alert states", read_alert_states)
    }

    fn outbox(&self) -> Result<Vec<OutboxRow>, StoreError> {
        let filter = format!("{}.outbox.*.*", self.names.prefix);
        let messages = self.run("read of the outbox", move |c| async move {
            read_subject(&c.outbox, filter).await
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
        self.run("prune", move |c| prune(c, cutoff, max_rows))
    }

    // `make_room` is the trait's no-op: the size of the history is bounded by the stream's own
    // limits (`max_age`, `max_msgs`), which the server keeps.
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_encoded_reversibly_into_subject_tokens() {
        for name in ["g1", "a.b c*>/é", "", "_", "00", "gate-7"] {
            let token = encode(name);
            assert!(
                token.bytes().all(|b| b.is_ascii_hexdigit() || b == b'_'),
                "{token}"
            );
            assert_eq!(decode(&token).as_deref(), Some(name));
        }
        assert_eq!(decode("zz"), None);
        assert_eq!(decode("abc"), None);
        assert_eq!(decode("ff"), None, "not UTF-8");
    }

    #[test]
    fn prefixes_that_cannot_name_a_stream_are_refused() {
        assert!(valid_prefix("GATEWATCH"));
        assert!(valid_prefix("site-2_gw"));
        for bad in ["", "a.b", "a b", "a*", "é"] {
            assert!(!valid_prefix(bad), "{bad}");
        }
    }
}
