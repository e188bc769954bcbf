//! The identification worker pool and its scheduler.
//!
//! Identification is CPU-bound and runs on dedicated std threads, never on the async runtime.
//! The scheduler keeps at most ONE pending job per gate: a newer window of the same gate replaces
//! the pending one (counted in `gatewatch_identification_jobs_replaced_total`), so the queue is
//! bounded by the number of gates whatever the ingestion rate. At most one job per gate is in
//! flight, so the warm start of a gate's next job is always its previous result: the pool keeps
//! each gate's [`Previous`] (the tracking memory of `analysis::tracking`) and hands it to the
//! next job. Every job runs under `catch_unwind`: a panic in the numerics is logged and counted
//! as a failed job. The pool knows when each job in flight started: one that runs past
//! `server.identification_timeout_seconds` is reported ([`WorkerPool::overdue`]) so that the
//! daemon's liveness fails while it runs. Why not cancel it: a thread cannot be stopped from
//! outside, and a cancellation flag checked between iterations does not reach a call that never
//! returns, which is what a stuck worker is (docs/operations.md, "A stuck identification").

use std::collections::{HashMap, HashSet, VecDeque};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::sync::lock;
use crate::analysis::{AnalysisError, Analyzer, Previous, WindowAnalysis, WindowInput};

/// What the pool needs from the numerics; implemented for [`AnalyzerMap`] and by test fakes.
pub trait WindowAnalyzer: Send + Sync + 'static {
    /// Analyses one window of `gate`.
    fn analyze(
        &self,
        gate: &str,
        input: WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError>;

    /// Analyses one window of `gate` whose last window is `previous`; the default ignores
    /// tracking and warm-starts [`WindowAnalyzer::analyze`] from the previous coefficients.
    fn analyze_tracked(
        &self,
        gate: &str,
        input: WindowInput<'_>,
        previous: Option<&Previous>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        let warm = previous.map(|p| p.coefficients.as_slice());
        self.analyze(gate, input, warm, seed)
    }

    /// What `gate` remembers after window `a` covering `[t_start, t_end]`; the default is
    /// [`Previous::after`].
    fn remember(
        &self,
        gate: &str,
        before: Option<&Previous>,
        a: &WindowAnalysis,
        t_start: f64,
        t_end: f64,
    ) -> Previous {
        let _ = gate;
        Previous::after(before, a, t_start, t_end)
    }

    /// Whether stored window `a` of `gate` was identified with the model `gate` has now, so
    /// that its coefficients may start the next refinement after a restart; the default
    /// (analyzers without a model of their own) says yes.
    fn same_model(&self, gate: &str, a: &WindowAnalysis) -> bool {
        let _ = (gate, a);
        true
    }
}

/// What a gate's tracking memory would be after `windows` (oldest first, each with its span),
/// as [`WindowAnalyzer::remember`] builds it: what a restart rebuilds from the stored history.
/// `None` without windows.
pub fn replay(
    analyzer: &dyn WindowAnalyzer,
    gate: &str,
    windows: &[(WindowAnalysis, f64, f64)],
) -> Option<Previous> {
    windows.iter().fold(None, |before, (a, t0, t1)| {
        Some(analyzer.remember(gate, before.as_ref(), a, *t0, *t1))
    })
}

/// One [`Analyzer`] per configured gate, and the defaults' analyzer for the others.
#[derive(Debug)]
pub struct AnalyzerMap {
    gates: HashMap<String, Analyzer>,
    default: Analyzer,
}

impl AnalyzerMap {
    /// Builds the analyzers from the configuration (compiles each model once).
    pub fn from_config(config: &super::config::Config) -> Result<AnalyzerMap, AnalysisError> {
        let default = Analyzer::new(config.defaults.analysis_settings())?
            .with_tracking(config.defaults.tracking.clone())?;
        let mut gates = HashMap::new();
        for (id, g) in &config.gates {
            let a = Analyzer::new(g.analysis_settings())
                .and_then(|a| a.with_tracking(g.tracking.clone()))
                .map_err(|e| AnalysisError::Settings(format!("gates.{id}: {e}")))?;
            gates.insert(id.clone(), a);
        }
        // Whether the models run as machine code: not where the host refuses executable
        // memory (systemd's MemoryDenyWriteExecute=yes); the results are the same, a cold
        // window costs about a fifth more CPU (docs/operations.md).
        let map = AnalyzerMap { gates, default };
        let (compiled, interpreted) = map.compiled_counts();
        tracing::info!(
            compiled,
            interpreted,
            jit_enabled = crate::model::jit_enabled(),
            "models: compiled to machine code or interpreted"
        );
        Ok(map)
    }

