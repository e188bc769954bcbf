//! Synthetic gate signals: a noise-driven single-degree-of-freedom gate whose damping follows a
//! scenario, and the chapter's worked example (section 8.5, equation 8.8).
//!
//! The gate model is
//!
//! ```text
//! m*ydd + c(t)*yd + c3*yd^3 + k*y = f(t),      c(t) = 2*zeta(t)*sqrt(k*m)
//! ```
//!
//! * `zeta(t)` follows a [`ZetaSchedule`]: constant, a linear ramp, a piecewise-linear table or an
//!   arbitrary closure. A negative `zeta` means self-excitation (negative damping).
//! * `c3 > 0` is a cubic velocity damping: negligible at ambient amplitudes, it makes a
//!   self-excited growth saturate into a limit cycle whose displacement amplitude is, by harmonic
//!   balance, `Y = sqrt(-4*c/(3*c3*omega^2))` (see [`GateParams::limit_cycle_force_amplitude`]).
//! * `f(t)` is turbulent forcing: one independent Gaussian value `N(0, forcing_std^2)` per output
//!   sample, **linearly interpolated** between samples. This keeps the force continuous (so RK4
//!   sees a smooth right-hand side within a sample and converges at its design order), and makes
//!   the forcing band-limited to roughly the sample rate: its power spectral density is flat to
//!   within a few percent below `rate_hz/10`, then falls off as `sinc^4`. At low frequency the
//!   equivalent two-sided force PSD is `forcing_std^2 / rate_hz / (2 pi)` per rad/s, so the
//!   stationary force response of a linear gate has standard deviation
//!   `forcing_std * sqrt(k / (2 c rate_hz))` (about 2.9 N for the defaults at `zeta = 1 %`).
//!
//! Integration is a fixed-step classical RK4 with `substeps` steps per output sample. The
//! simulator is a stream: [`GateSimulator::next_sample`] / [`GateSimulator::fill`] produce samples
//! one at a time with no allocation, so a daemon can run it indefinitely, and the random draws are
//! made per sample in a fixed order, so a seed gives the same samples whatever the chunk sizes.
//!
//! Output sample `i` is taken at `t = i / rate_hz`; sample 0 is the initial state.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// What the simulator outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Output {
    /// Support force `F = k*y`, N.
    #[default]
    Force,
    /// Displacement `y`, m.
    Displacement,
}

/// The damping ratio as a function of time (seconds since the start of the simulation).
pub enum ZetaSchedule {
    /// The same value all the time.
    Constant(f64),
    /// `from` until `start_s`, then linear to `to` over `duration_s`, then `to` for ever.
    Ramp {
        /// Start of the ramp, s.
        start_s: f64,
        /// Length of the ramp, s.
        duration_s: f64,
        /// Value before the ramp.
        from: f64,
        /// Value after the ramp.
        to: f64,
    },
    /// Piecewise-linear through `(t, zeta)` points sorted by time; held constant outside.
    Table(Vec<(f64, f64)>),
    /// Any function of time.
    Custom(Box<dyn Fn(f64) -> f64 + Send + Sync>),
}

impl std::fmt::Debug for ZetaSchedule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ZetaSchedule::Constant(z) => write!(f, "Constant({z})"),
            ZetaSchedule::Ramp {
                start_s,
                duration_s,
                from,
                to,
            } => write!(
                f,
                "Ramp({from} -> {to} from {start_s} s over {duration_s} s)"
            ),
            ZetaSchedule::Table(t) => write!(f, "Table({t:?})"),
            ZetaSchedule::Custom(_) => write!(f, "Custom(..)"),
        }
    }
}

impl ZetaSchedule {
    /// The damping ratio at time `t` (s).
    pub fn at(&self, t: f64) -> f64 {
        match self {
            ZetaSchedule::Constant(z) => *z,
            ZetaSchedule::Ramp {
                start_s,
                duration_s,
                from,
                to,
            } => {
                if t <= *start_s {
                    *from
                } else if t >= start_s + duration_s || *duration_s <= 0.0 {
                    *to
                } else {
                    from + (to - from) * (t - start_s) / duration_s
                }
            }
            ZetaSchedule::Table(pts) => {
                let Some(first) = pts.first() else {
                    return 0.0;
                };
                if t <= first.0 {
                    return first.1;
                }
                for w in pts.windows(2) {
                    let (t0, z0) = w[0];
                    let (t1, z1) = w[1];
                    if t <= t1 {
                        return if t1 > t0 {
                            z0 + (z1 - z0) * (t - t0) / (t1 - t0)
                        } else {
                            z1
                        };
                    }
                }
                pts[pts.len() - 1].1
            }
            ZetaSchedule::Custom(f) => f(t),
        }
    }

