//! The compiled model evaluated for `L` candidates at once (lockstep lanes).
//!
//! The same instructions as [`super::program`]'s scalar `run`, but every register and stack slot
//! is an `[f64; L]`: one dispatch of an instruction serves all lanes, and the per-lane loop inside
//! each instruction is a fixed-length loop over independent values that LLVM turns into vector
//! arithmetic. Each lane performs exactly the operations of the scalar evaluator in the same
//! order (no reassociation, no fused multiply-add: Rust never contracts `a * b + c`), so a lane's
//! result is bit-identical to `Program::eval` on that lane's inputs. Functions without a vector
//! form (`powf`, `exp`, ...) are applied lane by lane with the scalar routine; `sin` and `cos`
//! are the vector routines of [`super::trig`], which the scalar evaluator shares.

use super::linear::pow;
use super::parser::{max, min, sign, step};
use super::program::{Instr, Program, STACK_CAP};
use super::{MassKind, Model};
use crate::ode::LaneSystem;

impl Program {
    /// Evaluates the program on `L` lanes: `t[l], y[l], yd[l]` with coefficient `k` of lane `l`
    /// at `c[k][l]` (structure of arrays). A missing coefficient (`c` too short) reads as NaN.
    #[inline]
    pub fn eval_lanes<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[[f64; L]],
    ) -> [f64; L] {
        let mut out = [0.0; L];
        self.eval_lanes_then(t, y, yd, c, &mut out, |_| {});
        out
    }

    /// [`Self::eval_lanes`] into `out`, with `finish` applied to the result before it is written
    /// (`|_| {}` for the plain value).
    ///
    /// Why an out-parameter: a returned `[f64; L]` is written through the caller's return slot,
    /// and LLVM then kept the evaluator's accumulator in that memory, so every instruction
    /// stored and reloaded it on the critical path. Accumulating in a local and writing `out`
    /// once keeps it in registers: 1.3 times faster (38 -> 29 ns for 8 lanes of the daemon's model,
    /// `cargo bench --bench model_eval`), with the same operations in the same order.
    ///
    /// Why `finish`: the acceleration is `-R / M`, and negating and dividing `out` after it was
    /// written stored the result, loaded it back and stored it again on every right-hand-side
    /// evaluation (17 % of a batched RK4 step of van_der_pol_2 under `perf`). Applied to the
    /// accumulator it stays in registers. `finish` performs the same operations, so results are
    /// unchanged.
    ///
    /// The stack tier follows the program's depth: the stack is zeroed on every call, and most
    /// models need one slot or none (van_der_pol_2, the daemon's model and forced_linear: one).
    #[inline]
    pub fn eval_lanes_then<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[[f64; L]],
        out: &mut [f64; L],
        finish: impl FnOnce(&mut [f64; L]),
    ) {
        let (code, depth) = self.code();
        if depth <= 1 {
            run::<L, 1>(code, t, y, yd, c, out, finish)
        } else if depth <= 4 {
            run::<L, 4>(code, t, y, yd, c, out, finish)
        } else if depth <= 32 {
            run::<L, 32>(code, t, y, yd, c, out, finish)
        } else {
            run::<L, STACK_CAP>(code, t, y, yd, c, out, finish)
        }
    }
}

