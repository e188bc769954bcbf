//! The sliding window of one gate: a preallocated ring buffer of the last `window_seconds` of
//! samples (and a longer contiguous history behind it), with the identification cadence counted
//! in SAMPLE time.
//!
//! Memory: the buffer keeps values only (8 bytes per sample; the time of every sample follows
//! from the time of the newest and the rate since the window is uniform and contiguous), so a
//! gate costs 8 bytes per sample kept: six windows (`HISTORY_WINDOWS`), 96 KB at 10 s and
//! 200 Hz, or 110 cycles of a slower gate (`service::window_span`, [`Window::set_history`]),
//! and never more than the window plus 100 000 samples (`MAX_HISTORY_EXTRA`). The history is
//! what a limit cycle's envelope relaxation reads (100 cycles, docs/damping.md); the
//! identification reads the window, or more of the history on a slow gate
//! (`service::window_span`).
//!
//! Times are never accumulated: the first sample's time is derived from the newest sample's
//! actual time, `t_last - (len - 1) / rate_hz`. Adding the period sample after sample would
//! round at every step; at Unix-epoch magnitudes (ulp 2.4e-7 s) and 200 Hz that drifts about
//! 82 ms an hour into `window_start`, `window_end` and `analysed_until`.
//!
//! Rules for each incoming sample at time `t`, with `p = 1 / rate_hz` and `last` the newest
//! sample kept:
//! - `|t - last| < p/2`: duplicate, dropped (counted `duplicate`);
//! - `t - last <= -p/2`: older than the head, dropped (counted `out_of_order`);
//! - `t - last > 1.5 p`: gap: the window restarts at `t`, so no window spans a gap; identification
//!   resumes once a contiguous stretch of a full window has been collected after the gap;
//! - otherwise appended (timing jitter within half a period is tolerated).
//!
//! The rate: the daemon derives the times from `rate_hz`, so a source sampling at another rate
//! (250 Hz on a 200 Hz gate: every spacing 0.8 of a period, within the jitter tolerated) would
//! fill windows that are not what they claim. When a window is due, the `n` samples since the
//! check's starting point (the run's first sample; it moves to a due window's last sample once
//! [`RATE_CHECK_SPAN`] samples lie behind it) must imply `rate_hz` within [`RATE_TOLERANCE`]
//! (1 %) plus `1 / n`, what timestamps jittering by under half a period can do (the first window
//! of a 10 s, 200 Hz gate: 0.05 %). Otherwise the window is not handed out, the samples are
//! counted (`rate_mismatch`), and the window restarts at the current sample, so the next one
//! handed out holds a full window at the right rate. A JSON request of 3 or more samples is
//! checked whole before this (`ingest::implied_rate`); this catches the raw TCP lines and small
//! requests, one sample at a time.
//!
//! Clock jumps: after a full window's worth of CONSECUTIVE out-of-order samples, the source's
//! clock is taken to have jumped backwards (or one sample came from far in the future) and the
//! window restarts at the current sample (counted as a gap), so one bad timestamp cannot block a
//! gate for good.
//!
//! A window is due when it is full and `every` samples have arrived since the last due window
//! (or since the first full window after a gap). Since this depends only on the samples, a
//! stream replayed at any speed, in any chunking, yields the same windows.
//!
//! The first window (at the start and after a gap) may wait `offset` more samples
//! ([`Window::staggered`]; `offset < every`): the daemon gives each gate an offset fixed by its
//! ID ([`stagger_offset`]), so gates whose streams start together are identified spread over the
//! cadence instead of all at once, as Prometheus spreads its targets' scrapes over the scrape
//! interval by a hash of each target. Why: a full search costs about nine tracked windows
//! (docs/benchmarks.md), and 200 gates started together made one worker's first round 7 s of
//! searches against the 5 s cadence, so the last 71 gates' first windows were replaced before
//! they ran. Spread over the cadence the same work never falls a cadence behind (docs/design.md,
//! "Staggered gates").

use std::collections::VecDeque;

use crate::analysis::gate_hash;

/// Relative disagreement of a declared or implied sample rate with `rate_hz` that is refused.
pub const RATE_TOLERANCE: f64 = 0.01;

/// Fewest samples a window's rate check measures over before its starting point moves on (see
/// the module doc): over `n` spacings a right-rate source's jitter reads off by under `1 / n`,
/// which the check adds to [`RATE_TOLERANCE`], so over 200 the bar is 1.5 %. With a window due
/// every sample the stretch would otherwise be one spacing, read to within 100 %.
pub const RATE_CHECK_SPAN: usize = 200;

/// Outcome counts of one push.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct PushStats {
    /// Samples appended.
    pub accepted: u64,
    /// Duplicates dropped.
    pub duplicate: u64,
    /// Out-of-order samples dropped.
    pub out_of_order: u64,
    /// Gaps that restarted the window.
    pub gaps: u64,
    /// Samples whose spacing implied another rate than the window's, by more than
    /// [`RATE_TOLERANCE`], over the stretch since the last check (see the module doc): their
    /// window was not handed out and the window restarted.
    pub rate_mismatch: u64,
    /// The rate those samples implied, Hz (the last such stretch of the push).
    pub implied_rate_hz: Option<f64>,
}

