//! The model-free analysis of a window (no equation): the pre-processing, the spectrum's peak
//! and growth, and on a limit-cycle window its steadiness and the envelope's relaxation (or its
//! drift), both read from a record of `RELAXATION_CYCLES` cycles of the gate's history.
//! [`super::series`] runs it before the identification, whose initial population and verdict
//! use what it found.

use super::report::AmbientZeta;
use super::series::SeriesOptions;
use super::Signal;
use crate::data::TimeSeries;
use crate::identify;
use crate::spectral::{
    AmbientMethod, Regime, SpectralAnalyzer, SsiOptions, WindowOptions, WindowSpectral,
};
use std::f64::consts::PI;

/// The dominant frequency must have at least this many periods in the window (the spectral
/// floor is `MIN_PERIODS / duration`). Value: below three periods a drift or an edge effect
/// fills the lowest bins, and the Hilbert envelope (whose edges are discarded) has nothing left.
pub const MIN_PERIODS: f64 = 3.0;

/// The envelope growth constrains the biased population only when it is a clean exponential:
/// its standard error below this fraction of `|sigma|` (plus [`CLEAN_GROWTH_FLOOR`]). Value: a
/// 10 % error in sigma is a 10 % error in the damping the projection imposes, which the DE
/// corrects cheaply; a noisier slope would pull half the population to a wrong damping.
pub const CLEAN_GROWTH_RELATIVE_ERROR: f64 = 0.1;

/// Absolute floor of the clean-growth test, 1/s: lets an exactly exponential (noise-free)
/// envelope with `sigma` near zero pass. Value: far below any physical growth rate.
pub const CLEAN_GROWTH_FLOOR: f64 = 1e-9;

/// Pre-processing: force signals lose their centred moving average (drift), when the series is
/// uniformly sampled and the average is shorter than the series.
pub(super) fn preprocess(series: &TimeSeries, opts: &SeriesOptions) -> TimeSeries {
    let mut data = series.clone();
    if let Some(w) = moving_average_window(series, opts) {
        crate::spectral::remove_moving_average(&series.y, w, &mut data.y);
    }
    data
}

/// The samples of the centred moving average [`preprocess`] removes (odd), when it removes one.
pub(super) fn moving_average_window(series: &TimeSeries, opts: &SeriesOptions) -> Option<usize> {
    if opts.signal != Signal::Force || opts.moving_average_seconds <= 0.0 {
        return None;
    }
    moving_average_samples(
        series.uniform_step()?,
        series.len(),
        opts.moving_average_seconds,
    )
}

/// The samples (odd) of a centred moving average of `seconds` over a record of `len` samples
/// every `step` seconds, when it has one: more than one sample and fewer than the record
/// (`None` otherwise, and the drift is not removed).
pub fn moving_average_samples(step: f64, len: usize, seconds: f64) -> Option<usize> {
    let span = (seconds / step).round();
    if !(span.is_finite() && span >= 0.0 && span < len as f64) {
        return None;
    }
    let w = (span as usize) | 1;
    (w > 1 && w < len).then_some(w)
}

/// What the model-free analysis of the (pre-processed) window found.
pub(super) struct ModelFree {
    /// The options the window was analysed with (the prediction is analysed the same way).
    pub(super) window_options: WindowOptions,
    /// The full analysis (uniform sampling and a long enough record only).
    pub(super) spec: Option<WindowSpectral>,
    /// Measured dominant angular frequency, rad/s.
    pub(super) omega: Option<f64>,
    /// Envelope growth rate when it is a clean exponential, 1/s.
    pub(super) sigma_clean: Option<f64>,
    /// `zeta0` from the envelope's relaxation, on a limit-cycle window.
    pub(super) relaxation: Option<AmbientZeta>,
    /// `zeta0` from the envelope's drift over the window, on a limit-cycle window the relaxation
    /// refused or whose envelope fell ([`super::verdict::falls`]).
    pub(super) drift: Option<AmbientZeta>,
    /// Seconds of record behind `relaxation` or `drift`: the relaxation's record (the gate's
    /// history, or the window) or the window's for the drift.
    pub(super) envelope_record_seconds: Option<f64>,
    /// The ambient SSI-COV reading of the window with its history ([`ambient_record`]) and the
    /// seconds of record it read, first sample to last.
    pub(super) ambient_record: Option<(AmbientZeta, f64)>,
}

