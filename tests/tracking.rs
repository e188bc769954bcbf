//! Tracking between windows (issue 9, section 2) on the seeded gate simulator, through the
//! daemon's analyzer (`Analyzer::analyze_tracked` with the worker pool's per-gate memory): a
//! steady gate mostly takes the tracked path and agrees with the full search; a change of regime
//! (an onset, a 20 % frequency shift) falls back to the full search within one window.

use gatewatch::analysis::{
    Analyzer, Path, Previous, TrackingPolicy, Verdict, WindowAnalysis, WindowInput,
};
use gatewatch::service::config::Config;
use gatewatch::simulate::{GateParams, GateSimulator, Scenario, ZetaSchedule};

const RATE: f64 = 200.0;
/// 10 s windows every 5 s, as the daemon's defaults.
const WINDOW: usize = 2000;
const HOP: usize = 1000;

fn analyzer(policy: TrackingPolicy) -> Analyzer {
    let config = Config::embedded();
    Analyzer::new(config.defaults.analysis_settings())
        .unwrap()
        .with_tracking(policy)
        .unwrap()
}

/// One analysed window: its start time and result.
struct Window {
    t0: f64,
    a: WindowAnalysis,
}

/// Analyses `windows` half-overlapping windows of `signal` as the worker pool does (the memory
/// carried from window to window, the seed from the window's index).
fn track(analyzer: &Analyzer, signal: &[f64], windows: usize) -> Vec<Window> {
    track_every(analyzer, signal, windows, 1)
}

/// [`track`] where only every `stride`-th window is analysed: a busy worker pool whose
/// pending jobs were replaced `stride - 1` times in a row.
fn track_every(analyzer: &Analyzer, signal: &[f64], windows: usize, stride: usize) -> Vec<Window> {
    let mut previous: Option<Previous> = None;
    let mut out = Vec::new();
    for w in 0..windows {
        let start = w * stride * HOP;
        let values = &signal[start..start + WINDOW];
        let t0 = start as f64 / RATE;
        let a = analyzer
            .analyze_tracked(
                WindowInput {
                    t0,
                    rate_hz: RATE,
                    values,
                    history: &[],
                },
                previous.as_ref(),
                (start + WINDOW) as u64,
            )
            .unwrap();
        let t_end = t0 + (WINDOW - 1) as f64 / RATE;
        previous = Some(Previous::after(previous.as_ref(), &a, t0, t_end));
        out.push(Window { t0, a });
    }
    out
}

fn samples(sim: &mut GateSimulator, n: usize) -> Vec<f64> {
    let mut v = vec![0.0; n];
    sim.fill(&mut v);
    v
}

fn summary(ws: &[Window]) -> String {
    ws.iter()
        .map(|w| {
            format!(
                "t0={:5.1} {:7} {:?} fit={:.3} trusted={} agrees={:?} f={:?} fm={:?} zeta0={:?} c={:?} {:.3}s\n",
                w.t0,
                w.a.path.as_str(),
                w.a.damping.verdict,
                w.a.damping.fit_nmae,
                w.a.damping.trusted,
                w.a.damping.agrees,
                w.a.damping.frequency_hz,
                w.a.damping.model_frequency_hz,
                w.a.damping.zeta0,
                w.a.warm_start,
                w.a.seconds,
            )
        })
        .collect()
}