/// Windows of contiguous history the daemon keeps, the window included (see the module doc) ...
///
/// Why six: the envelope's relaxation and the limit-cycle steadiness test read the last 100
/// cycles (`analysis::RELAXATION_CYCLES`), and six 10 s windows hold them down to 1.67 Hz (a
/// 2 Hz barrier gate's 50 s). Three held 30 s, 60 cycles of that gate: its held cycle read
/// 0.45 points off at 91 % coverage, 0.31 and 98 % with 100 cycles (docs/benchmarks.md,
/// "Stop 83"). The cost is the copy handed to the worker with each window.
pub const HISTORY_WINDOWS: usize = 6;
/// ... but never more than this many samples beyond the window (800 KB a gate), so a very long
/// window does not multiply a gate's memory by six.
pub const MAX_HISTORY_EXTRA: usize = 100_000;

/// The samples a gate keeps for a window of `window` samples: [`HISTORY_WINDOWS`] windows, at
/// most [`MAX_HISTORY_EXTRA`] beyond the window.
pub fn history_samples(window: usize) -> usize {
    window + ((HISTORY_WINDOWS - 1) * window).min(MAX_HISTORY_EXTRA)
}

/// The offset of gate `id`'s first window, in samples below `every`: [`gate_hash`] of the ID
/// (with an index no window's last sample reaches, so it is not the number that phases the
/// gate's full searches) modulo `every`. A fixed function of the ID on every machine and build:
/// a gate's windows, and so its reports, stay where they were after an upgrade or a replay.
pub fn stagger_offset(id: &str, every: usize) -> usize {
    (gate_hash(id, u64::MAX) % every.max(1) as u64) as usize
}

/// A full window ready for identification.
#[derive(Debug, Clone, PartialEq)]
pub struct DueWindow {
    /// Time of the first sample.
    pub t0: f64,
    /// The samples.
    pub values: Vec<f64>,
    /// The contiguous samples held up to the window's end, oldest first (the window is its
    /// tail): at least the window, at most the history's capacity.
    pub history: Vec<f64>,
    /// Index (over all samples ever accepted for the gate, from 0) of the sample after the last.
    pub end_index: u64,
}

/// A due window not yet copied (see [`Window::push_latest`]).
struct Pending {
    t0: f64,
    end_index: u64,
    /// Samples pushed since it was due.
    after: usize,
}

/// The window of one gate.
#[derive(Debug, Clone)]
pub struct Window {
    rate_hz: f64,
    capacity: usize,
    /// Samples kept: the window and the history behind it (at least `capacity`).
    history: usize,
    every: usize,
    values: VecDeque<f64>,
    /// Time of the newest sample (the window's times are derived from it, see the module doc).
    t_last: Option<f64>,
    /// Samples accepted ever.
    accepted: u64,
    /// Samples accepted since the last due window (or since the gap).
    since_due: usize,
    /// Whether a window was due since the last gap.
    due_once: bool,
    /// Samples the first window after the start or a gap waits once full ([`Window::staggered`]).
    offset: usize,
    /// Consecutive out-of-order samples.
    consecutive_old: usize,
    /// Time of the sample the rate was last checked at (the start of the contiguous run, then
    /// each due window's last sample).
    check_t: Option<f64>,
    /// Samples accepted since `check_t`.
    since_check: usize,
}

impl Window {
    /// A window of `capacity` samples at `rate_hz`, due every `every` new samples.
    pub fn new(rate_hz: f64, capacity: usize, every: usize) -> Window {
        Window::with_history(rate_hz, capacity, every, capacity)
    }

    /// [`Window::new`] keeping up to `history` contiguous samples (at least the window), handed
    /// out with each due window ([`DueWindow::history`]).
    pub fn with_history(rate_hz: f64, capacity: usize, every: usize, history: usize) -> Window {
        let capacity = capacity.max(1);
        let history = history.max(capacity);
        Window {
            rate_hz,
            capacity,
            history,
            every: every.max(1),
            values: VecDeque::with_capacity(history),
            t_last: None,
            accepted: 0,
            since_due: 0,
            due_once: false,
            offset: 0,
            consecutive_old: 0,
            check_t: None,
            since_check: 0,
        }
    }

    /// Keeps up to `history` contiguous samples from now on (at least the window; the oldest
    /// go at once where fewer are kept): a slow gate's history follows its frequency
    /// (`service::window_span`).
    pub fn set_history(&mut self, history: usize) {
        self.history = history.max(self.capacity);
        while self.values.len() > self.history {
            self.values.pop_front();
        }
    }

    /// This window with its first due window (at the start and after each gap) `offset` samples
    /// after it is full; `offset` is taken modulo the cadence `every`, so the first window comes
    /// at most one cadence later and the cadence after it is unchanged.
    pub fn staggered(mut self, offset: usize) -> Window {
        self.offset = offset % self.every;
        self
    }

    /// Pushes samples `(t, v)` in order; returns the counts and every window that became due,
    /// each with its own copy of the samples. For tests and offline replays; the daemon calls
    /// [`Window::push_latest`].
    pub fn push(
        &mut self,
        samples: impl IntoIterator<Item = (f64, f64)>,
    ) -> (PushStats, Vec<DueWindow>) {
        let (stats, due, _) = self.push_inner(samples, true);
        (stats, due)
    }

