//! `gatewatch bench warning`: how well the daemon warns, scored against the simulator's truth.
//!
//! Each named scenario ([`crate::simulate::ScenarioName`]) on each gate preset is streamed
//! through the REAL daemon path, in sample time and faster than real time: a fresh
//! [`AppState`] (ingestion, per-gate window, worker pool, the real analyzers of the
//! configuration, the alert engine) gets the samples with [`AppState::ingest`], one
//! identification cadence at a time, and the bench waits for each window's identification before
//! sending the next, so no window is replaced and the result does not depend on the machine's
//! speed. Alerts are read by NAME from the gate's firing alerts as the API shows them
//! ([`AppState::gate_view`]) after every window, so a new alert (`GateDampingDeclining`) is
//! scored as soon as the engine raises it, without changing this file. The damping figures are
//! read through their JSON form (`zeta0`, `zeta0_interval`, `zeta0_source`) for the same reason.
//!
//! Scoring (pure functions over [`RunRecord`]s, tested on synthetic sequences) is in
//! `score`; what each column means is in `docs/benchmarks.md`.

use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;

use super::config::{Config, GateConfig};
use super::ingest::Batch;
use super::state::AppState;
use super::stdout::{errln, outln};
use super::worker::{AnalyzerMap, WindowAnalyzer};
use crate::simulate::{GatePreset, NoiseLevel, ScenarioName};

mod score;
#[cfg(test)]
mod tests;

pub use score::{alert_rows, regime_rows, AlertRow, Regime, RegimeRow, Targets};

/// Name of the negative-damping alert.
pub const ALERT_NEGATIVE: &str = "GateNegativeDamping";
/// Name of the trend alert (issue 8, section 3; scored when the engine raises it).
pub const ALERT_DECLINING: &str = "GateDampingDeclining";
/// Unix time of the first sample of every stream: any fixed value works, the daemon only sees
/// differences; fixed so that a run is reproducible.
const STREAM_EPOCH: f64 = 1_700_000_000.0;
/// Longest wall time one window's identification may take before the run is abandoned as stuck.
pub const WINDOW_TIMEOUT: Duration = Duration::from_secs(300);

