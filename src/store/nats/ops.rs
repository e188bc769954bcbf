//! The store's operations as they run on its runtime: the connection and the streams at
//! open, the write of a batch in its order, the pruning (reading a subject: `read`). Each returns the failure as text; `NatsStore` names the server and the
//! operation around it.

use std::sync::Arc;
use std::time::Duration;

use async_nats::jetstream;
use async_nats::jetstream::context::{CreateStreamErrorKind, GetStreamErrorKind};
use async_nats::jetstream::message::PublishMessage as Publish;
use async_nats::jetstream::stream::{
    self, DeleteMessageErrorKind, DiscardPolicy, LastRawMessageErrorKind, StorageType,
};
use async_nats::jetstream::ErrorCode;
use futures_util::StreamExt;

use super::super::row::{stored_row, HistoryRow};
use super::super::{Pruned, WriteBatch};
use super::names::{decode, encode, Names};
use super::read::read_from;
use super::{ctx, Conn, Failure, NatsOptions, StoredOutbox, PRUNE_SCAN_MAX};

/// The longest wait between two attempts to reconnect to a server that went away.
///
/// Why not the client's default (doubling from 2 ms up to 4 s): while the connection is down
/// every write fails, and once the server is back a write waits for the next attempt. At 4 s
/// that was most of what an outage cost beyond its own length; a daemon's one connection
/// trying once a second is nothing to a server.
pub const RECONNECT_DELAY_MAX: Duration = Duration::from_secs(1);

/// The wait before reconnection attempt `attempts` (1, 2, ...): none for the first, then
/// doubling from 2 ms up to [`RECONNECT_DELAY_MAX`].
pub fn reconnect_delay(attempts: usize) -> Duration {
    let doublings = u32::try_from(attempts.saturating_sub(1)).unwrap_or(u32::MAX);
    if doublings == 0 {
        return Duration::ZERO;
    }
    Duration::from_millis(2u64.saturating_pow(doublings)).min(RECONNECT_DELAY_MAX)
}

/// The JetStream context of a new connection to `url`, each request given `timeout`.
async fn context(url: &str, timeout: Duration) -> Result<jetstream::Context, Failure> {
    let client = async_nats::ConnectOptions::new()
        .name("gatewatch")
        .connection_timeout(timeout)
        .reconnect_delay_callback(reconnect_delay)
        .connect(url)
        .await
        .map_err(|e| format!("cannot connect: {e}"))?;
    let mut js = jetstream::new(client);
    js.set_timeout(timeout);
    Ok(js)
}

/// Connects and finds the four streams as they are, creating and changing nothing: a missing
/// one is an error naming it and the prefix (`NatsStore::open_read_only`). The history stream
/// is looked up first, so a wrong prefix is named by it.
pub(super) async fn look_up(url: String, timeout: Duration, names: Names) -> Result<Conn, Failure> {
    let js = context(&url, timeout).await?;
    let find = |name: String| {
        let js = js.clone();
        let prefix = names.prefix.clone();
        async move {
            match js.get_stream(&name).await {
                Ok(s) => Ok(s),
                Err(e) => match e.kind() {
                    GetStreamErrorKind::JetStream(j)
                        if j.error_code() == ErrorCode::STREAM_NOT_FOUND =>
                    {
                        Err(format!(
                            "stream {name} does not exist: nothing was ever stored under prefix \
                             {prefix} on this server (a daemon with storage.nats_prefix = \
                             \"{prefix}\" creates it at its first start)"
                        ))
                    }
                    _ => Err(format!("stream {name}: {e}")),
                },
            }
        }
    };
    let history = find(names.history.clone()).await?;
    let outbox = find(names.outbox.clone()).await?;
    let alerts = find(names.alerts.clone()).await?;
    let owner = find(names.owner.clone()).await?;
    Ok(Conn {
        js,
        history,
        outbox,
        alerts,
        owner,
        names,
    })
}

/// Connects and makes sure the four streams exist with the options' limits.
pub(super) async fn connect(o: NatsOptions, names: Names) -> Result<Conn, Failure> {
    let js = context(&o.url, o.timeout).await?;
    let history = file_stream(
        &names.history,
        "gatewatch: identification history, one subject per gate",
        format!("{}.history.*", names.prefix),
        0,
    );
    ensure(
        &js,
        stream::Config {
            max_age: o.retention,
            max_messages: i64::try_from(o.max_history_rows).unwrap_or(i64::MAX),
            discard: DiscardPolicy::Old,
            ..history
        },
    )
    .await?;
    let outbox = file_stream(
        &names.outbox,
        "gatewatch: undelivered notifications",
        format!("{}.outbox.*.*", names.prefix),
        0,
    );
    ensure(&js, outbox).await?;
    // A key-value table as JetStream's KV buckets are underneath: one subject per key, the
    // newest message of each kept. Not the client's KV API: its bucket creation (0.46) does not
    // read nats-server 2.9's answer.
    let alerts = file_stream(
        &names.alerts,
        "gatewatch: each gate's alert state, one subject per gate",
        format!("{}.alert.*", names.prefix),
        1,
    );
    ensure(&js, alerts).await?;
    // the owner lease (`lease`): one record, its newest message
    let owner = file_stream(
        &names.owner,
        "gatewatch: the owner lease of the prefix",
        names.owner_subject(),
        1,
    );
    ensure(&js, owner).await?;
    let history = get(&js, &names.history).await?;
    let outbox = get(&js, &names.outbox).await?;
    let alerts = get(&js, &names.alerts).await?;
    let owner = get(&js, &names.owner).await?;
    Ok(Conn {
        js,
        history,
        outbox,
        alerts,
        owner,
        names,
    })
}

