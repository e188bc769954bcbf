//! A gate's analysis memory across a restart, rebuilt from its latest stored windows.
//!
//! # Why
//! Without it a restart forgot what each gate had learnt, though the store held it:
//! - the trend of `zeta0`: `GateDampingDeclining` needs 6 windows, and its slope the horizon
//!   (10 minutes by default), so a restart during a slow drift delayed the warning by minutes;
//! - the ambient level: the at-once firing and the reading of a window that holds two states
//!   need 4 noise-driven windows first;
//! - the tracking model: every gate's first window went to the full search, 0.1 s each, so
//!   200 gates on one worker spent 17 s on their first round and jobs were replaced
//!   (`docs/benchmarks.md`, "Daemon").
//!
//! The history holds each window's report, model and span, so the memory is rebuilt with the
//! same code that built it live: [`DampingTrend::observe`] over the stored `zeta0` and interval,
//! [`AmbientLevel::resume`] over the stored reports, [`WindowAnalyzer::remember`] over the stored
//! windows (only those of the model the gate has now: [`WindowAnalyzer::same_model`]). The
//! tracking rules then treat the first window after the restart like any other: one that comes
//! more than `tracking.max_gap_windows` windows after the last stored one goes to the full
//! search, and the trend drops what fell out of its horizon.
//!
//! A gate whose newest stored window is older than the trend's horizon (wall clock) starts
//! afresh ([`rebuild`]). Not rebuilt: the pools of consecutive estimates (the first window after a restart stands
//! alone, with its own, wider interval) and the latest identification shown by the API. The
//! alert states have their own rows (`storage::resume`).

use crate::alert::AlertRules;
use crate::analysis::{
    AmbientLevel, DampingReport, DampingTrend, Path, Previous, TrendEstimate, WindowAnalysis,
    MAX_TREND_POINTS,
};
use crate::store::HistoryRow;

use super::worker::{replay, WindowAnalyzer};

/// Latest stored windows the level and the tracking memory are rebuilt from (the trend reads
/// its horizon). The level is the median of the last 12 noise-driven windows, and the tracking
/// memory counts the windows since the last full search (at most `tracking.full_every`, 12 by
/// default): 48 windows hold both with room for departed ones, which feed neither.
pub const RESUME_MODEL_WINDOWS: usize = 48;

/// What a gate remembers after a restart, for its entry in the daemon's state.
#[derive(Debug, Clone)]
pub struct GateMemory {
    /// The trend of `zeta0`, as the stored windows within its horizon left it.
    pub trend: DampingTrend,
    /// Its estimate after the last stored window (what the API shows until the next one).
    pub trend_estimate: Option<TrendEstimate>,
    /// The ambient level.
    pub level: AmbientLevel,
    /// The tracking memory for the worker pool (`None`: no stored window of the gate's model).
    pub previous: Option<Previous>,
    /// Stored windows read.
    pub windows: usize,
    /// Stored windows skipped because they do not decode (a row of a newer or broken version).
    pub skipped: usize,
}

/// How many of a gate's latest stored windows to read: the trend's horizon at the gate's
/// cadence, at least [`RESUME_MODEL_WINDOWS`], at most [`MAX_TREND_POINTS`].
pub fn windows_to_read(rules: &AlertRules, every_seconds: f64) -> usize {
    let every = if every_seconds.is_finite() && every_seconds > 0.0 {
        every_seconds
    } else {
        1.0
    };
    let horizon = (rules.trend_horizon_seconds / every).ceil();
    let n = if horizon.is_finite() && horizon >= 0.0 {
        horizon as usize + 1
    } else {
        0
    };
    n.clamp(RESUME_MODEL_WINDOWS, MAX_TREND_POINTS)
}

/// The memory of `gate` after its stored windows `rows` (oldest first, as
/// `Store::latest_history_rows` returns them), or `None` when there are none or the newest was
/// identified more than the trend's horizon before `now` (Unix seconds, wall clock): a daemon
/// down that long starts the gate afresh, since its trend would have nothing left in its
/// horizon and its level and model may no longer describe the gate (the water level, the flow).
pub fn rebuild(
    gate: &str,
    rows: &[HistoryRow],
    rules: &AlertRules,
    analyzer: &dyn WindowAnalyzer,
    now: f64,
) -> Option<GateMemory> {
    let newest = rows.last()?;
    let fresh = (now - newest.time) <= rules.trend_horizon_seconds;
    if !fresh {
        return None; // also when `now` or the stored time is not a number
    }
    let mut trend = DampingTrend::new(rules.trend_horizon_seconds);
    let mut trend_estimate = None;
    for r in rows {
        trend_estimate = trend.observe(
            r.window_end,
            r.zeta0,
            r.zeta0_interval,
            r.trusted,
            rules.fire_below,
        );
    }
    let tail = &rows[rows.len().saturating_sub(RESUME_MODEL_WINDOWS)..];
    let decoded: Vec<(WindowAnalysis, f64, f64)> = tail.iter().filter_map(window_of).collect();
    let level = AmbientLevel::resume(decoded.iter().map(|(a, _, _)| &a.damping));
    // the windows since the model last changed: a model changed in the configuration leaves its
    // older windows out, and a gate whose latest window is of another model starts afresh
    let same = decoded
        .iter()
        .rev()
        .take_while(|(a, _, _)| analyzer.same_model(gate, a))
        .count();
    let previous = replay(analyzer, gate, &decoded[decoded.len() - same..]);
    Some(GateMemory {
        trend,
        trend_estimate,
        level,
        previous,
        windows: rows.len(),
        skipped: tail.len() - decoded.len(),
    })
}

