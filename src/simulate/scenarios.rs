//! The scenarios an operator meets and the gates they happen to, as named presets.
//!
//! Every scenario is a damping schedule `zeta0(t)` (the TRUTH, kept beside the signal so a
//! benchmark can score an estimate), optionally a stiffness schedule (a falling water level) and
//! sensor faults, on one of the gate presets. Times are seconds of sample time from the
//! scenario's start; the gate is first brought to its stationary state by a warm-up at the
//! schedule's initial value ([`ScenarioDef::warmup_s`]), so the first window is already
//! representative. Definitions and reasons: `docs/damping.md`, "Scenarios".

use super::{GateParams, GateSimulator, Impacts, SensorFaults, ZetaSchedule};

/// Gate presets: the chapter's lab gate, a lock gate and a barrier gate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum GatePreset {
    /// The chapter's lab gate: 19.14 kg, 81 360 N/m (10.4 Hz), sampled at 200 Hz.
    #[default]
    Lab,
    /// A 2000 kg, 5 Hz lock gate sampled at 100 Hz.
    Lock,
    /// A 500 kg, 2 Hz barrier gate sampled at 50 Hz (20 cycles in a 10 s window).
    Barrier,
    /// A 10 000 kg, 1 Hz surge-barrier gate sampled at 20 Hz (10 cycles in a 10 s window).
    Surge,
}

/// Ratio of the limit-cycle force amplitude at `zeta = -2 %` to the ambient force std at
/// `zeta = +1 %`: the lab gate's (`c3 = 4e4`: ~50 N against ~2.9 N), kept for every preset so
/// that the scenarios look alike whatever the gate's scale.
const LIMIT_CYCLE_OVER_AMBIENT: f64 = 17.0;

impl GatePreset {
    /// Every preset, in table order.
    pub const ALL: [GatePreset; 4] = [
        GatePreset::Lab,
        GatePreset::Lock,
        GatePreset::Barrier,
        GatePreset::Surge,
    ];

    /// Name on the command line and in tables.
    pub fn as_str(self) -> &'static str {
        match self {
            GatePreset::Lab => "lab",
            GatePreset::Lock => "lock",
            GatePreset::Barrier => "barrier",
            GatePreset::Surge => "surge",
        }
    }

    /// Parses a name of [`Self::as_str`].
    pub fn parse(s: &str) -> Result<GatePreset, String> {
        GatePreset::ALL
            .into_iter()
            .find(|g| g.as_str() == s)
            .ok_or_else(|| {
                format!("unknown gate preset `{s}` (expected one of lab, lock, barrier, surge)")
            })
    }

    /// The preset's parameters (force output, no noise: see [`NoiseLevel`]).
    pub fn params(self) -> GateParams {
        let (mass, f_hz, rate_hz, forcing_std) = match self {
            GatePreset::Lab => return GateParams::default(),
            // the forcing scales with the gate (turbulence acts on a larger leaf); only the
            // ratios to the noise and to the limit cycle matter to an estimator
            GatePreset::Lock => (2000.0, 5.0, 100.0, 100.0),
            GatePreset::Barrier => (500.0, 2.0, 50.0, 25.0),
            GatePreset::Surge => (10_000.0, 1.0, 20.0, 500.0),
        };
        let w = 2.0 * std::f64::consts::PI * f_hz;
        let mut p = GateParams {
            mass,
            stiffness: mass * w * w,
            forcing_std,
            rate_hz,
            ..GateParams::default()
        };
        // c3 so that the -2 % limit cycle stands LIMIT_CYCLE_OVER_AMBIENT above the ambient
        // response: harmonic balance `Y = sqrt(-4 c / (3 c3 w^2))` solved for c3
        let y = LIMIT_CYCLE_OVER_AMBIENT * p.stationary_force_std(0.01) / p.stiffness;
        let c = -0.02 * p.critical_damping();
        p.c3 = -4.0 * c / (3.0 * w * w * y * y);
        p
    }
}

/// Sensor noise: absolute (signal units, as a load cell's noise floor is) or relative to the
/// preset's ambient force std at +1 % (a stream cannot know its own spread in advance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoiseLevel {
    /// RMS in output units (N).
    Absolute(f64),
    /// RMS as a fraction of the gate's predicted ambient response std at `zeta = +1 %`.
    Relative(f64),
}

impl NoiseLevel {
    /// The RMS in output units on gate `p`.
    pub fn rms(self, p: &GateParams) -> f64 {
        match self {
            NoiseLevel::Absolute(x) => x,
            NoiseLevel::Relative(r) => r * p.stationary_force_std(0.01),
        }
    }
}