/// `gatewatch bench warning`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchWarningArgs {
    /// Seeds per scenario and gate (seeds F..F+N-1, F the `--first-seed`).
    #[arg(long, allow_negative_numbers = true, default_value_t = 3)]
    pub seeds: u64,
    /// The first seed: extends a run to new streams without repeating the ones already run
    /// (`--seeds 4 --first-seed 5` streams seeds 5 to 8).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub first_seed: u64,
    /// Print JSON instead of the tables.
    #[arg(long)]
    pub json: bool,
    /// Hours of sample time streamed per seed on the stable scenarios (`stable`, `stable-low`),
    /// the false-alarm part; other scenarios run their defined length.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub hours: f64,
    /// Scenarios to run (default: all).
    #[arg(long, value_delimiter = ',')]
    pub scenarios: Vec<String>,
    /// Gate presets (lab, lock, barrier, surge).
    #[arg(long, value_delimiter = ',', default_value = "lab,lock")]
    pub gates: Vec<String>,
    /// Sensor noise RMS in signal units (N), the same on every gate; overrides --noise-rel.
    #[arg(long, allow_negative_numbers = true)]
    pub noise_abs: Option<f64>,
    /// Sensor noise RMS as a fraction of each gate's ambient response std at +1 % (0.125: the
    /// lab gate's 0.7 N load-cell floor against its 5.6 N ambient response, as in issue 8).
    #[arg(long, default_value_t = 0.125, allow_negative_numbers = true)]
    pub noise_rel: f64,
    /// Identification worker threads of the daemon under test.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub worker_threads: usize,
    /// Print every window to stderr: truth, zeta0 with its interval and source, the trend's
    /// slope and confident crossing, the firing alerts (for engineers checking a scenario).
    #[arg(long)]
    pub trace: bool,
    /// How a model-based zeta0 gets its interval (`model_interval`): newey-west (the
    /// configuration's default) or forcing.
    #[arg(long)]
    pub model_interval: Option<crate::analysis::ModelInterval>,
    /// Which reference instants the ambient SSI-COV correlations use (`ssi_reference`): lagged
    /// (the configuration's default) or common.
    #[arg(long)]
    pub ssi_reference: Option<crate::analysis::SsiReference>,
    /// What the gates' force signal holds (`force_terms`): all (the configuration's default)
    /// or stiffness, which is what the simulator records (`F = k*y`).
    #[arg(long)]
    pub force_terms: Option<crate::analysis::ForceTerms>,
    /// `GateNegativeDamping`'s `fire_at_once_probability` (default: the configuration's).
    #[arg(long, allow_negative_numbers = true)]
    pub fire_at_once_probability: Option<f64>,
    /// `GateNegativeDamping`'s `fire_at_once_min_ratio`: how far above its ambient level one
    /// window must stand to fire at once (default: `alert::at_once_ratio` of the gate's
    /// departure ratio, 3.5 from about 38 cycles a window up, 4.68 at 20).
    #[arg(long, allow_negative_numbers = true)]
    pub fire_at_once_min_ratio: Option<f64>,
    /// `GateNegativeDamping`'s `resolve_probability`: how sure a window must be that `zeta0`
    /// is at or above `clear_above` to count towards resolving (default: the configuration's,
    /// 0.9; 0.975 is the whole-interval rule).
    #[arg(long, allow_negative_numbers = true)]
    pub resolve_probability: Option<f64>,
    /// `GateDampingDeclining`'s `trend_min_span_seconds`: the sample time the trend's windows
    /// must span before it may warn (default: the configuration's, 300).
    #[arg(long, allow_negative_numbers = true)]
    pub trend_min_span_seconds: Option<f64>,
    /// Window length in seconds of sample time (`window_seconds`; default: the
    /// configuration's, 10): the shortest record an identification reads.
    #[arg(long, allow_negative_numbers = true)]
    pub window_seconds: Option<f64>,
    /// Cycles of the gate's frequency an identification reads at least (`window_cycles`;
    /// default: the configuration's, 40); 0 reads `--window-seconds` always, as before stop 86.
    #[arg(long, allow_negative_numbers = true)]
    pub window_cycles: Option<f64>,
    /// Identification cadence in seconds of new sample time (`identify_every_seconds`; default:
    /// the configuration's, 5). Records longer than the window keep it: on a 1 Hz gate's 50 s
    /// windows 5 s served better than 25 s (docs/benchmarks.md, "Stop 85").
    #[arg(long, allow_negative_numbers = true)]
    pub identify_every_seconds: Option<f64>,
    /// The pools' `max_seconds` (`[defaults.pooling]`; default: the configuration's, 60): the
    /// most sample time a pool spans. A slow gate's pool needs more seconds for its cycles.
    #[arg(long, allow_negative_numbers = true)]
    pub pool_max_seconds: Option<f64>,
}

/// What one run streams.
#[derive(Debug, Clone, Serialize)]
pub struct RunSpec {
    /// Scenario.
    #[serde(serialize_with = "ser_scenario")]
    pub scenario: ScenarioName,
    /// Gate preset.
    #[serde(serialize_with = "ser_gate")]
    pub gate: GatePreset,
    /// Simulation seed.
    pub seed: u64,
    /// Sensor noise RMS, signal units.
    pub noise_rms: f64,
    /// Sample time streamed after the warm-up, s.
    pub duration_s: f64,
    /// Print every window (estimate, interval, source, trend, alerts) to stderr (`--trace`).
    #[serde(skip)]
    pub trace: bool,
}

fn ser_scenario<S: serde::Serializer>(n: &ScenarioName, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(n.as_str())
}

fn ser_gate<S: serde::Serializer>(g: &GatePreset, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(g.as_str())
}

