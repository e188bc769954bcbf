//! The identification worker pool: replace-don't-queue, the queue bound, one job in flight per
//! gate, warm starts, seeds, panics, and the cadence in sample time.

use crate::service_common;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::http::StatusCode;
use gatewatch::service::config::Config;
use gatewatch::service::ingest::Batch;
use gatewatch::service::worker::{Job, ResultSink, Submitted, WorkerPool};

use service_common::*;

/// A pool of one worker (8 jobs queued at most) running a [`Fake`] that takes `sleep` per job:
/// the fake (its record of calls), the pool, and the count of jobs done.
fn counting_pool(sleep: Duration) -> (Arc<Fake>, WorkerPool, Arc<AtomicUsize>) {
    let fake = Arc::new(Fake {
        sleep,
        ..Default::default()
    });
    let done = Arc::new(AtomicUsize::new(0));
    let d = done.clone();
    let on_done: ResultSink = Arc::new(move |_: &Job, _, _| {
        d.fetch_add(1, Ordering::SeqCst);
    });
    let pool = WorkerPool::start(1, 8, fake.clone(), on_done).unwrap();
    (fake, pool, done)
}

/// A job of `gate` ending at sample `i`: 10 zeros at 100 Hz from `t0 = i` s, no history.
fn small_job(gate: &str, i: u64) -> Job {
    Job {
        gate: gate.into(),
        t0: i as f64,
        rate_hz: 100.0,
        values: vec![0.0; 10],
        history: vec![],
        end_index: i,
        generation: 0,
        ambient_level: None,
    }
}

#[tokio::test]
async fn slow_workers_replace_pending_jobs_instead_of_queueing() {
    let (fake, pool, done) = counting_pool(Duration::from_millis(200));
    let mut replaced = 0;
    let mut queued = 0;
    for i in 0..20 {
        match pool.submit(small_job("g1", i)) {
            Submitted::Replaced => replaced += 1,
            Submitted::Queued => queued += 1,
            other => panic!("{other:?}"),
        }
        assert!(
            pool.pending() <= 1,
            "never more than one pending job per gate"
        );
    }
    assert!(
        replaced > 0,
        "a slow worker makes newer windows replace pending ones"
    );
    assert_eq!(replaced + queued, 20);
    wait_until(|| done.load(Ordering::SeqCst) == queued).await;
    let calls = fake.calls.lock().unwrap().clone();
    assert_eq!(calls.len(), queued);
    // the newest window is the one analysed last
    assert_eq!(calls.last().unwrap().t0, 19.0);
    let (abandoned, clean) = pool.shutdown(Duration::from_secs(5)).await;
    assert_eq!((abandoned, clean), (0, true));
    assert_eq!(pool.submit(small_job("g1", 99)), Submitted::Closed);
}

#[tokio::test]
async fn the_queue_is_bounded() {
    let fake = Arc::new(Fake {
        sleep: Duration::from_millis(100),
        ..Default::default()
    });
    let pool = WorkerPool::start(2, 2, fake.clone(), Arc::new(|_: &Job, _, _| {})).unwrap();
    let job = |g: &str| Job {
        gate: g.into(),
        t0: 0.0,
        rate_hz: 100.0,
        values: vec![0.0; 4],
        history: vec![],
        end_index: 1,
        generation: 0,
        ambient_level: None,
    };
    let mut full = 0;
    for g in ["a", "b", "c", "d", "e", "f"] {
        if pool.submit(job(g)) == Submitted::QueueFull {
            full += 1;
        }
        assert!(pool.pending() <= 2);
    }
    assert!(full >= 1);
    pool.shutdown(Duration::from_secs(5)).await;
}

