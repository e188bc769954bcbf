//! What the API shows of a gate: its view, its summary in the list, its window and its last
//! identification.

#[allow(unused_imports)]
use super::*;

/// A gate as `GET /api/v1/gates/{id}` shows it.
#[derive(Debug, Clone, Serialize)]
pub struct GateView {
    /// Gate id.
    pub gate: String,
    /// Displayed alert state (`ok`, `pending`, `firing`, `resolved`, `unknown`); may be
    /// `unknown` while `GateNegativeDamping` still fires (see `firing`).
    pub alert_state: &'static str,
    /// Whether `GateNegativeDamping` is firing for this gate (the truth, whatever the display).
    pub firing: bool,
    /// The gate's firing alerts (`GateNegativeDamping`, `GateDataStale`, `GateDampingDeclining`).
    pub alerts: Vec<Alert>,
    /// Window statistics.
    pub window: WindowView,
    /// Latest identification (absent before the first).
    pub identification: Option<IdentificationView>,
    /// Message of the last failed identification, if the last one failed.
    pub last_error: Option<String>,
    /// Sample time (Unix s) of the last sample of the last window whose identification
    /// finished, successfully or not (absent before the first).
    pub analysed_until: Option<f64>,
    /// Trend of `zeta0` over the recent windows with an interval: slope per second, predicted
    /// crossing of `fire_below` (absent until enough windows).
    pub trend: Option<TrendEstimate>,
}

/// A gate as `GET /api/v1/gates` lists it: a few fixed-size fields, so a page costs the same
/// whatever the gate's alerts and identification hold (the full view is
/// `GET /api/v1/gates/{id}`).
#[derive(Debug, Clone, Serialize)]
pub struct GateSummary {
    /// Gate id.
    pub gate: String,
    /// Displayed alert state, as in [`GateView`].
    pub alert_state: &'static str,
    /// Whether `GateNegativeDamping` is firing.
    pub firing: bool,
    /// Whether `GateDataStale` is firing.
    pub stale: bool,
    /// Samples in the window.
    pub samples: usize,
    /// Time of the newest sample, Unix seconds.
    pub last_sample_time: Option<f64>,
    /// Damping ratio of the latest identification: the gate's damping only when `trusted`.
    pub zeta0: Option<f64>,
    /// Whether the latest identification's `zeta0` may be read as the gate's damping: its
    /// `identification.damping.trusted` in [`GateView`] (null before the first
    /// identification, as `zeta0`). An untrusted window still has a `zeta0`, e.g. a chance limit cycle's
    /// envelope, which listed alone read as the gate's damping.
    pub trusted: Option<bool>,
}

/// Window statistics.
#[derive(Debug, Clone, Serialize)]
pub struct WindowView {
    /// Samples held.
    pub samples: usize,
    /// Capacity.
    pub capacity: usize,
    /// Seconds spanned.
    pub span_seconds: f64,
    /// Held fraction.
    pub fill: f64,
    /// Time of the newest sample, Unix seconds.
    pub last_sample_time: Option<f64>,
    /// Samples accepted ever.
    pub samples_total: u64,
    /// Configured rate.
    pub rate_hz: f64,
    /// Seconds the gate's first window (and its first after a gap) waits once full: its
    /// stagger (`service::window`), 0 with `stagger = false`.
    pub stagger_seconds: f64,
    /// Seconds of sample time an identification reads now: `window_seconds`, or longer where
    /// that holds fewer than `window_cycles` cycles of the gate (`service::window_span`).
    pub identification_seconds: f64,
}

/// The latest identification.
#[derive(Debug, Clone, Serialize)]
pub struct IdentificationView {
    /// Time of the identification, Unix seconds (wall clock).
    pub time: f64,
    /// Sample time of the window's first sample, Unix seconds.
    pub window_start: f64,
    /// Sample time of the window's last sample, Unix seconds.
    pub window_end: f64,
    /// Equation with numbers.
    pub equation: String,
    /// Coefficients.
    pub coefficients: BTreeMap<String, f64>,
    /// Damping figures.
    pub damping: crate::analysis::DampingReport,
    /// Wall time, seconds.
    pub seconds: f64,
    /// How the window was identified: "tracked" (the previous model refined) or "full".
    pub path: crate::analysis::Path,
}
