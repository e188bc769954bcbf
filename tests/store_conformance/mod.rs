//! What every [`Store`] must do, written once and run against each implementation (the SQLite
//! file and a real NATS server, `tests/store_nats.rs`), so the two cannot drift apart. The
//! expectations are the SQLite store's (`src/store/tests.rs`). Each check takes an empty store.

use gatewatch::store::{
    HistoryQuery, HistoryRow, IdentificationRecord, NewOutboxRow, Store, WriteBatch,
};

mod fixtures;
pub use fixtures::outbox_row;
pub use fixtures::record;

/// The gate name no subject or key could hold as it is.
pub const AWKWARD_GATE: &str = "a.b c*>/é";

fn query(gate: &str, from: Option<f64>, to: Option<f64>, limit: usize) -> HistoryQuery {
    HistoryQuery {
        gate: gate.into(),
        from,
        to,
        limit,
    }
}

fn ends(rows: &[HistoryRow]) -> Vec<f64> {
    rows.iter().map(|r| r.window_end).collect()
}

/// The newest rows of a gate come oldest first, capped at `n`; the gates with history come
/// by name, capped at `limit`.
pub fn latest_rows_and_gates(s: &dyn Store) {
    let batch = WriteBatch {
        identifications: (0..10)
            .map(|i| record("g1", 1000.0 + 5.0 * f64::from(i), 0.01))
            .chain([record("g0", 990.0, -0.02), record("g2", 2000.0, 0.03)])
            .collect(),
        ..Default::default()
    };
    s.write(&batch).expect("write");
    assert_eq!(
        ends(&s.latest_history_rows("g1", 3).expect("latest")),
        [1035.0, 1040.0, 1045.0]
    );
    assert_eq!(s.latest_history_rows("g1", 100).expect("all").len(), 10);
    assert!(s.latest_history_rows("nobody", 3).expect("none").is_empty());
    let g0 = s.latest_history_rows("g0", 1).expect("g0");
    assert_eq!(g0[0].zeta0, Some(-0.02));
    assert_eq!(g0[0].zeta0_interval, Some((-0.03, -0.01)));
    assert_eq!(s.history_gates(10).expect("gates"), ["g0", "g1", "g2"]);
    assert_eq!(s.history_gates(2).expect("gates"), ["g0", "g1"]);
}

/// Written rows come back as written, filtered by gate, inclusive bounds on the window end and
/// the limit, oldest first (also when written out of order).
pub fn history_round_trip_with_bounds_and_limit(s: &dyn Store) {
    let batch = WriteBatch {
        identifications: (0..10)
            .rev()
            .map(|i| record("g1", 1000.0 + 5.0 * f64::from(i), 0.01))
            .chain([record("g2", 1010.0, -0.02)])
            .collect(),
        ..Default::default()
    };
    s.write(&batch).expect("write");
    let all = s.history(&query("g1", None, None, 100)).expect("history");
    assert_eq!(all.len(), 10);
    assert_eq!(all[0], record("g1", 1000.0, 0.01), "round trip");
    assert!(all.windows(2).all(|w| w[0].window_end < w[1].window_end));
    let some = s
        .history_rows(&query("g1", Some(1010.0), Some(1020.0), 100))
        .expect("history");
    assert_eq!(ends(&some), [1010.0, 1015.0, 1020.0]);
    let from = s
        .history_rows(&query("g1", Some(1030.0), None, 2))
        .expect("history");
    assert_eq!(ends(&from), [1030.0, 1035.0], "from, then the limit");
    assert_eq!(
        s.history(&query("g1", None, None, 3))
            .expect("history")
            .len(),
        3
    );
    let g2 = s.history(&query("g2", None, None, 10)).expect("history");
    assert_eq!(g2.len(), 1);
    assert_eq!(g2[0].zeta0(), Some(-0.02));
    assert_eq!(g2[0].zeta0_interval(), Some((-0.03, -0.01)));
    assert!(s
        .history(&query("nobody", None, None, 10))
        .expect("history")
        .is_empty());
}

