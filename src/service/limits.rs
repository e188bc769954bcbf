//! What a client can make the daemon hold, and how it is refused before it is held.
//!
//! - [`BodyBudget`]: the request-body bytes of ingestion requests in flight, reserved BEFORE the
//!   body is read. The per-request peak is a multiple of the body (docs/design.md, bounds), so
//!   bounding the sum of bodies bounds the ingestion memory; `max_concurrent_ingest` alone did
//!   not (16 x 4 MiB bodies took 1.8 GB).
//! - `api::admit_ingest` (the middleware, next to the error type it answers with) refuses early: a `Content-Length` over the body limit
//!   gets 413 before a byte of the body is read (hyper sends `100 Continue` only when the body is
//!   first polled, so an `Expect: 100-continue` client is told at once and sends nothing), and a
//!   reservation that does not fit gets 503 + Retry-After.
//! - [`BodyMeter`]: a gzip or chunked body's size is known only once read, so its bytes are
//!   reserved as they arrive, after decompression: the budget counts what is held, and a small
//!   gzip body costs its size, not the whole body limit (which let five Telegraf agents
//!   flushing at once fill a 16 MiB budget with 4 MiB reservations).
//! - [`close_connection`]: every refusal made before the body is read says `Connection: close`:
//!   the unread body makes the connection unusable, and a keep-alive client that is not told
//!   sees a broken pipe instead of the answer and its Retry-After.
//! - [`for_log`]: client input as it may appear in a log line (escaped, truncated).
//!
//! This module imports nothing of the service (`api` and `tcp` import it).

use std::sync::{Arc, Mutex};

use axum::http::{header, HeaderValue};
use axum::response::Response;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Most characters of client input written into one log field; the rest is cut (`...`).
pub const LOG_INPUT_MAX_CHARS: usize = 200;

/// The budget is counted in units of this many bytes, so that a 4 GiB budget fits the
/// semaphore's `u32` permits of one reservation.
const BUDGET_UNIT: usize = 1024;

/// Client input made safe for a log line: control characters (CR, LF, ESC, ...), quotes and
/// backslashes escaped as Rust's `{:?}` does, and at most [`LOG_INPUT_MAX_CHARS`] characters.
/// A raw CR or ANSI escape in a text log lets a client forge or hide log lines.
pub fn for_log(s: &str) -> String {
    let mut out = String::with_capacity(s.len().min(LOG_INPUT_MAX_CHARS) + 3);
    for (i, c) in s.chars().enumerate() {
        if i == LOG_INPUT_MAX_CHARS {
            out.push_str("...");
            break;
        }
        out.extend(c.escape_debug());
    }
    out
}

/// Request-body bytes in flight, bounded by `server.max_body_bytes_in_flight`. Cheap to clone.
#[derive(Debug, Clone)]
pub struct BodyBudget {
    units: Arc<Semaphore>,
}

impl BodyBudget {
    /// A budget of `bytes` (rounded up to whole KiB).
    pub fn new(bytes: usize) -> BodyBudget {
        BodyBudget {
            units: Arc::new(Semaphore::new(
                bytes.div_ceil(BUDGET_UNIT).min(Semaphore::MAX_PERMITS),
            )),
        }
    }

    /// Reserves `bytes` until the returned permit is dropped; `None` when they do not fit now.
    pub fn try_reserve(&self, bytes: usize) -> Option<OwnedSemaphorePermit> {
        let units = u32::try_from(bytes.div_ceil(BUDGET_UNIT).max(1)).ok()?;
        self.units.clone().try_acquire_many_owned(units).ok()
    }

    /// Bytes free now (whole KiB).
    pub fn available_bytes(&self) -> usize {
        self.units.available_permits() * BUDGET_UNIT
    }
}

/// A streamed body's reservation, grown as its bytes arrive ([`BodyMeter::charge`]) and given
/// back when the last clone is dropped (the request's middleware keeps one until the answer).
#[derive(Debug, Clone)]
pub struct BodyMeter {
    budget: BodyBudget,
    held: Arc<Mutex<Metered>>,
}

/// What a [`BodyMeter`] holds: the bytes counted and their permits.
#[derive(Debug)]
struct Metered {
    bytes: usize,
    permit: OwnedSemaphorePermit,
}

