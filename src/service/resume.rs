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
//! same code that built it live: [`DampingTrend::observe`] over what it read of each stored report
//! (`analysis::trend_reading`: the stored `zeta0` and interval, or a rising window's pool),
//! [`AmbientLevel::resume`] over the stored reports, [`WindowAnalyzer::remember`] over the stored
//! windows (only those of the model the gate has now: [`WindowAnalyzer::same_model`]). The
//! tracking rules then treat the first window after the restart like any other: one that comes
//! more than `tracking.max_gap_windows` windows after the last stored one goes to the full
//! search, and the trend drops what fell out of its horizon.
//!
//! Where the rebuilt memory differs from the live one: the trend and the level are exactly what
//! they were (they were fed the reports as stored). The tracking memory is replayed from the
//! stored reports, which the service's level and pools had already read, while the live pool
//! remembered the analysis's own report; and the stored coefficients are the window's model,
//! while with `tracking.waive_fit_on_noise` a waived window remembered the start it was refined
//! from. So the last window's trust and verdict may differ (a lone limit-cycle window the pool
//! made untrusted; a departed window the model read as self-excited), and the first window after
//! the restart may go to the full search where the live memory would have refined it, or be
//! refined where it would not; `tracking::accept` still decides whether the refined model
//! stands. Rows written before the path was stored right (session 26) all say `full`: the first
//! restart after the upgrade counts the windows since the last full search from the last one.
//!
//! A gate whose newest stored window is older than the trend's horizon (wall clock) starts
//! afresh ([`rebuild`]). Not rebuilt: the pools of consecutive estimates (the first window
//! after a restart stands alone, with its own, wider interval), the latest identification shown
//! by the API and the damping's gauges (the trend's gauges are set from the rebuilt trend when
//! the gate's entry is made). The alert states have their own rows (`storage::resume`).

use crate::alert::AlertRules;
use crate::analysis::{
    trend_reading, window_middle_lag, AmbientLevel, CycleAmplitude, DampingReport, DampingTrend,
    Path, Previous, TrendEstimate, TrendReading, WindowAnalysis, MAX_TREND_POINTS,
};
use crate::store::HistoryRow;

use super::worker::{replay, WindowAnalyzer};

/// Fewest latest stored windows read, and most the tracking memory is replayed over (the trend
/// reads its horizon, the level every window read). The level is the median of the last 24
/// noise-driven windows (`analysis::AMBIENT_LEVEL_WINDOWS`), and the tracking memory counts the
/// windows since the last full search (at most `tracking.full_every`, 12 by default): 48
/// windows hold both with room for departed ones, which feed neither.
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
    /// The damping law of the gate's last growth among the stored windows.
    pub cycle: CycleAmplitude,
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
    let windows: Vec<Option<(WindowAnalysis, f64, f64)>> = rows.iter().map(window_of).collect();
    for (r, w) in rows.iter().zip(&windows) {
        // what the trend read live (`analysis::trend_reading`: a rising window's pool), from the
        // stored report; the stored columns where it does not decode (they hold the reported
        // interval, which on a declining gate may reach below the window's own)
        let window_seconds = r.window_end - r.window_start;
        let reading = w.as_ref().map_or(
            TrendReading {
                zeta0: r.zeta0,
                interval: r.zeta0_interval,
                trusted: r.trusted,
                // the window's middle, as `trend_reading` reads a report without its lags
                lag_seconds: window_middle_lag(window_seconds),
            },
            |(a, _, _)| trend_reading(&a.damping, window_seconds),
        );
        trend_estimate = trend.observe(r.window_end, reading, rules.fire_below);
    }
    let decoded: Vec<(WindowAnalysis, f64, f64)> = windows.into_iter().flatten().collect();
    // every window read: a gate held on its limit cycle for minutes still finds the
    // noise-driven windows before it
    let level = AmbientLevel::resume(decoded.iter().map(|(a, _, end)| (&a.damping, *end)));
    let cycle = CycleAmplitude::resume(decoded.iter().map(|(a, _, end)| (&a.damping, *end)));
    // the windows since the model last changed (a model changed in the configuration leaves
    // its older windows out, and a gate whose latest window is of another model starts
    // afresh), at most RESUME_MODEL_WINDOWS of them
    let same = decoded
        .iter()
        .rev()
        .take(RESUME_MODEL_WINDOWS)
        .take_while(|(a, _, _)| analyzer.same_model(gate, a))
        .count();
    let previous = replay(analyzer, gate, &decoded[decoded.len() - same..]);
    Some(GateMemory {
        trend,
        trend_estimate,
        level,
        cycle,
        previous,
        windows: rows.len(),
        skipped: rows.len() - decoded.len(),
    })
}