/// The named scenarios.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ScenarioName {
    /// +1 % for 10 min: the stable gate (false alarms).
    Stable,
    /// +0.5 % for 10 min: a lightly damped stable gate (false alarms).
    StableLow,
    /// +2 % for 2 min, then linear to -2 % over 20 min, then -2 % for 1 min.
    SlowDrift,
    /// +2 % for 2 min, then linear to -2 % in 60 s, then -2 % for 2 min: the onset ramp.
    Onset,
    /// -2 % for 5 min, starting on the limit cycle (cubic damping saturating it).
    LimitCycle,
    /// On the -2 % limit cycle for 2 min, back to +2 % in 60 s, then +2 % for 3 min.
    Recovery,
    /// +2 % for 2 min, then a step to -2 %, held 3 min.
    Step,
    /// +1 %, with a 15 s burst at -3 % every 90 s (from 60 s on): intermittent self-excitation.
    Bursting,
    /// +1 % throughout while the stiffness falls to 70 % over 10 min (the frequency by 16 %):
    /// a falling water level; the damping is stable.
    WaterLevel,
    /// +1 % for 10 min with spikes, dropouts, clipping and a DC offset on the sensor.
    SensorFaults,
    /// +1 % for 10 min, struck about once a minute (debris, ice, a vessel): free vibrations
    /// 5 to 20 times the ambient response that decay at the gate's damping.
    Impacts,
}

impl ScenarioName {
    /// Every scenario, in table order.
    pub const ALL: [ScenarioName; 11] = [
        ScenarioName::Stable,
        ScenarioName::StableLow,
        ScenarioName::SlowDrift,
        ScenarioName::Onset,
        ScenarioName::LimitCycle,
        ScenarioName::Recovery,
        ScenarioName::Step,
        ScenarioName::Bursting,
        ScenarioName::WaterLevel,
        ScenarioName::SensorFaults,
        ScenarioName::Impacts,
    ];

    /// Name on the command line and in tables.
    pub fn as_str(self) -> &'static str {
        match self {
            ScenarioName::Stable => "stable",
            ScenarioName::StableLow => "stable-low",
            ScenarioName::SlowDrift => "slow-drift",
            ScenarioName::Onset => "onset",
            ScenarioName::LimitCycle => "limit-cycle",
            ScenarioName::Recovery => "recovery",
            ScenarioName::Step => "step",
            ScenarioName::Bursting => "bursting",
            ScenarioName::WaterLevel => "water-level",
            ScenarioName::SensorFaults => "sensor-faults",
            ScenarioName::Impacts => "impacts",
        }
    }

    /// Parses a name of [`Self::as_str`].
    pub fn parse(s: &str) -> Result<ScenarioName, String> {
        ScenarioName::ALL
            .into_iter()
            .find(|n| n.as_str() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = ScenarioName::ALL.iter().map(|n| n.as_str()).collect();
                format!(
                    "unknown scenario `{s}` (expected one of {})",
                    names.join(", ")
                )
            })
    }

    /// Whether the gate is stable throughout (its alerts are false alarms).
    pub fn is_stable(self) -> bool {
        matches!(
            self,
            ScenarioName::Stable
                | ScenarioName::StableLow
                | ScenarioName::WaterLevel
                | ScenarioName::SensorFaults
                | ScenarioName::Impacts
        )
    }

    /// The scenario on gate `p` (the gate sets the fault levels, which are relative to its
    /// ambient response).
    pub fn def(self, p: &GateParams) -> ScenarioDef {
        let ramp = |start_s: f64, duration_s: f64, from: f64, to: f64| ZetaSchedule::Ramp {
            start_s,
            duration_s,
            from,
            to,
        };
        let mut d = ScenarioDef {
            name: self,
            zeta: ZetaSchedule::Constant(0.01),
            stiffness_factor: None,
            faults: SensorFaults::default(),
            impacts: Impacts::default(),
            start_on_limit_cycle: false,
            duration_s: 600.0,
            warmup_s: 30.0,
        };
        match self {
            ScenarioName::Stable | ScenarioName::WaterLevel | ScenarioName::SensorFaults => {}
            ScenarioName::Impacts => {
                // sizes against the ambient displacement std at +1 %: a blow of 20 of them
                // lifts a 10 s window of the lock gate to about 5 times its ambient level, of
                // the lab gate (whose blows die out twice as fast) to about 4 times; the
                // smallest hardly show
                let s = p.stationary_force_std(0.01) / p.stiffness;
                d.impacts = Impacts {
                    every_s: 60.0,
                    amplitude_min: 5.0 * s,
                    amplitude_max: 20.0 * s,
                };
            }
            ScenarioName::StableLow => {
                d.zeta = ZetaSchedule::Constant(0.005);
                // the correlation time 1/(zeta omega) doubles: so does the warm-up
                d.warmup_s = 60.0;
            }
            ScenarioName::SlowDrift => {
                d.zeta = ramp(120.0, 1200.0, 0.02, -0.02);
                d.duration_s = 1380.0;
            }
            ScenarioName::Onset => {
                d.zeta = ramp(120.0, 60.0, 0.02, -0.02);
                d.duration_s = 300.0;
            }
            ScenarioName::LimitCycle => {
                d.zeta = ZetaSchedule::Constant(-0.02);
                d.start_on_limit_cycle = true;
                d.duration_s = 300.0;
            }
            ScenarioName::Recovery => {
                d.zeta = ramp(120.0, 60.0, -0.02, 0.02);
                d.start_on_limit_cycle = true;
                d.duration_s = 360.0;
            }
            ScenarioName::Step => {
                d.zeta = ramp(120.0, 0.0, 0.02, -0.02);
                d.duration_s = 300.0;
            }
            ScenarioName::Bursting => {
                d.zeta = ZetaSchedule::Function(bursting_zeta);
                d.duration_s = 420.0;
            }
        }
        if self == ScenarioName::WaterLevel {
            d.stiffness_factor = Some(ramp(0.0, 600.0, 1.0, 0.7));
        }
        if self == ScenarioName::SensorFaults {
            let s = p.stationary_force_std(0.01);
            d.faults = SensorFaults {
                spikes_per_s: 0.1,
                spike_height: 10.0 * s,
                dropouts_per_s: 1.0 / 150.0,
                dropout_s: 1.0,
                clip: 2.5 * s,
                dc_offset: 2.0 * s,
                dc_offset_from_s: 300.0,
            };
        }
        d
    }
}