/// A gate's alert state is replaced by the next one and deleted when the gate is forgotten.
pub fn alert_states_are_replaced_and_forgotten(s: &dyn Store) {
    let put = |gate: &str, state: &str| WriteBatch {
        alert_states: vec![(gate.into(), state.into())],
        ..Default::default()
    };
    s.write(&put("g1", "a")).expect("write");
    s.write(&put("g2", "b")).expect("write");
    s.write(&put("g1", "c")).expect("write");
    assert_eq!(
        s.alert_states().expect("read"),
        [("g1".into(), "c".into()), ("g2".into(), "b".into())]
    );
    s.write(&WriteBatch {
        forget_gates: vec!["g1".into(), "never stored".into()],
        ..Default::default()
    })
    .expect("write");
    assert_eq!(s.alert_states().expect("read"), [("g2".into(), "b".into())]);
}

/// Outbox ids grow in the order written; a superseding row removes the older rows of its
/// target and fingerprint; delivered ids are deleted (an unknown one is no error).
pub fn outbox_ids_supersede_and_delivery(s: &dyn Store) {
    let ids = s
        .write(&WriteBatch {
            outbox: vec![
                outbox_row("webhook a", "f1", "firing", true),
                outbox_row("webhook b", "f1", "firing", true),
                outbox_row("webhook a", "f1", "resolved", false),
                outbox_row("webhook a", "f2", "firing", true),
            ],
            ..Default::default()
        })
        .expect("write");
    assert_eq!(ids.len(), 4);
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids in order: {ids:?}");
    let all = s.outbox().expect("read");
    assert_eq!(all.iter().map(|r| r.id).collect::<Vec<_>>(), ids);
    assert_eq!(all[2].row, outbox_row("webhook a", "f1", "resolved", false));
    let newer = s
        .write(&WriteBatch {
            outbox: vec![outbox_row("webhook a", "f1", "firing", true)],
            delivered: vec![ids[3], 987_654],
            ..Default::default()
        })
        .expect("write");
    let left: Vec<(i64, String, String)> = s
        .outbox()
        .expect("read")
        .into_iter()
        .map(|r| (r.id, r.row.target, r.row.fingerprint))
        .collect();
    assert_eq!(
        left,
        [
            (ids[1], "webhook b".into(), "f1".into()),
            (newer[0], "webhook a".into(), "f1".into())
        ]
    );
}

/// Pruning deletes the rows whose window ended before the cutoff, then the oldest beyond the
/// row bound.
pub fn prune_applies_retention_then_the_row_bound(s: &dyn Store) {
    s.write(&WriteBatch {
        identifications: (0..20).map(|i| record("g", f64::from(i), 0.0)).collect(),
        ..Default::default()
    })
    .expect("write");
    let p = s.prune(5.0, 10).expect("prune");
    assert_eq!((p.expired, p.over_size), (5, 5));
    let left = s.history(&query("g", None, None, 100)).expect("history");
    assert_eq!(left.first().map(|r| r.window_end), Some(10.0));
    assert_eq!(left.len(), 10);
    let p = s.prune(5.0, 10).expect("prune again");
    assert_eq!((p.expired, p.over_size), (0, 0), "nothing left to prune");
}

/// A gate name with dots, spaces, wildcards, a slash and non-ASCII is stored and found as it is.
pub fn awkward_gate_names(s: &dyn Store) {
    s.write(&WriteBatch {
        identifications: vec![record(AWKWARD_GATE, 10.0, 0.01), record("a", 11.0, 0.01)],
        alert_states: vec![(AWKWARD_GATE.into(), "{\"x\":1}".into())],
        ..Default::default()
    })
    .expect("write");
    assert_eq!(s.history_gates(10).expect("gates"), ["a", AWKWARD_GATE]);
    let rows = s
        .history(&query(AWKWARD_GATE, None, None, 10))
        .expect("history");
    assert_eq!(rows, [record(AWKWARD_GATE, 10.0, 0.01)]);
    assert_eq!(
        s.alert_states().expect("states"),
        [(AWKWARD_GATE.to_string(), "{\"x\":1}".to_string())]
    );
}

