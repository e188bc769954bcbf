//! Wall-clock time as Unix seconds: the one conversion the daemon and its client use.

use std::time::{SystemTime, UNIX_EPOCH};

/// `t` as Unix seconds; a clock before 1970 reads 0 (a broken clock must not stop ingestion).
pub fn unix_seconds(t: SystemTime) -> f64 {
    t.duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// Now as Unix seconds.
pub fn now_unix() -> f64 {
    unix_seconds(SystemTime::now())
}