/// One identified window, beside the truth.
#[derive(Debug, Clone, Serialize)]
pub struct WindowRecord {
    /// Scenario time of the window's first sample, s.
    pub start: f64,
    /// Scenario time of the window's last sample, s.
    pub end: f64,
    /// The reported `zeta0` (`None`: no estimate, or the identification failed).
    pub zeta0: Option<f64>,
    /// The reported 95 % interval of `zeta0`.
    pub interval: Option<(f64, f64)>,
    /// The reported `zeta0_source`.
    pub source: Option<String>,
    /// True `zeta0` at the window's centre.
    pub truth_centre: f64,
    /// True `zeta0` averaged over the window.
    pub truth_mean: f64,
    /// Natural frequency at the window's centre, Hz (for Au's limit).
    pub frequency_hz: f64,
    /// Length of the record the identification read, s (`window_s`, or longer where
    /// `window_cycles` lengthened it).
    pub record_s: f64,
    /// Regime of the window.
    pub regime: Regime,
    /// Names of the gate's alerts firing after this window (and the early-warning baseline's
    /// `score::EWS_VARIANCE`, marked by `score::mark_ews`).
    pub firing: Vec<String>,
    /// Variance of the measured (noisy) signal over the window, for the early-warning baseline.
    pub variance: f64,
}

/// One stream's record.
#[derive(Debug, Clone, Serialize)]
pub struct RunRecord {
    /// What was streamed.
    pub spec: RunSpec,
    /// Window length, s.
    pub window_s: f64,
    /// First time the truth is at or below zero (`None`: never).
    pub t_zero: Option<f64>,
    /// First time the truth is at or below -1 %.
    pub t_minus_one: Option<f64>,
    /// Every window, in order.
    pub windows: Vec<WindowRecord>,
}

/// The daemon configuration of a run: the embedded defaults, `worker_threads`, and one gate
/// `id` with the preset's rate and stiffness (as an operator would configure it).
pub fn run_config(gate: GatePreset, worker_threads: usize) -> Config {
    let mut config = Config::embedded();
    config.server.worker_threads = worker_threads.max(1);
    let p = gate.params();
    config.gates.insert(
        gate.as_str().to_string(),
        GateConfig {
            rate_hz: p.rate_hz,
            stiffness: Some(p.stiffness),
            // The scenarios stream in sample time, faster than real time, from a fixed epoch:
            // the wall-clock bounds on sample times do not apply to a replay.
            max_future_seconds: 0.0,
            max_past_seconds: 0.0,
            // The windows end on multiples of the cadence in scenario time, as the scenarios'
            // events (the onset's zero and -1 % crossings) do: a detection is scored at the
            // estimator's delay, not at the phase of the gate's grid. With the shipped stagger a
            // gate's grid has its own phase, and a window can end up to one cadence before an
            // event the phase-0 grid sees at once (docs/benchmarks.md, "Staggered gates").
            stagger: false,
            ..config.defaults.clone()
        },
    );
    config
}

/// `(zeta0, interval, source)` of a damping report, read through its JSON form.
fn damping_fields(d: &serde_json::Value) -> (Option<f64>, Option<(f64, f64)>, Option<String>) {
    let zeta0 = d["zeta0"].as_f64().filter(|v| v.is_finite());
    let iv = &d["zeta0_interval"];
    let pair = |a: &serde_json::Value, b: &serde_json::Value| Some((a.as_f64()?, b.as_f64()?));
    let interval = if iv.is_array() {
        pair(&iv[0], &iv[1])
    } else if iv.is_object() {
        pair(&iv["lower"], &iv["upper"]).or_else(|| pair(&iv["lo"], &iv["hi"]))
    } else {
        None
    };
    let source = match &d["zeta0_source"] {
        serde_json::Value::String(s) => Some(s.clone()),
        serde_json::Value::Null => None,
        other => Some(other.to_string()),
    };
    (zeta0, interval, source)
}