/// The bursting scenario's damping: +1 %, and -3 % for 15 s of every 90 s from 60 s on.
fn bursting_zeta(t: f64) -> f64 {
    if t >= 60.0 && (t - 60.0).rem_euclid(90.0) < 15.0 {
        -0.03
    } else {
        0.01
    }
}

/// One scenario, ready to simulate.
#[derive(Debug)]
pub struct ScenarioDef {
    /// Its name.
    pub name: ScenarioName,
    /// The true damping ratio over time.
    pub zeta: ZetaSchedule,
    /// The stiffness as a factor of the gate's over time (`None`: constant).
    pub stiffness_factor: Option<ZetaSchedule>,
    /// Sensor faults.
    pub faults: SensorFaults,
    /// Blows on the gate.
    pub impacts: Impacts,
    /// Start on the harmonic-balance limit cycle of the initial (negative) damping, so the
    /// scenario is "held" there from its first window, not growing into it.
    pub start_on_limit_cycle: bool,
    /// Length, s of sample time (after the warm-up).
    pub duration_s: f64,
    /// Warm-up before `t = 0`, s: at least 20 correlation times `1/(zeta omega)` of the lab gate
    /// at +1 % (1.5 s), so the ambient response is stationary from the first sample.
    pub warmup_s: f64,
}

impl ScenarioDef {
    /// The true damping ratio at `t`.
    pub fn true_zeta(&self, t: f64) -> f64 {
        self.zeta.at(t)
    }

    /// Mean of the true damping ratio over `[t0, t1]`.
    pub fn mean_zeta(&self, t0: f64, t1: f64) -> f64 {
        self.zeta.mean(t0, t1)
    }

    /// A seeded simulator of this scenario on gate `p` with sensor noise `noise`. Its clock
    /// starts at `-warmup_s`: drop samples before `t = 0`. Fails only when a schedule was
    /// replaced by a `Custom` one, which cannot be shared with the simulator.
    pub fn simulator(
        &self,
        p: &GateParams,
        noise: NoiseLevel,
        seed: u64,
    ) -> Result<GateSimulator, String> {
        let uncloneable = || {
            format!(
                "scenario `{}`: a Custom schedule cannot be shared; use ZetaSchedule::Function",
                self.name.as_str()
            )
        };
        let mut params = p.clone();
        params.noise_std = noise.rms(p);
        let z0 = self.zeta.at(-self.warmup_s);
        if self.start_on_limit_cycle {
            if let Some(a) = params.limit_cycle_force_amplitude(z0) {
                params.y0 = a / params.stiffness;
                params.v0 = 0.0;
            }
        }
        let sched = self.zeta.try_clone().ok_or_else(uncloneable)?;
        let mut sim = GateSimulator::new(params, sched, seed)
            .with_start_time(-self.warmup_s)
            .with_faults(self.faults.clone())
            .with_impacts(self.impacts.clone());
        if let Some(k) = &self.stiffness_factor {
            sim = sim.with_stiffness_factor(k.try_clone().ok_or_else(uncloneable)?);
        }
        Ok(sim)
    }
}
