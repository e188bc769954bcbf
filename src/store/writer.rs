//! [`StoreWriter`]: the one thread that writes to the store.
//!
//! SQLite calls block (a commit waits for an fsync), so they never run on the async runtime nor
//! under the daemon's state lock: callers hand a [`WriteBatch`] to this thread through a
//! bounded queue ([`STORE_QUEUE_CAPACITY`]) and go on. The thread also prunes the history:
//! retention and `max_history_rows` once at start and every [`PRUNE_INTERVAL`]; the size bound
//! (`max_size_mb`, [`Store::make_room`]) after every commit, so the bound prunes the oldest
//! history instead of failing writes. A write refused as full all the same makes room and is
//! retried once.
//!
//! Up to [`MAX_MERGED`] queued requests are merged into one transaction (one fsync for a
//! burst), except that a request writing the state of a gate an earlier one forgot starts the
//! next (`StoreWriter::commit`). When it fails for another reason than a full store or a lock held by another
//! connection (one request's value refused by SQLite, say), the requests are written again one
//! by one, so only the bad one is lost. Not for a lock (`SQLITE_BUSY`): every request would
//! fail alike, each after waiting out the busy timeout (5 s), and a shutdown behind them
//! overran its deadline by tens of seconds.
//!
//! A write that fails (disk full, I/O error) or does not fit in the queue is counted in
//! [`StoreStats`] (exported as `gatewatch_store_write_errors_total`) and logged as an error
//! naming the file (at most one per [`WARN_EVERY`], with the number suppressed: a full disk
//! fails every write, and one line a second per gate would bury the rest of the log); its
//! callback is told, so the notifier still delivers the notification from memory. Nothing
//! waits for the disk.
//!
//! Before each commit, and every [`CHECK_INTERVAL`] when idle, the thread checks that the store
//! is still the one it opened ([`Store::check`]: for SQLite, that the path still names the open
//! file; for NATS, that no other daemon took the prefix's owner lease). Once it is not (the file was deleted or replaced under the daemon), every write is
//! refused, counted as [`StoreStats::file_gone`]
//! (`gatewatch_store_write_errors_total{reason="file_gone"}`), the first detection is logged
//! at once as an error naming the file, and [`StoreWriter::healthy`] is false (`/readyz`
//! answers 503) until the file is back.
//!
//! A write the store refuses (a full disk, an I/O error, a lock another process holds past
//! the busy timeout) makes [`StoreWriter::failing`] say so, naming the file and SQLite's error,
//! and `/readyz` answers 503 with it: an instance whose every write is lost is not one to
//! route to. The next commit that succeeds clears it and logs at level info that writes
//! resumed, with the write requests lost meanwhile; so does a write probe ([`Store::probe`])
//! every [`CHECK_INTERVAL`] while the writes fail and none was tried for that long, since with
//! `/readyz` failing the ingestion may stop arriving (a load balancer takes the instance out)
//! and nothing else would write.
//! Why: the failures were only counted and
//! logged, and a daemon that could not write for hours looked ready. Every
//! [`CHECK_INTERVAL`], and once in [`StoreWriter::start`] before the daemon listens, the writer
//! also asks how much space is left on the store's file system ([`Store::space_left`]) and
//! warns, naming the file and the bytes free, once until it recovers, under
//! [`LOW_SPACE_BYTES`]: a disk full at start used to say nothing until a write failed, and a
//! write into space the WAL already holds does not fail. Low space alone does not fail
//! `/readyz`: the writes still succeed; a write that fails does.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use super::{Store, WriteBatch, STORE_QUEUE_CAPACITY};

/// How often the writer prunes the history.
pub const PRUNE_INTERVAL: Duration = Duration::from_secs(3600);

/// How often an idle writer checks that the store's file is still there ([`Store::check`]: one
/// `stat`). A commit checks first anyway; this bounds how long `/readyz` stays green over a
/// deleted file when nothing is written.
pub const CHECK_INTERVAL: Duration = Duration::from_secs(5);

/// Requests merged into one transaction at most (a burst commits in one fsync).
const MAX_MERGED: usize = 256;

/// A failing store logs at most one error this often.
const WARN_EVERY: Duration = Duration::from_secs(30);

/// Under this many bytes free on the store's file system the writer warns (16 MiB: one WAL
/// budget of a small store, a few thousand rows).
pub const LOW_SPACE_BYTES: u64 = 16 << 20;

