//! The damping ratio over time: schedules and the predefined scenarios of the lab gate.

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
    /// A plain function of time: unlike `Custom` it can be cloned, so the truth and the
    /// simulator can each hold the schedule.
    Function(fn(f64) -> f64),
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
            ZetaSchedule::Function(_) => write!(f, "Function(..)"),
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
            ZetaSchedule::Function(f) => f(t),
        }
    }

    /// A copy of the schedule; `None` for `Custom` (a boxed closure cannot be cloned).
    pub fn try_clone(&self) -> Option<ZetaSchedule> {
        Some(match self {
            ZetaSchedule::Constant(z) => ZetaSchedule::Constant(*z),
            ZetaSchedule::Ramp {
                start_s,
                duration_s,
                from,
                to,
            } => ZetaSchedule::Ramp {
                start_s: *start_s,
                duration_s: *duration_s,
                from: *from,
                to: *to,
            },
            ZetaSchedule::Table(t) => ZetaSchedule::Table(t.clone()),
            ZetaSchedule::Function(f) => ZetaSchedule::Function(*f),
            ZetaSchedule::Custom(_) => return None,
        })
    }

    /// Mean over `[t0, t1]` (midpoint rule, 200 points: enough for the piecewise-linear and
    /// piecewise-constant schedules of the scenarios, whose kinks fall anywhere in a window).
    pub fn mean(&self, t0: f64, t1: f64) -> f64 {
        if t1 <= t0 {
            return self.at(t0);
        }
        let n = 200;
        (0..n)
            .map(|i| self.at(t0 + (i as f64 + 0.5) / n as f64 * (t1 - t0)))
            .sum::<f64>()
            / n as f64
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