#[test]
fn a_steady_gate_mostly_tracks_and_agrees_with_the_full_search() {
    let a = analyzer(TrackingPolicy::default());
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 7);
    let windows = 12;
    let signal = samples(&mut sim, WINDOW + (windows - 1) * HOP);
    let ws = track(&a, &signal, windows);
    let s = summary(&ws);
    assert_eq!(ws[0].a.path, Path::Full, "a new gate searches\n{s}");
    let tracked = ws.iter().filter(|w| w.a.path == Path::Tracked).count();
    assert!(
        // observed: 7 of the 11 windows after the first on this seed (debug build, 2026-11-23)
        tracked * 2 > windows - 1,
        "{tracked} of {windows} windows tracked\n{s}"
    );
    // The tracked result is as good as the full search on the same window, judged against the
    // truth (a single noise-driven window's full search itself scatters by several % in mass:
    // on this seed one full search read 20.4 kg for a 19.1 kg gate): the mass (set by the
    // frequency) no more than 2 % further from the truth, the same verdict, and the damping
    // ratio no more than 0.005 further from the true +1 %.
    let true_mass = GateParams::default().mass;
    for w in ws.iter().filter(|w| w.a.path == Path::Tracked) {
        let start = (w.t0 * RATE).round() as usize;
        let full = a
            .analyze(
                WindowInput {
                    t0: w.t0,
                    rate_hz: RATE,
                    values: &signal[start..start + WINDOW],
                    history: &[],
                },
                None,
                (start + WINDOW) as u64,
            )
            .unwrap();
        let (t, f) = (&w.a.warm_start, &full.warm_start);
        let (et, ef) = (
            (t[0] / true_mass - 1.0).abs(),
            (f[0] / true_mass - 1.0).abs(),
        );
        // 2 %: on these noise-driven windows the model fits poorly (NMAE about 0.6) and the
        // ambient estimate decides; the tracked mass stays within the scatter of full searches
        assert!(
            et <= ef + 0.02,
            "mass {t:?} vs {f:?} (true {true_mass})\n{s}"
        );
        assert_eq!(w.a.damping.verdict, full.damping.verdict, "{s}");
        let (zt, zf) = (w.a.damping.zeta0.unwrap(), full.damping.zeta0.unwrap());
        assert!(
            (zt - 0.01).abs() <= (zf - 0.01).abs() + 0.005,
            "zeta0 {zt} vs {zf} (true 0.01)\n{s}"
        );
    }
}

/// The first window that lies wholly after `change_s`, and the one before it.
fn first_after(ws: &[Window], change_s: f64) -> usize {
    ws.iter()
        .position(|w| w.t0 >= change_s)
        .expect("a window after the change")
}

#[test]
fn an_onset_falls_back_to_the_full_search_within_one_window() {
    let a = analyzer(TrackingPolicy::default());
    // Stable (zeta = +1 %) for 40 s, then within 1 s to zeta = -2 %: self-excitation.
    let schedule = ZetaSchedule::Ramp {
        start_s: 40.0,
        duration_s: 1.0,
        from: 0.01,
        to: -0.02,
    };
    let mut sim = GateSimulator::new(GateParams::default(), schedule, 11);
    let windows = 12;
    let signal = samples(&mut sim, WINDOW + (windows - 1) * HOP);
    let ws = track(&a, &signal, windows);
    let s = summary(&ws);
    let k = first_after(&ws, 41.0);
    assert!(
        ws[..k - 1].iter().any(|w| w.a.path == Path::Tracked),
        "the stable part tracks\n{s}"
    );
    assert_eq!(ws[k].a.path, Path::Full, "window {k}\n{s}");
    assert_ne!(ws[k].a.damping.verdict, Verdict::Damped, "{s}");
}

/// `len` samples of the stable lab gate whose frequency rises by 20 % at sample `change` (the
/// mass divided by 1.2^2; the installed stiffness is the model's k), the second gate settled
/// into its stationary response first.
fn frequency_shift(change: usize, len: usize) -> Vec<f64> {
    let before = GateParams::default();
    let after = GateParams {
        mass: before.mass / 1.44,
        ..before.clone()
    };
    let mut sim_a = GateSimulator::scenario(before, Scenario::Stable, 3);
    let mut sim_b = GateSimulator::scenario(after, Scenario::Stable, 4);
    let mut signal = samples(&mut sim_a, change);
    samples(&mut sim_b, 10 * WINDOW);
    signal.extend(samples(&mut sim_b, len - change));
    signal
}