/// Streams `spec` through a fresh daemon state with `analyzer` and records every window.
pub async fn run_stream(
    spec: &RunSpec,
    config: Config,
    analyzer: Arc<dyn WindowAnalyzer>,
) -> anyhow::Result<RunRecord> {
    let p = spec.gate.params();
    let def = spec.scenario.def(&p);
    let mut sim = def
        .simulator(&p, NoiseLevel::Absolute(spec.noise_rms), spec.seed)
        .map_err(anyhow::Error::msg)?;
    let id = spec.gate.as_str();
    let gate_cfg = config
        .gate(id)
        .ok_or_else(|| anyhow::anyhow!("gate `{id}` is not in the configuration"))?
        .clone();
    anyhow::ensure!(
        (gate_cfg.rate_hz - p.rate_hz).abs() < 1e-9,
        "gate `{id}`: configured rate {} Hz, preset {} Hz",
        gate_cfg.rate_hz,
        p.rate_hz
    );
    let rate = p.rate_hz;
    let every = gate_cfg.every_samples();
    let window_s = gate_cfg.window_samples() as f64 / rate;
    let history_s =
        crate::service::window::history_samples(gate_cfg.window_samples()) as f64 / rate;
    let state = AppState::new(config, analyzer)?;
    while sim.time() < -0.5 / rate {
        sim.next_sample();
    }
    // per cadence chunk: (start time, sum of squares of the clean signal, samples, sum and sum
    // of squares of the MEASURED signal), to classify a window's regime by its clean amplitude
    // and give the early-warning baseline the variance an operator would see, without keeping
    // hours of samples
    let mut chunks: Vec<(f64, f64, usize, f64, f64)> = Vec::new();
    let total = (spec.duration_s * rate).round() as usize;
    let mut sent = 0usize;
    let mut windows = Vec::new();
    let mut buf: Vec<(f64, f64)> = Vec::with_capacity(every);
    // chunks end where the gate's windows do: the first window comes a full window and the
    // gate's stagger offset after the start (`service::window`), the next ones every cadence
    let lead = (gate_cfg.window_samples() + gate_cfg.stagger_samples(id)) % every;
    while sent < total {
        let n = if sent == 0 && lead > 0 { lead } else { every }.min(total - sent);
        buf.clear();
        let (mut sq, mut m1, mut m2) = (0.0, 0.0, 0.0);
        let t_chunk = sent as f64 / rate;
        for i in 0..n {
            let v = sim.next_sample();
            let c = sim.last_clean();
            sq += c * c;
            m1 += v;
            m2 += v * v;
            buf.push((STREAM_EPOCH + (sent + i) as f64 / rate, v));
        }
        chunks.push((t_chunk, sq, n, m1, m2));
        sent += n;
        let summary = state
            .ingest(vec![Batch {
                gate: id.to_string(),
                samples: buf.clone(),
                rate: None,
                values_field: "values".into(),
                lines: None,
                precision: None,
            }])
            .map_err(|e| anyhow::anyhow!("ingest refused: {e:?}"))?;
        if summary.jobs == 0 {
            continue;
        }
        let end_unix = STREAM_EPOCH + (sent - 1) as f64 / rate;
        let waited = tokio::time::timeout(WINDOW_TIMEOUT, async {
            loop {
                let done = state
                    .gate_view(id)
                    .and_then(|v| v.analysed_until)
                    .is_some_and(|u| u >= end_unix - 0.25 / rate);
                if done {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(2)).await;
            }
        })
        .await;
        anyhow::ensure!(
            waited.is_ok(),
            "{} on {id}, seed {}: the window ending at {:.1} s was not identified within {:?}",
            spec.scenario.as_str(),
            spec.seed,
            end_unix - STREAM_EPOCH,
            WINDOW_TIMEOUT
        );
        let view = state
            .gate_view(id)
            .ok_or_else(|| anyhow::anyhow!("gate `{id}` vanished"))?;
        let end = end_unix - STREAM_EPOCH;
        // the identification shown is this window's only if its end matches (a failed job
        // leaves the previous one in place: then this window has no estimate); its start is
        // the record it read (`window_cycles` lengthens a slow gate's)
        let (zeta0, interval, source, start) = match &view.identification {
            Some(iv) if (iv.window_end - end_unix).abs() < 0.5 / rate => {
                let (z, i, s) = damping_fields(&serde_json::to_value(&iv.damping)?);
                // counted in samples, so a window of the configured length starts where the
                // grid says, not a rounding of Unix seconds away from it
                let n = ((iv.window_end - iv.window_start) * rate).round();
                (z, i, s, end - n / rate)
            }
            _ => (
                None,
                None,
                None,
                end - (gate_cfg.window_samples() - 1) as f64 / rate,
            ),
        };
        let centre = 0.5 * (start + end);
        let truth_centre = def.true_zeta(centre);
        let k_factor = def.stiffness_factor.as_ref().map_or(1.0, |k| k.at(centre));
        let frequency_hz = p.natural_frequency_hz() * k_factor.sqrt();
        let (sq, count, m1, m2) = chunks
            .iter()
            .filter(|c| c.0 >= start - 0.5 / rate && c.0 < end)
            .fold((0.0, 0usize, 0.0, 0.0), |a, c| {
                (a.0 + c.1, a.1 + c.2, a.2 + c.3, a.3 + c.4)
            });
        let measured_variance = {
            let n = count.max(1) as f64;
            (m2 / n - (m1 / n).powi(2)).max(0.0)
        };
        let amplitude = std::f64::consts::SQRT_2 * (sq / count.max(1) as f64).sqrt();
        let mut firing: Vec<String> = view.alerts.iter().map(|a| a.name.clone()).collect();
        firing.sort();
        firing.dedup();
        // The truth's largest change between instants 50 ms apart within the window (a step
        // shows as one jump).
        let steps = ((end - start) / 0.05).ceil().max(1.0) as usize;
        let at = |i: usize| def.true_zeta(start + (end - start) * i as f64 / steps as f64);
        let jump = (1..=steps).fold(0.0f64, |j, i| j.max((at(i) - at(i - 1)).abs()));
        let regime = Regime::classify_with_jump(&p, truth_centre, amplitude, jump);
        let truth_mean = def.mean_zeta(start, end);
        if spec.trace {
            let trusted = view
                .identification
                .as_ref()
                .is_some_and(|i| i.damping.trusted);
            let pct = |a: &crate::analysis::AmbientZeta| {
                let r = |v: f64| (v * 1e4).round() / 100.0;
                (r(a.zeta), r(a.low), r(a.high))
            };
            let facts = view.identification.as_ref().map(|i| {
                (
                    i.damping.regime,
                    i.damping.zeta0_windows,
                    i.damping.ambient_zeta.as_ref().map(pct),
                    i.damping.ambient_ratio.map(|r| (r * 100.0).round() / 100.0),
                    i.damping.model_zeta.as_ref().map(pct),
                    (i.damping.fit_nmae * 1000.0).round() / 1000.0,
                    i.damping.agrees,
                    i.damping.rms_swing.map(|r| (r * 100.0).round() / 100.0),
                    i.path,
                    i.damping.ssi_growing,
                    i.damping.ambient_common_zeta.as_ref().map(pct),
                )
            });
            let trend = view.trend.as_ref().map(|t| {
                (
                    t.slope_per_second * 60.0 * 100.0,
                    t.slope_upper * 60.0 * 100.0,
                    t.crossing_seconds_confident,
                )
            });
            errln!(
                "t {end:7.1}  true {:+.2} %  zeta0 {:?} {:?} {:?} trusted {trusted}  trend \
                 (%/min, upper %/min, confident crossing s) {trend:?}  firing {firing:?}  (regime, pooled, ssi, ambient ratio, model, fit nmae, agrees, rms swing, path, growing, ssi common) {facts:?}  scored {} (true mean {:+.2} %)  f {:?} Hz  growth (1/s, se) {:?}{}{}",
                100.0 * truth_centre,
                zeta0.map(|z| (z * 1e4).round() / 100.0),
                interval.map(|(a, b)| ((a * 1e4).round() / 100.0, (b * 1e4).round() / 100.0)),
                source,
                regime.as_str(),
                100.0 * truth_mean,
                view.identification
                    .as_ref()
                    .and_then(|i| i.damping.frequency_hz)
                    .map(|f| (f * 1e4).round() / 1e4),
                view.identification.as_ref().map(|i| {
                    let r = |v: Option<f64>| v.map(|v| (v * 1e4).round() / 1e4);
                    (r(i.damping.growth_rate), r(i.damping.growth_rate_stderr))
                }),
                // a window held back by the ambient pool (its figure is the pool's)
                if view
                    .identification
                    .as_ref()
                    .is_some_and(|i| i.damping.zeta0_held)
                {
                    "  held"
                } else {
                    ""
                },
                // the readings the report did not show: the prediction-error method's (where the
                // window rose) and a rising window's pool (which the trend read)
                view.identification.as_ref().map_or(String::new(), |i| {
                    let mut more = String::new();
                    if let Some(p) = &i.damping.prediction_error_zeta {
                        more += &format!("  prediction errors {:?}", pct(p));
                    }
                    if let Some(p) = &i.damping.pooled_zeta {
                        more += &format!("  pool {:?}", pct(p));
                    }
                    // the window's own interval where the report's reaches down to the trend
                    // (`analysis::reach_down_to_trend`): what the trend and the alert read
                    if let Some((lo, hi)) = i.damping.window_interval {
                        let p = |v: f64| (v * 1e4).round() / 100.0;
                        more += &format!("  own ({}, {})", p(lo), p(hi));
                    }
                    // the window's RMS, in the signal's unit (the scale the trend's replays
                    // compare with the damping: a stable gate's variance goes as 1 / zeta)
                    if let Some(rms) = i.damping.signal_rms {
                        more += &format!("  rms {rms:.5e}");
                    }
                    // how far before the window's end the trend placed its reading (the middle
                    // of the record behind it, `analysis::trend_reading`)
                    let seconds = i.window_end - i.window_start;
                    let lag = crate::analysis::trend_reading(&i.damping, seconds).lag_seconds;
                    more += &format!("  lag {lag:.1}");
                    more
                }),
            );
        }
        windows.push(WindowRecord {
            start,
            end,
            zeta0,
            interval,
            source,
            truth_centre,
            truth_mean,
            frequency_hz,
            record_s: end - start + 1.0 / rate,
            regime,
            firing,
            variance: measured_variance,
        });
        // keep only the chunks a future window can reach: it reads at most the history
        let keep_from = end - history_s - window_s;
        chunks.retain(|c| c.0 >= keep_from);
    }
    let (_abandoned, _clean) = state.pool().shutdown(Duration::from_secs(10)).await;
    state.shutdown_notifier(Duration::from_secs(1)).await;
    let horizon = spec.duration_s.max(def.duration_s);
    Ok(RunRecord {
        spec: spec.clone(),
        window_s,
        t_zero: def.zeta.first_time_at_or_below(0.0, 0.0, horizon, 0.5),
        t_minus_one: def.zeta.first_time_at_or_below(-0.01, 0.0, horizon, 0.5),
        windows,
    })
}