/// Since when the store's writes fail, and why.
#[derive(Debug, Clone)]
struct Failing {
    /// The first failure's error.
    message: String,
    /// When it happened.
    since: Instant,
    /// When the last write failed (the probe waits for the writes to go quiet).
    last: Instant,
    /// [`StoreStats::write_failed`] before it: the requests lost since are the difference.
    failed_before: u64,
}

/// What a write's callback is told: the outbox ids, or why nothing was written.
pub type WriteResult = Result<Vec<i64>, String>;

/// Called on the writer thread once the batch is committed (or failed).
pub type Then = Box<dyn FnOnce(WriteResult) + Send>;

enum Request {
    Write(WriteBatch, Option<Then>),
    /// Answered once every request before it is done.
    Flush(SyncSender<()>),
}

/// How many items of each part (identifications, alert states, forgotten gates, outbox rows,
/// delivered ids) one request put into a merged batch, to split it back.
#[derive(Debug, Clone, Copy)]
struct Parts([usize; 5]);

impl Parts {
    fn of(b: &WriteBatch) -> Parts {
        Parts([
            b.identifications.len(),
            b.alert_states.len(),
            b.forget_gates.len(),
            b.outbox.len(),
            b.delivered.len(),
        ])
    }

    /// Moves this request's items out of the front of `merged` (requests are taken in the
    /// order they were merged).
    fn take_front(self, merged: &mut WriteBatch) -> WriteBatch {
        fn front<T>(v: &mut Vec<T>, n: usize) -> Vec<T> {
            v.drain(..n.min(v.len())).collect()
        }
        let [i, a, f, o, d] = self.0;
        WriteBatch {
            identifications: front(&mut merged.identifications, i),
            alert_states: front(&mut merged.alert_states, a),
            forget_gates: front(&mut merged.forget_gates, f),
            outbox: front(&mut merged.outbox, o),
            delivered: front(&mut merged.delivered, d),
        }
    }
}

/// Counters of the store, for `/metrics`.
#[derive(Debug, Default)]
pub struct StoreStats {
    /// Transactions committed.
    pub commits: AtomicU64,
    /// Write requests lost because the queue was full.
    pub queue_full: AtomicU64,
    /// Write requests lost because SQLite failed (disk full, I/O error...).
    pub write_failed: AtomicU64,
    /// Write requests refused because the store's file was deleted or replaced.
    pub file_gone: AtomicU64,
    /// Whether the last check found the store's file deleted or replaced.
    pub gone: AtomicBool,
    /// History rows deleted by the retention.
    pub expired_rows: AtomicU64,
    /// History rows deleted by `max_history_rows`.
    pub over_size_rows: AtomicU64,
    /// History rows deleted by the size bound (`max_size_mb`).
    pub over_bytes_rows: AtomicU64,
    /// Write requests queued or being written, not yet committed or failed: at a shutdown
    /// whose flush missed its deadline, the writes that are lost.
    pub pending: AtomicU64,
}

/// Handle to the writer thread. Cheap to clone.
#[derive(Clone)]
pub struct StoreWriter {
    tx: Arc<Mutex<Option<SyncSender<Request>>>>,
    thread: Arc<Mutex<Option<JoinHandle<()>>>>,
    stats: Arc<StoreStats>,
    warn: Arc<Mutex<(Option<Instant>, u64)>>,
    /// [`Store::location`], so the log of a failed write names the file.
    location: Arc<str>,
    /// Set while the store's writes fail; cleared by the next commit.
    failing: Arc<Mutex<Option<Failing>>>,
    /// Whether the low-space warning was given (until space is back above the mark).
    low_space: Arc<AtomicBool>,
}

impl std::fmt::Debug for StoreWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StoreWriter")
            .field("stats", &self.stats)
            .finish()
    }
}