#[test]
fn a_frequency_shift_of_20_percent_falls_back_within_one_window() {
    let a = analyzer(TrackingPolicy::default());
    let windows = 12;
    let change = 8 * HOP;
    let signal = frequency_shift(change, WINDOW + (windows - 1) * HOP);
    let ws = track(&a, &signal, windows);
    let s = summary(&ws);
    let k = first_after(&ws, change as f64 / RATE);
    assert!(
        ws[..k - 1].iter().any(|w| w.a.path == Path::Tracked),
        "the first regime tracks\n{s}"
    );
    assert_eq!(ws[k].a.path, Path::Full, "window {k}\n{s}");
    let (m0, m1) = (ws[0].a.warm_start[0], ws[k].a.warm_start[0]);
    assert!(
        (m0 / m1 / 1.44 - 1.0).abs() < 0.05,
        "mass {m0} -> {m1}\n{s}"
    );
}

#[test]
fn tracking_off_always_searches() {
    let a = analyzer(TrackingPolicy {
        enabled: false,
        ..TrackingPolicy::default()
    });
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 7);
    let signal = samples(&mut sim, WINDOW + 2 * HOP);
    let ws = track(&a, &signal, 3);
    assert!(ws.iter().all(|w| w.a.path == Path::Full));
}

#[test]
fn a_tracked_window_never_charges_more_than_the_refinement_budget() {
    // Before the budget was a hard cap, the default 60 let tracked windows of this gate charge
    // 105 to 141 integrations (docs/benchmarks.md, "Where a tracked window's CPU goes").
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 7);
    let windows = 8;
    let signal = samples(&mut sim, WINDOW + (windows - 1) * HOP);
    for budget in [TrackingPolicy::default().refine_evaluations, 12] {
        let a = analyzer(TrackingPolicy {
            refine_evaluations: budget,
            ..TrackingPolicy::default()
        });
        let ws = track(&a, &signal, windows);
        let s = summary(&ws);
        let tracked: Vec<_> = ws.iter().filter(|w| w.a.path == Path::Tracked).collect();
        assert!(!tracked.is_empty(), "budget {budget}: none tracked\n{s}");
        for w in tracked {
            assert!(
                w.a.evaluations <= budget && w.a.evaluations >= 2,
                "budget {budget}: {} charged at t0 = {}\n{s}",
                w.a.evaluations,
                w.t0
            );
        }
    }
}

#[test]
fn replaced_jobs_still_track_and_a_shift_across_the_gap_falls_back_within_one_window() {
    let a = analyzer(TrackingPolicy::default());
    // Two jobs replaced between analysed windows: each window starts 15 s after the last, 5 s
    // after its end (0.5 window lengths of gap, within the default max_gap_windows = 2; before
    // the option every such window ran the full search).
    let stride = 3;
    let windows = 8;
    let change = 5 * stride * HOP;
    let signal = frequency_shift(change, WINDOW + (windows - 1) * stride * HOP);
    let ws = track_every(&a, &signal, windows, stride);
    let s = summary(&ws);
    let k = first_after(&ws, change as f64 / RATE);
    assert_eq!(k, 5, "{s}");
    assert!(
        ws[1..k].iter().any(|w| w.a.path == Path::Tracked),
        "the first regime tracks across the gaps\n{s}"
    );
    assert_eq!(ws[k].a.path, Path::Full, "window {k}\n{s}");
    let (m0, m1) = (ws[0].a.warm_start[0], ws[k].a.warm_start[0]);
    assert!(
        (m0 / m1 / 1.44 - 1.0).abs() < 0.05,
        "mass {m0} -> {m1}\n{s}"
    );
    // with no gap allowed, the same windows all search
    let strict = analyzer(TrackingPolicy {
        max_gap_windows: 0.0,
        ..TrackingPolicy::default()
    });
    let ws = track_every(&strict, &signal, k, stride);
    assert!(
        ws.iter().all(|w| w.a.path == Path::Full),
        "{}",
        summary(&ws)
    );
}
