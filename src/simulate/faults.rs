//! Sensor faults: what a load cell and its cabling do to a signal besides white noise.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Faults applied to the measured output, in output units (N for force), in this order: a DC
/// offset from `dc_offset_from_s` on, spikes, clipping, dropouts. All zero: no fault.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SensorFaults {
    /// Mean number of single-sample spikes per second (Poisson; a spike is one sample, as an
    /// electrical transient on the bridge is shorter than a sample interval).
    pub spikes_per_s: f64,
    /// Height of a spike, output units (sign random).
    pub spike_height: f64,
    /// Mean number of dropouts per second (Poisson).
    pub dropouts_per_s: f64,
    /// Length of one dropout, s: the reading is 0 (a loose connector reads zero, it does not
    /// stop the stream, so the daemon sees plausible-looking samples).
    pub dropout_s: f64,
    /// Saturation of the amplifier: `|output|` is clipped to this, output units (0: none).
    pub clip: f64,
    /// A step in the zero point (re-zeroing, temperature), output units.
    pub dc_offset: f64,
    /// Time the DC offset appears, s.
    pub dc_offset_from_s: f64,
}

impl SensorFaults {
    /// Whether any fault is set.
    pub fn is_active(&self) -> bool {
        self.spikes_per_s > 0.0
            || self.dropouts_per_s > 0.0
            || self.clip > 0.0
            || self.dc_offset != 0.0
    }

    /// The faulty reading of `out` at time `t`. Draws the same number of random values at every
    /// sample whatever happens, so a seed gives the same faults whatever else is set.
    pub(crate) fn apply(
        &self,
        mut out: f64,
        t: f64,
        rate_hz: f64,
        rng: &mut ChaCha8Rng,
        dropout_left: &mut u64,
    ) -> f64 {
        let u_spike: f64 = rng.random();
        let u_sign: f64 = rng.random();
        let u_drop: f64 = rng.random();
        if self.dc_offset != 0.0 && t >= self.dc_offset_from_s {
            out += self.dc_offset;
        }
        if u_spike < self.spikes_per_s / rate_hz {
            out += if u_sign < 0.5 {
                -self.spike_height
            } else {
                self.spike_height
            };
        }
        if self.clip > 0.0 {
            out = out.clamp(-self.clip, self.clip);
        }
        if *dropout_left == 0 && u_drop < self.dropouts_per_s / rate_hz {
            *dropout_left = (self.dropout_s * rate_hz).round().max(1.0) as u64;
        }
        if *dropout_left > 0 {
            *dropout_left -= 1;
            out = 0.0;
        }
        out
    }
}
