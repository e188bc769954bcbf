//! The noise-driven gate: its parameters and the streaming RK4 simulator.

use super::{Impacts, Output, Scenario, SensorFaults, ZetaSchedule};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

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
    /// Stiffness as a factor of `p.stiffness` over time (a falling water level); `None`: 1.
    k_factor: Option<ZetaSchedule>,
    /// Time of sample 0, s (negative: a warm-up the scenario's clock starts after).
    t_start: f64,
    /// Sensor faults applied to the measured output.
    faults: SensorFaults,
    /// Its own random stream, so adding faults leaves forcing and noise unchanged.
    fault_rng: ChaCha8Rng,
    /// Samples left in the current dropout.
    dropout_left: u64,
    /// The clean output of the last sample returned.
    last_clean: f64,
    /// Blows on the gate.
    impacts: Impacts,
    /// Their own random stream, so adding blows leaves forcing, noise and faults unchanged.
    impact_rng: ChaCha8Rng,
    /// Time of the next blow, s (infinite: none).
    next_impact: f64,
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
        let mut fault_rng = ChaCha8Rng::seed_from_u64(seed);
        fault_rng.set_stream(2);
        let mut impact_rng = ChaCha8Rng::seed_from_u64(seed);
        impact_rng.set_stream(3);
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
            k_factor: None,
            t_start: 0.0,
            faults: SensorFaults::default(),
            fault_rng,
            dropout_left: 0,
            last_clean: 0.0,
            impacts: Impacts::default(),
            impact_rng,
            next_impact: f64::INFINITY,
        };
        s.f_now = s.draw_force();
        s.f_next = s.draw_force();
        s
    }

    /// A simulator of one of the predefined scenarios.
    pub fn scenario(params: GateParams, scenario: Scenario, seed: u64) -> GateSimulator {
        GateSimulator::new(params, scenario.schedule(), seed)
    }

    /// Lets the stiffness follow `factor(t) * stiffness` (a falling water level lowers the
    /// added mass' restoring force and the frequency); the damping coefficient follows it so that
    /// `zeta(t)` stays what the schedule says.
    pub fn with_stiffness_factor(mut self, factor: ZetaSchedule) -> GateSimulator {
        self.k_factor = Some(factor);
        self
    }

    /// Starts the clock at `t_start` (s): sample 0 is at `t_start`, so a negative value is a
    /// warm-up that brings the gate to its stationary response before the scenario's `t = 0`.
    pub fn with_start_time(mut self, t_start: f64) -> GateSimulator {
        self.t_start = t_start;
        self
    }

    /// Applies `faults` to the measured output (spikes, dropouts, clipping, a DC offset).
    pub fn with_faults(mut self, faults: SensorFaults) -> GateSimulator {
        self.faults = faults;
        self
    }

    /// Strikes the gate with `impacts`: blows at seeded times and sizes, the first one
    /// `[0.5, 1.5] * every_s` after `t = 0` (or after the current time, if later), so a warm-up
    /// before a scenario's clock starts is never struck. Call it after [`Self::with_start_time`].
    pub fn with_impacts(mut self, impacts: Impacts) -> GateSimulator {
        self.next_impact = if impacts.is_active() {
            impacts.next_after(self.time().max(0.0), &mut self.impact_rng)
        } else {
            f64::INFINITY
        };
        self.impacts = impacts;
        self
    }

    /// The clean (noise-, drift- and fault-free) output of the sample last returned.
    pub fn last_clean(&self) -> f64 {
        self.last_clean
    }

    /// Stiffness at time `t`, N/m.
    #[inline]
    fn stiffness_at(&self, t: f64) -> f64 {
        match &self.k_factor {
            Some(f) => self.p.stiffness * f.at(t),
            None => self.p.stiffness,
        }
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
        self.t_start + self.index as f64 / self.p.rate_hz
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
    fn accel(&self, y: f64, v: f64, c: f64, k: f64, t_frac: f64) -> f64 {
        let f = self.f_now + (self.f_next - self.f_now) * t_frac;
        (f - c * v - self.p.c3 * v * v * v - k * y) / self.p.mass
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
            let tm = t0 + b * dt;
            let k = self.stiffness_at(tm);
            let crit = match self.k_factor {
                Some(_) => 2.0 * (k * self.p.mass).sqrt(),
                None => self.crit,
            };
            let c = crit * self.schedule.at(tm);
            let (y, v) = (self.y, self.v);
            let k1y = v;
            let k1v = self.accel(y, v, c, k, a);
            let k2y = v + 0.5 * h * k1v;
            let k2v = self.accel(y + 0.5 * h * k1y, k2y, c, k, b);
            let k3y = v + 0.5 * h * k2v;
            let k3v = self.accel(y + 0.5 * h * k2y, k3y, c, k, b);
            let k4y = v + h * k3v;
            let k4v = self.accel(y + h * k3y, k4y, c, k, e);
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
            Output::Force => self.stiffness_at(self.time()) * self.y,
            Output::Displacement => self.y,
        }
    }

    /// The next sample (output at [`Self::time`], then the state advances by one interval).
    pub fn next_sample(&mut self) -> f64 {
        let t = self.time();
        let clean = self.clean_output();
        self.last_clean = clean;
        let mut out = clean;
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
        if self.faults.is_active() {
            out = self.faults.apply(
                out,
                t,
                self.p.rate_hz,
                &mut self.fault_rng,
                &mut self.dropout_left,
            );
        }
        if t >= self.next_impact {
            // the blow acts between this sample and the next: the state changes, the sample
            // already taken does not
            let omega = (self.stiffness_at(t) / self.p.mass).sqrt();
            self.v += self.impacts.kick(omega, &mut self.impact_rng);
            self.next_impact = self.impacts.next_after(t, &mut self.impact_rng);
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