    /// First time at or after `from_s` (scanned in steps of `step_s` up to `until_s`) where
    /// `zeta <= level`; refined by bisection. `None` if it never happens in that span.
    pub fn first_time_at_or_below(
        &self,
        level: f64,
        from_s: f64,
        until_s: f64,
        step_s: f64,
    ) -> Option<f64> {
        if self.at(from_s) <= level {
            return Some(from_s);
        }
        let mut t = from_s;
        while t < until_s {
            let t1 = (t + step_s).min(until_s);
            if self.at(t1) <= level {
                let (mut lo, mut hi) = (t, t1);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if self.at(mid) <= level {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                return Some(hi);
            }
            t = t1;
        }
        None
    }
}

/// Predefined scenarios of the chapter's lab gate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scenario {
    /// `zeta = +1 %` all the time: a damped gate shaken by turbulence.
    Stable,
    /// `zeta = +2 %` for `hold_s`, then a linear ramp to `-2 %` over `ramp_s`, then `-2 %`:
    /// the onset of self-excitation, saturating into a limit cycle through the cubic damping.
    Onset {
        /// Stable time before the ramp starts, s.
        hold_s: f64,
        /// Length of the ramp, s.
        ramp_s: f64,
    },
    /// `zeta = -2 %` from the start: growth from the noise floor into the limit cycle.
    LimitCycle,
}

impl Scenario {
    /// `Onset` with the default 60 s hold and 300 s ramp.
    pub const ONSET_DEFAULT: Scenario = Scenario::Onset {
        hold_s: 60.0,
        ramp_s: 300.0,
    };

    /// The damping schedule of the scenario.
    pub fn schedule(&self) -> ZetaSchedule {
        match *self {
            Scenario::Stable => ZetaSchedule::Constant(0.01),
            Scenario::Onset { hold_s, ramp_s } => ZetaSchedule::Ramp {
                start_s: hold_s,
                duration_s: ramp_s,
                from: 0.02,
                to: -0.02,
            },
            Scenario::LimitCycle => ZetaSchedule::Constant(-0.02),
        }
    }
}

/// Physical and sampling parameters of the simulated gate.
#[derive(Debug, Clone, PartialEq)]
pub struct GateParams {
    /// Mass `m`, kg.
    pub mass: f64,
    /// Stiffness `k`, N/m.
    pub stiffness: f64,
    /// Cubic velocity damping `c3`, N s^3/m^3 (saturates growth into a limit cycle).
    pub c3: f64,
    /// Standard deviation of the turbulent force per sample, N (0: free motion).
    pub forcing_std: f64,
    /// Output sample rate, Hz.
    pub rate_hz: f64,
    /// RK4 steps per output sample.
    pub substeps: usize,
    /// What is output.
    pub output: Output,
    /// Standard deviation of additive white measurement noise, in output units (absolute: a
    /// stream does not know its own standard deviation in advance).
    pub noise_std: f64,
    /// Linear drift added to the output, output units per second.
    pub drift_per_s: f64,
    /// Amplitude of a slow sinusoidal drift added to the output, output units.
    pub drift_amplitude: f64,
    /// Period of the sinusoidal drift, s.
    pub drift_period_s: f64,
    /// Initial displacement, m.
    pub y0: f64,
    /// Initial velocity, m/s.
    pub v0: f64,
}