/// Numbers come back bit for bit, also those whose shortest decimal form is long
/// (`0.03 + 2e-4` is 0.030199999999999998, not 0.0302): the NATS store keeps a row as JSON
/// and the SQLite store the damping report, and serde_json's default float parser is off by
/// one unit in the last place for some of them (the crate enables `float_roundtrip`).
pub fn numbers_come_back_bit_for_bit(s: &dyn Store) {
    let awkward = [
        0.03 + 2e-4,
        0.1 + 0.2,
        1.0 / 3.0,
        0.03 + 16e-4 - 1e-17,
        -0.005_651_371_999_999_965,
        1e-300,
        123_456.789_012_345_67,
        f64::MIN_POSITIVE,
    ];
    let records: Vec<IdentificationRecord> = awkward
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            let mut r = record("bits", 100.0 + i as f64 + x.abs().min(0.5), x);
            r.time = 1_714_564_800.0 + x;
            r.fit_nmae = x;
            r
        })
        .collect();
    s.write(&WriteBatch {
        identifications: records.clone(),
        ..Default::default()
    })
    .expect("write");
    let back = s.history(&query("bits", None, None, 100)).expect("history");
    assert_eq!(back.len(), records.len());
    for (b, r) in back.iter().zip(&records) {
        let bits = |r: &IdentificationRecord| {
            let mut v = vec![r.time, r.window_start, r.window_end, r.fit_nmae];
            v.extend(r.coefficients.iter().map(|(_, c)| *c));
            v.push(r.zeta0().unwrap_or(f64::NAN));
            let (lo, hi) = r.zeta0_interval().unwrap_or((f64::NAN, f64::NAN));
            v.extend([lo, hi]);
            v.into_iter().map(f64::to_bits).collect::<Vec<u64>>()
        };
        assert_eq!(bits(b), bits(r), "{b:?} is not {r:?}");
    }
}

/// One check of an empty store.
pub type Check = fn(&dyn Store);

/// Every check, by name.
/// Five gates written interleaved, as the daemon writes them, 2 600 windows each (more than
/// one fetch of the NATS reader, and a gate's rows far apart in the stream): the newest rows
/// of a gate and a bounded range of its history come right, whatever the history's length.
/// (The NATS store reads the newest rows from the stream's end and keeps only the requested
/// rows of a range while the subject streams by: `src/store/nats/read.rs`.)
pub fn many_gates_interleaved(s: &dyn Store) {
    const GATES: usize = 5;
    const PER_GATE: usize = 2600;
    let gate = |g: usize| format!("m{g}");
    let end = |i: usize| 5000.0 + 5.0 * i as f64;
    for chunk in (0..PER_GATE).collect::<Vec<_>>().chunks(500) {
        let identifications = chunk
            .iter()
            .flat_map(|&i| (0..GATES).map(move |g| (g, i)))
            .map(|(g, i)| record(&gate(g), end(i), 0.001 * g as f64))
            .collect();
        s.write(&WriteBatch {
            identifications,
            ..Default::default()
        })
        .expect("write");
    }
    let all: Vec<f64> = (0..PER_GATE).map(end).collect();
    let latest = |g: usize, n: usize| ends(&s.latest_history_rows(&gate(g), n).expect("latest"));
    assert_eq!(latest(3, 7), all[PER_GATE - 7..], "the newest 7 of m3");
    assert_eq!(latest(0, 1), [end(PER_GATE - 1)], "the newest of m0");
    assert_eq!(latest(4, 1999), all[PER_GATE - 1999..]);
    assert_eq!(latest(2, PER_GATE), all, "exactly all");
    assert_eq!(latest(1, 10 * PER_GATE), all, "more than there are");
    assert!(latest(1, 0).is_empty());
    let rows = s.latest_history_rows(&gate(3), 2).expect("latest");
    assert!(rows
        .iter()
        .all(|r| r.gate == "m3" && r.zeta0 == Some(0.003)));
    let range = s
        .history_rows(&query(&gate(1), Some(all[100]), Some(all[2500]), 1500))
        .expect("range");
    assert_eq!(ends(&range), all[100..1600], "from, to, then the limit");
    let whole = s
        .history_rows(&query(&gate(4), None, None, 100_000))
        .expect("whole");
    assert_eq!(ends(&whole), all);
    assert!(s
        .history_rows(&query(&gate(2), Some(1e9), None, 10))
        .expect("past the end")
        .is_empty());
}

pub const CHECKS: &[(&str, Check)] = &[
    ("latest rows and gates", latest_rows_and_gates),
    (
        "history round trip",
        history_round_trip_with_bounds_and_limit,
    ),
    ("alert states", alert_states_are_replaced_and_forgotten),
    ("outbox", outbox_ids_supersede_and_delivery),
    ("prune", prune_applies_retention_then_the_row_bound),
    ("awkward gate names", awkward_gate_names),
    ("numbers bit for bit", numbers_come_back_bit_for_bit),
    ("many gates interleaved", many_gates_interleaved),
];