    /// How many of the analyzers' models (the defaults' and each configured gate's) run as
    /// machine code, and how many are interpreted.
    pub fn compiled_counts(&self) -> (usize, usize) {
        let all = || self.gates.values().chain(std::iter::once(&self.default));
        let compiled = all().filter(|a| a.model().is_compiled()).count();
        (compiled, self.gates.len() + 1 - compiled)
    }
}

impl WindowAnalyzer for AnalyzerMap {
    fn analyze(
        &self,
        gate: &str,
        input: WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        self.gates
            .get(gate)
            .unwrap_or(&self.default)
            .analyze(input, warm, seed)
    }

    fn analyze_tracked(
        &self,
        gate: &str,
        input: WindowInput<'_>,
        previous: Option<&Previous>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        self.gates
            .get(gate)
            .unwrap_or(&self.default)
            .analyze_tracked(input, previous, seed)
    }

    fn same_model(&self, gate: &str, a: &WindowAnalysis) -> bool {
        self.gates
            .get(gate)
            .unwrap_or(&self.default)
            .describes(&a.equation, &a.warm_start)
    }

    /// [`Previous::after`], and for a gate's first window its schedule's phase
    /// ([`Previous::first_of`]) so that gates started together do not search together.
    fn remember(
        &self,
        gate: &str,
        before: Option<&Previous>,
        a: &WindowAnalysis,
        t_start: f64,
        t_end: f64,
    ) -> Previous {
        let next = Previous::after(before, a, t_start, t_end);
        match before {
            Some(_) => next,
            None => {
                let analyzer = self.gates.get(gate).unwrap_or(&self.default);
                next.first_of(gate, analyzer.tracking())
            }
        }
    }
}

/// Reproducible seed of a window: FNV-1a of the gate id, mixed with the window's end index.
pub fn window_seed(gate: &str, end_index: u64) -> u64 {
    crate::analysis::gate_hash(gate, end_index)
}

/// One identification job.
#[derive(Debug, Clone)]
pub struct Job {
    /// Gate id.
    pub gate: String,
    /// Time of the first sample.
    pub t0: f64,
    /// Sample rate.
    pub rate_hz: f64,
    /// Samples.
    pub values: Vec<f64>,
    /// The contiguous samples up to the window's end, oldest first ([`WindowInput::history`];
    /// empty: the window alone).
    pub history: Vec<f64>,
    /// Index of the sample after the window's last (seeds the job).
    pub end_index: u64,
    /// The life of the gate the window belongs to (the service numbers each gate entry it
    /// makes): a result is reported only to the entry that asked for it, not to a gate of the
    /// same name made after the first expired. 0 where there is only one life.
    pub generation: u64,
    /// The gate's ambient level and departure ratio when the window was dispatched (`None`:
    /// no level yet): a window that stands the ratio above the level is read by the
    /// prediction-error method as well (`analysis::read_by_prediction_errors`).
    pub ambient_level: Option<(f64, f64)>,
}

/// How a job ended.
#[derive(Debug)]
pub enum JobOutcome {
    /// Analysed.
    Done(Box<WindowAnalysis>),
    /// The analyzer refused the window or settings.
    Failed(AnalysisError),
    /// The analyzer panicked (message).
    Panicked(String),
}

/// Called on the worker thread with each finished job and its wall time.
pub type ResultSink = Arc<dyn Fn(&Job, JobOutcome, Duration) + Send + Sync>;

/// What `submit` did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Submitted {
    /// Queued.
    Queued,
    /// Replaced the gate's pending job.
    Replaced,
    /// The queue is full (more gates waiting than `job_queue`): dropped.
    QueueFull,
    /// The pool is shutting down: dropped.
    Closed,
}

/// A job a worker runs.
struct Running {
    started: Instant,
    end_index: u64,
    /// Whether [`WorkerPool::newly_overdue`] returned it.
    reported: bool,
}

/// A job that has run longer than `server.identification_timeout_seconds`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Overdue {
    /// Its gate.
    pub gate: String,
    /// Index of the sample after its window's last.
    pub end_index: u64,
    /// How long it has run.
    pub running: Duration,
}

#[derive(Default)]
struct Sched {
    pending: HashMap<String, Job>,
    order: VecDeque<String>,
    /// The gates whose job a worker runs, with when it started and the window's end index.
    in_flight: HashMap<String, Running>,
    /// Each gate's tracking memory (bounded by the live gates: an expired gate's is forgotten,
    /// [`WorkerPool::forget`]).
    previous: HashMap<String, Previous>,
    /// Gates forgotten while their job was in flight: that job's memory is not kept.
    forgotten: HashSet<String>,
    closed: bool,
    running_workers: usize,
}