/// A gate's next window waits for its window in flight, even with a worker free: two windows of
/// one gate analysed at once would race for its tracking memory and could report out of order.
/// (Until stop 67 the test above claimed this in its name, but it submits one job per gate.)
#[tokio::test]
async fn a_gates_next_window_waits_for_the_one_in_flight() {
    let fake = Arc::new(Fake {
        hold_call: Some(0),
        ..Default::default()
    });
    let pool = WorkerPool::start(2, 8, fake.clone(), Arc::new(|_: &Job, _, _| {})).unwrap();
    let calls = || fake.calls.lock().unwrap().clone();
    assert_eq!(pool.submit(small_job("a", 0)), Submitted::Queued);
    wait_until(|| calls().len() == 1 && pool.in_flight() == 1).await;
    // a's next window is queued; the free worker takes b's window instead
    assert_eq!(pool.submit(small_job("a", 1)), Submitted::Queued);
    assert_eq!(pool.submit(small_job("b", 2)), Submitted::Queued);
    wait_until(|| calls().len() == 2).await;
    assert_eq!(calls()[1].gate, "b", "{:?}", calls()[1].t0);
    wait_until(|| pool.in_flight() == 1).await; // b's done, a's first still held
                                                // a worker is free and a's second window is queued: give it time to start, wrongly
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(
        calls().len(),
        2,
        "a's second window started beside its first"
    );
    assert_eq!(pool.in_flight(), 1);
    assert_eq!(pool.pending(), 1);
    fake.release();
    wait_until(|| calls().len() == 3 && pool.in_flight() == 0).await;
    let third = &calls()[2];
    assert_eq!((third.gate.as_str(), third.t0), ("a", 1.0));
    let (abandoned, clean) = pool.shutdown(Duration::from_secs(5)).await;
    assert_eq!((abandoned, clean), (0, true));
}

#[tokio::test]
async fn warm_start_seed_and_panics() {
    let fake = Arc::new(Fake {
        panic_on: Some(1),
        ..Default::default()
    });
    let (app, state) = app_with(config(""), fake.clone());
    for k in 0..4 {
        // each post makes one window due (1 s window, 0.5 s cadence)
        let n = if k == 0 { 100 } else { 50 };
        let start = if k == 0 {
            0.0
        } else {
            1.0 + 0.5 * (k - 1) as f64
        };
        assert_eq!(
            post_json(&app, uniform("g1", start, n)).await.0,
            StatusCode::NO_CONTENT
        );
        wait_until(|| fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0)
            .await;
    }
    let calls = fake.calls.lock().unwrap().clone();
    assert_eq!(calls[0].warm, None);
    assert_eq!(calls[1].warm, Some(vec![0.0]));
    // call 1 panicked: call 2 still warm-starts from the last success
    assert_eq!(calls[2].warm, Some(vec![0.0]));
    assert_eq!(calls[3].warm, Some(vec![2.0]));
    assert_eq!(
        calls[0].seed,
        gatewatch::service::worker::window_seed("g1", 100)
    );
    assert_ne!(calls[0].seed, calls[1].seed);
    assert!(calls.iter().all(|c| c.gate == "g1"));
    assert_eq!(
        metric(
            &state,
            "gatewatch_identification_failures_total{reason=\"panic\"}"
        ),
        1.0
    );
    // still serving
    assert_eq!(
        send(&app, "GET", "/healthz", Body::empty(), None).await.0,
        StatusCode::OK
    );
}

#[tokio::test]
async fn cadence_is_in_sample_time_whatever_the_replay_speed() {
    // the same stream posted in 0.1 s chunks and in 0.05 s chunks, waiting for each job:
    // identical windows and seeds
    async fn windows(chunk: usize) -> Vec<(u64, usize, i64)> {
        let fake = Arc::new(Fake::default());
        let (app, state) = app_with(config(""), fake.clone());
        let mut sent = 0;
        while sent < 400 {
            let (s, _) = post_json(&app, uniform("g1", 50.0 + sent as f64 / 100.0, chunk)).await;
            assert_eq!(s, StatusCode::NO_CONTENT);
            sent += chunk;
            wait_until(|| state.pool().pending() == 0 && state.pool().in_flight() == 0).await;
        }
        let calls = fake.calls.lock().unwrap().clone();
        calls
            .iter()
            .map(|c| (c.seed, c.len, (c.t0 * 1000.0).round() as i64))
            .collect()
    }
    let a = windows(10).await;
    let b = windows(5).await;
    assert_eq!(a.len(), 7, "full at 1 s, then every 0.5 s until 4 s");
    assert_eq!(a, b);
}

