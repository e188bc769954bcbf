//! A gate's derived settings and their validation (the checks `serve` and `check-config`
//! share), apart from the configuration types in `config.rs`.

#[allow(unused_imports)]
use super::*;
use crate::number::Num;

impl GateConfig {
    /// Samples in a full window.
    pub fn window_samples(&self) -> usize {
        (self.window_seconds * self.rate_hz).round() as usize
    }

    /// New samples between identifications.
    pub fn every_samples(&self) -> usize {
        ((self.identify_every_seconds * self.rate_hz).round() as usize).max(1)
    }

    /// The longest span of sample time the gate's trend can hold: its horizon, and no more than
    /// [`crate::analysis::MAX_TREND_POINTS`] windows at its cadence.
    pub fn trend_reach_seconds(&self) -> f64 {
        let windows = (crate::analysis::MAX_TREND_POINTS - 1) as f64;
        self.alert
            .trend_horizon_seconds
            .min(windows * self.identify_every_seconds)
    }

    /// Samples gate `id`'s first window (and its first after a gap) waits once full: the ID's
    /// stagger offset below the cadence and below the window (so that a long cadence, an hour,
    /// does not hold back a gate's first report by as much; the first window comes at most two
    /// windows after the start), or 0 with `stagger = false`.
    pub fn stagger_samples(&self, id: &str) -> usize {
        if self.stagger {
            let spread = self.every_samples().min(self.window_samples().max(1));
            crate::service::window::stagger_offset(id, spread)
        } else {
            0
        }
    }

    /// The analysis settings of this gate. The known stiffness is passed as constant `k`.
    pub fn analysis_settings(&self) -> AnalysisSettings {
        let mut params: Vec<(String, f64)> =
            self.params.iter().map(|(k, v)| (k.clone(), *v)).collect();
        if let Some(k) = self.stiffness {
            if !self.params.contains_key("k") {
                params.push(("k".into(), k));
            }
        }
        AnalysisSettings {
            signal: self.signal,
            force_terms: self.force_terms,
            stiffness: self.stiffness,
            model: self.model.clone(),
            params,
            population: self.population,
            generations: self.generations,
            amplitude_limit: self.amplitude_limit,
            max_fit_nmae: self.max_fit_nmae,
            polish_rtol: self.polish_rtol,
            polish_solver: self.polish_solver,
            model_interval: self.model_interval,
            ssi_reference: self.ssi_reference,
        }
    }

