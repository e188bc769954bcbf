//! The daemon's one way to take a `std::sync::Mutex`.

use std::sync::{Mutex, MutexGuard};

/// Locks `m`, recovering from poisoning: every critical section of the daemon leaves its data
/// consistent before anything in it can panic (the numerics run outside any lock, under
/// `catch_unwind`), so a poisoned lock still guards valid data, and one panicking thread must
/// not take the whole daemon down.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