/// The model-free analysis (uniform sampling only), with the analyzer replaced when it does not
/// fit the window's length and rate.
pub(super) fn model_free(
    data: &TimeSeries,
    history: &[f64],
    opts: &SeriesOptions,
    spectral: &mut Option<SpectralAnalyzer>,
) -> ModelFree {
    let n = data.len();
    let fs = data.uniform_step().map(|h| 1.0 / h);
    let duration = data.t[n - 1] - data.t[0];
    let window_options = WindowOptions {
        moving_average: 0,
        min_freq_hz: MIN_PERIODS / duration.max(f64::MIN_POSITIVE),
        ambient: AmbientMethod::Ssi(SsiOptions {
            common_reference: opts.ssi_reference == super::SsiReference::Common,
            ..SsiOptions::default()
        }),
        ..WindowOptions::default()
    };
    let fits = |sa: &SpectralAnalyzer| {
        fs.is_some_and(|fs| sa.len() == n && (sa.rate_hz() - fs).abs() <= 1e-9 * fs)
    };
    if !spectral.as_ref().is_some_and(fits) {
        *spectral = fs.and_then(|fs| SpectralAnalyzer::new(n, fs).ok());
    }
    let spec = spectral
        .as_mut()
        .and_then(|sa| sa.analyze_window(&data.y, &window_options).ok())
        .map(|s| match fs {
            Some(fs) => steady_over_cycles(s, history, fs, n, &window_options, opts),
            None => s,
        });
    // A short record (a few periods) cannot give an envelope growth, but its dominant frequency
    // still constrains the search.
    let peak_hz = spec.as_ref().map(|s| s.peak.frequency_hz).or_else(|| {
        let mut detrended = data.y.clone();
        crate::spectral::detrend_linear(&mut detrended);
        spectral
            .as_mut()
            .and_then(|sa| {
                sa.dominant_frequency(&detrended, window_options.min_freq_hz)
                    .ok()
            })
            .map(|p| p.frequency_hz)
    });
    let sigma_clean = spec.as_ref().and_then(|s| {
        let g = &s.growth;
        (g.stderr < CLEAN_GROWTH_RELATIVE_ERROR * g.sigma.abs() + CLEAN_GROWTH_FLOOR)
            .then_some(g.sigma)
    });
    // On a limit cycle the equivalent damping is zero; the envelope's relaxation still sees
    // zeta0 (docs/damping.md, "The limit cycle"), and where the window is not on a saturated
    // cycle (the end of a growth, a shrinking cycle: the relaxation refuses it) the envelope's
    // drift across the amplitudes it visits does. The same pre-processing as the window's.
    // a record's seconds from its first sample to its last, as a window's span is counted
    let span = |len: usize, fs: f64| len.saturating_sub(1) as f64 / fs;
    let window_seconds = fs.map(|fs| span(n, fs));
    let (relaxation, drift, envelope_record_seconds) = match (&spec, spectral.as_mut()) {
        (Some(s), Some(sa)) if s.regime == crate::spectral::Regime::LimitCycle => {
            let mut work = data.y.clone();
            crate::spectral::detrend_linear(&mut work);
            let f = s.peak.frequency_hz;
            let relax = crate::spectral::RelaxationOptions {
                detrend_max_degree: relaxation_detrend_degree(history, n),
                ..crate::spectral::RelaxationOptions::default()
            };
            let (relaxation, record_seconds) =
                match fs.and_then(|fs| relaxation_record(history, fs, f, n, opts)) {
                    Some((record, fs)) => (
                        SpectralAnalyzer::new(record.len(), fs)
                            .and_then(|mut long| long.envelope_relaxation(&record, f, &relax)),
                        Some(span(record.len(), fs)),
                    ),
                    None => (sa.envelope_relaxation(&work, f, &relax), window_seconds),
                };
            let drift_opts = crate::spectral::DriftOptions::default();
            let mut drift = || {
                sa.envelope_drift(&work, f, relax.band, &drift_opts)
                    .ok()
                    .as_ref()
                    .map(AmbientZeta::from)
            };
            match relaxation {
                // a cycle whose envelope fell is no saturated cycle, which the relaxation
                // assumes: the drift over the window is read as well, and where no held cycle
                // reads the fall (`CycleAmplitude::read_fall`) the reported interval spans it
                // (`span_the_fall`)
                Ok(r) if super::verdict::falls(s.growth.sigma, s.growth.stderr) => {
                    (Some(AmbientZeta::from(&r)), drift(), record_seconds)
                }
                Ok(r) => (Some(AmbientZeta::from(&r)), None, record_seconds),
                Err(_) => {
                    let d = drift();
                    (None, d, d.and(window_seconds))
                }
            }
        }
        _ => (None, None, None),
    };
    let ambient_record = match (&spec, fs) {
        (Some(s), Some(fs)) if s.ambient.is_some() => {
            ambient_record(history, fs, s.peak.frequency_hz, n, &window_options, opts)
                .map(|(a, len)| (a, span(len, fs)))
        }
        _ => None,
    };
    ModelFree {
        window_options,
        spec,
        ambient_record,
        omega: peak_hz.map(|f| 2.0 * PI * f),
        sigma_clean,
        relaxation,
        drift,
        envelope_record_seconds,
    }
}

