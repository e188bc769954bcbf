//! The order of the daemon's store writes is the order of its state changes.
//!
//! A window's result and a forget of its gate (`DELETE`, or the gate's expiry) meet on the
//! state's lock. Before stop 60, the result released the lock before it queued its store write,
//! so a forget could queue its own write in between: the late window write restored the
//! forgotten gate's alert state at the next start. This test stops the worker at that point and
//! forgets the gate there. The stop is a tracing layer that holds the worker in the log line of
//! the alert the window fires, which the daemon writes just before it queues the window's write.
//! That is why this test has a binary of its own: its subscriber is global, and the worker
//! threads log through it.

mod service_common;

use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use gatewatch::service::state::AppState;
use gatewatch::service::storage::Persistence;
use service_common::*;
use tracing::field::{Field, Visit};
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::Layer;

const GATE: &str = "race";

/// Holds the thread that logs the first `GateNegativeDamping` firing of [`GATE`] until the test
/// releases it.
struct HoldAtFiring {
    entered: Mutex<Option<mpsc::Sender<()>>>,
    release: Mutex<mpsc::Receiver<()>>,
}

#[derive(Default)]
struct Fields {
    message: String,
    gate: String,
    alert: String,
    status: String,
}

impl Visit for Fields {
    fn record_str(&mut self, field: &Field, value: &str) {
        self.set(field, value.to_string());
    }
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        self.set(field, format!("{value:?}"));
    }
}

impl Fields {
    fn set(&mut self, field: &Field, value: String) {
        match field.name() {
            "message" => self.message = value,
            "gate" => self.gate = value,
            "alert" => self.alert = value,
            "status" => self.status = value,
            _ => {}
        }
    }
}

impl<S: tracing::Subscriber> Layer<S> for HoldAtFiring {
    fn on_event(&self, event: &tracing::Event<'_>, _: Context<'_, S>) {
        let mut f = Fields::default();
        event.record(&mut f);
        if f.message != "alert"
            || f.gate != GATE
            || f.alert != "GateNegativeDamping"
            || f.status != "firing"
        {
            return;
        }
        // once: the first firing only
        let Some(entered) = self.entered.lock().unwrap().take() else {
            return;
        };
        entered.send(()).unwrap();
        let _ = self
            .release
            .lock()
            .unwrap()
            .recv_timeout(Duration::from_secs(30));
    }
}

fn open(db: &std::path::Path, fake: Arc<Fake>) -> Arc<AppState> {
    let c = config("unknown_gate_expiry_seconds = 600\n");
    let p = Persistence::open(db, &c.storage, c.sample_lead_bound()).expect("store");
    AppState::with_persistence(c, fake, Some(p)).expect("state")
}

#[tokio::test]
async fn a_gate_forgotten_while_its_window_is_reported_stays_forgotten_after_a_restart() {
    let (entered_tx, entered) = mpsc::channel();
    let (release, release_rx) = mpsc::channel::<()>();
    tracing::subscriber::set_global_default(tracing_subscriber::registry().with(HoldAtFiring {
        entered: Mutex::new(Some(entered_tx)),
        release: Mutex::new(release_rx),
    }))
    .expect("the only subscriber of this binary");

    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    let fake = Arc::new(Fake {
        zeta: vec![-0.03],
        ..Default::default()
    });
    let state = open(&db, fake.clone());
    let app = gatewatch::service::api::router(state.clone());

    // windows of a self-excited gate until its GateNegativeDamping fires: the worker reporting
    // that window is then held in the alert's log line
    let mut sent = 0usize;
    let mut held = false;
    for k in 0..20 {
        let n = if k == 0 { 100 } else { 50 };
        let (s, _) = post_json(&app, uniform(GATE, sent as f64 / 100.0, n)).await;
        assert!(s.is_success(), "{s}");
        sent += n;
        let waited = SystemTime::now();
        loop {
            if entered.try_recv().is_ok() {
                held = true;
                break;
            }
            if fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0 {
                break;
            }
            assert!(
                waited.elapsed().unwrap() < Duration::from_secs(10),
                "window {k} not reported"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        if held {
            break;
        }
    }
    assert!(held, "GateNegativeDamping never fired");

    // the operator deletes the gate while the worker is held
    let forgetting = {
        let state = state.clone();
        std::thread::spawn(move || state.forget_gate(GATE).map(|f| f.gate))
    };
    std::thread::sleep(Duration::from_millis(300));
    // the old code: the forget has run by now (the lock was free), and its write is queued
    // before the window's
    release.send(()).unwrap();
    let forgotten = forgetting.join().expect("forget thread");
    assert_eq!(forgotten.as_deref(), Ok(GATE));
    assert_eq!(state.alert_state(GATE), None, "forgotten in memory");
    // the held window's report ends (and queues its write) before the store closes
    wait_until(|| state.pool().in_flight() == 0).await;

    let p = state.persistence.clone().expect("a store");
    assert!(p.writer.close(Duration::from_secs(10)), "writes flushed");
    drop((p, app, state)); // the store's lock file goes with its last holder

    let state = open(&db, Arc::new(Fake::default()));
    assert_eq!(
        state.alert_state(GATE),
        None,
        "the forgotten gate's alert state came back from the store"
    );
    assert!(!state.gate_ids().contains(&GATE.to_string()));
}