impl StoreWriter {
    /// Starts the thread. `retention` and `max_rows` drive the pruning.
    pub fn start(
        store: Arc<dyn Store>,
        retention: Duration,
        max_rows: u64,
    ) -> std::io::Result<StoreWriter> {
        let (tx, rx) = mpsc::sync_channel::<Request>(STORE_QUEUE_CAPACITY);
        let stats = Arc::new(StoreStats::default());
        let warn = Arc::new(Mutex::new((None, 0)));
        let writer = StoreWriter {
            tx: Arc::new(Mutex::new(Some(tx))),
            thread: Arc::new(Mutex::new(None)),
            stats: stats.clone(),
            warn: warn.clone(),
            location: store.location().into(),
            failing: Arc::new(Mutex::new(None)),
            low_space: Arc::new(AtomicBool::new(false)),
        };
        // The free space once here, on the caller's thread, before the daemon listens: a store
        // on a nearly full disk is said at start, not only once a write fails (and a write
        // into space the WAL already holds does not fail). The thread checks again every
        // CHECK_INTERVAL; `low_space` keeps it from repeating the warning.
        writer.check_space(store.as_ref());
        let w = writer.clone();
        let thread = std::thread::Builder::new()
            .name("gatewatch-store".into())
            .spawn(move || {
                let mut next_prune = Instant::now();
                let mut next_check = Instant::now();
                loop {
                    if Instant::now() >= next_check {
                        let _ = w.check(store.as_ref());
                        w.check_space(store.as_ref());
                        w.probe(store.as_ref(), CHECK_INTERVAL);
                        next_check = Instant::now() + CHECK_INTERVAL;
                    }
                    if Instant::now() >= next_prune {
                        w.prune(store.as_ref(), retention, max_rows);
                        w.make_room(store.as_ref(), false);
                        next_prune = Instant::now() + PRUNE_INTERVAL;
                    }
                    let wake = next_prune.min(next_check);
                    let first =
                        match rx.recv_timeout(wake.saturating_duration_since(Instant::now())) {
                            Ok(r) => r,
                            Err(RecvTimeoutError::Timeout) => continue,
                            Err(RecvTimeoutError::Disconnected) => break,
                        };
                    let mut writes = Vec::new();
                    let mut flushes = Vec::new();
                    let mut next = Some(first);
                    while let Some(r) = next.take() {
                        match r {
                            Request::Write(b, then) => writes.push((b, then)),
                            Request::Flush(done) => flushes.push(done),
                        }
                        if writes.len() < MAX_MERGED {
                            next = rx.try_recv().ok();
                        }
                    }
                    let n = writes.len() as u64;
                    w.commit(store.as_ref(), writes);
                    w.stats.pending.fetch_sub(n, Ordering::Relaxed);
                    for f in flushes {
                        let _ = f.send(());
                    }
                }
            })?;
        *writer.thread.lock().unwrap_or_else(|p| p.into_inner()) = Some(thread);
        Ok(writer)
    }

    /// Write requests SQLite failed so far ([`StoreStats::write_failed`]).
    pub fn failed_writes(&self) -> u64 {
        self.stats.write_failed.load(Ordering::Relaxed)
    }

    /// Write requests queued or being written ([`StoreStats::pending`]).
    pub fn pending(&self) -> u64 {
        self.stats.pending.load(Ordering::Relaxed)
    }

    /// The counters.
    pub fn stats(&self) -> Arc<StoreStats> {
        self.stats.clone()
    }

    /// False while the store's file is deleted or replaced (the last check found it so):
    /// nothing written now survives, and `/readyz` says so.
    pub fn healthy(&self) -> bool {
        !self.stats.gone.load(Ordering::Relaxed)
    }

    /// Why the store's writes fail, naming its file, the first error and the requests lost
    /// so far; `None` when the last commit succeeded (or nothing failed yet). `/readyz`
    /// answers 503 with it.
    pub fn failing(&self) -> Option<String> {
        let f = self
            .failing
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()?;
        let lost = self.failed_writes().saturating_sub(f.failed_before);
        Some(format!(
            "store {}: writes fail since {} s ago ({lost} write requests lost): {}",
            self.location,
            f.since.elapsed().as_secs(),
            f.message
        ))
    }

    /// A commit failed with `msg`: the store is failing, from the first such failure on.
    fn write_failed(&self, msg: &str, failed_before: u64) {
        let mut f = self.failing.lock().unwrap_or_else(|p| p.into_inner());
        match f.as_mut() {
            Some(f) => f.last = Instant::now(),
            None => {
                *f = Some(Failing {
                    message: msg.to_string(),
                    since: Instant::now(),
                    last: Instant::now(),
                    failed_before,
                })
            }
        }
    }

    /// A commit succeeded: a failing store's writes resumed, said once at level info.
    fn write_succeeded(&self) {
        let Some(f) = self
            .failing
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take()
        else {
            return;
        };
        let lost = self.failed_writes().saturating_sub(f.failed_before);
        tracing::info!(
            store = %self.location,
            lost,
            "store {}: writes resumed after {} s; {lost} write requests were lost meanwhile \
             (first error: {})",
            self.location,
            f.since.elapsed().as_secs(),
            f.message
        );
    }