    pub(crate) fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        let err = |key: &str, msg: &str| Err(ConfigError::new(format!("{prefix}.{key}: {msg}")));
        // a rule on two settings: named by whichever of the two the file writes
        let pair = |key: &str, other: &str, msg: &str| {
            Err(ConfigError::on_pair(
                &format!("{prefix}.{key}"),
                &format!("{prefix}.{other}"),
                msg,
            ))
        };
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return err("rate_hz", "must be > 0");
        }
        if let Some(k) = self.stiffness {
            if !(k.is_finite() && k > 0.0) {
                return err("stiffness", "must be > 0");
            }
        } else if self.signal == Signal::Force {
            return err("stiffness", "required when signal = \"force\"");
        }
        if self.model.trim().is_empty() {
            return err("model", "must not be empty");
        }
        for (name, v) in &self.params {
            if !v.is_finite() {
                return err(&format!("params.{name}"), "must be a finite number");
            }
        }
        // `k` is the stiffness's name in the equation (`analysis_settings`): a different
        // `params.k` made the equation use it while the force was converted to deflection with
        // `stiffness`, and every coefficient came out scaled, without a word.
        if let (Some(k), Some(v)) = (self.stiffness, self.params.get("k")) {
            if *v != k {
                return err(
                    "params.k",
                    &format!(
                        "{} conflicts with stiffness = {}: `k` in the equation is the \
                         stiffness; set it once, as stiffness",
                        Num(*v),
                        Num(k)
                    ),
                );
            }
        }
        if self.population < 4 {
            return err("population", "must be >= 4");
        }
        // The library's bounds (crate::identify::MAX_POPULATION says why), refused when the
        // configuration is loaded rather than by every window's analysis.
        if self.population > crate::identify::MAX_POPULATION {
            return err(
                "population",
                &format!("must be <= {}", crate::identify::MAX_POPULATION),
            );
        }
        if self.generations == 0 {
            return err("generations", "must be > 0");
        }
        if self.generations > crate::identify::MAX_GENERATIONS {
            return err(
                "generations",
                &format!("must be <= {}", crate::identify::MAX_GENERATIONS),
            );
        }
        if let Some(a) = self.amplitude_limit {
            if !(a.is_finite() && a > 0.0) {
                return err("amplitude_limit", "must be > 0");
            }
        }
        if !(self.max_fit_nmae.is_finite() && self.max_fit_nmae > 0.0) {
            return err("max_fit_nmae", "must be > 0");
        }
        if !(crate::identify::MIN_TOLERANCE..1.0).contains(&self.polish_rtol) {
            return err(
                "polish_rtol",
                "must be in [1e-14, 1) (identify::MIN_TOLERANCE)",
            );
        }
        if !(self.window_seconds.is_finite() && self.window_seconds > 0.0) {
            return err("window_seconds", "must be > 0");
        }
        let product = format!(
            "({} s * {} Hz)",
            Num(self.window_seconds),
            Num(self.rate_hz)
        );
        if self.window_samples() < 16 {
            return pair(
                "window_seconds",
                "rate_hz",
                &format!("window_seconds * rate_hz must be >= 16 samples {product}"),
            );
        }
        if self.window_samples() > MAX_WINDOW_SAMPLES {
            return pair(
                "window_seconds",
                "rate_hz",
                &format!(
                    "window_seconds * rate_hz must be <= {MAX_WINDOW_SAMPLES} samples {product}"
                ),
            );
        }
        // fewer than the ambient estimator reads at all would lengthen the window to no use
        let min_cycles = crate::analysis::MIN_WINDOW_CYCLES;
        if !(self.window_cycles.is_finite()
            && (self.window_cycles == 0.0
                || (min_cycles..=MAX_WINDOW_CYCLES).contains(&self.window_cycles)))
        {
            return err(
                "window_cycles",
                &format!("must be 0 (off) or in {min_cycles}..={MAX_WINDOW_CYCLES}"),
            );
        }
        if !(self.identify_every_seconds.is_finite() && self.identify_every_seconds > 0.0) {
            return err("identify_every_seconds", "must be > 0");
        }
        for (key, v) in [
            ("max_future_seconds", self.max_future_seconds),
            ("max_past_seconds", self.max_past_seconds),
        ] {
            if !(v.is_finite() && (0.0..=MAX_SECONDS).contains(&v)) {
                return err(key, &format!("must be in 0..={MAX_SECONDS} (0: no bound)"));
            }
        }
        for (key, v) in [
            ("window_seconds", self.window_seconds),
            ("identify_every_seconds", self.identify_every_seconds),
            ("alert.stale_after_seconds", self.alert.stale_after_seconds),
        ] {
            if v > MAX_SECONDS {
                return err(key, &format!("must be <= {MAX_SECONDS} (one year)"));
            }
        }
        let a = &self.alert;
        if !a.fire_below.is_finite() {
            return err("alert.fire_below", "must be a finite number");
        }
        if !a.clear_above.is_finite() {
            return err("alert.clear_above", "must be a finite number");
        }
        if a.clear_above < a.fire_below {
            return pair(
                "alert.clear_above",
                "alert.fire_below",
                &format!(
                    "alert.clear_above ({}) must be >= alert.fire_below ({})",
                    Num(a.clear_above),
                    Num(a.fire_below)
                ),
            );
        }
        if a.for_windows == 0 {
            return err("alert.for_windows", "must be >= 1");
        }
        if a.resolve_windows == 0 {
            return err("alert.resolve_windows", "must be >= 1");
        }
        if !(a.stale_after_seconds.is_finite() && a.stale_after_seconds > 0.0) {
            return err("alert.stale_after_seconds", "must be > 0");
        }
        if let Err(e) = self.tracking.validate() {
            let (key, msg) = e.split_once(": ").unwrap_or((&e, "invalid"));
            return err(&format!("tracking.{key}"), msg);
        }
        if let Err(e) = self.pooling.pools() {
            let (key, msg) = e.split_once(": ").unwrap_or((&e, "invalid"));
            return err(&format!("pooling.{key}"), msg);
        }
        // the model is compiled here as `serve` compiles it, so `check-config` refuses what
        // `serve` would refuse (a model that does not parse, has no `ydd` or no unknowns)
        if let Err(e) = Analyzer::new(self.analysis_settings()) {
            // A param the model language refuses whatever the equation (its name: `yd`, `c1`,
            // `a b`) is the fault of its own key, `params.NAME`: it was reported as `model`,
            // at the line of the table's header, and the user looked for the fault in the
            // equation.
            if let Some((name, msg)) = self
                .params
                .iter()
                .find_map(|(name, v)| param_fault(name, *v).map(|m| (name, m)))
            {
                return err(&format!("params.{name}"), &msg);
            }
            let msg = match e {
                AnalysisError::Settings(m) => m,
                other => other.to_string(),
            };
            let msg = msg.strip_prefix("model: ").unwrap_or(&msg).to_string();
            return err("model", &msg);
        }
        if let Some(p) = a.fire_probability {
            if !(p > 0.0 && p < 1.0) {
                return err("alert.fire_probability", "must be in (0, 1)");
            }
        }
        let p = a.fire_at_once_probability;
        if !(p > 0.5 && p <= 1.0) {
            return err("alert.fire_at_once_probability", "must be in (0.5, 1]");
        }
        if let Some(r) = a.fire_at_once_min_ratio {
            if !(r.is_finite() && r >= 1.0) {
                return err("alert.fire_at_once_min_ratio", "must be a number >= 1");
            }
        }
        let p = a.resolve_probability;
        if !(p > 0.5 && p < 1.0) {
            return err("alert.resolve_probability", "must be in (0.5, 1)");
        }
        for (key, v) in [
            ("alert.trend_horizon_seconds", a.trend_horizon_seconds),
            ("alert.warn_lead_seconds", a.warn_lead_seconds),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= MAX_SECONDS) {
                return err(key, &format!("must be > 0 and <= {MAX_SECONDS} (one year)"));
            }
        }
        if !(a.trend_min_span_seconds.is_finite() && a.trend_min_span_seconds >= 0.0) {
            return err("alert.trend_min_span_seconds", "must be >= 0");
        }
        // The trend spans at most its horizon, and at most MAX_TREND_POINTS windows: a longer
        // minimum span was accepted and GateDampingDeclining could never fire.
        let reach = self.trend_reach_seconds();
        if a.trend_min_span_seconds > reach {
            let other = if a.trend_min_span_seconds > a.trend_horizon_seconds {
                "alert.trend_horizon_seconds"
            } else {
                "identify_every_seconds"
            };
            return pair(
                "alert.trend_min_span_seconds",
                other,
                &format!(
                    "alert.trend_min_span_seconds ({} s) is longer than the trend can span ({} s: \
                     alert.trend_horizon_seconds, and at most {} windows of \
                     identify_every_seconds), so GateDampingDeclining could never fire",
                    Num(a.trend_min_span_seconds),
                    Num(reach),
                    crate::analysis::MAX_TREND_POINTS
                ),
            );
        }
        if a.warn_for_windows == 0 {
            return err("alert.warn_for_windows", "must be >= 1");
        }
        if a.warn_resolve_windows == 0 {
            return err("alert.warn_resolve_windows", "must be >= 1");
        }
        // an empty label value is no label to Alertmanager: routes on `severity` miss the alert
        if a.severity.trim().is_empty() {
            return err("alert.severity", "must not be empty");
        }
        if a.warn_severity.trim().is_empty() {
            return err("alert.warn_severity", "must not be empty");
        }
        Ok(())
    }
}

/// An equation every param may stand beside: it uses only names no param can take (`y`, `ydd`,
/// `c1`), and a param the equation does not use is no fault, so it compiles with any param the
/// model language accepts.
const PARAM_PROBE_EQUATION: &str = "ydd + c1*y = 0";

/// Why the model language refuses the param `name = value` whatever the equation, if it does.
/// The model checks its params before it reads the equation (`Model::parse`), so a param
/// refused beside [`PARAM_PROBE_EQUATION`] is refused beside any equation, with the same
/// message; the rule itself stays in the model, in one place.
fn param_fault(name: &str, value: f64) -> Option<String> {
    crate::model::Model::parse(PARAM_PROBE_EQUATION, &[(name.to_string(), value)])
        .err()
        .map(|e| e.message)
}
