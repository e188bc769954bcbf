//! Numbers in messages: [`Num`] prints a user's number plainly when it is moderate and in
//! scientific form when it is not.
//!
//! Why: Rust's `{}` prints an `f64` in full positional form, so a message refusing
//! `rate_hz = 1e300` or `--rate 1e300` quoted a 301-digit number, and `1e-300` came out as
//! 300 zeros; `{:e}` everywhere would print `600` as `6e2`. Used by the errors that quote a
//! value the user gave (configuration, command-line options, ingested samples).

use std::fmt;

/// Below this magnitude (but not zero) a number is printed in scientific form.
const PLAIN_MIN: f64 = 1e-4;
/// From this magnitude on a number is printed in scientific form (15 integer digits are still
/// read at a glance, and every integer below it is exact in an `f64`).
const PLAIN_MAX: f64 = 1e15;

/// `x` for a message: plain (`600`, `0.25`, `-3.5`) when `1e-4 <= |x| < 1e15` or `x` is 0,
/// scientific (`1e300`, `-2.5e-7`) otherwise; `inf`, `-inf` and `NaN` as Rust prints them.
/// A precision (`{:.3}`) applies to the plain form only: a scientific one is always the
/// shortest that reads back as `x` (a width right-aligns it).
///
/// ```
/// use gatewatch::number::Num;
/// assert_eq!(Num(600.0).to_string(), "600");
/// assert_eq!(Num(1e300).to_string(), "1e300");
/// assert_eq!(format!("{:.2}", Num(3.14159)), "3.14");
/// assert_eq!(format!("{:.2}", Num(-1e-300)), "-1e-300");
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl Num {
    /// Whether `x` is printed in plain form (for a caller with a plain format of its own).
    pub fn is_plain(self) -> bool {
        let a = self.0.abs();
        !self.0.is_finite() || a == 0.0 || (PLAIN_MIN..PLAIN_MAX).contains(&a)
    }
}

/// `x` rounded to `digits` significant digits, through its decimal form, so that it prints
/// short: `0.01235`, not `0.012345678901234567` (the store's curve points), `0.005` for a step
/// computed from times as `0.004999999999999999`. Infinite, NaN and zero are returned as they
/// are.
///
/// ```
/// use gatewatch::number::round_significant;
/// assert_eq!(round_significant(0.012345678901234567, 4), 0.01235);
/// assert_eq!(round_significant(0.004999999999999999, 12), 0.005);
/// ```
pub fn round_significant(x: f64, digits: usize) -> f64 {
    if !x.is_finite() || x == 0.0 {
        return x;
    }
    format!("{x:.*e}", digits.saturating_sub(1))
        .parse()
        .unwrap_or(x)
}

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        if self.is_plain() {
            return fmt::Display::fmt(&x, f);
        }
        // the shortest form, whatever the precision (`{:.4e}` would print `1.0000e300`); a
        // width right-aligns it, as numbers are
        let width = f.width().unwrap_or(0);
        write!(f, "{:>width$}", format!("{x:e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn moderate_numbers_are_plain_and_extreme_ones_scientific() {
        for (x, shown) in [
            (0.0, "0"),
            (-0.0, "-0"),
            (600.0, "600"),
            (0.25, "0.25"),
            (-3.5, "-3.5"),
            (31_536_000.0, "31536000"),
            (1e-4, "0.0001"),
            (999_999_999_999_999.0, "999999999999999"),
            (1e15, "1e15"),
            (1e300, "1e300"),
            (-1e300, "-1e300"),
            (1.5e-7, "1.5e-7"),
            (1e-300, "1e-300"),
            (f64::MAX, "1.7976931348623157e308"),
            (f64::MIN_POSITIVE, "2.2250738585072014e-308"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
            (f64::NAN, "NaN"),
        ] {
            assert_eq!(Num(x).to_string(), shown, "{x:e}");
            // the printed form reads back as the number itself
            if x.is_finite() {
                assert_eq!(
                    shown.parse::<f64>().unwrap().to_bits(),
                    x.to_bits(),
                    "{shown}"
                );
            }
        }
    }

    #[test]
    fn a_precision_applies_to_the_plain_form_only() {
        assert_eq!(format!("{:.4}", Num(62.831_853_071_795_86)), "62.8319");
        assert_eq!(format!("{:.1}", Num(600.0)), "600.0");
        assert_eq!(format!("{:.4}", Num(1e300)), "1e300");
        assert_eq!(format!("{:.4}", Num(-2.5e-9)), "-2.5e-9");
        // the width too, as for any Display
        assert_eq!(format!("{:>6}", Num(1e300)), " 1e300");
    }
}
