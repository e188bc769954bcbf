//! Reading a subject of a stream through an ephemeral consumer, in bounded memory: every
//! message handed to a function as it arrives ([`read_each`]), the first `max` collected
//! ([`read_from`]), the last `n` read from the end ([`read_last`]), and a gate's history rows
//! selected as they stream by ([`FirstRows`]).
//!
//! # Why not collect the subject
//! A gate's history subject holds every window of the retention: 17 280 rows a day at the
//! default cadence, 518 400 in the default 30 days, about 1.9 kB each. Reading it whole for
//! one history request or for a restart's newest rows held all of it at once (914 MB of
//! resident memory for one gate's week, `gatewatch bench history --nats`, docs/benchmarks.md)
//! and took longer than the operation timeout past about a month. A history request now
//! keeps at most its limit of rows while the subject streams by, and the newest rows are read
//! from the stream's end.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};
use std::time::Duration;

use async_nats::jetstream::consumer::{pull, AckPolicy, DeliverPolicy};
use async_nats::jetstream::stream;
use futures_util::StreamExt;

use super::super::row::HistoryRow;
use super::{ctx, Failure, FETCH_BATCH, FETCH_EXPIRES};

/// An ephemeral consumer of `subject` (a filter) from `start` on, without acks; its name and
/// the number of messages it has to deliver.
async fn consumer(
    stream: &stream::Stream,
    subject: &str,
    start: DeliverPolicy,
) -> Result<
    (
        async_nats::jetstream::consumer::Consumer<pull::Config>,
        String,
        u64,
    ),
    Failure,
> {
    let mut consumer = stream
        .create_consumer(pull::Config {
            filter_subject: subject.to_string(),
            deliver_policy: start,
            ack_policy: AckPolicy::None,
            // an abandoned reader's consumer goes away by itself
            inactive_threshold: Duration::from_secs(60),
            memory_storage: true,
            ..Default::default()
        })
        .await
        .map_err(ctx(format!("reader of {subject}")))?;
    let info = consumer
        .info()
        .await
        .map_err(ctx(format!("reader of {subject}")))?;
    let (name, pending) = (info.name.clone(), info.num_pending);
    Ok((consumer, name, pending))
}

/// Hands every message of `subject` (a filter) in `stream` from `start` on that was stored
/// when the read began to `each`, as `(sequence, subject, payload)` in stream order, until
/// `each` returns `false` or none is left; fetched [`FETCH_BATCH`] at a time (each fetch
/// answered within [`FETCH_EXPIRES`] when its messages went away meanwhile), nothing kept
/// here.
///
/// # Why the read ends at the stream's last sequence at its start
/// The consumer's count of what is left includes what a writer stores meanwhile. Reading
/// until that count reached zero chased a busy writer: reading two gates' alert states while
/// a writer replaced them every 2 ms, 14 of 155 reads ran into a 2 s timeout, one to two
/// messages a fetch (docs/benchmarks.md, "NATS reads that chased their writer"). A message
/// stored after the start is newer than the read; the next read has it.
pub(super) async fn read_each(
    stream: &stream::Stream,
    subject: String,
    start: DeliverPolicy,
    mut each: impl FnMut(u64, &str, &[u8]) -> Result<bool, Failure>,
) -> Result<(), Failure> {
    let last = stream
        .get_info()
        .await
        .map_err(ctx(format!("info of the stream of {subject}")))?
        .state
        .last_sequence;
    let (consumer, name, mut pending) = consumer(stream, &subject, start).await?;
    let result: Result<(), Failure> = async {
        while pending > 0 {
            let want = usize::try_from(pending)
                .unwrap_or(usize::MAX)
                .min(FETCH_BATCH);
            let mut batch = consumer
                .fetch()
                .max_messages(want)
                .expires(FETCH_EXPIRES)
                .messages()
                .await
                .map_err(ctx(format!("read of {subject}")))?;
            let mut got = 0;
            while let Some(m) = batch.next().await {
                let m = m.map_err(ctx(format!("read of {subject}")))?;
                let info = m.info().map_err(ctx(format!("read of {subject}")))?;
                let seq = info.stream_sequence;
                if seq > last {
                    return Ok(()); // stored after the read began
                }
                pending = info.pending;
                got += 1;
                if !each(seq, &m.message.subject, &m.message.payload)? || seq == last {
                    return Ok(());
                }
            }
            if got == 0 {
                break; // nothing more came: the rest was deleted meanwhile
            }
        }
        Ok(())
    }
    .await;
    // the consumer is not needed any more (and expires by itself if this fails)
    let _ = stream.delete_consumer(&name).await;
    result
}