impl Default for GateParams {
    /// The chapter's lab gate: `m = 19.14 kg`, `k = 81360 N/m` (`f_n ~ 10.4 Hz`), 200 Hz,
    /// 8 RK4 substeps, force output, `forcing_std = 1 N` (stable force std ~2.9 N at 1 %),
    /// `c3 = 4.0e4` (limit-cycle force amplitude ~50 N at `zeta = -2 %`), no noise, no drift.
    fn default() -> Self {
        GateParams {
            mass: 19.14,
            stiffness: 81360.0,
            c3: 4.0e4,
            forcing_std: 1.0,
            rate_hz: 200.0,
            substeps: 8,
            output: Output::Force,
            noise_std: 0.0,
            drift_per_s: 0.0,
            drift_amplitude: 0.0,
            drift_period_s: 600.0,
            y0: 0.0,
            v0: 0.0,
        }
    }
}

impl GateParams {
    /// Undamped natural frequency `sqrt(k/m)/(2 pi)`, Hz.
    pub fn natural_frequency_hz(&self) -> f64 {
        (self.stiffness / self.mass).sqrt() / (2.0 * std::f64::consts::PI)
    }

    /// Critical damping `2 sqrt(k m)`, N s/m: `c = zeta * critical_damping()`.
    pub fn critical_damping(&self) -> f64 {
        2.0 * (self.stiffness * self.mass).sqrt()
    }

    /// Harmonic-balance force amplitude `k*Y` of the limit cycle at damping ratio `zeta < 0`
    /// (`None` if `zeta >= 0` or `c3 <= 0`).
    pub fn limit_cycle_force_amplitude(&self, zeta: f64) -> Option<f64> {
        if zeta >= 0.0 || self.c3 <= 0.0 {
            return None;
        }
        let c = zeta * self.critical_damping();
        let w2 = self.stiffness / self.mass;
        Some(self.stiffness * (-4.0 * c / (3.0 * self.c3 * w2)).sqrt())
    }

    /// Predicted stationary standard deviation of the force response of the linear gate at
    /// damping ratio `zeta > 0` to the interpolated white forcing (low-frequency approximation).
    pub fn stationary_force_std(&self, zeta: f64) -> f64 {
        let c = zeta * self.critical_damping();
        self.forcing_std * (self.stiffness / (2.0 * c * self.rate_hz)).sqrt()
    }
}

/// A streaming, seeded simulator of a gate signal.
#[derive(Debug)]
pub struct GateSimulator {
    p: GateParams,
    schedule: ZetaSchedule,
    crit: f64,
    /// Index of the next sample to output.
    index: u64,
    y: f64,
    v: f64,
    /// Forcing at the current sample and at the next one (interpolated in between).
    f_now: f64,
    f_next: f64,
    force_rng: ChaCha8Rng,
    noise_rng: ChaCha8Rng,
}

impl GateSimulator {
    /// A simulator of `params` whose damping follows `schedule`, seeded with `seed`.
    ///
    /// # Panics
    /// If `rate_hz`, `mass` or `stiffness` is not positive or `substeps == 0`.
    pub fn new(params: GateParams, schedule: ZetaSchedule, seed: u64) -> GateSimulator {
        assert!(params.rate_hz > 0.0 && params.mass > 0.0 && params.stiffness > 0.0);
        assert!(params.substeps > 0);
        let mut force_rng = ChaCha8Rng::seed_from_u64(seed);
        force_rng.set_stream(0);
        let mut noise_rng = ChaCha8Rng::seed_from_u64(seed);
        noise_rng.set_stream(1);
        let mut s = GateSimulator {
            crit: params.critical_damping(),
            y: params.y0,
            v: params.v0,
            p: params,
            schedule,
            index: 0,
            f_now: 0.0,
            f_next: 0.0,
            force_rng,
            noise_rng,
        };
        s.f_now = s.draw_force();
        s.f_next = s.draw_force();
        s
    }

    /// A simulator of one of the predefined scenarios.
    pub fn scenario(params: GateParams, scenario: Scenario, seed: u64) -> GateSimulator {
        GateSimulator::new(params, scenario.schedule(), seed)
    }

    fn draw_force(&mut self) -> f64 {
        if self.p.forcing_std > 0.0 {
            let z: f64 = StandardNormal.sample(&mut self.force_rng);
            self.p.forcing_std * z
        } else {
            0.0
        }
    }

    /// The parameters.
    pub fn params(&self) -> &GateParams {
        &self.p
    }

    /// The damping schedule.
    pub fn schedule(&self) -> &ZetaSchedule {
        &self.schedule
    }