/// The configuration of a stream on file with one subject filter and at most
/// `max_per_subject` messages a subject (0: no limit): what the four streams share.
fn file_stream(
    name: &str,
    description: &str,
    subject: String,
    max_per_subject: i64,
) -> stream::Config {
    stream::Config {
        name: name.to_string(),
        description: Some(description.into()),
        subjects: vec![subject],
        max_messages_per_subject: max_per_subject,
        storage: StorageType::File,
        ..Default::default()
    }
}

/// How many times [`ensure`] looks again after another client created the stream first.
const ENSURE_ATTEMPTS: usize = 3;

/// Creates the stream `config` describes, or brings the existing one to it; the error names it.
///
/// Why not the client's `create_or_update_stream`: it sends an update first, and Debian's
/// nats-server 2.9.10 dies (a nil pointer in `stream.updateWithAdvisory`, exit status 2) when
/// an update reaches a stream that another client's create has registered but not yet given
/// its store. Four daemons opening a fresh prefix at once killed the server in 3 of 60 runs
/// of `store_nats_lease::of_two_claims_with_the_same_expected_sequence_exactly_one_wins` (four
/// rounds each) on a loaded machine, and in none of 120 with this order (docs/benchmarks.md,
/// stop 65). So the stream is looked up first and changed only when its limits
/// differ from ours; a missing one is created, and concurrent creates are safe on the server
/// (the same configuration is accepted again, or refused as existing or overlapping, and then
/// looked up). An update still races a create only when two clients want different limits
/// for a stream that does not exist yet.
async fn ensure(js: &jetstream::Context, config: stream::Config) -> Result<(), Failure> {
    let name = config.name.clone();
    let named = |e: &dyn std::fmt::Display| format!("stream {name}: {e}");
    for _ in 0..ENSURE_ATTEMPTS {
        match js.get_stream(&name).await {
            Ok(existing) => {
                if same_limits(&existing.cached_info().config, &config) {
                    return Ok(());
                }
                return js
                    .update_stream(config)
                    .await
                    .map(|_| ())
                    .map_err(|e| named(&e));
            }
            Err(e) => match e.kind() {
                GetStreamErrorKind::JetStream(j)
                    if j.error_code() == ErrorCode::STREAM_NOT_FOUND => {}
                _ => return Err(named(&e)),
            },
        }
        match js.create_stream(config.clone()).await {
            Ok(_) => return Ok(()),
            Err(e) => match e.kind() {
                // another client created it between the lookup and the create: look again
                CreateStreamErrorKind::JetStream(j)
                    if j.error_code() == ErrorCode::STREAM_NAME_EXIST
                        || j.error_code() == ErrorCode::STREAM_SUBJECT_OVERLAP => {}
                _ => return Err(named(&e)),
            },
        }
    }
    Err(named(&format!(
        "created by another client and not found, {ENSURE_ATTEMPTS} times"
    )))
}

/// Whether the stream as the server describes it has the settings [`connect`] gives it. The
/// server fills in what a configuration leaves unset, and says "no limit" as -1 where the
/// configuration says 0, so only the settings `connect` sets are compared, each limit with 0
/// and below read as none.
fn same_limits(current: &stream::Config, wanted: &stream::Config) -> bool {
    let limit = |n: i64| n.max(0);
    current.subjects == wanted.subjects
        && current.description == wanted.description
        && current.storage == wanted.storage
        && current.discard == wanted.discard
        && current.max_age == wanted.max_age
        && limit(current.max_messages) == limit(wanted.max_messages)
        && limit(current.max_messages_per_subject) == limit(wanted.max_messages_per_subject)
}

/// The stream `name` as a handle for its operations; the error names it.
async fn get(js: &jetstream::Context, name: &str) -> Result<stream::Stream, Failure> {
    js.get_stream(name)
        .await
        .map_err(|e| format!("stream {name}: {e}"))
}