/// The body budget ran out while a streamed body was read: answered 503 + Retry-After.
#[derive(Debug)]
pub struct BudgetExceeded {
    /// Bytes of the body read so far, the chunk that did not fit included.
    pub bytes: usize,
}

impl std::fmt::Display for BudgetExceeded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the request-body budget (server.max_body_bytes_in_flight) is used up \
             after {} bytes of this body",
            self.bytes
        )
    }
}

impl std::error::Error for BudgetExceeded {}

impl BodyMeter {
    /// A meter that starts with one unit of `budget` (1 KiB); `None` when not even that is free.
    pub fn start(budget: &BodyBudget) -> Option<BodyMeter> {
        let permit = budget.try_reserve(1)?;
        Some(BodyMeter {
            budget: budget.clone(),
            held: Arc::new(Mutex::new(Metered { bytes: 0, permit })),
        })
    }

    /// Counts `n` more bytes of the body, reserving what they need beyond what is held.
    pub fn charge(&self, n: usize) -> Result<(), BudgetExceeded> {
        let mut m = self.held.lock().unwrap_or_else(|e| e.into_inner());
        m.bytes = m.bytes.saturating_add(n);
        let held = m.permit.num_permits() * BUDGET_UNIT;
        if m.bytes > held {
            let more = self
                .budget
                .try_reserve(m.bytes - held)
                .ok_or(BudgetExceeded { bytes: m.bytes })?;
            m.permit.merge(more);
        }
        Ok(())
    }

    /// Bytes counted so far.
    pub fn bytes(&self) -> usize {
        self.held.lock().unwrap_or_else(|e| e.into_inner()).bytes
    }
}

/// Marks a response as the last of its connection (see the module documentation).
pub fn close_connection(mut r: Response) -> Response {
    r.headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_characters_are_escaped_and_long_input_cut() {
        let s = for_log("m,gate=g1 force=1\r\x1b[2KFAKE\n");
        assert!(!s.contains('\r') && !s.contains('\x1b') && !s.contains('\n'));
        assert!(s.contains("\\r\\u{1b}[2KFAKE\\n"), "{s}");
        let long = "x".repeat(1000);
        assert_eq!(for_log(&long).len(), LOG_INPUT_MAX_CHARS + 3);
    }

    #[test]
    fn the_budget_refuses_what_does_not_fit_and_frees_on_drop() {
        let b = BodyBudget::new(10 * 1024);
        let p = b.try_reserve(8 * 1024).unwrap();
        assert!(b.try_reserve(4 * 1024).is_none());
        assert!(b.try_reserve(2 * 1024).is_some());
        drop(p);
        assert!(b.try_reserve(10 * 1024).is_some());
        assert!(b.try_reserve(usize::MAX).is_none());
    }

    #[test]
    fn a_meter_reserves_what_arrives_and_gives_it_back_with_its_last_clone() {
        let b = BodyBudget::new(10 * 1024);
        let m = BodyMeter::start(&b).unwrap();
        assert_eq!(b.available_bytes(), 9 * 1024);
        m.charge(1000).unwrap(); // within the first unit
        assert_eq!(b.available_bytes(), 9 * 1024);
        let again = m.clone();
        again.charge(3000).unwrap(); // 4000 bytes: 4 units
        assert_eq!((m.bytes(), b.available_bytes()), (4000, 6 * 1024));
        let other = BodyMeter::start(&b).unwrap();
        // 5 units free beside its own first: 6 KiB fits, one byte more does not
        other.charge(6 * 1024).unwrap();
        assert_eq!(b.available_bytes(), 0);
        let e = other.charge(1).unwrap_err();
        assert_eq!(e.bytes, 6 * 1024 + 1);
        assert!(e.to_string().contains("max_body_bytes_in_flight"), "{e}");
        drop(other);
        drop(m);
        assert_eq!(b.available_bytes(), 6 * 1024, "a clone still holds");
        drop(again);
        assert_eq!(b.available_bytes(), 10 * 1024);
        // an exhausted budget admits no new stream
        let _all = b.try_reserve(10 * 1024).unwrap();
        assert!(BodyMeter::start(&b).is_none());
    }
}