    /// The true damping ratio at time `t` (s).
    pub fn true_zeta(&self, t: f64) -> f64 {
        self.schedule.at(t)
    }

    /// Time of the next sample `next_sample` will return, s.
    pub fn time(&self) -> f64 {
        self.index as f64 / self.p.rate_hz
    }

    /// Index of the next sample.
    pub fn sample_index(&self) -> u64 {
        self.index
    }

    /// Current state `(y, v)` (displacement m, velocity m/s) at [`Self::time`].
    pub fn state(&self) -> (f64, f64) {
        (self.y, self.v)
    }

    /// Acceleration at state `(y, v)`, time `t` within the current sample interval, with the
    /// damping coefficient `c` (held over one RK4 step).
    #[inline]
    fn accel(&self, y: f64, v: f64, c: f64, t_frac: f64) -> f64 {
        let f = self.f_now + (self.f_next - self.f_now) * t_frac;
        (f - c * v - self.p.c3 * v * v * v - self.p.stiffness * y) / self.p.mass
    }

    /// Advances the state by one sample interval (RK4 substeps).
    fn advance(&mut self) {
        let dt = 1.0 / self.p.rate_hz;
        let n = self.p.substeps;
        let h = dt / n as f64;
        let t0 = self.time();
        for j in 0..n {
            let a = j as f64 / n as f64;
            let b = (j as f64 + 0.5) / n as f64;
            let e = (j as f64 + 1.0) / n as f64;
            // Damping evaluated at the step's midpoint: the schedule varies on a scale of
            // seconds, far slower than a substep.
            let c = self.crit * self.schedule.at(t0 + b * dt);
            let (y, v) = (self.y, self.v);
            let k1y = v;
            let k1v = self.accel(y, v, c, a);
            let k2y = v + 0.5 * h * k1v;
            let k2v = self.accel(y + 0.5 * h * k1y, k2y, c, b);
            let k3y = v + 0.5 * h * k2v;
            let k3v = self.accel(y + 0.5 * h * k2y, k3y, c, b);
            let k4y = v + h * k3v;
            let k4v = self.accel(y + h * k3y, k4y, c, e);
            self.y = y + h / 6.0 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y);
            self.v = v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        }
        self.f_now = self.f_next;
        self.f_next = self.draw_force();
        self.index += 1;
    }

    /// The clean (noise- and drift-free) output of the current state.
    #[inline]
    fn clean_output(&self) -> f64 {
        match self.p.output {
            Output::Force => self.p.stiffness * self.y,
            Output::Displacement => self.y,
        }
    }

    /// The next sample (output at [`Self::time`], then the state advances by one interval).
    pub fn next_sample(&mut self) -> f64 {
        let t = self.time();
        let mut out = self.clean_output();
        if self.p.noise_std > 0.0 {
            let z: f64 = StandardNormal.sample(&mut self.noise_rng);
            out += self.p.noise_std * z;
        }
        if self.p.drift_per_s != 0.0 {
            out += self.p.drift_per_s * t;
        }
        if self.p.drift_amplitude != 0.0 && self.p.drift_period_s > 0.0 {
            out += self.p.drift_amplitude
                * (2.0 * std::f64::consts::PI * t / self.p.drift_period_s).sin();
        }
        self.advance();
        out
    }

    /// Fills `out` with the next `out.len()` samples.
    pub fn fill(&mut self, out: &mut [f64]) {
        for o in out.iter_mut() {
            *o = self.next_sample();
        }
    }
}

impl Iterator for GateSimulator {
    type Item = f64;
    /// Never ends.
    fn next(&mut self) -> Option<f64> {
        Some(self.next_sample())
    }
}

/// Options of the chapter's worked example (section 8.5, equation 8.8).
#[derive(Debug, Clone, PartialEq)]
pub struct WorkedExampleOptions {
    /// Duration, s (10 in the chapter).
    pub duration_s: f64,
    /// Sample rate, Hz (200).
    pub rate_hz: f64,
    /// RK4 steps per sample (20 is converged to far below the noise; see the tests).
    pub substeps: usize,
    /// Gaussian noise standard deviation as a fraction of the clean signal's standard deviation
    /// (0.01 in the chapter).
    pub noise_fraction: f64,
    /// Linear drift added to the force, N/s (0: none).
    pub drift_per_s: f64,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for WorkedExampleOptions {
    fn default() -> Self {
        WorkedExampleOptions {
            duration_s: 10.0,
            rate_hz: 200.0,
            substeps: 20,
            noise_fraction: 0.01,
            drift_per_s: 0.0,
            seed: 0,
        }
    }
}

/// The worked example's signal.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkedExample {
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Support force with noise and drift, N.
    pub force: Vec<f64>,
    /// Support force without noise or drift, N.
    pub clean: Vec<f64>,
}