/// Deletes outbox row `seq`; a row that is already gone (delivered twice, or an id the stream
/// never had) is no error, as a `DELETE` of a missing row is none in SQLite. The server says so
/// in more than one way (`no message found`; `stream store EOF` past the last sequence), so a
/// refused deletion is checked by reading the row.
pub(super) async fn delete_outbox_row(c: &Conn, seq: u64) -> Result<(), Failure> {
    let Err(e) = c.outbox.delete_message(seq).await else {
        return Ok(());
    };
    // the server answered (it is up): is the row there?
    if matches!(e.kind(), DeleteMessageErrorKind::JetStream(_)) {
        let gone = match c.outbox.get_raw_message(seq).await {
            Err(g) => no_message(&g),
            Ok(_) => false,
        };
        if gone {
            return Ok(());
        }
    }
    Err(format!("deletion of outbox row {seq}: {e}"))
}

/// Publishes one message and waits for the server to store it; its stream sequence.
pub(super) async fn publish(c: &Conn, subject: String, publish: Publish) -> Result<u64, Failure> {
    let ack =
        c.js.send_publish(subject.clone(), publish)
            .await
            .map_err(ctx(format!("publish to {subject}")))?
            .await
            .map_err(ctx(format!("publish to {subject}")))?;
    Ok(ack.sequence)
}

/// [`Store::write`] on the runtime, in the order the module gives.
pub(super) async fn write_batch(c: Arc<Conn>, batch: WriteBatch) -> Result<Vec<i64>, Failure> {
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

/// The alert states, sorted by gate: the last message of each subject of the alert stream
/// (one per gate), each read by its subject.
///
/// Why not a consumer over the stream: a writer replaces a gate's state by storing a new
/// message and deleting the old one, so a read over the messages stored when it began misses
/// the gates replaced meanwhile, and one that follows the stream chases the writer
/// (`read::read_each`). One request per gate, [`ALERT_READS_IN_FLIGHT`] at a time, is bounded
/// by the gates (at most `max_gates`) and gives each gate's newest state.
pub(super) async fn read_alert_states(c: Arc<Conn>) -> Result<Vec<(String, String)>, Failure> {
    let filter = format!("{}.alert.*", c.names.prefix);
    let subjects = gate_subjects(&c.alerts, &filter, "alert states").await?;
    let reads = futures_util::stream::iter(subjects)
        .map(|(subject, gate)| {
            let alerts = &c.alerts;
            async move {
                let got = alerts.get_last_raw_message_by_subject(&subject).await;
                (gate, got)
            }
        })
        .buffer_unordered(ALERT_READS_IN_FLIGHT)
        .collect::<Vec<_>>()
        .await;
    let mut out = Vec::with_capacity(reads.len());
    for (gate, got) in reads {
        let message = match got {
            Ok(m) => m,
            // deleted since the listing: the gate was removed from the configuration
            Err(e) if no_message(&e) => continue,
            Err(e) => return Err(format!("alert state of gate {gate}: {e}")),
        };
        let state = String::from_utf8(message.payload.to_vec())
            .map_err(ctx(format!("alert state of gate {gate}")))?;
        out.push((gate, state));
    }
    out.sort();
    Ok(out)
}

/// Alert-state reads [`read_alert_states`] keeps in flight at once: the gates' round trips
/// overlap, so 10 000 gates (`max_gates`' largest) cost about 300 round trips, within the
/// operation timeout also on a server a few milliseconds away.
const ALERT_READS_IN_FLIGHT: usize = 32;

/// Whether a raw get found no message (the server's two ways of saying it).
fn no_message(e: &stream::LastRawMessageError) -> bool {
    match e.kind() {
        LastRawMessageErrorKind::NoMessageFound => true,
        LastRawMessageErrorKind::JetStream(j) => j.error_code() == ErrorCode::NO_MESSAGE_FOUND,
        _ => false,
    }
}

/// The subjects of `stream` matching `filter` that hold a message, each with its gate;
/// `what` names them in errors ("alert states", "history").
async fn gate_subjects(
    stream: &stream::Stream,
    filter: &str,
    what: &str,
) -> Result<Vec<(String, String)>, Failure> {
    let mut info = stream
        .info_with_subjects(filter)
        .await
        .map_err(ctx(format!("subjects of the {what}")))?;
    let mut out = Vec::new();
    while let Some(s) = info.next().await {
        let (subject, count) = s.map_err(ctx(format!("subjects of the {what}")))?;
        if count > 0 {
            let token = subject.rsplit('.').next().unwrap_or_default();
            let gate =
                decode(token).ok_or_else(|| format!("{what} subject {subject:?} is not a gate"))?;
            out.push((subject, gate));
        }
    }
    Ok(out)
}

/// The gates of the history stream's subjects, sorted.
pub(super) async fn read_history_gates(c: Arc<Conn>) -> Result<Vec<String>, Failure> {
    let filter = format!("{}.history.*", c.names.prefix);
    let mut gates: Vec<String> = gate_subjects(&c.history, &filter, "history")
        .await?
        .into_iter()
        .map(|(_, gate)| gate)
        .collect();
    gates.sort();
    Ok(gates)
}

/// [`Store::prune`] on the runtime: the expired rows at the start of the stream, then the
/// oldest beyond `max_rows`.
pub(super) async fn prune(c: Arc<Conn>, cutoff: f64, max_rows: u64) -> Result<Pruned, Failure> {
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