/// Cycles over which a limit cycle's envelope must be steady (the classifier's
/// `max_limit_cycle_cv`) for a window to keep the class: `RELAXATION_CYCLES` (100), the record its
/// `zeta0` is then read from.
///
/// Why in cycles: the test tells a cycle's steady envelope from a noise-driven response's, whose
/// envelope has Rayleigh's CV of 0.52 only over a record much longer than its correlation time
/// `1 / (zeta w)`, which is `1 / (2 pi zeta)` cycles: 32 cycles at +0.5 %. A 10 s window holds
/// 100 of the lab gate's cycles (3 correlation times) but 50 of a 5 Hz lock gate's (1.6), and
/// over so few the envelope of a stable gate often looks steady. On one 2.3 h stream of each at
/// +0.5 % (seed 24), 0.7 % of the lab gate's windows and 4.8 % of the lock gate's were classed
/// limit cycles, each read negative by the envelope's relaxation (it cannot read anything else);
/// two of the lock gate's in a row paged (docs/alerts.md, "A steady stretch of a stable gate
/// read as a cycle").
pub const LIMIT_CYCLE_CYCLES: f64 = RELAXATION_CYCLES;

/// `spec` with a limit-cycle window of fewer than [`LIMIT_CYCLE_CYCLES`] cycles demoted to
/// `Undecided` when the envelope over the last `LIMIT_CYCLE_CYCLES` cycles of `history` (as many
/// of them as it holds; pre-processed and detrended as the window is) is not steady. The
/// window's own growth and SSI reading stand; only the envelope's CV is read over the longer
/// record (about its fitted exponential, as the window's is, so a steady growth into the cycle
/// still passes). Without history beyond the window the window's class stands. The daemon keeps
/// six windows (`service::window::HISTORY_WINDOWS`): 60 s, so 100 cycles of any gate from
/// 1.67 Hz up (a 2 Hz gate's 10 s window holds 20).
fn steady_over_cycles(
    mut spec: WindowSpectral,
    history: &[f64],
    fs: f64,
    n: usize,
    window: &WindowOptions,
    opts: &SeriesOptions,
) -> WindowSpectral {
    let f = spec.peak.frequency_hz;
    if spec.regime != Regime::LimitCycle || f.is_nan() || f <= 0.0 {
        return spec;
    }
    let len = record_len(history, fs, f, LIMIT_CYCLE_CYCLES);
    let Some(work) = history_record(history, fs, len, n, opts) else {
        return spec;
    };
    let cv = SpectralAnalyzer::new(work.len(), fs)
        .and_then(|mut long| long.growth_rate(&work, f, &window.growth))
        .map(|g| g.envelope_cv);
    if cv.is_ok_and(|cv| cv.is_nan() || cv >= window.classify.max_limit_cycle_cv) {
        // what `spectral::classify` says without the limit-cycle row: a window classed a cycle
        // has an SSI point below `max_limit_cycle_zeta`, so its interval never lies above
        // `min_damped_zeta`
        spec.regime = Regime::Undecided;
    }
    spec
}

