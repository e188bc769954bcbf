//! The rows the store tests write: shared by `tests/store_conformance` and the SQLite store's
//! own tests (`src/store/tests.rs`, which include this file), each importing the store's types.

use super::{IdentificationRecord, NewOutboxRow};

/// A trusted identification of `gate` for the window ending at `end`, with damping `zeta`.
pub fn record(gate: &str, end: f64, zeta: f64) -> IdentificationRecord {
    IdentificationRecord {
        gate: gate.into(),
        time: end + 0.5,
        window_start: end - 10.0,
        window_end: end,
        equation: format!("ydd + {zeta}*yd + y = 0"),
        coefficients: vec![("c1".into(), zeta), ("k".into(), 1.0)],
        damping: serde_json::json!({"zeta0": zeta, "zeta0_interval": [zeta - 0.01, zeta + 0.01],
            "trusted": true, "frequency_hz": 1.5}),
        verdict: "damped".into(),
        fit_nmae: 0.02,
        path: "full".into(),
    }
}

/// An outbox row for `target` of alert `fp` (created at 100 s, batch 1, an empty payload).
pub fn outbox_row(target: &str, fp: &str, status: &str, supersedes: bool) -> NewOutboxRow {
    NewOutboxRow {
        target: target.into(),
        fingerprint: fp.into(),
        status: status.into(),
        created: 100.0,
        batch: 1,
        payload: "{}".into(),
        supersedes,
    }
}