/// Gates whose streams start together are identified spread over the cadence: with the
/// shipped `stagger = true` each gate's first window ends its ID's offset after the window is
/// full (below the cadence), the offsets differ, and the cadence after the first window is
/// unchanged; with `stagger = false` every first window ends as soon as it is full.
#[tokio::test]
async fn gates_started_together_are_identified_spread_over_the_cadence() {
    async fn first_windows(stagger: bool) -> (Config, Vec<Call>, Vec<f64>) {
        // 1 s windows every 0.5 s at 100 Hz: the first window is full at sample 100
        let cfg = Config::from_toml(&format!(
            "[server]\nworker_threads = 1\nlisten = \"127.0.0.1:0\"\n\
             [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n\
             max_past_seconds = 0.0\nstagger = {stagger}\n"
        ))
        .unwrap();
        let fake = Arc::new(Fake::default());
        let (app, state) = app_with(cfg.clone(), fake.clone());
        // every gate sends 2 s of samples from the same instant, in one request
        for g in 0..12 {
            let (s, _) = post_json(&app, uniform(&format!("g{g}"), 50.0, 200)).await;
            assert_eq!(s, StatusCode::NO_CONTENT);
            wait_until(|| state.pool().pending() == 0 && state.pool().in_flight() == 0).await;
        }
        let calls = fake.calls.lock().unwrap().clone();
        // what the API shows of each gate's stagger
        let shown = (0..12)
            .map(|g| {
                state
                    .gate_view(&format!("g{g}"))
                    .unwrap()
                    .window
                    .stagger_seconds
            })
            .collect();
        (cfg, calls, shown)
    }
    // the newest due window of each request is the one identified (older ones are replaced)
    let window_end = |c: &Call| ((c.t0 - 50.0) * 100.0).round() as usize + c.len;
    let (cfg, calls, shown) = first_windows(true).await;
    assert_eq!(calls.len(), 12);
    for (g, seconds) in shown.iter().enumerate() {
        let offset = cfg.defaults.stagger_samples(&format!("g{g}"));
        assert_eq!(*seconds, offset as f64 / 100.0, "g{g}");
    }
    let mut offsets = Vec::new();
    for c in &calls {
        let offset = cfg.defaults.stagger_samples(&c.gate);
        assert!(offset < 50, "{}: offset {offset}", c.gate);
        offsets.push(offset);
        // windows due at 100 + offset, then every 50 samples: the last one within 200 samples
        let last = 100 + offset + (200 - 100 - offset) / 50 * 50;
        assert_eq!(window_end(c), last, "{}", c.gate);
    }
    offsets.sort_unstable();
    offsets.dedup();
    assert!(
        offsets.len() >= 8,
        "12 gates share too few offsets: {offsets:?}"
    );
    let (_, plain, shown) = first_windows(false).await;
    assert!(plain.iter().all(|c| window_end(c) == 200), "{plain:?}");
    assert!(shown.iter().all(|s| *s == 0.0), "{shown:?}");
}