/// Largest over smallest standard deviation of the three thirds of `y` (`None` with fewer than
/// 6 samples or a constant third): how abruptly the response changed inside the window.
/// Measured (`docs/damping.md`, "A window that holds two states"): on noise-driven windows of both
/// bench gates a median of 1.5 to 1.65 and at most 6.6; at most 1.07 on a held limit cycle; 3.9
/// to 18.6 on the windows a burst begins or ends in.
pub fn rms_swing(y: &[f64]) -> Option<f64> {
    let third = y.len() / 3;
    if third < 2 {
        return None;
    }
    let sd: Vec<f64> = y
        .chunks_exact(third)
        .take(3)
        .map(identify::std_dev)
        .collect();
    let (lo, hi) = sd.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| {
        (lo.min(v), hi.max(v))
    });
    (lo > 0.0 && hi.is_finite()).then(|| hi / lo)
}

/// Change of the RMS level between the window and the record before it beyond which the
/// envelope relaxation may remove a bend (a polynomial up to [`BEND_DEGREE`]), not only a line.
/// Why 1.2: the cycle's amplitude follows `sqrt(-zeta0)`, so a level a fifth higher means a
/// damping that moved by about 44 % in 10 s, the onset's ramp (20 to 40 % a window); a held
/// cycle at -2 % moves its 10 s level by a few percent. A weak one (-0.5 %) wanders by tens of
/// percent, and there the bend is removed too often: measured in docs/damping.md ("A cycle that
/// bends"), 1.1 cost that cycle's pooled coverage 10 points, 1.2 two.
pub const BEND_LEVEL_CHANGE: f64 = 1.2;

/// Highest polynomial degree the relaxation removes where the level moved (a cubic: the rise
/// and the levelling-off of the window an onset's ramp ends in; docs/damping.md).
pub const BEND_DEGREE: usize = 3;

/// The relaxation's `detrend_max_degree` for the window that ends `history` (`n` samples):
/// [`BEND_DEGREE`] when the standard deviation of the window and of the `n` samples before it
/// differ by more than [`BEND_LEVEL_CHANGE`], else 1 (a line at most). Without `2 n` samples
/// of history nothing says the level moved: 1.
pub fn relaxation_detrend_degree(history: &[f64], n: usize) -> usize {
    let len = history.len();
    if n < 2 || len < 2 * n {
        return 1;
    }
    let before = identify::std_dev(&history[len - 2 * n..len - n]);
    let now = identify::std_dev(&history[len - n..]);
    let ratio = now / before;
    let moved = ratio.is_finite()
        && ratio > 0.0
        && !(1.0 / BEND_LEVEL_CHANGE..=BEND_LEVEL_CHANGE).contains(&ratio);
    if moved {
        BEND_DEGREE
    } else {
        1
    }
}

/// Cycles of a limit cycle that the envelope relaxation reads when the gate's history holds
/// them. Why: its error is set by the record's length in cycles, not seconds; a 5 Hz gate's
/// 10 s window (50 cycles) read -1 % as -1.6 %, and the same gate with 104 cycles as -1.2 %,
/// like the 10.4 Hz lab gate's 10 s window (docs/benchmarks.md, "The limit cycle across
/// zeta0"). 100 cycles are 10 s at 10 Hz, 20 s at 5 Hz, 50 s at 2 Hz.
pub const RELAXATION_CYCLES: f64 = 100.0;