/// Largest `--hours` of one run.
const MAX_HOURS: f64 = 744.0;

/// The runs `args` asks for, in table order.
pub fn plan(args: &BenchWarningArgs) -> anyhow::Result<Vec<RunSpec>> {
    anyhow::ensure!(args.seeds >= 1, "--seeds must be at least 1");
    anyhow::ensure!(
        args.first_seed.checked_add(args.seeds).is_some(),
        "--first-seed {} with --seeds {}: the last seed does not fit in 64 bits",
        args.first_seed,
        args.seeds
    );
    // Every window of a run is kept until the tables are printed (about 200 bytes each): a
    // month of 5 s windows is 0.1 GB per run.
    anyhow::ensure!(
        args.hours > 0.0 && args.hours <= MAX_HOURS,
        "--hours must be > 0 and at most {MAX_HOURS} (a month of sample time per run), got {}",
        crate::number::Num(args.hours)
    );
    anyhow::ensure!(
        args.worker_threads <= crate::service::config::MAX_WORKER_THREADS,
        "--worker-threads must be at most {}, as server.worker_threads, got {}",
        crate::service::config::MAX_WORKER_THREADS,
        args.worker_threads
    );
    anyhow::ensure!(
        args.noise_rel >= 0.0 && args.noise_rel.is_finite(),
        "--noise-rel must be >= 0"
    );
    if let Some(p) = args.fire_at_once_probability {
        anyhow::ensure!(
            p > 0.5 && p <= 1.0,
            "--fire-at-once-probability must be in (0.5, 1]"
        );
    }
    if let Some(r) = args.fire_at_once_min_ratio {
        anyhow::ensure!(
            r >= 1.0 && r.is_finite(),
            "--fire-at-once-min-ratio must be a number >= 1"
        );
    }
    if let Some(p) = args.resolve_probability {
        anyhow::ensure!(
            p > 0.5 && p < 1.0,
            "--resolve-probability must be in (0.5, 1)"
        );
    }
    if let Some(s) = args.trend_min_span_seconds {
        anyhow::ensure!(
            s >= 0.0 && s.is_finite(),
            "--trend-min-span-seconds must be a number >= 0"
        );
    }
    if let Some(a) = args.noise_abs {
        anyhow::ensure!(a >= 0.0 && a.is_finite(), "--noise-abs must be >= 0");
    }
    let scenarios: Vec<ScenarioName> = if args.scenarios.is_empty() {
        ScenarioName::ALL.to_vec()
    } else {
        args.scenarios
            .iter()
            .map(|s| ScenarioName::parse(s).map_err(|e| anyhow::anyhow!("--scenarios: {e}")))
            .collect::<anyhow::Result<_>>()?
    };
    let gates: Vec<GatePreset> = args
        .gates
        .iter()
        .map(|s| GatePreset::parse(s).map_err(|e| anyhow::anyhow!("--gates: {e}")))
        .collect::<anyhow::Result<_>>()?;
    for &gate in &gates {
        configure(args, gate)?;
    }
    let mut out = Vec::new();
    for &scenario in &scenarios {
        for &gate in &gates {
            let p = gate.params();
            let noise = match args.noise_abs {
                Some(a) => NoiseLevel::Absolute(a),
                None => NoiseLevel::Relative(args.noise_rel),
            };
            let duration_s = if matches!(scenario, ScenarioName::Stable | ScenarioName::StableLow) {
                args.hours * 3600.0
            } else {
                scenario.def(&p).duration_s
            };
            for seed in args.first_seed..args.first_seed + args.seeds {
                out.push(RunSpec {
                    scenario,
                    gate,
                    seed,
                    noise_rms: noise.rms(&p),
                    duration_s,
                    trace: args.trace,
                });
            }
        }
    }
    Ok(out)
}

