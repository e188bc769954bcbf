//! Blows on the gate: debris, an ice floe, a vessel touching the leaf.
//!
//! # Why a scenario of its own
//! A blow starts a free vibration far above the gate's ambient level whose envelope jumps within
//! a cycle and then decays at the gate's own (positive) damping. The window it lands late in sees
//! an envelope that grows, steeply and far above the level: what a self-excited onset looks like
//! to a test of the envelope's growth. The alert rules were built around that case (a growing
//! window far above the level is negative but never at once, `docs/alerts.md`), and nothing
//! measured it until this scenario: a gate that is struck must never page.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Blows on the gate, each an instantaneous change of velocity (an impulse short against the
/// gate's period) that starts a free vibration of a seeded size, on top of the motion the gate
/// already has. All zero: no blow.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Impacts {
    /// Mean seconds between blows (0: none); each interval is uniform on `[0.5, 1.5]` times it.
    pub every_s: f64,
    /// Smallest displacement amplitude a blow starts, m.
    pub amplitude_min: f64,
    /// Largest displacement amplitude a blow starts, m (the size is uniform between the two).
    pub amplitude_max: f64,
}

impl Impacts {
    /// Whether any blow is set.
    pub fn is_active(&self) -> bool {
        self.every_s > 0.0 && self.amplitude_max > 0.0
    }

    /// The time of the next blow after one at `t`, s.
    pub(crate) fn next_after(&self, t: f64, rng: &mut ChaCha8Rng) -> f64 {
        let u: f64 = rng.random();
        t + self.every_s * (0.5 + u)
    }

    /// The velocity change of a blow on a gate of angular frequency `omega`, m/s: an amplitude
    /// uniform between the two bounds, of either sign.
    pub(crate) fn kick(&self, omega: f64, rng: &mut ChaCha8Rng) -> f64 {
        let u_size: f64 = rng.random();
        let u_sign: f64 = rng.random();
        let amplitude =
            self.amplitude_min + (self.amplitude_max - self.amplitude_min).max(0.0) * u_size;
        let dv = amplitude * omega;
        if u_sign < 0.5 {
            -dv
        } else {
            dv
        }
    }
}
