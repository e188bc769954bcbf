//! `sin` and `cos` of the model language, one routine for the scalar and the lane evaluators.
//!
//! Why not `f64::sin`: it is a call into the C library per lane, with branches on the argument's
//! size, so the lane evaluator could not vectorise it, and under `perf` it was half of the
//! forced linear seed case's time (`sin(c5*t)`; docs/benchmarks.md, "sin and cos in lanes").
//! Why by hand: `wide` (already in the tree through nalgebra) has a branch-free `f64x4` sine
//! (the same reduction and polynomials as here), but on plain SSE2 it converts each quotient to
//! an integer one lane at a time and compares 64-bit integers, which SSE2 lacks; it measured no
//! faster than this kernel (forced_linear 0.1108 against 0.1105 s per run, `bench seed-cases
//! --runs 25`), which keeps the quadrant in the rounded quotient's low mantissa bits and selects
//! with bit masks, so that LLVM vectorises the loop over the lanes with SSE2 alone. It is
//! Cody-Waite reduction by pi/2 in three parts and Cephes' minimax polynomials, as in Agner
//! Fog's vector class library.
//!
//! Bit-identical across lane widths: the scalar evaluator calls the same kernel on one lane,
//! and a lane's result depends only on its argument (IEEE operations, no fused multiply-add:
//! Rust never contracts `a * b + c`). Arguments outside `|x| <= `[`REDUCTION_LIMIT`] (and NaN,
//! infinities) take `f64::sin` / `f64::cos` in both evaluators: beyond it the three-part
//! reduction loses digits. Accuracy against the C library's routines (correctly rounded in
//! practice) is tested in `model::tests::trig_accuracy`: at most 2 units in the last place of
//! the larger of the result and 2^-53 inside the limit (1.41 for sin, 1.00 for cos measured on
//! 400,000 random arguments up to 1e6 and the multiples of pi/4 up to 500 pi and their
//! neighbours).

#![allow(clippy::excessive_precision)]

/// Largest `|x|` reduced here: `n * DP1` (the first part of pi/2 has 25 significant bits)
/// stays exact for quotients `n` below 2^28, i.e. `|x|` below about 4e8; 1e6 leaves a margin of
/// 400 and covers any phase a model's `sin(w*t)` reaches on a day of data at 10 Hz (`w t` about
/// 5e6 would need 9 days).
pub const REDUCTION_LIMIT: f64 = 1e6;

// The constants are written as published (Cephes), digits beyond an f64's included, so that they
// can be checked against the source; the compiler rounds them.
// pi/2 in three parts (Cephes' DP1..DP3 for pi/4, doubled): n * DP1 and n * DP2 are exact for
// the quotients n below REDUCTION_LIMIT * 2 / pi.
const DP1: f64 = 7.853_981_554_508_209_228_515_625E-1 * 2.0;
const DP2: f64 = 7.946_627_356_147_928_367_14E-9 * 2.0;
const DP3: f64 = 3.061_616_997_868_382_943_07E-17 * 2.0;
// Cephes' minimax polynomials of sin and cos on [-pi/4, pi/4] (as in Agner Fog's vector class
// library and the `wide` crate).
const S: [f64; 6] = [
    -1.666_666_666_666_663_072_95E-1,
    8.333_333_333_322_118_588_78E-3,
    -1.984_126_982_958_953_859_96E-4,
    2.755_731_362_138_572_452_13E-6,
    -2.505_074_776_285_780_728_66E-8,
    1.589_623_015_765_465_680_60E-10,
];
const C: [f64; 6] = [
    4.166_666_666_666_659_292_18E-2,
    -1.388_888_888_887_305_641_16E-3,
    2.480_158_728_885_170_453_48E-5,
    -2.755_731_417_929_673_881_12E-7,
    2.087_570_084_197_473_167_78E-9,
    -1.135_853_652_138_768_173_00E-11,
];
/// 1.5 * 2^52: adding it rounds a number below 2^51 in magnitude to the nearest integer (ties
/// to even), which then sits in the low bits of the sum's mantissa (offset by 2^51, a multiple
/// of 4, so the two lowest bits are the quadrant).
const ROUND: f64 = 6_755_399_441_055_744.0;

/// The value of `sin` (`shift` 0) or `cos` (`shift` 1) at `x`, for `|x| <= REDUCTION_LIMIT`:
/// straight-line code of `f64` arithmetic and 64-bit integer bit operations, which SSE2 has,
/// so that a loop over lanes vectorises (no branch, no conversion to an integer).
#[inline(always)]
fn kernel(x: f64, shift: u64) -> f64 {
    let rounded = x * std::f64::consts::FRAC_2_PI + ROUND;
    let quadrant = rounded.to_bits().wrapping_add(shift);
    let n = rounded - ROUND;
    let r = ((x - n * DP1) - n * DP2) - n * DP3;
    let z = r * r;
    let ps = S[0] + z * (S[1] + z * (S[2] + z * (S[3] + z * (S[4] + z * S[5]))));
    let pc = C[0] + z * (C[1] + z * (C[2] + z * (C[3] + z * (C[4] + z * C[5]))));
    let s = r + (r * z) * ps;
    let c = (1.0 - 0.5 * z) + (z * z) * pc;
    // Odd quadrants take the other polynomial; quadrants 2 and 3 flip the sign.
    let take_cos = (quadrant & 1).wrapping_neg();
    let bits = (c.to_bits() & take_cos) | (s.to_bits() & !take_cos);
    f64::from_bits(bits ^ ((quadrant & 2) << 62))
}

#[inline(always)]
fn apply<const L: usize>(a: &mut [f64; L], shift: u64, f: fn(f64) -> f64) {
    let x = *a;
    for (a, &x) in a.iter_mut().zip(&x) {
        *a = kernel(x, shift);
    }
    // Lanes the reduction does not cover take `f` (one vector test over the lanes; the scalar
    // loop runs only when a lane fails it). NaN is outside too.
    let outside = |x: f64| x.is_nan() || x.abs() > REDUCTION_LIMIT;
    if x.iter().fold(false, |any, &x| any | outside(x)) {
        for (a, &x) in a.iter_mut().zip(&x) {
            if outside(x) {
                *a = f(x);
            }
        }
    }
}

/// `sin` of every lane in place (see the module docs).
#[inline(always)]
pub fn sin_lanes<const L: usize>(a: &mut [f64; L]) {
    apply(a, 0, f64::sin);
}

/// `cos` of every lane in place (see the module docs).
#[inline(always)]
pub fn cos_lanes<const L: usize>(a: &mut [f64; L]) {
    apply(a, 1, f64::cos);
}

/// `sin(x)`, the value the lane evaluator gives for `x` (see the module docs).
#[inline]
pub fn sin(x: f64) -> f64 {
    let mut a = [x];
    sin_lanes(&mut a);
    a[0]
}

/// `cos(x)`, the value the lane evaluator gives for `x` (see the module docs).
#[inline]
pub fn cos(x: f64) -> f64 {
    let mut a = [x];
    cos_lanes(&mut a);
    a[0]
}