#[inline(always)]
fn run<const L: usize, const N: usize>(
    code: &[Instr],
    t: &[f64; L],
    y: &[f64; L],
    yd: &[f64; L],
    c: &[[f64; L]],
    out: &mut [f64; L],
    finish: impl FnOnce(&mut [f64; L]),
) {
    // References, not copies: copying the three variables cost 24 vector moves per call.
    let zero = [0.0; L];
    let vars: [&[f64; L]; 4] = [t, y, yd, &zero];
    let nan = [f64::NAN; L];
    let mut st = [[0.0f64; L]; N];
    let mut sp = 0usize;
    let mut acc = [0.0f64; L];
    // `acc[l] = f(acc[l], operand[l])` for every lane.
    macro_rules! each {
        (|$a:ident, $b:ident| $e:expr, $v:expr) => {{
            let v: &[f64; L] = $v;
            for l in 0..L {
                let ($a, $b) = (acc[l], v[l]);
                acc[l] = $e;
            }
        }};
        (|$a:ident| $e:expr) => {{
            for l in 0..L {
                let $a = acc[l];
                acc[l] = $e;
            }
        }};
    }
    macro_rules! var {
        ($i:expr) => {
            vars[($i & 3) as usize]
        };
    }
    macro_rules! coef {
        ($i:expr) => {
            match c.get($i as usize) {
                Some(v) => v,
                None => &nan,
            }
        };
    }
    macro_rules! splat {
        ($x:expr) => {
            &[$x; L]
        };
    }
    macro_rules! push {
        ($v:expr) => {{
            let v: [f64; L] = *$v;
            if let Some(s) = st.get_mut(sp) {
                *s = acc;
            }
            sp += 1;
            acc = v;
        }};
    }
    macro_rules! pop {
        () => {{
            sp = sp.wrapping_sub(1);
            match st.get(sp) {
                Some(v) => v,
                None => &nan,
            }
        }};
    }
    for ins in code {
        match *ins {
            Instr::LoadK(x) => acc = [x; L],
            Instr::LoadC(i) => acc = *coef!(i),
            Instr::LoadV(i) => acc = *var!(i),
            Instr::PushK(x) => push!(splat!(x)),
            Instr::PushC(i) => push!(coef!(i)),
            Instr::PushV(i) => push!(var!(i)),
            Instr::AddK(x) => each!(|a, b| a + b, splat!(x)),
            Instr::AddC(i) => each!(|a, b| a + b, coef!(i)),
            Instr::AddV(i) => each!(|a, b| a + b, var!(i)),
            Instr::SubK(x) => each!(|a, b| a - b, splat!(x)),
            Instr::SubC(i) => each!(|a, b| a - b, coef!(i)),
            Instr::SubV(i) => each!(|a, b| a - b, var!(i)),
            Instr::RSubK(x) => each!(|a, b| b - a, splat!(x)),
            Instr::RSubC(i) => each!(|a, b| b - a, coef!(i)),
            Instr::RSubV(i) => each!(|a, b| b - a, var!(i)),
            Instr::MulK(x) => each!(|a, b| a * b, splat!(x)),
            Instr::MulC(i) => each!(|a, b| a * b, coef!(i)),
            Instr::MulV(i) => each!(|a, b| a * b, var!(i)),
            Instr::DivK(x) => each!(|a, b| a / b, splat!(x)),
            Instr::DivC(i) => each!(|a, b| a / b, coef!(i)),
            Instr::DivV(i) => each!(|a, b| a / b, var!(i)),
            Instr::RDivK(x) => each!(|a, b| b / a, splat!(x)),
            Instr::RDivC(i) => each!(|a, b| b / a, coef!(i)),
            Instr::RDivV(i) => each!(|a, b| b / a, var!(i)),
            Instr::PowK(x) => each!(|a, b| pow(a, b), splat!(x)),
            Instr::PowC(i) => each!(|a, b| pow(a, b), coef!(i)),
            Instr::PowV(i) => each!(|a, b| pow(a, b), var!(i)),
            // Stack forms: the popped value is the left operand.
            Instr::AddS => each!(|a, b| a + b, pop!()),
            Instr::SubS => each!(|a, b| b - a, pop!()),
            Instr::MulS => each!(|a, b| a * b, pop!()),
            Instr::DivS => each!(|a, b| b / a, pop!()),
            Instr::PowS => each!(|a, b| pow(b, a), pop!()),
            Instr::MinS => each!(|a, b| min(b, a), pop!()),
            Instr::MaxS => each!(|a, b| max(b, a), pop!()),
            Instr::Neg => each!(|a| -a),
            Instr::Square => each!(|a| a * a),
            Instr::Cube => each!(|a| a * a * a),
            Instr::Powi(n) => each!(|a| a.powi(n)),
            Instr::Sin => super::trig::sin_lanes(&mut acc),
            Instr::Cos => super::trig::cos_lanes(&mut acc),
            Instr::Tan => each!(|a| a.tan()),
            Instr::Exp => each!(|a| a.exp()),
            Instr::Ln => each!(|a| a.ln()),
            Instr::Sqrt => each!(|a| a.sqrt()),
            Instr::Abs => each!(|a| a.abs()),
            Instr::Sign => each!(|a| sign(a)),
            Instr::Tanh => each!(|a| a.tanh()),
            Instr::Step => each!(|a| step(a)),
        }
    }
    finish(&mut acc);
    *out = acc;
}