/// A stored window as the analysis made it: its report, its coefficients as the refinement's
/// start, its path, its span. `None` when the stored JSON does not decode.
fn window_of(r: &HistoryRow) -> Option<(WindowAnalysis, f64, f64)> {
    let mut damping: DampingReport = serde_json::from_str(&r.damping).ok()?;
    // the report as the gate's memory read it live: with the window's own interval, before the
    // service reached it down to the trend (`analysis::reach_down_to_trend`)
    damping.zeta0_interval = damping.own_interval();
    damping.window_interval = None;
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
    // the configured gates first, by name; then, where unknown gates are accepted, the other
    // gates with history, up to `max_gates` in all
    let mut gates: Vec<String> = config.gates.keys().cloned().collect();
    if config.server.accept_unknown_gates && gates.len() < config.server.max_gates {
        match store.history_gates(config.server.max_gates) {
            Ok(stored) => gates.extend(
                stored
                    .into_iter()
                    .filter(|g| !config.gates.contains_key(g))
                    // a gate `..` of an older version's store, or of a hand-edited file
                    .filter(|g| super::storage::restorable_gate(g, "history", &store.location()))
                    .take(config.server.max_gates - gates.len()),
            ),
            Err(e) => tracing::error!(
                store = %store.location(),
                "cannot list the gates with history in {}: {e}",
                store.location()
            ),
        }
    }
    let (mut windows, mut skipped) = (0, 0);
    let now = super::clock::unix_seconds(std::time::SystemTime::now());
    for gate in gates {
        let Some(cfg) = config.gate(&gate) else {
            continue;
        };
        let n = windows_to_read(&cfg.alert, cfg.identify_every_seconds);
        match store.latest_history_rows(&gate, n) {
            Ok(rows) => {
                if let Some(m) = rebuild(&gate, &rows, &cfg.alert, analyzer, now) {
                    if m.skipped > 0 {
                        tracing::warn!(
                            %gate,
                            skipped = m.skipped,
                            store = %store.location(),
                            "{} stored windows of gate {gate} do not decode, its memory is \
                             rebuilt without them",
                            m.skipped
                        );
                    }
                    windows += m.windows;
                    skipped += m.skipped;
                    memories.insert(gate, m);
                }
            }
            Err(e) => {
                tracing::error!(%gate, store = %store.location(), "cannot read the gate's history, it starts afresh: {e}")
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
    use crate::analysis::{
        reach_down_to_trend, AmbientZeta, AnalysisError, Verdict, WindowInput, Zeta0Source,
    };
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

    /// A noise-driven window ending at `end`, of the model written `equation`, taken on `path`,
    /// as the analysis reports it.
    fn analysis(end: f64, zeta: f64, equation: &str, path: Path) -> WindowAnalysis {
        let a = AmbientZeta {
            zeta,
            low: zeta - 0.004,
            high: zeta + 0.004,
        };
        let damping = DampingReport {
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
        WindowAnalysis {
            equation: equation.into(),
            coefficients: vec![("c1".into(), zeta), ("c2".into(), 1.0)],
            damping,
            evaluations: 100,
            seconds: 0.1,
            warm_start: vec![zeta, 1.0],
            path,
        }
    }

    /// The history row the daemon stores for `a` (its report as the service left it), the
    /// window ending at `end` and identified 1 s later.
    fn stored(a: &WindowAnalysis, end: f64) -> HistoryRow {
        let r = crate::service::storage::identification_record(
            "g",
            std::time::UNIX_EPOCH + std::time::Duration::from_secs_f64(end + 1.0),
            (end - 10.0, end),
            a,
        );
        let d = &a.damping;
        HistoryRow {
            gate: r.gate,
            time: r.time,
            window_start: r.window_start,
            window_end: r.window_end,
            equation: r.equation,
            coefficients: serde_json::to_string(&r.coefficients).unwrap(),
            damping: r.damping.to_string(),
            verdict: r.verdict,
            fit_nmae: r.fit_nmae,
            path: r.path,
            zeta0: d.zeta0,
            zeta0_interval: d.zeta0_interval,
            frequency_hz: d.frequency_hz,
            trusted: d.trusted,
        }
    }

    /// A stored window of the series below (for the tests that need rows only).
    fn row(end: f64, zeta: f64, equation: &str, path: &str) -> HistoryRow {
        let path = if path == "tracked" {
            Path::Tracked
        } else {
            Path::Full
        };
        stored(&analysis(end, zeta, equation, path), end)
    }

    fn rules() -> AlertRules {
        AlertRules {
            trend_horizon_seconds: 600.0,
            fire_below: 0.0,
            ..AlertRules::default()
        }
    }

    /// The rebuilt memory is what the live code built from the same windows: the trend fed
    /// what it reads of each window (a rising window's pool), the level `observe_span` built,
    /// and the tracking memory the pool built with `remember` over the windows since the model
    /// last changed.
    #[test]
    fn the_memory_is_what_the_windows_built_live() {
        let analyzer = Remembers { known: "new" };
        let (mut trend, mut estimate) = (DampingTrend::new(600.0), None);
        let (mut by_columns, mut from_columns) = (DampingTrend::new(600.0), None);
        let mut level = AmbientLevel::default();
        let mut cycle = CycleAmplitude::default();
        let mut previous: Option<Previous> = None;
        let mut rows = Vec::new();
        let mut widened = 0;
        for i in 0..20 {
            let end = 1000.0 + 5.0 * f64::from(i);
            let zeta = 0.02 - 0.0005 * f64::from(i);
            // the model changed at the 15th window; windows 17 to 19 were tracked
            let eq = if i < 15 { "old" } else { "new" };
            let path = if i >= 17 { Path::Tracked } else { Path::Full };
            // the last three read high, as a declining gate's windows do near zero
            let zeta = zeta + if i >= 17 { 0.005 } else { 0.0 };
            let mut a = analysis(end, zeta, &format!("{eq} {zeta}"), path);
            // the pool remembers the analysis's report; the service then reads it and stores it
            previous = if i < 15 {
                None
            } else {
                Some(analyzer.remember("g", previous.as_ref(), &a, end - 10.0, end))
            };
            if i == 12 {
                // a window that grew into its cycle, which the model decided (no SSI estimate to read it as
                // noise-driven)
                a.damping.growth_zeta = Some((-0.02, -0.025, -0.015).into());
                a.damping.growth_law_zeta = Some((-0.02, -0.03, -0.01).into());
                a.damping.limit_cycle_amplitude = Some(50.0);
                a.damping.zeta0_source = Some(crate::analysis::Zeta0Source::Model);
                a.damping.trusted = true;
                a.damping.regime = Some(crate::spectral::Regime::SelfExcited);
                a.damping.ambient_zeta = None;
            }
            level.observe_span(&mut a.damping, end - 10.0, end);
            cycle.observe(end, &mut a.damping);
            if i == 8 {
                // a rising window, reported alone: the trend read the pool it joined
                a.damping.pooled_zeta = Some((0.03, 0.026, 0.034).into());
            }
            let d = &a.damping;
            estimate = trend.observe(end, trend_reading(d, 10.0), 0.0);
            let columns = TrendReading {
                zeta0: d.zeta0,
                interval: d.zeta0_interval,
                trusted: d.trusted,
                lag_seconds: 5.0,
            };
            from_columns = by_columns.observe(end, columns, 0.0);
            // the service then reaches the declining gate's interval down to the trend (with
            // no span asked, so these few windows do): stored widened, read back as its own
            if let Some(e) = &estimate {
                widened += usize::from(reach_down_to_trend(
                    &mut a.damping,
                    e,
                    &trend,
                    end,
                    10.0,
                    0.0,
                ));
            }
            rows.push(stored(&a, end));
        }
        assert!(widened > 0, "no window reached down to the trend");
        let m = rebuild("g", &rows, &rules(), &analyzer, 1100.0).unwrap();
        assert_eq!(m.trend_estimate, estimate);
        // and the decline the live trend confirmed, on which a window reaches down
        assert!(trend.declined_within_horizon(1095.0, 0.0));
        assert!(m.trend.declined_within_horizon(1095.0, 0.0));
        assert_ne!(
            estimate, from_columns,
            "the rising window's pool changes the trend"
        );
        assert!(estimate.is_some_and(|e| e.slope_per_second < 0.0));
        assert_eq!(m.level, level);
        assert!(m.level.level().is_some());
        assert_eq!(m.cycle, cycle);
        assert_ne!(m.cycle, CycleAmplitude::default());
        assert_eq!(m.previous, previous);
        let p = m.previous.expect("windows of the gate's model");
        assert_eq!(
            p.since_full, 3,
            "3 tracked windows since the last full search"
        );
        assert_eq!((p.t_start, p.t_end), (1085.0, 1095.0));
        assert_eq!((m.windows, m.skipped), (20, 0));
        // a gate whose latest window is of another model keeps no tracking memory
        let other = rebuild("g", &rows, &rules(), &Remembers { known: "old" }, 1100.0).unwrap();
        assert_eq!(other.previous, None);
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

    /// A window whose model did not integrate (`fit_nmae` infinite, stored by serde_json as
    /// `null`, as are its other non-finite figures) decodes: it was counted as a damaged row at
    /// every restart and left out of the rebuilt memory.
    #[test]
    fn a_window_whose_model_did_not_integrate_decodes() {
        let mut a = analysis(1005.0, 0.01, "m", Path::Full);
        a.damping.fit_nmae = f64::INFINITY;
        a.damping.trusted = false;
        a.damping.amplitude = Some(f64::INFINITY);
        let rows = vec![row(1000.0, 0.01, "m", "full"), stored(&a, 1005.0)];
        assert!(
            rows[1].damping.contains("\"fit_nmae\":null"),
            "{}",
            rows[1].damping
        );
        let m = rebuild("g", &rows, &rules(), &Remembers { known: "m" }, 1006.0).unwrap();
        assert_eq!((m.windows, m.skipped), (2, 0));
        let (decoded, _, _) = window_of(&rows[1]).unwrap();
        assert_eq!(decoded.damping.fit_nmae, f64::INFINITY);
        assert!(!decoded.damping.trusted);
    }

    /// `read` takes the configured gates first, then other gates with history where unknown
    /// gates are accepted, `max_gates` in all: a stored gate that sorts first does not push a
    /// configured one out; a gate the configuration no longer accepts is not read.
    #[test]
    fn configured_gates_are_resumed_first() {
        use crate::store::{SqliteStore, Store, WriteBatch};
        let dir = tempfile::tempdir().unwrap();
        let store = SqliteStore::open(&dir.path().join("gw.db"), 64).unwrap();
        let now = crate::service::clock::unix_seconds(std::time::SystemTime::now());
        let mut identifications = Vec::new();
        for gate in ["a_old", "g1", "zz_other"] {
            for i in 0..3 {
                let end = now - 30.0 + 5.0 * f64::from(i);
                let a = analysis(end, 0.01, "m", Path::Full);
                identifications.push(crate::service::storage::identification_record(
                    gate,
                    std::time::SystemTime::now(),
                    (end - 10.0, end),
                    &a,
                ));
            }
        }
        store
            .write(&WriteBatch {
                identifications,
                ..Default::default()
            })
            .unwrap();
        let analyzer = Remembers { known: "m" };
        let gates = |toml: &str| {
            let config = crate::service::config::Config::from_toml(toml).unwrap();
            read(&store, &config, &analyzer)
                .into_keys()
                .collect::<Vec<_>>()
        };
        assert_eq!(gates("[server]\nmax_gates = 1\n[gates.g1]\n"), ["g1"]);
        assert_eq!(
            gates("[server]\nmax_gates = 2\n[gates.g1]\n"),
            ["a_old", "g1"]
        );
        assert_eq!(
            gates("[server]\nmax_gates = 8\naccept_unknown_gates = false\n[gates.g1]\n"),
            ["g1"]
        );
        assert_eq!(gates("[server]\nmax_gates = 8\n").len(), 3);
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
