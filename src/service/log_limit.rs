//! A warning repeated at a client's pace, logged at most once per interval.
//!
//! Why: each connection refused at `max_http_connections`, `max_tcp_connections` or outside
//! `tcp_allowed_networks` logged its own warning, so a connection flood became a log flood (91
//! lines for 91 refusals), while the metrics already count every one. The TCP bad-line warning
//! had its own per-connection limit; these are per listener.

use std::time::{Duration, Instant};

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
}