impl Model {
    /// `R(t, y, yd)` for `L` lanes (coefficient `k` of lane `l` at `c[k][l]`); lane `l` equals
    /// [`Model::residual`] on its inputs bit for bit.
    #[inline]
    pub fn residual_lanes<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[[f64; L]],
    ) -> [f64; L] {
        let mut out = [0.0; L];
        if let Some(jit) = &self.jit {
            if jit.residual(t, y, yd, c.as_flattened(), &mut out) {
                return out;
            }
        }
        self.residual.eval_lanes(t, y, yd, c)
    }

    /// `ydd = -R / M` for `L` lanes; lane `l` equals [`Model::accel`] on its inputs bit for bit.
    #[inline]
    pub fn accel_lanes<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[[f64; L]],
    ) -> [f64; L] {
        let mut r = [0.0; L];
        self.accel_lanes_into(t, y, yd, c, &mut r);
        r
    }

    /// [`Self::accel_lanes`] into `r` (see `Program::eval_lanes_then` for why).
    #[inline]
    pub fn accel_lanes_into<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[[f64; L]],
        r: &mut [f64; L],
    ) {
        if let Some(jit) = &self.jit {
            if jit.accel(t, y, yd, c.as_flattened(), r) {
                return;
            }
        }
        let neg = |a: &mut [f64; L]| a.iter_mut().for_each(|v| *v = -*v);
        match self.mass_kind {
            MassKind::One => self.residual.eval_lanes_then(t, y, yd, c, r, neg),
            MassKind::Const(m) => self
                .residual
                .eval_lanes_then(t, y, yd, c, r, |a| a.iter_mut().for_each(|v| *v = -*v / m)),
            MassKind::Coef(i) => {
                let nan = [f64::NAN; L];
                let m = c.get(i as usize).unwrap_or(&nan);
                self.residual.eval_lanes_then(t, y, yd, c, r, |a| {
                    for l in 0..L {
                        a[l] = -a[l] / m[l];
                    }
                })
            }
            MassKind::Varying => {
                self.residual.eval_lanes_then(t, y, yd, c, r, |_| {});
                let m = self.mass.eval_lanes(t, y, yd, c);
                for l in 0..L {
                    r[l] = -r[l] / m[l];
                }
            }
        }
    }
}

/// A model with `L` coefficient vectors bound to it, in structure-of-arrays form (coefficient
/// `k` of lane `l` at `coeffs[k][l]`): `L` first-order systems `[y, yd]' = [yd, ydd]`.
#[derive(Debug, Clone, Copy)]
pub struct BoundLanes<'a, const L: usize> {
    /// The compiled model.
    pub model: &'a Model,
    /// The lanes' coefficients.
    pub coeffs: &'a [[f64; L]],
}

impl<const L: usize> LaneSystem<L, 2> for BoundLanes<'_, L> {
    #[inline]
    fn rhs(&self, t: &[f64; L], s: &[[f64; L]; 2], ds: &mut [[f64; L]; 2]) {
        ds[0] = s[1];
        self.model
            .accel_lanes_into(t, &s[0], &s[1], self.coeffs, &mut ds[1]);
    }
}