struct Shared {
    sched: Mutex<Sched>,
    cv: Condvar,
    queue_bound: usize,
    analyzer: Arc<dyn WindowAnalyzer>,
    sink: ResultSink,
}

/// The worker pool.
pub struct WorkerPool {
    shared: Arc<Shared>,
    threads: Mutex<Vec<JoinHandle<()>>>,
}

impl std::fmt::Debug for WorkerPool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerPool").finish_non_exhaustive()
    }
}

impl WorkerPool {
    /// Starts `threads` workers; at most `queue_bound` gates wait at once.
    pub fn start(
        threads: usize,
        queue_bound: usize,
        analyzer: Arc<dyn WindowAnalyzer>,
        sink: ResultSink,
    ) -> std::io::Result<WorkerPool> {
        let shared = Arc::new(Shared {
            sched: Mutex::new(Sched::default()),
            cv: Condvar::new(),
            queue_bound: queue_bound.max(1),
            analyzer,
            sink,
        });
        let mut handles = Vec::new();
        for i in 0..threads.max(1) {
            let s = shared.clone();
            lock(&shared.sched).running_workers += 1;
            let h = std::thread::Builder::new()
                .name(format!("gatewatch-worker-{i}"))
                .spawn(move || worker_loop(s));
            match h {
                Ok(h) => handles.push(h),
                Err(e) => {
                    lock(&shared.sched).running_workers -= 1;
                    return Err(e);
                }
            }
        }
        Ok(WorkerPool {
            shared,
            threads: Mutex::new(handles),
        })
    }

    /// Submits a job; replaces the gate's pending job if there is one.
    pub fn submit(&self, job: Job) -> Submitted {
        let mut s = lock(&self.shared.sched);
        if s.closed {
            return Submitted::Closed;
        }
        let outcome = if let Some(slot) = s.pending.get_mut(&job.gate) {
            *slot = job;
            Submitted::Replaced
        } else if s.pending.len() >= self.shared.queue_bound {
            return Submitted::QueueFull;
        } else {
            s.order.push_back(job.gate.clone());
            s.pending.insert(job.gate.clone(), job);
            Submitted::Queued
        };
        drop(s);
        self.shared.cv.notify_one();
        outcome
    }

    /// Forgets `gate` (an expired gate): its pending job and its tracking memory, and the memory
    /// of a job of it still in flight. Without it every gate name ever seen kept its memory (a
    /// model and an ambient level) until a restart: the pool's memory is bounded by the live
    /// gates only if expired ones leave it.
    pub fn forget(&self, gate: &str) {
        let mut s = lock(&self.shared.sched);
        s.previous.remove(gate);
        if s.pending.remove(gate).is_some() {
            s.order.retain(|g| g != gate);
        }
        if s.in_flight.contains_key(gate) {
            s.forgotten.insert(gate.to_string());
        }
    }

    /// Gives `gate` the tracking memory `p` (rebuilt at a restart) unless it has one already.
    pub fn restore(&self, gate: &str, p: Previous) {
        lock(&self.shared.sched)
            .previous
            .entry(gate.to_string())
            .or_insert(p);
    }

    /// Gates whose tracking memory the pool holds.
    pub fn remembered_gates(&self) -> usize {
        lock(&self.shared.sched).previous.len()
    }

    /// Workers still running.
    pub fn running_workers(&self) -> usize {
        lock(&self.shared.sched).running_workers
    }

    /// Jobs waiting.
    pub fn pending(&self) -> usize {
        lock(&self.shared.sched).pending.len()
    }

    /// Jobs in flight.
    pub fn in_flight(&self) -> usize {
        lock(&self.shared.sched).in_flight.len()
    }

    /// The job in flight that has run longest: its gate and how long it has run. `None` when
    /// no job runs.
    pub fn longest_running(&self) -> Option<(String, Duration)> {
        let s = lock(&self.shared.sched);
        s.in_flight
            .iter()
            .map(|(g, r)| (g, r.started.elapsed()))
            .max_by_key(|(_, d)| *d)
            .map(|(g, d)| (g.clone(), d))
    }

    /// The jobs in flight that have run longer than `limit` (gate, window end index, time run),
    /// longest first.
    pub fn overdue(&self, limit: Duration) -> Vec<Overdue> {
        let s = lock(&self.shared.sched);
        let mut v: Vec<Overdue> = s
            .in_flight
            .iter()
            .map(|(g, r)| Overdue {
                gate: g.clone(),
                end_index: r.end_index,
                running: r.started.elapsed(),
            })
            .filter(|o| o.running > limit)
            .collect();
        v.sort_by(|a, b| b.running.cmp(&a.running).then_with(|| a.gate.cmp(&b.gate)));
        v
    }