/// The record the relaxation reads: the last `RELAXATION_CYCLES` cycles of `history` (as much as
/// it holds), pre-processed and detrended as the window is, or the longest tail of them over
/// which the cycle's level held (below); `None` when that is no longer than the window's `n`
/// samples (then the window itself is read).
///
/// The relaxation assumes a stationary cycle, so a record whose level differs from the
/// window's (the end of a growth, a ramp of the damping) is not read whole. Its part before the
/// window is read in blocks of one window, from the window back (the oldest block takes the
/// remainder): the record ends at the first block whose RMS differs from the window's by more
/// than [`MAX_HISTORY_LEVEL_CHANGE`]. Why blocks: where the record is at most one window longer
/// than the window (a 5 Hz gate's 20 s) this is the one test of the record before the window,
/// as until stop 83; on a 2 Hz gate (50 s, four windows before the one read) one test of the
/// mean over 40 s let in the growth into an onset's cycle: its windows read 0.54 points off at
/// 76 % coverage, and 0.33 at 89 % with the blocks (docs/damping.md, "On a slow gate, 100
/// cycles of history").
pub(super) fn relaxation_record(
    history: &[f64],
    fs: f64,
    frequency_hz: f64,
    n: usize,
    opts: &SeriesOptions,
) -> Option<(Vec<f64>, f64)> {
    let len = record_len(history, fs, frequency_hz, RELAXATION_CYCLES);
    held_record(history, fs, len, n, MAX_HISTORY_LEVEL_CHANGE, opts)
}

/// The last `len` samples of `history` ([`history_record`]), or the longest tail of them whose
/// blocks before the window (one window each, from the window back; the oldest takes the
/// remainder) all keep their RMS within a factor `max_change` of the window's; `None` when that
/// is no longer than the window's `n` samples.
fn held_record(
    history: &[f64],
    fs: f64,
    len: usize,
    n: usize,
    max_change: f64,
    opts: &SeriesOptions,
) -> Option<(Vec<f64>, f64)> {
    let work = history_record(history, fs, len, n, opts)?;
    let len = work.len();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let level = rms(&work[len - n..]);
    let held = |block: &[f64]| {
        let ratio = rms(block) / level;
        ratio.is_finite() && (1.0 / max_change..=max_change).contains(&ratio)
    };
    // the blocks before the window, newest first: whole windows, the oldest with the remainder
    let before = len - n;
    let blocks = (before / n).max(1);
    let mut kept = 0;
    for k in 1..=blocks {
        let start = if k == blocks { 0 } else { before - k * n };
        if !held(&work[start..before - (k - 1) * n]) {
            break;
        }
        kept = k;
    }
    match kept {
        0 => None,
        k if k == blocks => Some((work, fs)),
        k => Some((history_record(history, fs, (k + 1) * n, n, opts)?, fs)),
    }
}

/// Cycles of a noise-driven gate's response that its ambient SSI-COV reading reads where the
/// window holds fewer (`DampingReport::ambient_record_zeta`), the same 100 as the envelope's
/// relaxation: 20 s of a 5 Hz gate, 50 s of a 2 Hz gate, a 10 Hz gate's window alone.
///
/// Why: what limits the reading is its cycles (Au's law), and one 10 s window of a 2 Hz gate
/// (20 cycles) scatters about 1.5 times as far as Au's limit. The pool of nine to eleven such
/// windows over 60 s scattered about as little as a pool of two or three 100-cycle readings over
/// the same 60 s (0.47 and 0.53 points at +1 %), but it could not know it: it builds its
/// interval from the windows' own, each floored at Au's law and read from four jackknife
/// blocks, and claimed 2.8 points of width where the readings' pool claims 1.9, covering the
/// truth in 100 % of the runs against 95 % (`tests/ambient_pooling.rs`; docs/damping.md, "One
/// ambient reading of 100 cycles"). A reading of the longer record gets its interval from its
/// own blocks.
pub const AMBIENT_RECORD_CYCLES: f64 = RELAXATION_CYCLES;

