//! Log lines that would come at other people's pace, bounded.
//!
//! [`LogLimiter`]: a warning repeated at a client's pace, logged at most once per interval.
//! Each connection refused at `max_http_connections`, `max_tcp_connections` or outside
//! `tcp_allowed_networks` logged its own warning, so a connection flood became a log flood (91
//! lines for 91 refusals), while the metrics already count every one. The TCP bad-line warning
//! had its own per-connection limit; these are per listener.
//!
//! [`BatchLog`]: the lines of one batch of per-gate events, at most [`GATE_LINES_PER_BATCH`]
//! one by one, the rest in one summary line with their count by kind. When a network or a
//! collector fails, every gate goes silent at once: the once-a-second tick raised
//! `GateDataStale` for each in the same sweep and logged one line per gate, then one more per
//! gate when the unknown ones expired and one more for each resolved alert (6 011 lines for
//! 2 000 gates; 30 000 at `max_gates = 10000`), burying the one line that says what happened.
//! Every event is still notified, stored and in the metrics (`gatewatch_alert_firing`,
//! `gatewatch_gates_expired_total`); only the log is summarised.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Most per-gate lines one batch of events logs one by one (a tick's stale, resolved or
/// expired gates; an ingestion's alerts); the rest go into one summary line.
pub const GATE_LINES_PER_BATCH: usize = 10;

/// The per-gate lines of one batch: the first [`GATE_LINES_PER_BATCH`] are logged, the others
/// counted by kind (at most a few kinds: alert name and status, or "expired").
#[derive(Debug, Default)]
pub struct BatchLog {
    logged: usize,
    held: BTreeMap<String, u64>,
}

impl BatchLog {
    /// A batch with nothing logged yet.
    pub fn new() -> Self {
        BatchLog::default()
    }

    /// Whether this line is to be logged; if not, it is counted under `kind`.
    pub fn allow(&mut self, kind: impl FnOnce() -> String) -> bool {
        if self.logged < GATE_LINES_PER_BATCH {
            self.logged += 1;
            true
        } else {
            *self.held.entry(kind()).or_default() += 1;
            false
        }
    }

    /// The lines held back, and their count by kind (`GateDataStale firing: 1990`), when any.
    pub fn held_back(&self) -> Option<(u64, String)> {
        if self.held.is_empty() {
            return None;
        }
        let by_kind: Vec<String> = self.held.iter().map(|(k, n)| format!("{k}: {n}")).collect();
        Some((self.held.values().sum(), by_kind.join(", ")))
    }
}

/// The interval of the accept loops' warnings.
pub const ACCEPT_WARNING_INTERVAL: Duration = Duration::from_secs(10);

/// Lets a repeated event's log line through at most once per `every`.
#[derive(Debug)]
pub struct LogLimiter {
    every: Duration,
    last: Option<Instant>,
    held: u64,
}

impl LogLimiter {
    /// A limiter that lets the first event through.
    pub const fn new(every: Duration) -> Self {
        LogLimiter {
            every,
            last: None,
            held: 0,
        }
    }

    /// `Some(n)` when the event at `now` is to be logged, `n` the events held back since the
    /// last one logged (the line says so); `None` when it is held back.
    pub fn allow(&mut self, now: Instant) -> Option<u64> {
        match self.last {
            Some(t) if now.saturating_duration_since(t) < self.every => {
                self.held += 1;
                None
            }
            _ => {
                self.last = Some(now);
                Some(std::mem::take(&mut self.held))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_line_per_interval_with_the_count_held_back() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut l = LogLimiter::new(Duration::from_secs(10));
        assert_eq!(l.allow(at(0)), Some(0));
        assert_eq!(l.allow(at(1)), None);
        assert_eq!(l.allow(at(9_999)), None);
        assert_eq!(l.allow(at(10_000)), Some(2));
        assert_eq!(l.allow(at(10_001)), None);
        assert_eq!(l.allow(at(30_000)), Some(1));
        assert_eq!(l.allow(at(40_000)), Some(0));
        // a clock that goes back (it cannot with Instant, but the arithmetic saturates)
        assert_eq!(l.allow(at(5_000)), None);
    }

    #[test]
    fn a_batch_logs_its_first_lines_and_counts_the_rest_by_kind() {
        let mut b = BatchLog::new();
        let mut logged = 0;
        for i in 0..25 {
            let kind = if i % 2 == 0 { "a firing" } else { "b resolved" };
            if b.allow(|| kind.to_string()) {
                logged += 1;
            }
        }
        assert_eq!(logged, GATE_LINES_PER_BATCH);
        assert_eq!(
            b.held_back(),
            Some((15, "a firing: 8, b resolved: 7".to_string()))
        );
        assert_eq!(BatchLog::new().held_back(), None);
    }
}