    /// [`Window::push`] keeping only the newest window that became due (newer windows replace
    /// older ones before they are queued), with the number that became due. Only that one is
    /// copied. Why: one request may hold hours of samples; with `window_seconds = 600` each due
    /// window copied 2.7 MB of window and history, and a 700,000-sample request made 700 such
    /// copies (1.5 GB, seconds under the state lock) to keep one.
    pub fn push_latest(
        &mut self,
        samples: impl IntoIterator<Item = (f64, f64)>,
    ) -> (PushStats, Option<DueWindow>, u64) {
        let (stats, mut due, count) = self.push_inner(samples, false);
        (stats, due.pop(), count)
    }

    /// The push. With `keep_all` every due window is copied as it comes; without, the newest is
    /// only marked (`pending`) and copied at the end, or before a gap clears the buffer. The
    /// samples the buffer drops after the mark are kept aside (`evicted`, at most `every`: the
    /// next window is due `every` samples later and replaces the mark), so the copy is exactly
    /// the window and history the mark saw.
    fn push_inner(
        &mut self,
        samples: impl IntoIterator<Item = (f64, f64)>,
        keep_all: bool,
    ) -> (PushStats, Vec<DueWindow>, u64) {
        let period = 1.0 / self.rate_hz;
        let mut stats = PushStats::default();
        let mut due = Vec::new();
        let mut count = 0u64;
        let mut pending: Option<Pending> = None;
        let mut evicted: Vec<f64> = Vec::new();
        for (t, v) in samples {
            let mut restart = self.t_last.is_none();
            if let Some(last) = self.t_last {
                let dt = t - last;
                if dt.abs() < 0.5 * period {
                    stats.duplicate += 1;
                    continue;
                }
                let clock_jump = dt <= -0.5 * period && self.consecutive_old + 1 >= self.capacity;
                if dt <= -0.5 * period && !clock_jump {
                    stats.out_of_order += 1;
                    self.consecutive_old += 1;
                    continue;
                }
                if dt > 1.5 * period || clock_jump {
                    stats.gaps += 1;
                    if let Some(p) = pending.take() {
                        due = vec![self.materialize(&p, &evicted)];
                    }
                    self.values.clear();
                    self.since_due = 0;
                    self.due_once = false;
                    restart = true;
                }
            }
            if self.values.len() == self.history {
                if let (Some(front), Some(_)) = (self.values.pop_front(), pending.as_ref()) {
                    evicted.push(front);
                }
            }
            self.values.push_back(v);
            if let Some(p) = pending.as_mut() {
                p.after += 1;
            }
            self.consecutive_old = 0;
            self.t_last = Some(t);
            self.accepted += 1;
            self.since_due += 1;
            stats.accepted += 1;
            if restart {
                self.check_t = Some(t);
                self.since_check = 0;
            } else {
                self.since_check += 1;
            }
            // before the first due window `since_due` counts every sample since the start or
            // the gap, so the window has been full for `since_due - capacity` samples
            let ready = if self.due_once {
                self.since_due >= self.every
            } else {
                self.since_due >= self.capacity + self.offset
            };
            if self.values.len() >= self.capacity && ready {
                // the rate the samples since the last check imply: a source at 250 Hz on a
                // 200 Hz gate keeps every spacing within the jitter tolerated above (0.8 of a
                // period), and its windows would be read as 8 s at 200 Hz
                let implied = self
                    .check_t
                    .filter(|_| self.since_check > 0)
                    .map(|tc| self.since_check as f64 / (t - tc));
                // a source at the right rate whose times each jitter by under half a period
                // reads off by under 1 / n over n spacings
                let bound = RATE_TOLERANCE + 1.0 / self.since_check.max(1) as f64;
                let mismatch =
                    implied.filter(|r| ((r - self.rate_hz) / self.rate_hz).abs() > bound);
                let checked = self.since_check;
                if checked >= RATE_CHECK_SPAN || mismatch.is_some() {
                    self.check_t = Some(t);
                    self.since_check = 0;
                }
                if let Some(r) = mismatch {
                    stats.rate_mismatch += checked as u64;
                    stats.implied_rate_hz = Some(r);
                    if let Some(p) = pending.take() {
                        due = vec![self.materialize(&p, &evicted)];
                    }
                    self.values.clear();
                    self.values.push_back(v);
                    self.since_due = 1;
                    self.due_once = false;
                    continue;
                }
                self.due_once = true;
                self.since_due = 0;
                count += 1;
                let mark = Pending {
                    t0: t - (self.capacity - 1) as f64 * period,
                    end_index: self.accepted,
                    after: 0,
                };
                if keep_all {
                    due.push(self.materialize(&mark, &[]));
                } else {
                    pending = Some(mark);
                    evicted.clear();
                }
            }
        }
        if let Some(p) = pending {
            due = vec![self.materialize(&p, &evicted)];
        }
        (stats, due, count)
    }