/// Mass of equation 8.8, kg.
pub const EX_MASS: f64 = 19.14;
/// Linear damping of equation 8.8 (negative: self-excited), N s/m.
pub const EX_C1: f64 = -12.18;
/// Cubic damping of equation 8.8, N s^3/m^3: our reading of the extracted `4.473 * 10^?`.
///
/// The chapter calls its 10 s window "a growth phase of regular vibrations" starting at
/// `y0 = 0.3368 mm`. Taken as `4.473e7`, the limit cycle (harmonic balance:
/// `A = sqrt(4*12.18 / (3*c3)) / omega`) would be 9.2e-6 m, far below `y0`, and the motion would
/// collapse within 0.1 s instead of growing. With `4.473e2` the limit cycle is 2.9 mm: the
/// vibration grows from 0.34 mm at `sigma = 12.18/(2*19.14) = 0.32 1/s` and saturates within the
/// window, which is what the chapter describes. The exponent's sign or digit was lost in the
/// text extraction; see `docs/damping.md`.
pub const EX_C3: f64 = 4.473e2;
/// Stiffness of equation 8.8, N/m.
pub const EX_K: f64 = 81360.0;
/// Initial displacement of the worked example, m.
pub const EX_Y0: f64 = 0.3368e-3;
/// Initial velocity of the worked example, m/s.
pub const EX_V0: f64 = 5.8e-3;