/// The seeds a run streams, as the header prints them: `3` (seeds 1 to 3) or `5..=8`.
fn seed_range(args: &BenchWarningArgs) -> String {
    if args.first_seed == 1 {
        args.seeds.to_string()
    } else {
        let last = args.first_seed.saturating_add(args.seeds.saturating_sub(1));
        format!("{}..={last}", args.first_seed)
    }
}

/// The daemon's configuration for one run on `gate`: the preset's ([`run_config`]) with the
/// overrides `args` asks for, checked as a configuration file's `[gates.*]` table is (the error
/// names the key and the flags).
fn configure(args: &BenchWarningArgs, gate: GatePreset) -> anyhow::Result<Config> {
    let mut config = run_config(gate, args.worker_threads);
    for (name, g) in config.gates.iter_mut() {
        if let Some(m) = args.model_interval {
            g.model_interval = m;
        }
        if let Some(r) = args.ssi_reference {
            g.ssi_reference = r;
        }
        if let Some(t) = args.force_terms {
            g.force_terms = t;
        }
        if let Some(p) = args.fire_at_once_probability {
            g.alert.fire_at_once_probability = p;
        }
        if let Some(r) = args.fire_at_once_min_ratio {
            g.alert.fire_at_once_min_ratio = Some(r);
        }
        if let Some(p) = args.resolve_probability {
            g.alert.resolve_probability = p;
        }
        if let Some(s) = args.trend_min_span_seconds {
            g.alert.trend_min_span_seconds = s;
        }
        if let Some(w) = args.window_seconds {
            g.window_seconds = w;
        }
        if let Some(c) = args.window_cycles {
            g.window_cycles = c;
        }
        if let Some(e) = args.identify_every_seconds {
            g.identify_every_seconds = e;
        }
        if let Some(m) = args.pool_max_seconds {
            g.pooling.max_seconds = m;
        }
        g.validate(&format!("gates.{name}")).map_err(|e| {
            anyhow::anyhow!(
                "{e} (--window-seconds, --window-cycles, --identify-every-seconds, \
                 --pool-max-seconds)"
            )
        })?;
    }
    Ok(config)
}