/// The first `max` messages of `subject` (a filter) in `stream`, `(sequence, subject,
/// payload)` in stream order.
pub(super) async fn read_from(
    stream: &stream::Stream,
    subject: String,
    max: usize,
) -> Result<Vec<(u64, String, Vec<u8>)>, Failure> {
    let mut out = Vec::new();
    if max == 0 {
        return Ok(out);
    }
    read_each(stream, subject, DeliverPolicy::All, |seq, s, p| {
        out.push((seq, s.to_string(), p.to_vec()));
        Ok(out.len() < max)
    })
    .await?;
    Ok(out)
}

/// The last `n` messages of `subject` in `stream`, `(sequence, payload)` in stream order, read
/// from the end: the consumer starts at the stream's last sequence less `step`, `step` growing
/// fourfold from `n` until `n` messages of the subject lie after it (the server counts them
/// when the consumer is made), so a gate's newest rows cost a few probes and about `n` to
/// `4 n` messages whatever the history's length, and memory for `n`.
pub(super) async fn read_last(
    stream: &stream::Stream,
    subject: String,
    n: usize,
) -> Result<Vec<(u64, Vec<u8>)>, Failure> {
    if n == 0 {
        return Ok(Vec::new());
    }
    let state = stream
        .get_info()
        .await
        .map_err(ctx(format!("info of the stream of {subject}")))?
        .state;
    let (first, last) = (state.first_sequence, state.last_sequence);
    let want = u64::try_from(n).unwrap_or(u64::MAX);
    let mut step = want;
    let start = loop {
        let start = last.saturating_sub(step.saturating_sub(1)).max(first);
        if start <= first {
            break DeliverPolicy::All;
        }
        let policy = DeliverPolicy::ByStartSequence {
            start_sequence: start,
        };
        let (_, name, pending) = consumer(stream, &subject, policy).await?;
        let _ = stream.delete_consumer(&name).await;
        if pending >= want {
            break DeliverPolicy::ByStartSequence {
                start_sequence: start,
            };
        }
        step = step.saturating_mul(4);
    };
    let mut out = VecDeque::with_capacity(n.min(FETCH_BATCH));
    read_each(stream, subject, start, |seq, _, p| {
        if out.len() == n {
            out.pop_front();
        }
        out.push_back((seq, p.to_vec()));
        Ok(true)
    })
    .await?;
    Ok(out.into())
}

/// The `k` history rows with the smallest `(window_end, sequence)` offered, in memory for `k`:
/// a history request's rows selected while its subject streams by. Equal ends keep the order
/// stored, as SQLite's `ORDER BY window_end, seq`.
pub(super) struct FirstRows {
    k: usize,
    heap: BinaryHeap<Keyed>,
}

/// A row and its order key.
struct Keyed {
    end: f64,
    seq: u64,
    row: HistoryRow,
}

impl Keyed {
    fn cmp_key(&self, other: &Keyed) -> Ordering {
        self.end
            .total_cmp(&other.end)
            .then(self.seq.cmp(&other.seq))
    }
}

impl PartialEq for Keyed {
    fn eq(&self, other: &Keyed) -> bool {
        self.cmp_key(other) == Ordering::Equal
    }
}

impl Eq for Keyed {}

impl PartialOrd for Keyed {
    fn partial_cmp(&self, other: &Keyed) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Keyed {
    fn cmp(&self, other: &Keyed) -> Ordering {
        self.cmp_key(other)
    }
}

impl FirstRows {
    /// Keeps at most `k` rows.
    pub(super) fn new(k: usize) -> FirstRows {
        FirstRows {
            k,
            heap: BinaryHeap::with_capacity(k.min(FETCH_BATCH) + 1),
        }
    }

    /// Offers row `row` stored at sequence `seq`.
    pub(super) fn offer(&mut self, seq: u64, row: HistoryRow) {
        if self.k == 0 {
            return;
        }
        let keyed = Keyed {
            end: row.window_end,
            seq,
            row,
        };
        if self.heap.len() < self.k {
            self.heap.push(keyed);
        } else if self.heap.peek().is_some_and(|top| keyed < *top) {
            self.heap.pop();
            self.heap.push(keyed);
        }
    }

    /// The rows kept, oldest window first.
    pub(super) fn into_rows(self) -> Vec<HistoryRow> {
        self.heap
            .into_sorted_vec()
            .into_iter()
            .map(|k| k.row)
            .collect()
    }
}