    /// While writes fail and none was tried for `quiet`, [`Store::probe`]: when it succeeds,
    /// writes resumed (the ingestion whose writes would show it may have stopped with
    /// `/readyz`). Not while real writes are tried: they decide, and a probe that passes where
    /// they fail (a one-page write into space the WAL already holds, on a full disk or at the
    /// size bound) would make readiness flap.
    fn probe(&self, store: &dyn Store, quiet: Duration) {
        let tried = self
            .failing
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
            .map(|f| f.last.elapsed());
        if tried.is_none_or(|t| t < quiet) {
            return;
        }
        if let Some(Ok(())) = store.probe() {
            self.write_succeeded();
        }
    }

    /// Warns once when the store's file system has less than [`LOW_SPACE_BYTES`] free, and
    /// once more when it has again.
    fn check_space(&self, store: &dyn Store) {
        let Some(free) = store.space_left() else {
            return;
        };
        let low = free < LOW_SPACE_BYTES;
        if self.low_space.swap(low, Ordering::Relaxed) == low {
            return;
        }
        if low {
            tracing::warn!(
                store = %self.location,
                free_bytes = free,
                "store {}: its file system has {free} bytes free: writes fail once the disk is \
                 full (then /readyz answers 503 naming the file); free space on that disk",
                self.location
            );
        } else {
            tracing::info!(
                store = %self.location,
                free_bytes = free,
                "store {}: its file system has {free} bytes free again",
                self.location
            );
        }
    }

    /// [`Store::check`], remembered in [`StoreStats::gone`]; the change either way is logged at
    /// once (not rate-limited: it happens once and says why everything after fails).
    fn check(&self, store: &dyn Store) -> Result<(), String> {
        match store.check() {
            Ok(()) => {
                if self.stats.gone.swap(false, Ordering::Relaxed) {
                    tracing::warn!(store = %self.location, "store {}: the file is back, writes resume", self.location);
                }
                Ok(())
            }
            Err(e) => {
                let msg = e.to_string();
                if !self.stats.gone.swap(true, Ordering::Relaxed) {
                    tracing::error!(
                        store = %self.location,
                        "store {msg}; ingestion and alerting go on from memory, /readyz fails"
                    );
                }
                Err(msg)
            }
        }
    }

    /// Queues a write; never blocks. `then` runs on the writer thread after the commit, or at
    /// once (on the caller's thread) with an error when the queue is full or closed.
    pub fn submit(&self, batch: WriteBatch, then: Option<Then>) {
        if batch.is_empty() {
            if let Some(then) = then {
                then(Ok(Vec::new()));
            }
            return;
        }
        let guard = self.tx.lock().unwrap_or_else(|p| p.into_inner());
        let Some(tx) = guard.as_ref() else {
            drop(guard);
            self.failed("the store is closed", &self.stats.queue_full);
            if let Some(then) = then {
                then(Err("the store is closed".into()));
            }
            return;
        };
        // counted before the send: the writer may take it at once
        self.stats.pending.fetch_add(1, Ordering::Relaxed);
        match tx.try_send(Request::Write(batch, then)) {
            Ok(()) => {}
            Err(TrySendError::Full(Request::Write(_, then)))
            | Err(TrySendError::Disconnected(Request::Write(_, then))) => {
                drop(guard);
                self.stats.pending.fetch_sub(1, Ordering::Relaxed);
                self.failed(
                    &format!("write queue full ({STORE_QUEUE_CAPACITY} requests)"),
                    &self.stats.queue_full,
                );
                if let Some(then) = then {
                    then(Err("store write queue full".into()));
                }
            }
            Err(_) => {}
        }
    }

    /// Blocks until every write queued before it is committed (or failed), or `within` passed.
    /// Returns whether it finished in time.
    pub fn flush(&self, within: Duration) -> bool {
        let (done_tx, done_rx) = mpsc::sync_channel(1);
        {
            let guard = self.tx.lock().unwrap_or_else(|p| p.into_inner());
            let Some(tx) = guard.as_ref() else {
                return true;
            };
            let deadline = Instant::now() + within;
            let mut req = Request::Flush(done_tx);
            // the queue may be full: retry until the deadline rather than block forever
            loop {
                match tx.try_send(req) {
                    Ok(()) => break,
                    Err(TrySendError::Full(r)) if Instant::now() < deadline => {
                        req = r;
                        std::thread::sleep(Duration::from_millis(5));
                    }
                    Err(_) => return false,
                }
            }
        }
        done_rx.recv_timeout(within).is_ok()
    }