    /// The window marked by `p`: the buffer as it stood then is `evicted` (dropped from the front
    /// since) followed by the buffer without the `p.after` samples pushed since.
    fn materialize(&self, p: &Pending, evicted: &[f64]) -> DueWindow {
        let held = self.values.len() - p.after;
        let history: Vec<f64> = evicted
            .iter()
            .copied()
            .chain(self.values.iter().take(held).copied())
            .collect();
        let values = history[history.len() - self.capacity..].to_vec();
        DueWindow {
            t0: p.t0,
            values,
            history,
            end_index: p.end_index,
        }
    }

    /// Samples held in the window (the history behind it not counted).
    pub fn len(&self) -> usize {
        self.values.len().min(self.capacity)
    }

    /// Whether no sample is held.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Capacity in samples.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Held fraction of a full window.
    pub fn fill_ratio(&self) -> f64 {
        self.len() as f64 / self.capacity as f64
    }

    /// Seconds spanned by the window's held samples.
    pub fn span_seconds(&self) -> f64 {
        self.len().saturating_sub(1) as f64 / self.rate_hz
    }

    /// Samples the first window after the start or a gap waits once full
    /// ([`Window::staggered`]).
    pub fn offset(&self) -> usize {
        self.offset
    }

    /// Time of the newest sample.
    pub fn last_time(&self) -> Option<f64> {
        self.t_last
    }