/// Output of the bench: the regime rows and the alert rows (`--json` prints this; the windows
/// themselves are in `--trace`).
#[derive(Debug, Serialize)]
pub struct Report {
    /// Per scenario, gate and regime.
    pub regimes: Vec<RegimeRow>,
    /// Per scenario and gate: detection delays and false alarms.
    pub alerts: Vec<AlertRow>,
}

async fn bench(args: BenchWarningArgs) -> anyhow::Result<Report> {
    let specs = plan(&args)?;
    let mut records = Vec::new();
    let mut analyzers: Vec<(GatePreset, Arc<dyn WindowAnalyzer>)> = Vec::new();
    for (i, spec) in specs.iter().enumerate() {
        let config = configure(&args, spec.gate)?;
        let analyzer = match analyzers.iter().find(|a| a.0 == spec.gate) {
            Some(a) => a.1.clone(),
            None => {
                let a: Arc<dyn WindowAnalyzer> = Arc::new(AnalyzerMap::from_config(&config)?);
                analyzers.push((spec.gate, a.clone()));
                a
            }
        };
        errln!(
            "[{}/{}] {} on {} gate, seed {}, {:.0} s of sample time",
            i + 1,
            specs.len(),
            spec.scenario.as_str(),
            spec.gate.as_str(),
            spec.seed,
            spec.duration_s
        );
        records.push(run_stream(spec, config, analyzer).await?);
    }
    for r in &mut records {
        score::mark_ews(&mut r.windows, &score::EwsRule::default());
    }
    Ok(Report {
        regimes: regime_rows(&records),
        alerts: alert_rows(&records, &Targets::ISSUE_8),
    })
}