    /// Flushes (until `within`), stops the thread. Idempotent.
    pub fn close(&self, within: Duration) -> bool {
        let flushed = self.flush(within);
        self.tx.lock().unwrap_or_else(|p| p.into_inner()).take();
        if flushed {
            if let Some(t) = self.thread.lock().unwrap_or_else(|p| p.into_inner()).take() {
                let _ = t.join();
            }
        }
        flushed
    }

    /// Commits the requests taken from the queue, merged into as few transactions as their
    /// order allows: a transaction writes every alert state before it deletes the forgotten
    /// gates' (`WriteBatch::forget_gates`), so a request that writes the state of a gate an
    /// earlier request of the same transaction forgot (an expired gate that sends again, a
    /// gate deleted through the API while its sender goes on) starts the next transaction.
    /// Merged with it, the new gate's state was written and then deleted in the same commit,
    /// and a restart lost it.
    fn commit(&self, store: &dyn Store, writes: Vec<(WriteBatch, Option<Then>)>) {
        let mut group = Vec::with_capacity(writes.len());
        let mut forgotten = std::collections::HashSet::new();
        for (b, then) in writes {
            if b.alert_states
                .iter()
                .any(|(g, _)| forgotten.contains(g.as_str()))
            {
                self.commit_merged(store, std::mem::take(&mut group));
                forgotten.clear();
            }
            forgotten.extend(b.forget_gates.iter().cloned());
            group.push((b, then));
        }
        self.commit_merged(store, group);
    }

    /// Commits `writes` in one transaction (retried one by one as the module says).
    fn commit_merged(&self, store: &dyn Store, writes: Vec<(WriteBatch, Option<Then>)>) {
        if writes.is_empty() {
            return;
        }
        if let Err(msg) = self.check(store) {
            self.stats
                .file_gone
                .fetch_add(writes.len() as u64, Ordering::Relaxed);
            self.warn(&msg);
            for then in writes.into_iter().filter_map(|(_, then)| then) {
                then(Err(msg.clone()));
            }
            return;
        }
        let mut merged = WriteBatch::default();
        let mut parts = Vec::with_capacity(writes.len());
        let mut thens = Vec::with_capacity(writes.len());
        for (b, then) in writes {
            parts.push(Parts::of(&b));
            merged.append(b);
            thens.push(then);
        }
        let failed_before = self.failed_writes();
        let mut result = store.write(&merged);
        if result.as_ref().is_err_and(super::StoreError::is_full) {
            // the size bound's margin did not suffice, or the disk is full: free the oldest
            // history and try once more (alert state and outbox are never pruned)
            self.make_room(store, true);
            result = store.write(&merged);
        }
        match result {
            Ok(ids) => {
                self.stats.commits.fetch_add(1, Ordering::Relaxed);
                self.write_succeeded();
                self.make_room(store, false);
                let mut ids = ids.into_iter();
                for (p, then) in parts.into_iter().zip(thens) {
                    let mine: Vec<i64> = ids.by_ref().take(p.0[3]).collect();
                    if let Some(then) = then {
                        then(Ok(mine));
                    }
                }
            }
            Err(e) if !e.is_full() && !e.is_busy() && thens.len() > 1 => {
                // One request can sink the merged transaction for a reason of its own (a
                // constraint, a value SQLite refuses): the others are written one by one, so
                // only the bad one is lost. Not after a full store or a lock held elsewhere:
                // every one would fail alike (a lock: each after the busy timeout).
                tracing::debug!(store = %self.location, "merged write failed ({e}), retrying its {} requests one by one", thens.len());
                let mut first_error = None;
                let mut any_ok = false;
                for (p, then) in parts.into_iter().zip(thens) {
                    let batch = p.take_front(&mut merged);
                    let r = store.write(&batch).map_err(|e| e.to_string());
                    match &r {
                        Ok(_) => {
                            self.stats.commits.fetch_add(1, Ordering::Relaxed);
                            any_ok = true;
                        }
                        Err(msg) => {
                            self.stats.write_failed.fetch_add(1, Ordering::Relaxed);
                            first_error.get_or_insert_with(|| msg.clone());
                        }
                    }
                    if let Some(then) = then {
                        then(r);
                    }
                }
                // one bad request is its own loss; the store fails only when none got through
                match (&first_error, any_ok) {
                    (_, true) => self.write_succeeded(),
                    (Some(msg), false) => self.write_failed(msg, failed_before),
                    (None, false) => {}
                }
                self.make_room(store, false);
                if let Some(msg) = first_error {
                    self.warn(&msg);
                }
            }
            Err(e) => {
                let msg = e.to_string();
                for _ in &thens {
                    self.stats.write_failed.fetch_add(1, Ordering::Relaxed);
                }
                self.write_failed(&msg, failed_before);
                self.warn(&msg);
                for then in thens.into_iter().flatten() {
                    then(Err(msg.clone()));
                }
            }
        }
    }