    /// [`WorkerPool::overdue`] jobs not returned by an earlier call of this function: each
    /// overdue job once (to be logged once, not every second while it runs).
    pub fn newly_overdue(&self, limit: Duration) -> Vec<Overdue> {
        let mut s = lock(&self.shared.sched);
        let mut v = Vec::new();
        for (g, r) in s.in_flight.iter_mut() {
            let running = r.started.elapsed();
            if running > limit && !r.reported {
                r.reported = true;
                v.push(Overdue {
                    gate: g.clone(),
                    end_index: r.end_index,
                    running,
                });
            }
        }
        v.sort_by(|a, b| a.gate.cmp(&b.gate));
        v
    }

    /// Stops taking jobs, abandons pending ones and waits up to `grace` for the jobs in flight.
    /// Returns the number of pending jobs abandoned and whether every worker stopped in time
    /// (a worker still computing after the deadline is detached; the process exit ends it).
    pub async fn shutdown(&self, grace: Duration) -> (usize, bool) {
        let abandoned = {
            let mut s = lock(&self.shared.sched);
            s.closed = true;
            let n = s.pending.len();
            s.pending.clear();
            s.order.clear();
            n
        };
        self.shared.cv.notify_all();
        let deadline = Instant::now() + grace;
        loop {
            if self.running_workers() == 0 {
                for h in lock(&self.threads).drain(..) {
                    let _ = h.join();
                }
                return (abandoned, true);
            }
            if Instant::now() >= deadline {
                return (abandoned, false);
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

/// Counts its worker out of `running_workers` when the thread ends: at the pool's shutdown, or
/// by a panic outside the job's `catch_unwind` (then nothing restarts the thread, and
/// `/healthz` says so).
struct WorkerAlive(Arc<Shared>);

impl Drop for WorkerAlive {
    fn drop(&mut self) {
        lock(&self.0.sched).running_workers -= 1;
    }
}

fn worker_loop(shared: Arc<Shared>) {
    // dropped after any guard of the loop below (declared first), so its lock does not deadlock
    let _alive = WorkerAlive(shared.clone());
    loop {
        let (job, previous) = {
            let mut s = lock(&shared.sched);
            loop {
                if s.closed {
                    return;
                }
                // the oldest waiting gate that is not in flight
                let pos = s.order.iter().position(|g| !s.in_flight.contains_key(g));
                if let Some(pos) = pos {
                    let gate = s.order.remove(pos).expect("position is in range");
                    let job = s.pending.remove(&gate).expect("order and pending agree");
                    s.in_flight.insert(
                        gate.clone(),
                        Running {
                            started: Instant::now(),
                            end_index: job.end_index,
                            reported: false,
                        },
                    );
                    let previous = s.previous.get(&gate).cloned();
                    break (job, previous);
                }
                s = shared.cv.wait(s).unwrap_or_else(|p| p.into_inner());
            }
        };
        let started = Instant::now();
        let seed = window_seed(&job.gate, job.end_index);
        let result = catch_unwind(AssertUnwindSafe(|| {
            shared.analyzer.analyze_tracked(
                &job.gate,
                WindowInput {
                    t0: job.t0,
                    rate_hz: job.rate_hz,
                    values: &job.values,
                    history: &job.history,
                },
                previous.as_ref(),
                seed,
            )
        }));
        let elapsed = started.elapsed();
        let outcome = match result {
            Ok(Ok(mut a)) => {
                if let Some((level, ratio)) = job.ambient_level {
                    crate::analysis::read_by_prediction_errors(
                        &mut a.damping,
                        &job.values,
                        job.rate_hz,
                        level,
                        ratio,
                    );
                }
                let t_end = job.t0 + job.values.len().saturating_sub(1) as f64 / job.rate_hz;
                let next =
                    shared
                        .analyzer
                        .remember(&job.gate, previous.as_ref(), &a, job.t0, t_end);
                let mut s = lock(&shared.sched);
                if !s.forgotten.remove(&job.gate) {
                    s.previous.insert(job.gate.clone(), next);
                }
                JobOutcome::Done(Box::new(a))
            }
            Ok(Err(e)) => JobOutcome::Failed(e),
            Err(panic) => {
                let msg = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "non-string panic payload".into());
                JobOutcome::Panicked(msg)
            }
        };
        // the sink must not take the worker down either
        let sink = shared.sink.clone();
        if catch_unwind(AssertUnwindSafe(|| sink(&job, outcome, elapsed))).is_err() {
            tracing::error!(gate = %job.gate, "result handler panicked");
        }
        {
            let mut s = lock(&shared.sched);
            s.in_flight.remove(&job.gate);
            // a failed or panicked job of a forgotten gate left nothing to drop
            s.forgotten.remove(&job.gate);
        }
        shared.cv.notify_all();
    }
}