/// Largest ratio of a block's RMS to the window's for the ambient record to read it (blocks of
/// one window, from the window back, as [`relaxation_record`]). Why 2 and not the cycle's 1.25:
/// a noise-driven response's 10 s RMS scatters widely by chance (its envelope's correlation
/// time is `1 / (2 pi zeta)` cycles, 16 at +1 %, near a 2 Hz gate's whole window), and at 1.5
/// the unit test's steady 2 Hz stream at +1 % already stopped at the first block. Twice the
/// RMS is four times the variance, which under the same forcing is a quarter of the damping:
/// another state.
/// A burst, a limit cycle or its early decay stands 3 to 17 times above the ambient response,
/// and the pool reads a window that rose towards its gate's departure ratio alone whatever its
/// record (`analysis::rising`).
const MAX_AMBIENT_LEVEL_CHANGE: f64 = 2.0;

/// The SSI-COV reading (the window's options: lagged or common instants, the peak `frequency_hz`)
/// of the last [`AMBIENT_RECORD_CYCLES`] cycles of `history` back to where the level moved by
/// more than [`MAX_AMBIENT_LEVEL_CHANGE`], pre-processed as the window is, with the record's
/// samples; `None` where that record is no longer than the window's `n` samples (a gate whose
/// window holds 100 cycles, the first window of a stream) or SSI-COV found no mode in it.
fn ambient_record(
    history: &[f64],
    fs: f64,
    frequency_hz: f64,
    n: usize,
    window: &WindowOptions,
    opts: &SeriesOptions,
) -> Option<(AmbientZeta, usize)> {
    let AmbientMethod::Ssi(ssi) = window.ambient else {
        return None;
    };
    if !(frequency_hz.is_finite() && frequency_hz > 0.0) {
        return None;
    }
    let len = record_len(history, fs, frequency_hz, AMBIENT_RECORD_CYCLES);
    let (record, _) = held_record(history, fs, len, n, MAX_AMBIENT_LEVEL_CHANGE, opts)?;
    let e = crate::spectral::ssi_cov_damping(&record, fs, frequency_hz, &ssi).ok()?;
    let a = AmbientZeta::from(&crate::spectral::AmbientDamping::from(e));
    Some((a, record.len()))
}

/// Samples in the last `cycles` cycles at `frequency_hz` of `history` sampled at `fs`, at most
/// the history's length.
fn record_len(history: &[f64], fs: f64, frequency_hz: f64, cycles: f64) -> usize {
    ((cycles * fs / frequency_hz).ceil() as usize).min(history.len())
}

/// The last `len` samples of `history` (at most all of it) sampled at `fs`, pre-processed and
/// detrended as the window is; `None` when that is not longer than the window's `n` samples or
/// the history holds a non-finite sample. What the steadiness test and the relaxation read.
fn history_record(
    history: &[f64],
    fs: f64,
    len: usize,
    n: usize,
    opts: &SeriesOptions,
) -> Option<Vec<f64>> {
    let len = len.min(history.len());
    if len <= n || !history.iter().all(|v| v.is_finite()) {
        return None;
    }
    let raw = &history[history.len() - len..];
    let series = TimeSeries::new((0..len).map(|i| i as f64 / fs).collect(), raw.to_vec()).ok()?;
    let mut work = preprocess(&series, opts).y;
    crate::spectral::detrend_linear(&mut work);
    Some(work)
}

/// Largest ratio of the RMS level of the history before the window to the window's for the
/// relaxation to read the history. Why 1.25: a held cycle's 5 s level moves by a few percent
/// (envelope CV 0.1 to 0.3 over about ten correlation times), while on the onset ramp the cycle
/// grows by about 30 % in the 10 s the history adds on a 5 Hz gate (the amplitude follows
/// `sqrt(-zeta0)`), and that lag cost the ramp's limit-cycle windows their coverage.
const MAX_HISTORY_LEVEL_CHANGE: f64 = 1.25;