#[tokio::test]
async fn a_day_of_samples_keeps_the_reported_times_true() {
    // 2026-11-23 00:00 UTC at 200 Hz for a day; the true time of sample i is T0 + i / 200.
    // Window times derived by adding the period drifted ~82 ms an hour into window_start,
    // window_end and analysed_until.
    const T0: f64 = 1_795_392_000.0;
    const RATE: f64 = 200.0;
    let cfg = Config::from_toml(
        "[server]\nworker_threads = 1\nlisten = \"127.0.0.1:0\"\n\
         [defaults]\nrate_hz = 200.0\nwindow_seconds = 1.0\nidentify_every_seconds = 3600.0\n\
         max_past_seconds = 0.0\nmax_future_seconds = 0.0\n",
    )
    .unwrap();
    // the gate's first window waits its stagger offset (below the 200-sample window here)
    let offset = cfg.defaults.stagger_samples("g1") as u64;
    assert!(offset < 200);
    let fake = Arc::new(Fake::default());
    let (_app, state) = app_with(cfg, fake.clone());
    let day = 86_400 * 200u64;
    let chunk = 900 * 200u64; // a quarter of an hour per request
    let mut i = 0u64;
    while i < day {
        let samples = (i..i + chunk)
            .map(|k| (T0 + k as f64 / RATE, 0.0))
            .collect();
        let batch = Batch {
            gate: "g1".into(),
            samples,
            rate: None,
            values_field: "values".into(),
            lines: None,
            precision: None,
        };
        state.ingest(vec![batch]).unwrap();
        i += chunk;
    }
    // windows end at sample 200 + offset, then every 720 000 samples: the last ends 23 cadences
    // after the first. The fake reports 1.5 Hz, so the identification reads the 40 cycles of
    // `window_cycles` as far as the history holds: six windows, 1 200 samples
    let last = 200 + offset + 23 * 720_000u64 - 1;
    let (start, end) = (T0 + (last - 1_199) as f64 / RATE, T0 + last as f64 / RATE);
    let tolerance = 0.01 / RATE; // a hundredth of a period
    wait_until(|| {
        state
            .gate_view("g1")
            .and_then(|v| v.analysed_until)
            .is_some_and(|t| t > end - 1.0)
    })
    .await;
    let v = state.gate_view("g1").unwrap();
    assert_eq!(v.window.identification_seconds, 6.0);
    // and what it read is on /metrics
    let read = state
        .metrics
        .identification_record_seconds
        .with_label_values(&["g1"]);
    assert_eq!(read.get(), 6.0);
    let id = v.identification.expect("identified");
    for (what, got, want) in [
        ("window_start", id.window_start, start),
        ("window_end", id.window_end, end),
        ("analysed_until", v.analysed_until.unwrap(), end),
    ] {
        assert!(
            (got - want).abs() < tolerance,
            "{what}: {got} instead of {want} ({} s off)",
            got - want
        );
    }
}

/// `forget` drops a gate's pending job and its tracking memory, and the memory of a job of it
/// that was in flight is not kept when that job ends; other gates keep theirs.
#[tokio::test]
async fn a_forgotten_gate_leaves_no_memory_even_with_a_job_in_flight() {
    let (fake, pool, done) = counting_pool(Duration::from_millis(300));
    assert_eq!(pool.submit(small_job("kept", 0)), Submitted::Queued);
    wait_until(|| done.load(Ordering::SeqCst) == 1).await;
    assert_eq!(pool.remembered_gates(), 1);
    // "gone" in flight, and a pending job of it behind "kept"'s
    assert_eq!(pool.submit(small_job("gone", 1)), Submitted::Queued);
    wait_until(|| pool.in_flight() == 1).await;
    assert_eq!(pool.submit(small_job("kept", 2)), Submitted::Queued);
    assert_eq!(pool.submit(small_job("gone", 3)), Submitted::Queued);
    assert_eq!(pool.pending(), 2);
    pool.forget("gone");
    assert_eq!(pool.pending(), 1, "its pending job is dropped");
    wait_until(|| done.load(Ordering::SeqCst) == 3 && pool.in_flight() == 0).await;
    assert_eq!(
        pool.remembered_gates(),
        1,
        "the in-flight job of a forgotten gate leaves no memory"
    );
    let calls = fake.calls.lock().unwrap().clone();
    assert_eq!(
        calls.iter().map(|c| c.gate.as_str()).collect::<Vec<_>>(),
        ["kept", "gone", "kept"]
    );
    // forgetting it again, or a gate never seen, is harmless; a new job of it starts afresh
    pool.forget("gone");
    pool.forget("never");
    assert_eq!(pool.submit(small_job("gone", 4)), Submitted::Queued);
    wait_until(|| done.load(Ordering::SeqCst) == 4).await;
    assert_eq!(fake.calls.lock().unwrap().last().unwrap().warm, None);
    assert_eq!(pool.remembered_gates(), 2);
    pool.shutdown(Duration::from_secs(5)).await;
}