    /// Samples accepted ever.
    pub fn accepted_total(&self) -> u64 {
        self.accepted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream(n: usize, rate: f64) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| (1000.0 + i as f64 / rate, (i as f64 * 0.1).sin()))
            .collect()
    }

    #[test]
    fn same_windows_whatever_the_chunking() {
        let data = stream(5_000, 100.0);
        let run = |chunk: usize| {
            let mut w = Window::new(100.0, 300, 50);
            let mut due = Vec::new();
            for c in data.chunks(chunk) {
                due.extend(w.push(c.iter().copied()).1);
            }
            due
        };
        let one = run(1);
        assert_eq!(one.len(), 1 + (5_000 - 300) / 50);
        assert_eq!(one[0].end_index, 300);
        assert_eq!(one[1].end_index, 350);
        for chunk in [7, 100, 1234, 5_000] {
            assert_eq!(run(chunk), one, "chunk {chunk}");
        }
    }

    /// A source at another rate than the window's is refused when its window falls due: 250 Hz
    /// on a 200 Hz window (spacing 0.8 of a period, each within the jitter tolerated) hands out
    /// no window; 0.5 % off is within the tolerance; once the source is fixed, the first window
    /// handed out implies the right rate within the tolerance.
    #[test]
    fn a_source_at_another_rate_hands_out_no_window() {
        let at = |rate: f64, n: usize, t0: f64| -> Vec<(f64, f64)> {
            (0..n).map(|i| (t0 + i as f64 / rate, 1.0)).collect()
        };
        let mut w = Window::new(200.0, 2000, 1000);
        let (s, due) = w.push(at(250.0, 6000, 1000.0));
        assert!(due.is_empty(), "{} windows at 250 Hz", due.len());
        assert!(s.rate_mismatch >= 4000, "{s:?}");
        assert!((s.implied_rate_hz.unwrap() - 250.0).abs() < 0.1, "{s:?}");
        assert_eq!(s.accepted, 6000);
        // fixed: 200 Hz from one period after the last sample
        let t_switch = 1000.0 + 5999.0 / 250.0 + 1.0 / 200.0;
        let (s, due) = w.push(at(200.0, 5000, t_switch));
        assert_eq!(s.rate_mismatch, 0, "{s:?}");
        assert!(!due.is_empty());
        // the check is on the rate of the whole stretch: at most 1 % of the window (0.1 s) may
        // be 250 Hz samples from before the switch
        assert!(
            due[0].t0 >= t_switch - 0.01 * 10.0,
            "{} before {t_switch}",
            due[0].t0
        );

        let mut w = Window::new(200.0, 2000, 1000);
        let (s, due) = w.push(at(201.0, 6000, 1000.0));
        assert_eq!((s.rate_mismatch, due.len()), (0, 5), "{s:?}");
    }

    /// A source at the right rate whose times jitter by up to 0.2 of a period (every spacing
    /// between 0.6 and 1.4 periods: none dropped, no gap) passes the rate check whatever the
    /// cadence, a window due every sample included; at 125 Hz on a 100 Hz
    /// window it is caught at the first window even so.
    #[test]
    fn jittered_times_at_the_right_rate_pass_the_rate_check() {
        // a deterministic jitter in (-0.2, 0.2) periods
        let jitter = |i: usize| 0.2 * (((i * 7919) % 1000) as f64 / 500.0 - 1.0);
        let jittered = |rate: f64, n: usize| -> Vec<(f64, f64)> {
            (0..n)
                .map(|i| (1000.0 + (i as f64 + jitter(i)) / rate, 1.0))
                .collect()
        };
        for every in [1, 50, 100] {
            let mut w = Window::new(100.0, 100, every);
            let (s, due) = w.push(jittered(100.0, 3000));
            assert_eq!(s.rate_mismatch, 0, "every {every}: {s:?}");
            assert_eq!(due.len(), 1 + (3000 - 100) / every, "every {every}");
            let mut w = Window::new(100.0, 100, every);
            let (s, due) = w.push(jittered(125.0, 3000));
            assert!(
                due.is_empty(),
                "every {every}: {} windows at 125 Hz",
                due.len()
            );
            assert!(s.rate_mismatch > 0, "every {every}");
        }
    }

    /// `push_latest` hands out exactly the newest window `push` would have (its samples and its
    /// history), with the count of windows that became due, whatever the chunking, through
    /// gaps, duplicates, out-of-order samples, a clock jump and a history longer than the
    /// window.
    #[test]
    fn push_latest_is_the_last_of_push() {
        let mut data = stream(4_000, 100.0);
        // a gap at 1500 (2 s missing), duplicates and stragglers at 2200, a gap shortly after a
        // due window at 3000
        data.drain(1500..1700);
        let dup = data[2000];
        data.insert(2001, dup);
        data.insert(2002, (dup.0 - 0.3, 9.0));
        data.drain(3000..3010);
        // the source's clock jumps back an hour: a window's worth of old samples, then it heals
        data.extend((0..700).map(|i| (1000.0 - 3600.0 + i as f64 / 100.0, 0.5)));
        for (history, every, offset) in [(300, 50, 0), (900, 50, 7), (700, 1, 0), (300, 300, 3)] {
            for chunk in [1, 7, 49, 50, 51, 333, 4_000] {
                let fresh = || Window::with_history(100.0, 300, every, history).staggered(offset);
                let (mut all, mut latest) = (fresh(), fresh());
                for c in data.chunks(chunk) {
                    let (s1, due) = all.push(c.iter().copied());
                    let (s2, last, count) = latest.push_latest(c.iter().copied());
                    let case = format!("history {history}, every {every}, chunk {chunk}");
                    assert_eq!(s1, s2, "{case}");
                    assert_eq!(count, due.len() as u64, "{case}");
                    assert_eq!(last.as_ref(), due.last(), "{case}");
                }
            }
        }
    }

    /// The first window waits its offset once full, the cadence after it is unchanged, a gap
    /// makes the next first window wait again, and any chunking gives the same windows.
    #[test]
    fn a_staggered_window_waits_its_offset_once_then_keeps_the_cadence() {
        let (rate, cap, every, offset) = (100.0, 300, 50, 37);
        let mut data = stream(1_000, rate);
        // a gap of a second after sample 700: the window restarts there
        for (t, _) in &mut data[700..] {
            *t += 1.0;
        }
        let run = |chunk: usize, offset: usize| {
            let mut w = Window::new(rate, cap, every).staggered(offset);
            let mut due = Vec::new();
            for c in data.chunks(chunk) {
                due.extend(w.push(c.iter().copied()).1);
            }
            due
        };
        let plain: Vec<u64> = run(1, 0).iter().map(|d| d.end_index).collect();
        let late = run(1, offset);
        let ends: Vec<u64> = late.iter().map(|d| d.end_index).collect();
        assert_eq!(plain[..2], [300, 350]);
        assert_eq!(ends[..3], [337, 387, 437]);
        // after the gap (700 samples before it, the new stretch from index 700): 1000 - 700 =
        // 300 samples fill one window, and the offset pushes its first window past the end
        assert_eq!(*plain.last().unwrap(), 1000);
        assert_eq!(*ends.last().unwrap(), 687);
        // each due window is the window's last `cap` samples, whatever the offset
        for d in &late {
            let end = d.end_index as usize;
            let expect: Vec<f64> = data[end - cap..end].iter().map(|s| s.1).collect();
            assert_eq!(d.values, expect);
        }
        for chunk in [7, 100, 1_000] {
            assert_eq!(run(chunk, offset), late, "chunk {chunk}");
        }
        // an offset is taken below the cadence: `every + 3` acts as 3
        assert_eq!(run(1, every + 3)[0].end_index, 303);
    }

    /// The offset is a fixed function of the ID (the same after an upgrade), below the cadence,
    /// and spreads many gates evenly over it.
    #[test]
    fn stagger_offsets_are_fixed_and_spread_the_gates() {
        // pinned, so that a change of the hash (which would move every gate's windows) is noticed
        assert_eq!(stagger_offset("lab", 1_000), 781);
        assert_eq!(stagger_offset("lock", 500), 43);
        assert_eq!(stagger_offset("", 7), 2);
        assert_eq!(stagger_offset("anything", 1), 0);
        assert_eq!(stagger_offset("anything", 0), 0);
        let mut bins = [0usize; 10];
        for i in 0..200 {
            let o = stagger_offset(&format!("g{i}"), 1_000);
            assert!(o < 1_000);
            bins[o / 100] += 1;
        }
        // 20 expected per tenth of the cadence
        assert!(bins.iter().all(|&n| (10..=30).contains(&n)), "{bins:?}");
    }

    #[test]
    fn duplicates_and_out_of_order_are_dropped() {
        let mut w = Window::new(100.0, 10, 5);
        let (s, _) = w.push([
            (0.0, 1.0),
            (0.01, 2.0),
            (0.01, 9.0),
            (0.005 + 0.001, 3.0),
            (0.0, 4.0),
            (0.02, 5.0),
        ]);
        assert_eq!(s.accepted, 3);
        assert_eq!(s.duplicate, 2); // 0.01 again, and 0.006 (within half a period of 0.01)
        assert_eq!(s.out_of_order, 1);
        assert_eq!(w.len(), 3);
    }

    #[test]
    fn a_gap_restarts_the_window_and_no_window_spans_it() {
        let rate = 100.0;
        let mut w = Window::new(rate, 100, 20);
        let mut data = stream(150, rate);
        // a gap of 2 periods
        data.extend((0..250).map(|i| (1000.0 + (151 + i) as f64 / rate, 0.0)));
        let mut due = Vec::new();
        let mut gaps = 0;
        for s in data.chunks(13) {
            let (st, d) = w.push(s.iter().copied());
            gaps += st.gaps;
            due.extend(d);
        }
        assert_eq!(gaps, 1);
        let gap_t = 1000.0 + 149.0 / rate;
        for d in &due {
            let t_end = d.t0 + (d.values.len() - 1) as f64 / rate;
            assert!(
                t_end <= gap_t + 1e-9 || d.t0 > gap_t,
                "window {}..{} spans the gap at {gap_t}",
                d.t0,
                t_end
            );
        }
        // before the gap: full at 100, then 120, 140; after it: first full at 150 + 100
        let ends: Vec<u64> = due.iter().map(|d| d.end_index).collect();
        assert_eq!(
            ends,
            vec![100, 120, 140, 250, 270, 290, 310, 330, 350, 370, 390]
        );
        // a small jitter is not a gap
        let mut w = Window::new(rate, 100, 20);
        let (s, _) = w.push([(0.0, 0.0), (0.0149, 0.0), (0.0249, 0.0)]);
        assert_eq!((s.accepted, s.gaps), (3, 0));
    }

    #[test]
    fn a_clock_jump_heals_after_a_window() {
        let mut w = Window::new(100.0, 50, 10);
        w.push(stream(60, 100.0));
        // one sample from the far future, then the normal stream goes on
        let (s, _) = w.push([(1e12, 0.0)]);
        assert_eq!(s.gaps, 1);
        let later: Vec<(f64, f64)> = stream(200, 100.0).into_iter().skip(60).collect();
        let (s, due) = w.push(later);
        assert_eq!(s.out_of_order, 49);
        assert_eq!(s.gaps, 1);
        assert!(!due.is_empty(), "the window fills again after the jump");
        assert_eq!(w.len(), 50);
    }

    #[test]
    fn ring_buffer_is_bounded() {
        let mut w = Window::new(100.0, 50, 10);
        w.push(stream(1000, 100.0));
        assert_eq!(w.len(), 50);
        assert!(w.values.capacity() >= 50);
        assert!((w.fill_ratio() - 1.0).abs() < 1e-12);
        assert!((w.span_seconds() - 0.49).abs() < 1e-9);
        assert_eq!(w.accepted_total(), 1000);
    }

    #[test]
    fn a_day_at_unix_epoch_magnitude_does_not_drift() {
        // 2026-11-23 at 200 Hz: the true time of sample i is T0 + i / rate, computed from the
        // index (its own rounding is one ulp, 2.4e-7 s). Accumulating the period drifted ~2 s.
        const T0: f64 = 1_795_392_000.0;
        let rate = 200.0;
        let day = 86_400 * 200u64;
        let capacity = 2_000;
        let every = 200 * 3_600; // one window an hour keeps the copies few
        let mut w = Window::new(rate, capacity, every);
        let true_time = |i: u64| T0 + i as f64 / rate;
        let (stats, due) = w.push((0..day).map(|i| (true_time(i), 0.0)));
        assert_eq!(stats.accepted, day);
        assert_eq!(due.len(), 1 + (day as usize - capacity) / every);
        let tolerance = 0.01 / rate; // a hundredth of a period
        for d in &due {
            let first = d.end_index - capacity as u64;
            let start_err = (d.t0 - true_time(first)).abs();
            let end = d.t0 + (d.values.len() - 1) as f64 / rate;
            let end_err = (end - true_time(d.end_index - 1)).abs();
            assert!(
                start_err < tolerance && end_err < tolerance,
                "window ending at sample {}: start off by {start_err} s, end by {end_err} s",
                d.end_index
            );
        }
    }

    /// One step of a generated stream on a grid of periods (`on` below is the newest time
    /// generated on the grid): the next grid point jittered by up to 0.2 of a period; a repeat
    /// of `on`; a straggler 1 to 3 periods before it; a time just inside the duplicate line
    /// (0.40 to 0.49 of a period either side of `on`) or just beyond the out-of-order line
    /// (0.51 to 0.6 before it); a gap of 3 to 30 periods; a lurch (the next grid point 0.3 to
    /// 0.45 of a period late, from 1.1 to 1.65 periods after the last: either side of the gap
    /// line, then the one after on time); or a burst of 18 to 21 samples from 3 periods back
    /// and older, with a repeat of `on` among them (a clock jump from the 20th on).
    #[derive(Debug, Clone, Copy)]
    enum Step {
        Next(f64),
        Repeat,
        Straggler(u8),
        Near(f64),
        Old(f64),
        Gap(u8, f64),
        Lurch(f64),
        Burst(u8, u8),
    }

    fn step() -> impl proptest::strategy::Strategy<Value = Step> {
        use proptest::prelude::*;
        prop_oneof![
            40 => (-0.2f64..0.2).prop_map(Step::Next),
            2 => Just(Step::Repeat),
            2 => (1u8..=3).prop_map(Step::Straggler),
            1 => prop_oneof![-0.49f64..-0.40, 0.40f64..0.49].prop_map(Step::Near),
            1 => (0.51f64..0.6).prop_map(Step::Old),
            1 => ((3u8..=30), -0.2f64..0.2).prop_map(|(k, e)| Step::Gap(k, e)),
            1 => (0.3f64..0.45).prop_map(Step::Lurch),
            1 => ((18u8..=21), (0u8..18)).prop_map(|(k, at)| Step::Burst(k, at)),
        ]
    }

    /// The times of `steps` at `rate` Hz; a sample's value is its index.
    fn times(steps: &[Step], rate: f64) -> Vec<(f64, f64)> {
        let p = 1.0 / rate;
        let at = |grid: i64, e: f64| 1000.0 + (grid as f64 + e) * p;
        let (mut grid, mut on) = (0i64, 1000.0);
        let mut ts = Vec::with_capacity(steps.len());
        for s in steps {
            match *s {
                Step::Next(e) => {
                    grid += 1;
                    on = at(grid, e);
                    ts.push(on);
                }
                Step::Repeat => ts.push(on),
                Step::Straggler(k) => ts.push(on - f64::from(k) * p),
                Step::Near(f) => ts.push(on + f * p),
                Step::Old(f) => ts.push(on - f * p),
                Step::Gap(k, e) => {
                    grid += i64::from(k);
                    on = at(grid, e);
                    ts.push(on);
                }
                Step::Lurch(late) => {
                    ts.push(at(grid + 1, late));
                    grid += 2;
                    on = at(grid, 0.0);
                    ts.push(on);
                }
                Step::Burst(k, repeat_at) => {
                    for j in 0..k {
                        if j == repeat_at {
                            ts.push(on);
                        }
                        ts.push(on - f64::from(3 + j) * p);
                    }
                }
            }
        }
        ts.into_iter()
            .enumerate()
            .map(|(i, t)| (t, i as f64))
            .collect()
    }

    /// The module doc's rules, sample by sample: the accepted samples' indices, cut into the
    /// contiguous stretches a gap or a clock jump starts, each with its count of accepted
    /// samples since the start (`DueWindow::end_index`).
    fn stretches(data: &[(f64, f64)], rate: f64, capacity: usize) -> Vec<Vec<(usize, u64)>> {
        let p = 1.0 / rate;
        let mut out: Vec<Vec<(usize, u64)>> = Vec::new();
        let (mut last, mut old, mut accepted) = (None::<f64>, 0usize, 0u64);
        for (i, &(t, _)) in data.iter().enumerate() {
            match last.map(|l| t - l) {
                // a duplicate neither counts as old nor ends a run of old samples
                Some(dt) if dt.abs() < 0.5 * p => continue,
                Some(dt) if dt <= -0.5 * p && old + 1 < capacity => {
                    old += 1;
                    continue;
                }
                Some(dt) if dt <= 1.5 * p && dt > -0.5 * p => {
                    accepted += 1;
                    out.last_mut().unwrap().push((i, accepted));
                }
                // the first sample, a gap, or the `capacity`-th old sample in a row
                _ => {
                    accepted += 1;
                    out.push(vec![(i, accepted)]);
                }
            }
            old = 0;
            last = Some(t);
        }
        out
    }

    /// Streams with duplicates, stragglers, gaps, clock jumps and jittered times, many of them
    /// at the rules' lines (seeded, 400 cases): the windows handed out are exactly those the
    /// module doc's rules give (each stretch of `L` contiguous samples, `L >= capacity`, gives
    /// `1 + (L - capacity) / every`, each the last `capacity` samples of its stretch at that
    /// point, with the history behind them and the count of samples accepted); the buffer
    /// never holds more than the history; the counts add up; two chunks give the same windows;
    /// and `push_latest` gives the last of them.
    #[test]
    fn windows_are_the_ones_the_rules_give_through_gaps_duplicates_and_stragglers() {
        use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
        let (rate, capacity, every, history) = (10.0, 20, 5, 50);
        let new = || Window::with_history(rate, capacity, every, history);
        let strategy = (proptest::collection::vec(step(), 0..400), 0.0f64..1.0);
        let mut runner = TestRunner::new_with_rng(
            Config {
                cases: 400,
                failure_persistence: None,
                ..Config::default()
            },
            TestRng::from_seed(RngAlgorithm::ChaCha, &[7; 32]),
        );
        let handed_out = std::cell::Cell::new((0usize, 0usize));
        runner
            .run(&strategy, |(steps, cut)| {
                use proptest::{prop_assert, prop_assert_eq};
                let data = times(&steps, rate);
                let mut w = new();
                let (stats, due) = w.push(data.iter().copied());
                prop_assert!(w.values.len() <= history);
                prop_assert_eq!(
                    stats.accepted + stats.duplicate + stats.out_of_order,
                    data.len() as u64
                );
                // Within a stretch the samples accepted lie on consecutive grid points, each
                // within 0.45 of a period of its point, apart from a stretch's first (a time
                // off the grid after a gap or a clock jump; then within 1.5 periods of its
                // successor). So n spacings read a rate off by under 1 / n: never refused.
                prop_assert_eq!(stats.rate_mismatch, 0);
                let mut want = Vec::new();
                let stretches = stretches(&data, rate, capacity);
                for s in &stretches {
                    let mut end = capacity;
                    while end <= s.len() {
                        let index = |x: &[(usize, u64)]| x.iter().map(|a| a.0).collect::<Vec<_>>();
                        want.push((
                            index(&s[end - capacity..end]),
                            index(&s[end.saturating_sub(history)..end]),
                            s[end - 1].1,
                        ));
                        end += every;
                    }
                }
                let index = |v: &[f64]| v.iter().map(|x| *x as usize).collect::<Vec<_>>();
                let got: Vec<_> = due
                    .iter()
                    .map(|d| (index(&d.values), index(&d.history), d.end_index))
                    .collect();
                prop_assert_eq!(&got, &want);
                let restarts = stretches.len().saturating_sub(1) as u64;
                prop_assert_eq!(stats.gaps, restarts);
                let mut n = handed_out.get();
                n.0 += due.len();
                n.1 += usize::from(
                    steps
                        .iter()
                        .any(|s| matches!(s, Step::Burst(k, _) if *k >= 20)),
                );
                handed_out.set(n);
                // any chunking, the same windows; `push_latest`, the last of them
                let split = (cut * data.len() as f64) as usize;
                let mut w2 = new();
                let mut chunked = w2.push(data[..split].iter().copied()).1;
                chunked.extend(w2.push(data[split..].iter().copied()).1);
                prop_assert_eq!(&chunked, &due);
                let (_, latest, count) = new().push_latest(data.iter().copied());
                prop_assert_eq!((latest.as_ref(), count), (due.last(), due.len() as u64));
                Ok(())
            })
            .unwrap();
        // the streams are long enough between gaps that the property is about real windows,
        // and clock jumps happen
        let (windows, with_jumps) = handed_out.get();
        assert!(
            windows > 400 * 5 && with_jumps > 40,
            "{windows} windows, {with_jumps} cases with a clock jump"
        );
    }

    #[test]
    fn the_history_is_six_windows_with_a_cap() {
        // 60 s at 10 s windows: 100 cycles of a 2 Hz gate (50 s) fit
        assert_eq!(history_samples(2_000), 12_000);
        assert_eq!(history_samples(500) as f64 / 50.0, 60.0);
        assert_eq!(history_samples(10_000_000), 10_100_000);
    }

    #[test]
    fn the_history_can_grow_and_shrink_between_pushes() {
        let data = stream(2_000, 100.0);
        let mut w = Window::with_history(100.0, 300, 50, 600);
        let due = w.push(data[..700].iter().copied()).1;
        assert_eq!(due.last().unwrap().history.len(), 600);
        // longer: the history fills up to it, contiguous, the windows as before
        w.set_history(1_000);
        let due = w.push(data[700..1_500].iter().copied()).1;
        let last = due.last().unwrap();
        assert_eq!((last.history.len(), last.values.len()), (1_000, 300));
        let want: Vec<f64> = data[500..1_500].iter().map(|s| s.1).collect();
        assert_eq!(last.history, want);
        // shorter: the oldest go at once, never below the window
        w.set_history(100);
        assert_eq!(w.values.len(), 300);
        let due = w.push(data[1_500..1_550].iter().copied()).1;
        assert_eq!(due.last().unwrap().history.len(), 300);
    }

    #[test]
    fn the_history_behind_the_window_is_handed_out_and_restarts_at_a_gap() {
        let data = stream(1_000, 100.0);
        let mut w = Window::with_history(100.0, 300, 50, 900);
        let due = w.push(data.iter().copied()).1;
        // the windows are the plain window's, whatever history is kept
        let plain = Window::new(100.0, 300, 50).push(data.iter().copied()).1;
        assert_eq!(due.len(), plain.len());
        for (d, p) in due.iter().zip(&plain) {
            assert_eq!(
                (d.t0, &d.values, d.end_index),
                (p.t0, &p.values, p.end_index)
            );
            assert_eq!(p.history, p.values);
            // the window is the history's tail, and the history is contiguous up to its end
            assert!(d.history.len() >= 300 && d.history.len() <= 900);
            assert_eq!(&d.history[d.history.len() - 300..], &d.values[..]);
            let first = d.end_index as usize - d.history.len();
            let want: Vec<f64> = data[first..d.end_index as usize]
                .iter()
                .map(|s| s.1)
                .collect();
            assert_eq!(d.history, want);
        }
        assert_eq!(due.last().unwrap().history.len(), 900);
        // the window's fill does not count the history
        assert_eq!((w.len(), w.fill_ratio()), (300, 1.0));
        // a gap restarts the history with the window
        let later: Vec<(f64, f64)> = (0..400).map(|i| (2000.0 + i as f64 / 100.0, 1.0)).collect();
        let due = w.push(later).1;
        assert_eq!(due[0].history.len(), 300);
        assert!(due.iter().all(|d| d.history.iter().all(|v| *v == 1.0)));
    }
}