    fn prune(&self, store: &dyn Store, retention: Duration, max_rows: u64) {
        let now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default();
        let cutoff = now.saturating_sub(retention).as_secs_f64();
        match store.prune(cutoff, max_rows) {
            Ok(p) => {
                self.stats
                    .expired_rows
                    .fetch_add(p.expired, Ordering::Relaxed);
                self.stats
                    .over_size_rows
                    .fetch_add(p.over_size, Ordering::Relaxed);
                if p.expired + p.over_size > 0 {
                    tracing::info!(
                        expired = p.expired,
                        over_size = p.over_size,
                        "store: history pruned"
                    );
                }
            }
            Err(e) => self.warn(&e.to_string()),
        }
    }

    /// The size bound ([`Store::make_room`]): counted and logged when it deleted rows.
    fn make_room(&self, store: &dyn Store, force: bool) {
        match store.make_room(force) {
            Ok(0) => {}
            Ok(n) => {
                self.stats.over_bytes_rows.fetch_add(n, Ordering::Relaxed);
                tracing::info!(
                    store = %self.location,
                    rows = n,
                    "store: oldest history pruned to stay under storage.max_size_mb"
                );
            }
            // forced, the write is retried at once and its own error (which says whether the
            // bound or the disk is full) is the one logged
            Err(e) if force => {
                tracing::debug!(store = %self.location, "store: making room failed: {e}")
            }
            Err(e) => self.warn(&e.to_string()),
        }
    }

    fn failed(&self, msg: &str, counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
        self.warn(msg);
    }