/// A stored window as the analysis made it: its report, its coefficients as the refinement's
/// start, its path, its span. `None` when the stored JSON does not decode.
fn window_of(r: &HistoryRow) -> Option<(WindowAnalysis, f64, f64)> {
    let damping: DampingReport = serde_json::from_str(&r.damping).ok()?;
    let coefficients: Vec<(String, f64)> = serde_json::from_str(&r.coefficients).ok()?;
    let path = if r.path == Path::Tracked.as_str() {
        Path::Tracked
    } else {
        Path::Full
    };
    let a = WindowAnalysis {
        equation: r.equation.clone(),
        warm_start: coefficients.iter().map(|(_, v)| *v).collect(),
        coefficients,
        damping,
        evaluations: 0,
        seconds: 0.0,
        path,
    };
    Some((a, r.window_start, r.window_end))
}

/// The memory of every gate with stored windows that the configuration still accepts (at most
/// `server.max_gates`), read from `store` (blocking). A failed read is logged and leaves the
/// gates it concerns to start afresh.
pub fn read(
    store: &dyn crate::store::Store,
    config: &super::config::Config,
    analyzer: &dyn WindowAnalyzer,
) -> std::collections::BTreeMap<String, GateMemory> {
    let mut memories = std::collections::BTreeMap::new();
    let gates = match store.history_gates(config.server.max_gates) {
        Ok(g) => g,
        Err(e) => {
            tracing::error!("cannot read the gates' history, every gate starts afresh: {e}");
            return memories;
        }
    };
    let (mut windows, mut skipped) = (0, 0);
    let now = super::clock::unix_seconds(std::time::SystemTime::now());
    for gate in gates {
        let Some(cfg) = config.gate(&gate) else {
            continue; // no longer configured, and unknown gates are not accepted
        };
        let n = windows_to_read(&cfg.alert, cfg.identify_every_seconds);
        match store.latest_history_rows(&gate, n) {
            Ok(rows) => {
                if let Some(m) = rebuild(&gate, &rows, &cfg.alert, analyzer, now) {
                    windows += m.windows;
                    skipped += m.skipped;
                    memories.insert(gate, m);
                }
            }
            Err(e) => {
                tracing::error!(%gate, "cannot read the gate's history, it starts afresh: {e}")
            }
        }
    }
    tracing::info!(
        gates = memories.len(),
        windows,
        skipped,
        "analysis memory rebuilt from the store (storage.resume_analysis)"
    );
    memories
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::{AmbientZeta, AnalysisError, Verdict, WindowInput, Zeta0Source};
    use crate::spectral::Regime;

    /// An analyzer that only remembers (the default `remember`), and knows one model: the
    /// equations that start with `known`.
    struct Remembers {
        known: &'static str,
    }

    impl WindowAnalyzer for Remembers {
        fn analyze(
            &self,
            _: &str,
            _: WindowInput<'_>,
            _: Option<&[f64]>,
            _: u64,
        ) -> Result<WindowAnalysis, AnalysisError> {
            Err(AnalysisError::Window("not in these tests".into()))
        }

        fn same_model(&self, _: &str, a: &WindowAnalysis) -> bool {
            a.equation.starts_with(self.known)
        }
    }

    /// A stored noise-driven window ending at `end` (identified 1 s later), of the model
    /// written `equation`, taken on `path`.
    fn row(end: f64, zeta: f64, equation: &str, path: &str) -> HistoryRow {
        let a = AmbientZeta {
            zeta,
            low: zeta - 0.004,
            high: zeta + 0.004,
        };
        let d = DampingReport {
            zeta0: Some(zeta),
            zeta0_interval: Some((a.low, a.high)),
            zeta0_source: Some(Zeta0Source::Ambient),
            ambient_zeta: Some(a),
            trusted: true,
            verdict: Verdict::Damped,
            regime: Some(Regime::Damped),
            signal_rms: Some(5.0 + end / 100.0),
            fit_nmae: 0.5,
            ..DampingReport::unknown()
        };
        HistoryRow {
            gate: "g".into(),
            time: end + 1.0,
            window_start: end - 10.0,
            window_end: end,
            equation: equation.into(),
            coefficients: serde_json::to_string(&[("c1", zeta), ("c2", 1.0)]).unwrap(),
            damping: serde_json::to_string(&d).unwrap(),
            verdict: "damped".into(),
            fit_nmae: 0.5,
            path: path.into(),
            zeta0: Some(zeta),
            zeta0_interval: Some((a.low, a.high)),
            frequency_hz: Some(10.0),
            trusted: true,
        }
    }

    fn rules() -> AlertRules {
        AlertRules {
            trend_horizon_seconds: 600.0,
            fire_below: 0.0,
            ..AlertRules::default()
        }
    }

    /// The rebuilt memory is what the live code builds from the same windows: the trend fed
    /// the stored figures, the level of the stored reports, and the tracking memory of the
    /// windows since the model last changed (their coefficients, their count since the last
    /// full search).
    #[test]
    fn the_memory_is_what_the_windows_built_live() {
        let rows: Vec<HistoryRow> = (0..20)
            .map(|i| {
                let end = 1000.0 + 5.0 * f64::from(i);
                let zeta = 0.02 - 0.0005 * f64::from(i);
                // the model changed at the 15th window; windows 17 to 19 were tracked
                let eq = if i < 15 { "old" } else { "new" };
                let path = if i >= 17 { "tracked" } else { "full" };
                row(end, zeta, &format!("{eq} {zeta}"), path)
            })
            .collect();
        let m = rebuild("g", &rows, &rules(), &Remembers { known: "new" }, 1100.0).unwrap();
        let mut live = DampingTrend::new(600.0);
        let mut estimate = None;
        for r in &rows {
            estimate = live.observe(r.window_end, r.zeta0, r.zeta0_interval, true, 0.0);
        }
        assert_eq!(m.trend_estimate, estimate);
        assert!(m.trend_estimate.is_some_and(|e| e.slope_per_second < 0.0));
        let reports: Vec<DampingReport> = rows
            .iter()
            .map(|r| serde_json::from_str(&r.damping).unwrap())
            .collect();
        assert_eq!(m.level, AmbientLevel::resume(&reports));
        assert!(m.level.level().is_some());
        let p = m.previous.expect("windows of the gate's model");
        assert_eq!(p.coefficients, [0.02 - 0.0005 * 19.0, 1.0]);
        assert_eq!(
            p.since_full, 3,
            "3 tracked windows since the last full search"
        );
        assert_eq!((p.t_start, p.t_end), (1085.0, 1095.0));
        assert_eq!((m.windows, m.skipped), (20, 0));
        // a gate whose latest window is of another model keeps no tracking memory
        let other = rebuild("g", &rows, &rules(), &Remembers { known: "old" }, 1100.0).unwrap();
        assert_eq!(other.previous, None);
        assert_eq!(other.level, m.level);
    }

    /// No windows, or a newest window older than the trend's horizon: the gate starts afresh.
    /// A window that does not decode is skipped and counted.
    #[test]
    fn stale_or_missing_history_and_broken_rows() {
        let rows = vec![
            row(1000.0, 0.01, "m", "full"),
            row(1005.0, 0.01, "m", "full"),
        ];
        let analyzer = Remembers { known: "m" };
        assert!(rebuild("g", &[], &rules(), &analyzer, 1006.0).is_none());
        assert!(rebuild("g", &rows, &rules(), &analyzer, 1006.0 + 600.0).is_some());
        assert!(rebuild("g", &rows, &rules(), &analyzer, 1006.0 + 600.1).is_none());
        assert!(rebuild("g", &rows, &rules(), &analyzer, f64::NAN).is_none());
        let mut broken = rows.clone();
        broken[0].damping = "{not json".into();
        let m = rebuild("g", &broken, &rules(), &analyzer, 1006.0).unwrap();
        assert_eq!((m.windows, m.skipped), (2, 1));
        assert_eq!(m.previous.map(|p| p.t_end), Some(1005.0));
    }

    /// The trend's horizon at the gate's cadence, clamped to what the level and the model need
    /// and to the trend's bound.
    #[test]
    fn windows_to_read_follow_the_horizon() {
        assert_eq!(windows_to_read(&rules(), 5.0), 121);
        assert_eq!(windows_to_read(&rules(), 60.0), RESUME_MODEL_WINDOWS);
        assert_eq!(windows_to_read(&rules(), 0.01), MAX_TREND_POINTS);
        // a cadence that is not a number counts as 1 s
        assert_eq!(windows_to_read(&rules(), f64::NAN), 601);
    }
}