/// `gatewatch bench warning`: exit 0 when every run streamed (whether the targets are met is in
/// the table), 2 on bad arguments, 1 when a run failed.
pub fn bench_warning(args: BenchWarningArgs) -> ExitCode {
    if let Err(e) = plan(&args) {
        errln!("gatewatch bench warning: {e:#}");
        return ExitCode::from(2);
    }
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            errln!("gatewatch bench warning: {e}");
            return ExitCode::FAILURE;
        }
    };
    let json = args.json;
    let header = format!(
        "gatewatch bench warning: seeds {}, gates {}, stable scenarios {} h per seed, noise {}",
        seed_range(&args),
        args.gates.join(","),
        args.hours,
        match args.noise_abs {
            Some(a) => format!("{a} RMS (absolute)"),
            None => format!("{} x the ambient std at +1 %", args.noise_rel),
        }
    );
    match rt.block_on(bench(args)) {
        Ok(report) => {
            let printed = if json {
                serde_json::to_string_pretty(&report)
                    .map_err(anyhow::Error::from)
                    .and_then(|s| Ok(outln!("{s}")?))
            } else {
                let text = format!(
                    "{header}\n\n{}",
                    score::render(&report.regimes, &report.alerts)
                );
                std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes())
                    .map_err(anyhow::Error::from)
            };
            match printed {
                Ok(()) => ExitCode::SUCCESS,
                // a closed stdout (`| head`) ends the run quietly
                Err(e) => super::stdout::exit_code("gatewatch bench warning", &e),
            }
        }
        Err(e) => super::stdout::exit_code("gatewatch bench warning", &e),
    }
}