/// A fake whose `remember` panics: outside the job's `catch_unwind`, so the worker thread dies,
/// as a bug there would kill it in production.
struct DiesAfterTheFirstWindow(Fake);

impl gatewatch::service::worker::WindowAnalyzer for DiesAfterTheFirstWindow {
    fn analyze(
        &self,
        gate: &str,
        input: gatewatch::analysis::WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<gatewatch::analysis::WindowAnalysis, gatewatch::analysis::AnalysisError> {
        self.0.analyze(gate, input, warm, seed)
    }

    fn remember(
        &self,
        _: &str,
        _: Option<&gatewatch::analysis::Previous>,
        _: &gatewatch::analysis::WindowAnalysis,
        _: f64,
        _: f64,
    ) -> gatewatch::analysis::Previous {
        panic!("scripted bug outside the job's catch_unwind");
    }
}

/// A worker thread that died is counted out, and `/healthz` (liveness) answers 503 naming it:
/// nothing restarts the thread, so only a restart of the daemon brings identification back.
/// `/readyz` says why too.
#[tokio::test]
async fn a_dead_worker_thread_fails_liveness_naming_it() {
    let (app, state) = gatewatch::service::server::build_app(
        config(""),
        Arc::new(DiesAfterTheFirstWindow(Fake::default())),
    )
    .unwrap();
    let (s, body, _) = send(&app, "GET", "/healthz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK, "{body}");
    assert_eq!(
        post_json(&app, uniform("g1", 0.0, 100)).await.0,
        StatusCode::NO_CONTENT
    );
    wait_until(|| state.pool().running_workers() == 0).await;
    let (s, body, _) = send(&app, "GET", "/healthz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE);
    let text = body.as_str().unwrap_or_default().to_string();
    assert!(
        text.contains("0 of 1 identification worker threads running"),
        "{body}"
    );
    let (s, body, _) = send(&app, "GET", "/readyz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE);
    assert!(
        body.as_str()
            .is_some_and(|t| t.contains("0 of 1 identification worker threads running")),
        "{body}"
    );
}

/// A fake whose first window blocks until `release` is set: a worker stuck in a computation
/// that does not return (as nalgebra's uncapped Schur iteration once did, session 53).
#[derive(Default)]
struct StuckOnce {
    inner: Fake,
    release: std::sync::atomic::AtomicBool,
    entered: std::sync::atomic::AtomicBool,
}

impl gatewatch::service::worker::WindowAnalyzer for StuckOnce {
    fn analyze(
        &self,
        gate: &str,
        input: gatewatch::analysis::WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<gatewatch::analysis::WindowAnalysis, gatewatch::analysis::AnalysisError> {
        if !self.entered.swap(true, Ordering::SeqCst) {
            while !self.release.load(Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        self.inner.analyze(gate, input, warm, seed)
    }
}

/// `gatewatch_identification_longest_running_seconds` as rendered at a scrape.
fn longest_running(state: &gatewatch::service::state::AppState) -> f64 {
    let text = state.render_metrics();
    let line = text
        .lines()
        .find(|l| l.starts_with("gatewatch_identification_longest_running_seconds "))
        .unwrap_or_else(|| panic!("no longest-running gauge in\n{text}"));
    line.rsplit(' ').next().unwrap().parse().unwrap()
}

/// An identification that runs past `server.identification_timeout_seconds` fails liveness
/// and readiness naming its gate while it runs, shows in the longest-running gauge, is
/// reported once (the tick logs it), and the daemon is healthy again once the job returns.
#[tokio::test]
async fn a_stuck_identification_fails_liveness_until_it_returns() {
    let stuck = Arc::new(StuckOnce::default());
    let (app, state) = gatewatch::service::server::build_app(
        config("identification_timeout_seconds = 0.5"),
        stuck.clone(),
    )
    .unwrap();
    assert_eq!(longest_running(&state), 0.0);
    assert_eq!(
        post_json(&app, uniform("g1", 0.0, 100)).await.0,
        StatusCode::NO_CONTENT
    );
    wait_until(|| stuck.entered.load(Ordering::SeqCst)).await;
    assert_eq!(state.pool().in_flight(), 1);
    // the worker is stuck: after the timeout both probes fail, naming the gate and the key
    let mut body = String::new();
    wait_until(|| {
        let why = state.unrecoverable();
        body = why.join("; ");
        !why.is_empty()
    })
    .await;
    assert!(
        body.contains("gate `g1`")
            && body.contains("past server.identification_timeout_seconds = 0.5")
            && body.contains("its worker is stuck"),
        "{body}"
    );
    let (s, text, _) = send(&app, "GET", "/healthz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE, "{text}");
    assert!(
        text.as_str().unwrap_or_default().contains("gate `g1`"),
        "{text}"
    );
    let (s, text, _) = send(&app, "GET", "/readyz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE, "{text}");
    assert!(longest_running(&state) > 0.5);
    // the tick reports (logs) the stuck job once: nothing is new afterwards
    state.tick(std::time::SystemTime::now());
    assert!(state
        .pool()
        .newly_overdue(Duration::from_secs_f64(0.5))
        .is_empty());
    assert_eq!(state.pool().overdue(Duration::from_secs_f64(0.5)).len(), 1);
    // the job returns: healthy again, nothing in flight
    stuck.release.store(true, Ordering::SeqCst);
    wait_until(|| state.pool().in_flight() == 0).await;
    let (s, text, _) = send(&app, "GET", "/healthz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK, "{text}");
    assert_eq!(longest_running(&state), 0.0);
    assert_eq!(stuck.inner.n.load(Ordering::SeqCst), 1);
}

/// A job that ran past the limit is returned once by `newly_overdue` and on every call by
/// `overdue`; a job within the limit by neither.
#[tokio::test]
async fn an_overdue_job_is_new_once() {
    let stuck = Arc::new(StuckOnce::default());
    let pool = WorkerPool::start(1, 4, stuck.clone(), Arc::new(|_: &Job, _, _| {})).unwrap();
    let job = Job {
        gate: "g1".into(),
        t0: 0.0,
        rate_hz: 100.0,
        values: vec![0.0; 100],
        history: Vec::new(),
        end_index: 100,
        generation: 0,
        ambient_level: None,
    };
    assert_eq!(pool.submit(job), Submitted::Queued);
    wait_until(|| stuck.entered.load(Ordering::SeqCst)).await;
    assert!(pool.overdue(Duration::from_secs(3600)).is_empty());
    assert!(pool.newly_overdue(Duration::from_secs(3600)).is_empty());
    tokio::time::sleep(Duration::from_millis(30)).await;
    let limit = Duration::from_millis(20);
    let first = pool.newly_overdue(limit);
    assert_eq!(first.len(), 1);
    assert_eq!((first[0].gate.as_str(), first[0].end_index), ("g1", 100));
    assert!(first[0].running > limit);
    assert!(pool.newly_overdue(limit).is_empty());
    assert_eq!(pool.overdue(limit).len(), 1);
    let (gate, running) = pool.longest_running().unwrap();
    assert_eq!(gate, "g1");
    assert!(running >= first[0].running);
    stuck.release.store(true, Ordering::SeqCst);
    wait_until(|| pool.in_flight() == 0).await;
    assert!(pool.overdue(Duration::ZERO).is_empty());
    assert_eq!(pool.longest_running(), None);
    pool.shutdown(Duration::from_secs(5)).await;
}
