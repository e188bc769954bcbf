//! Filling a SQLite store to its size bound: shared by `tests/store_common` and the SQLite
//! store's own tests (`src/store/tests.rs`, which include this file), each importing the store's
//! types.

use super::{SqliteStore, Store, WriteBatch};

/// Writes alert states named `{prefix}{n}` (large, then smaller ones into what is left) until
/// the store says it is full. Alert states are what the size bound never prunes (it prunes the
/// oldest history), so the store stays full.
pub fn fill_to_the_brim(store: &SqliteStore, prefix: &str) {
    let mut n = 0;
    for size in [100_000, 10_000, 1000, 100] {
        loop {
            n += 1;
            let batch = WriteBatch {
                alert_states: vec![(format!("{prefix}{n}"), "x".repeat(size))],
                ..Default::default()
            };
            if let Err(e) = store.write(&batch) {
                assert!(e.is_full() && e.to_string().contains("full"), "{e}");
                break;
            }
            assert!(n < 100_000, "never full");
        }
    }
}