/// The worked example: free motion of
/// `19.14*ydd + (-12.18 + 447.3*yd^2)*yd + 81360*y = 0` from `y0 = 0.3368e-3 m`,
/// `v0 = 5.8e-3 m/s`, output `F = 81360*y` at `rate_hz`, plus Gaussian noise of
/// `noise_fraction` times the clean signal's standard deviation and an optional linear drift.
///
/// The vibration grows from ~27 N of force amplitude towards the ~240 N limit cycle (see
/// [`EX_C3`] for the reading of the chapter's cubic coefficient).
pub fn worked_example(opts: &WorkedExampleOptions) -> WorkedExample {
    let params = GateParams {
        mass: EX_MASS,
        stiffness: EX_K,
        c3: EX_C3,
        forcing_std: 0.0,
        rate_hz: opts.rate_hz,
        substeps: opts.substeps,
        output: Output::Force,
        noise_std: 0.0,
        drift_per_s: 0.0,
        drift_amplitude: 0.0,
        drift_period_s: 1.0,
        y0: EX_Y0,
        v0: EX_V0,
    };
    let zeta = EX_C1 / params.critical_damping();
    let n = (opts.duration_s * opts.rate_hz).round() as usize;
    let mut sim = GateSimulator::new(params, ZetaSchedule::Constant(zeta), opts.seed);
    let mut clean = vec![0.0; n];
    sim.fill(&mut clean);
    let mean = clean.iter().sum::<f64>() / n.max(1) as f64;
    let std = (clean.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n.max(1) as f64).sqrt();
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    rng.set_stream(2);
    let force = clean
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            let z: f64 = StandardNormal.sample(&mut rng);
            x + opts.noise_fraction * std * z + opts.drift_per_s * i as f64 / opts.rate_hz
        })
        .collect();
    WorkedExample {
        rate_hz: opts.rate_hz,
        force,
        clean,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rms(x: &[f64]) -> f64 {
        (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
    }

    #[test]
    fn same_seed_same_samples_whatever_the_chunks() {
        let p = GateParams {
            noise_std: 0.1,
            drift_amplitude: 0.5,
            drift_per_s: 0.01,
            ..GateParams::default()
        };
        let mut a = GateSimulator::scenario(p.clone(), Scenario::ONSET_DEFAULT, 42);
        let mut whole = vec![0.0; 2000];
        a.fill(&mut whole);
        let mut b = GateSimulator::scenario(p.clone(), Scenario::ONSET_DEFAULT, 42);
        let mut pieces = Vec::new();
        let sizes = [1usize, 7, 200, 13, 999, 1, 779];
        for &s in &sizes {
            let mut buf = vec![0.0; s];
            b.fill(&mut buf);
            pieces.extend_from_slice(&buf);
        }
        assert_eq!(pieces.len(), 2000);
        assert_eq!(whole, pieces, "chunking changed the samples");
        let mut c = GateSimulator::scenario(p, Scenario::ONSET_DEFAULT, 43);
        let mut other = vec![0.0; 2000];
        c.fill(&mut other);
        assert_ne!(whole, other, "different seeds gave the same samples");
    }

    #[test]
    fn stable_force_std_matches_prediction() {
        let p = GateParams::default();
        let predicted = p.stationary_force_std(0.01);
        let mut sim = GateSimulator::scenario(p, Scenario::Stable, 7);
        let mut x = vec![0.0; 200 * 300];
        sim.fill(&mut x);
        let s = rms(&x[200 * 20..]);
        // Within 20 %: 280 s holds ~170 correlation times (1/(zeta*omega) = 1.5 s) of the
        // response, so the sample std has a relative scatter of ~5 %; the remainder allows for
        // the interpolated forcing not being exactly white at 10 Hz.
        assert!(
            (s / predicted - 1.0).abs() < 0.2,
            "std {s} vs predicted {predicted}"
        );
        assert!(s > 1.0 && s < 10.0, "stable force std {s} N");
    }

    #[test]
    fn stable_scenario_ar_damping_is_near_one_percent() {
        use crate::spectral::{ambient_damping, ArOptions};
        let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 11);
        let mut x = vec![0.0; 200 * 140];
        sim.fill(&mut x);
        // Two 60 s windows after a 20 s burn-in.
        for w in x[200 * 20..].chunks(200 * 60) {
            let a = ambient_damping(w, 200.0, &ArOptions::default()).unwrap();
            assert!((a.zeta - 0.01).abs() < 0.003, "zeta {a:?}");
            assert!(a.zeta_low > 0.0);
        }
    }

    #[test]
    fn onset_true_zeta_crosses_minus_one_percent_when_expected() {
        let sim = GateSimulator::scenario(GateParams::default(), Scenario::ONSET_DEFAULT, 1);
        // From +2 % at 60 s to -2 % at 360 s: -1 % is three quarters of the way, at 285 s.
        let t = sim
            .schedule()
            .first_time_at_or_below(-0.01, 0.0, 1000.0, 1.0)
            .unwrap();
        assert!((t - 285.0).abs() < 1e-6, "crossed at {t}");
        assert!((sim.true_zeta(0.0) - 0.02).abs() < 1e-12);
        assert!((sim.true_zeta(210.0) - 0.0).abs() < 1e-12);
        assert!((sim.true_zeta(1e4) + 0.02).abs() < 1e-12);
    }

    #[test]
    fn onset_grows_into_a_clearly_larger_limit_cycle() {
        let p = GateParams::default();
        let lc = p.limit_cycle_force_amplitude(-0.02).unwrap();
        let stable = p.stationary_force_std(0.02);
        let scenario = Scenario::Onset {
            hold_s: 20.0,
            ramp_s: 60.0,
        };
        let mut sim = GateSimulator::scenario(p, scenario, 21);
        let mut x = vec![0.0; 200 * 110];
        sim.fill(&mut x);
        // Stable phase (10-20 s): the response std of the +2 % gate, within 35 % (a 10 s
        // window holds only ~13 correlation times).
        let s = rms(&x[200 * 10..200 * 20]);
        assert!(
            (s / stable - 1.0).abs() < 0.35,
            "stable std {s} vs {stable}"
        );
        // 20 s after the ramp ended: the -2 % limit cycle.
        let amp = rms(&x[200 * 100..]) * std::f64::consts::SQRT_2;
        assert!((amp / lc - 1.0).abs() < 0.1, "amplitude {amp} vs {lc}");
        assert!(amp > 10.0 * s);
    }

    #[test]
    fn table_schedule_interpolates() {
        let s = ZetaSchedule::Table(vec![(0.0, 0.01), (10.0, -0.01), (20.0, -0.01)]);
        assert!((s.at(-1.0) - 0.01).abs() < 1e-15);
        assert!((s.at(5.0) - 0.0).abs() < 1e-15);
        assert!((s.at(15.0) + 0.01).abs() < 1e-15);
        assert!((s.at(99.0) + 0.01).abs() < 1e-15);
        let c = ZetaSchedule::Custom(Box::new(|t| 0.01 - 0.001 * t));
        let t = c.first_time_at_or_below(-0.01, 0.0, 100.0, 1.0).unwrap();
        assert!((t - 20.0).abs() < 1e-9);
    }

    #[test]
    fn limit_cycle_settles_at_harmonic_balance_amplitude() {
        let p = GateParams::default();
        let predicted = p.limit_cycle_force_amplitude(-0.02).unwrap();
        let stable = p.stationary_force_std(0.01) * std::f64::consts::SQRT_2;
        let mut sim = GateSimulator::scenario(p, Scenario::LimitCycle, 3);
        let mut x = vec![0.0; 200 * 40];
        sim.fill(&mut x);
        // Amplitude of a sinusoid = sqrt(2) * rms, over 5 s blocks of the last 20 s.
        let blocks: Vec<f64> = x[200 * 20..]
            .chunks(1000)
            .map(|b| rms(b) * std::f64::consts::SQRT_2)
            .collect();
        let (lo, hi) = blocks
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(hi / lo < 1.1, "envelope not settled: {blocks:?}");
        let mean = blocks.iter().sum::<f64>() / blocks.len() as f64;
        assert!(
            (mean / predicted - 1.0).abs() < 0.1,
            "limit cycle {mean} vs harmonic balance {predicted}"
        );
        assert!(
            mean > 5.0 * stable,
            "limit cycle {mean} not clearly above {stable}"
        );
    }

    #[test]
    fn worked_example_converged_in_substeps() {
        let base = WorkedExampleOptions {
            noise_fraction: 0.0,
            ..WorkedExampleOptions::default()
        };
        let a = worked_example(&base);
        let b = worked_example(&WorkedExampleOptions {
            substeps: 40,
            ..base.clone()
        });
        assert_eq!(a.force.len(), 2000);
        let scale = a.clean.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let err = a
            .clean
            .iter()
            .zip(&b.clean)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(
            err < 1e-6 * scale,
            "20 vs 40 substeps differ by {err} (scale {scale})"
        );
        assert!((a.clean[0] - EX_K * EX_Y0).abs() < 1e-9);
    }

    #[test]
    fn worked_example_noise_is_one_percent() {
        let ex = worked_example(&WorkedExampleOptions::default());
        let n = ex.clean.len() as f64;
        let mean = ex.clean.iter().sum::<f64>() / n;
        let std = (ex.clean.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
        let noise: Vec<f64> = ex.force.iter().zip(&ex.clean).map(|(a, b)| a - b).collect();
        let r = rms(&noise) / std;
        assert!((r - 0.01).abs() < 0.001, "noise fraction {r}");
    }

    #[test]
    fn worked_example_settles_on_its_limit_cycle() {
        let ex = worked_example(&WorkedExampleOptions {
            noise_fraction: 0.0,
            ..WorkedExampleOptions::default()
        });
        let p = GateParams {
            mass: EX_MASS,
            stiffness: EX_K,
            c3: EX_C3,
            ..GateParams::default()
        };
        let predicted = p
            .limit_cycle_force_amplitude(EX_C1 / p.critical_damping())
            .unwrap();
        // A growth phase: ~27 N at the start, growing towards the ~240 N limit cycle.
        assert!(ex.clean[0] > 25.0 && ex.clean[0] < 30.0);
        let head = rms(&ex.clean[..200]) * std::f64::consts::SQRT_2;
        let tail = &ex.clean[ex.clean.len() - 400..];
        assert!(rms(tail) * std::f64::consts::SQRT_2 > 5.0 * head);
        let amp = rms(tail) * std::f64::consts::SQRT_2;
        assert!(
            (amp / predicted - 1.0).abs() < 0.1,
            "tail amplitude {amp} vs harmonic balance {predicted}"
        );
    }
}