    fn warn(&self, msg: &str) {
        let mut w = self.warn.lock().unwrap_or_else(|p| p.into_inner());
        let now = Instant::now();
        if w.0.is_none_or(|t| now.duration_since(t) >= WARN_EVERY) {
            tracing::error!(
                store = %self.location,
                suppressed_since_last_error = w.1,
                "store {}: write failed, ingestion and alerting go on from memory: {msg}",
                self.location
            );
            *w = (Some(now), 0);
        } else {
            w.1 += 1;
            tracing::debug!(store = %self.location, "store write failed: {msg}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{HistoryQuery, IdentificationRecord, SqliteStore};

    fn record(end: f64) -> IdentificationRecord {
        IdentificationRecord {
            gate: "g1".into(),
            time: 1.0,
            window_start: 0.0,
            window_end: end,
            equation: "ydd + y = 0".into(),
            coefficients: vec![],
            damping: serde_json::json!({}),
            verdict: "damped".into(),
            fit_nmae: 0.0,
            path: "full".into(),
        }
    }

    /// Three requests merged into one transaction, the middle one refused by SQLite (a NaN
    /// window end is stored as NULL, which the NOT NULL column refuses): the other two are
    /// written, only the bad one is lost and counted.
    #[test]
    fn one_bad_request_does_not_sink_the_merged_ones() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Arc::new(SqliteStore::open(&dir.path().join("gw.db"), 64).expect("open"));
        let writer = StoreWriter::start(store.clone(), Duration::from_secs(u64::MAX / 4), 1 << 20)
            .expect("writer");
        let (tx, rx) = mpsc::channel();
        let writes = [1.0, f64::NAN, 3.0]
            .into_iter()
            .enumerate()
            .map(|(i, end)| {
                let tx = tx.clone();
                let then: Then = Box::new(move |r: WriteResult| {
                    let _ = tx.send((i, r));
                });
                (
                    WriteBatch {
                        identifications: vec![record(end)],
                        ..Default::default()
                    },
                    Some(then),
                )
            })
            .collect();
        writer.commit(store.as_ref(), writes);
        let results: Vec<(usize, WriteResult)> = rx.try_iter().collect();
        let ok: Vec<bool> = results.iter().map(|(_, r)| r.is_ok()).collect();
        assert_eq!(ok, [true, false, true], "{results:?}");
        let err = results[1].1.as_ref().expect_err("the bad one");
        assert!(err.contains("NOT NULL"), "{err}");
        let stats = writer.stats();
        assert_eq!(stats.write_failed.load(Ordering::Relaxed), 1);
        let rows = store
            .history(&HistoryQuery {
                gate: "g1".into(),
                from: None,
                to: None,
                limit: 10,
            })
            .expect("history");
        let ends: Vec<f64> = rows.iter().map(|r| r.window_end).collect();
        assert_eq!(ends.len(), 2);
        assert!((ends[0] - 1.0).abs() < 1e-9 && (ends[1] - 3.0).abs() < 1e-9);
        assert!(writer.close(Duration::from_secs(30)));
    }

    /// A gate forgotten (its expiry, `DELETE /api/v1/gates/{id}`) and written again by a later
    /// request taken in the same burst (it sent again): its new state is kept. Merged into one
    /// transaction, which writes the states before it deletes, the new state was deleted with
    /// the old; a state written before the forgetting is still deleted.
    #[test]
    fn a_gate_written_again_after_it_was_forgotten_keeps_its_new_state() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Arc::new(SqliteStore::open(&dir.path().join("gw.db"), 64).expect("open"));
        let writer = StoreWriter::start(store.clone(), Duration::from_secs(u64::MAX / 4), 1 << 20)
            .expect("writer");
        let state = |g: &str, v: &str| WriteBatch {
            alert_states: vec![(g.into(), v.into())],
            ..Default::default()
        };
        let forget = |g: &str| WriteBatch {
            forget_gates: vec![g.into()],
            ..Default::default()
        };
        writer.commit(
            store.as_ref(),
            vec![
                (state("back", "old"), None),
                (state("gone", "old"), None),
                (forget("back"), None),
                (forget("gone"), None),
                (state("back", "new"), None),
            ],
        );
        let states = store.alert_states().expect("states");
        assert_eq!(states, [("back".to_string(), "new".to_string())]);
        assert!(writer.close(Duration::from_secs(30)));
    }

    /// The seam `/readyz` reads: a store whose writes fail (a real SQLite error: the file's
    /// write lock held by another connection, past a short busy timeout) makes
    /// [`StoreWriter::failing`] name the file and the error; the next commit that succeeds
    /// clears it.
    #[test]
    fn failing_writes_are_reported_until_one_succeeds() {
        let dir = tempfile::tempdir().expect("tempdir");
        let db = dir.path().join("gw.db");
        let store = Arc::new(SqliteStore::open(&db, 64).expect("open"));
        let writer = StoreWriter::start(store.clone(), Duration::from_secs(u64::MAX / 4), 1 << 20)
            .expect("writer");
        let batch = || {
            vec![(
                WriteBatch {
                    identifications: vec![record(1.0)],
                    ..Default::default()
                },
                None,
            )]
        };
        writer.commit(store.as_ref(), batch());
        assert_eq!(writer.failing(), None);
        let other = rusqlite::Connection::open(&db).expect("open");
        other.execute_batch("BEGIN EXCLUSIVE").expect("lock");
        writer.commit(store.as_ref(), batch());
        writer.commit(store.as_ref(), batch());
        let why = writer.failing().expect("failing");
        assert!(
            why.contains(&db.display().to_string()) && why.contains("2 write requests lost"),
            "{why}"
        );
        assert!(why.contains("locked"), "{why}");
        other.execute_batch("COMMIT").expect("unlock");
        writer.commit(store.as_ref(), batch());
        assert_eq!(writer.failing(), None);
        // with nothing to write (the ingestion stopped with /readyz), the probe clears it
        other.execute_batch("BEGIN EXCLUSIVE").expect("lock");
        writer.commit(store.as_ref(), batch());
        assert!(writer.failing().is_some());
        other.execute_batch("COMMIT").expect("unlock");
        writer.probe(store.as_ref(), Duration::ZERO);
        assert_eq!(writer.failing(), None);
        assert!(writer.close(Duration::from_secs(30)));
    }
}
