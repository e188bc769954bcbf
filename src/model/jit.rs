//! The compiled model as machine code: the accumulator program translated by Cranelift.
//!
//! Why: the interpreters of [`super::program`] and [`super::program_lanes`] dispatch once per
//! instruction and keep the stack in memory; for 8 lanes that is about 1.3 ns per instruction, and
//! the lane evaluator was 40 % of a daemon's cold window (docs/benchmarks.md, "The model as
//! machine code"). Translated, the stack disappears (it is known at compile time, so every slot
//! becomes an SSA value held in a register) and nothing is dispatched.
//!
//! What: for one model, up to five functions with one signature,
//! `fn(t, y, yd, c, out)` (five pointers, nothing returned):
//!
//! - the acceleration `-R / M` for 1, 4 and 8 lanes (a constant or coefficient mass only; a
//!   varying mass stays with the interpreter);
//! - the residual `R` for 1 and 8 lanes (the force output's residuals).
//!
//! Lanes are `f64x2` vectors (SSE2, every x86-64; NEON on aarch64): 8 lanes are four of them,
//! advanced together instruction by instruction. One lane is plain `f64`. `sin` and `cos` call
//! the kernels of [`super::trig`] (the lane kernel on a stack slot holding every vector).
//!
//! Exactness: every lane performs the operations of the interpreter in the same order with the
//! same IEEE-754 double operations (add, sub, mul, div, neg, abs, sqrt; Cranelift neither contracts
//! `a * b + c` into a fused multiply-add nor reassociates), and `powi` is expanded into the
//! multiplications of compiler-builtins' `__powidf2`, which is what `f64::powi` calls for an
//! exponent known only at run time. So results are bit-identical to the interpreter, except
//! which NaN a NaN is (an operation on two NaNs returns one of them, chosen by the operand
//! order of the machine instruction; Rust promises no NaN's bits, and every consumer only asks
//! `is_finite`): `jit_matches_the_interpreter_bit_for_bit` below, on random inputs that reach
//! zeros, infinities and NaNs, and `tests/lanes.rs`. `sin` and `cos` are the interpreter's own
//! kernels, whose value does not depend on the lane count. Programs with any other instruction
//! (`pow` with a non-integer exponent, `min`, `exp`, ...) are not translated and stay with the
//! interpreter: [`Compiled::new`] returns `None`.
//!
//! Memory: the translated code lives in pages owned by the module; [`Compiled`] frees them when
//! dropped (the last clone of a [`super::Model`]).

use super::program::{Instr, Program};
use cranelift_codegen::ir::{
    types, AbiParam, InstBuilder, MemFlags, StackSlotData, StackSlotKind, Type, Value,
};
use cranelift_codegen::settings::{self, Configurable};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::{JITBuilder, JITModule};
use cranelift_module::{FuncId, Linkage, Module};
use std::sync::atomic::{AtomicBool, Ordering};

/// Set when a translation failed for a reason of the host, not of the program.
static UNAVAILABLE: AtomicBool = AtomicBool::new(false);

/// Longest program translated. Translation is paid once per parsed model (0.3 ms for the
/// daemon's model against 1.6 us to parse it, criterion `parse/daemon_model`) and grows with
/// the program's length (a 200,000-instruction program took seconds); a longer program (a model
/// of hundreds of terms, which nobody identifies) stays with the interpreter, so a parse stays
/// cheap whatever the equation's length.
pub(crate) const MAX_INSTRUCTIONS: usize = 512;

/// The signature of every translated function: `t`, `y`, `yd` (one value per lane), the
/// coefficients (`c[k][l]` at `c + (k * lanes + l)`), and the output (one value per lane).
///
/// Calling one is sound only with pointers valid for the reads and the write of its lane count
/// and with at least [`Compiled::coefficients`] coefficient rows (see [`Compiled`]).
pub(crate) type LaneFn =
    unsafe extern "C" fn(*const f64, *const f64, *const f64, *const f64, *mut f64);

/// How the acceleration finishes from `R`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Finish {
    /// `-R`.
    Neg,
    /// `-R / m`.
    NegDivConst(f64),
    /// `-R / c[i]`.
    NegDivCoef(u32),
}

/// A model's translated functions.
///
/// # Safety of the calls
///
/// The functions read, for a lane count `L`: `L` doubles at each of `t`, `y` and `yd`,
/// `L * (i + 1)` doubles at `c` for the largest coefficient index `i` they use (that is,
/// `coefficients * L` doubles at most), and write `L` doubles at `out`. They touch no other
/// memory but their own stack frame, keep no pointer, and call only the `sin`/`cos` callbacks
/// below (on that frame's slot, or on a value). Their one caller, `Compiled::call`, passes
/// `&[f64; L]` for the variables and the output and checks the coefficients' length; the reads
/// and the write are unaligned vector accesses (no alignment is assumed beyond `f64`'s).
pub(crate) struct Compiled {
    /// Owns the code pages; `None` only during drop.
    module: Option<JITModule>,
    coefficients: usize,
    accel1: LaneFn,
    accel4: LaneFn,
    accel8: LaneFn,
    residual1: LaneFn,
    residual8: LaneFn,
}

// SAFETY: `JITModule` is not `Send` or `Sync` because of fields used while compiling and
// linking (a `RefCell` of symbols, a boxed memory provider holding raw pointers to its pages).
// `Compiled` never touches the module after `new` returns: no method reads it, and the only use
// is `free_memory` in `drop`, which has exclusive access. The pages are allocated with the
// global allocator, which may free them from any thread. The function pointers are plain code
// addresses, valid until that drop, and the code they point to is read-only and keeps no state,
// so calling them from several threads at once is sound.
unsafe impl Send for Compiled {}
// SAFETY: see `Send` above; `&Compiled` gives access only to the `Copy` function pointers and
// `coefficients`.
unsafe impl Sync for Compiled {}

impl std::fmt::Debug for Compiled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Compiled")
            .field("coefficients", &self.coefficients)
            .finish_non_exhaustive()
    }
}

impl Drop for Compiled {
    fn drop(&mut self) {
        if let Some(m) = self.module.take() {
            // SAFETY: the function pointers are private fields of `self`, which is being
            // dropped; they are only called by `Compiled::call` through `&self`, so none can
            // be called after this.
            unsafe { m.free_memory() };
        }
    }
}

impl Compiled {
    /// Translates the residual program `r` with the acceleration's `finish`; `None` when the
    /// program has an instruction without a translation or the host has no Cranelift backend.
    pub(crate) fn new(r: &Program, finish: Finish) -> Option<Compiled> {
        let (code, _) = r.code();
        if code.len() > MAX_INSTRUCTIONS || !code.iter().all(translatable) {
            return None;
        }
        if UNAVAILABLE.load(Ordering::Relaxed) {
            return None;
        }
        let compiled = Self::translate(code, finish);
        if compiled.is_none() {
            // The host refused executable memory (systemd's `MemoryDenyWriteExecute=yes`, a
            // seccomp or SELinux policy) or has no backend: it will not change, so the next
            // models go straight to the interpreter.
            UNAVAILABLE.store(true, Ordering::Relaxed);
        }
        compiled
    }

    fn translate(code: &[Instr], finish: Finish) -> Option<Compiled> {
        let coefficients = needed_coefficients(code, finish);
        let mut flags = settings::builder();
        flags.set("opt_level", "speed").ok()?;
        flags.set("is_pic", "false").ok()?;
        flags.set("use_colocated_libcalls", "false").ok()?;
        let isa = cranelift_native::builder()
            .ok()?
            .finish(settings::Flags::new(flags))
            .ok()?;
        let mut builder = JITBuilder::with_isa(isa, cranelift_module::default_libcall_names());
        builder.symbol("gatewatch_sin_lanes", sin_lanes as *const u8);
        builder.symbol("gatewatch_cos_lanes", cos_lanes as *const u8);
        builder.symbol("gatewatch_sin1", sin1 as *const u8);
        builder.symbol("gatewatch_cos1", cos1 as *const u8);
        let mut module = JITModule::new(builder);
        let ptr = module.target_config().pointer_type();
        let mut by_ptr = module.make_signature();
        by_ptr.params.push(AbiParam::new(ptr));
        let mut scalar = module.make_signature();
        scalar.params.push(AbiParam::new(types::F64));
        scalar.returns.push(AbiParam::new(types::F64));
        let mut import = |name: &str, sig: &cranelift_codegen::ir::Signature| {
            module.declare_function(name, Linkage::Import, sig).ok()
        };
        let callees = Callees {
            sin_lanes: import("gatewatch_sin_lanes", &by_ptr)?,
            cos_lanes: import("gatewatch_cos_lanes", &by_ptr)?,
            sin1: import("gatewatch_sin1", &scalar)?,
            cos1: import("gatewatch_cos1", &scalar)?,
        };
        let specs = [
            ("accel1", types::F64, 1, Some(finish)),
            ("accel4", types::F64X2, 4, Some(finish)),
            ("accel8", types::F64X2, 8, Some(finish)),
            ("residual1", types::F64, 1, None),
            ("residual8", types::F64X2, 8, None),
        ];
        let mut ids = Vec::with_capacity(specs.len());
        let mut ctx = module.make_context();
        let mut fctx = FunctionBuilderContext::new();
        for (name, ty, lanes, fin) in specs {
            ctx.func.signature.params = vec![AbiParam::new(ptr); 5];
            ctx.func.signature.returns.clear();
            emit(
                &mut module,
                &mut ctx.func,
                &mut fctx,
                callees,
                code,
                ty,
                lanes,
                fin,
            );
            let id = module
                .declare_function(name, Linkage::Local, &ctx.func.signature)
                .ok()?;
            module.define_function(id, &mut ctx).ok()?;
            module.clear_context(&mut ctx);
            ids.push(id);
        }
        if module.finalize_definitions().is_err() {
            // SAFETY: no function pointer was taken from this module.
            unsafe { module.free_memory() };
            return None;
        }
        let f = |i: usize| -> LaneFn {
            let p = module.get_finalized_function(ids[i]);
            // SAFETY: `p` is the entry of a function just compiled with the signature of
            // `LaneFn` (five pointer parameters, no result) in the host's default calling
            // convention, which Cranelift's `make_context` gives and which is `extern "C"`.
            unsafe { std::mem::transmute::<*const u8, LaneFn>(p) }
        };
        let (accel1, accel4, accel8, residual1, residual8) = (f(0), f(1), f(2), f(3), f(4));
        Some(Compiled {
            module: Some(module),
            coefficients,
            accel1,
            accel4,
            accel8,
            residual1,
            residual8,
        })
    }

    /// `-R / M` on `L` lanes into `out` (coefficient `k` of lane `l` at `c[k * L + l]`); `false`,
    /// with nothing done, when there is no function for `L` lanes (1, 4 and 8 have one) or `c`
    /// holds fewer coefficients than the program reads (the interpreter then reads NaN).
    #[inline(always)]
    pub(crate) fn accel<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[f64],
        out: &mut [f64; L],
    ) -> bool {
        let f = match L {
            1 => self.accel1,
            4 => self.accel4,
            8 => self.accel8,
            _ => return false,
        };
        self.call(f, t, y, yd, c, out)
    }

    /// `R` on `L` lanes into `out`, as [`Self::accel`] (1 and 8 lanes have a function).
    #[inline(always)]
    pub(crate) fn residual<const L: usize>(
        &self,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[f64],
        out: &mut [f64; L],
    ) -> bool {
        let f = match L {
            1 => self.residual1,
            8 => self.residual8,
            _ => return false,
        };
        self.call(f, t, y, yd, c, out)
    }

    /// The one call of translated code. `f` must be one of this model's functions for `L`
    /// lanes (the two callers above pick it by `L`).
    #[inline(always)]
    fn call<const L: usize>(
        &self,
        f: LaneFn,
        t: &[f64; L],
        y: &[f64; L],
        yd: &[f64; L],
        c: &[f64],
        out: &mut [f64; L],
    ) -> bool {
        if c.len() < self.coefficients * L {
            return false;
        }
        // SAFETY: `f` is this model's function for `L` lanes (the callers' match), alive as
        // long as `self`; `t`, `y`, `yd` and `out` hold `L` doubles each, and `c` holds at
        // least `coefficients * L` (checked above): what the struct's contract asks.
        unsafe {
            f(
                t.as_ptr(),
                y.as_ptr(),
                yd.as_ptr(),
                c.as_ptr(),
                out.as_mut_ptr(),
            )
        };
        true
    }
}

fn translatable(i: &Instr) -> bool {
    use Instr::*;
    !matches!(
        i,
        PowK(_) | PowC(_) | PowV(_) | PowS | MinS | MaxS | Tan | Exp | Ln | Sign | Tanh | Step
    )
}

/// One more than the largest coefficient index read (0 when none is).
fn needed_coefficients(code: &[Instr], finish: Finish) -> usize {
    use Instr::*;
    let mut n = match finish {
        Finish::NegDivCoef(i) => i as usize + 1,
        _ => 0,
    };
    for ins in code {
        if let LoadC(i) | PushC(i) | AddC(i) | SubC(i) | RSubC(i) | MulC(i) | DivC(i) | RDivC(i) =
            *ins
        {
            n = n.max(i as usize + 1);
        }
    }
    n
}

/// The Rust functions the translated code calls: `sin` and `cos` of [`super::trig`] on the
/// lanes of an 8-double buffer, and on one double.
#[derive(Clone, Copy)]
struct Callees {
    sin_lanes: FuncId,
    cos_lanes: FuncId,
    sin1: FuncId,
    cos1: FuncId,
}

/// `trig::sin_lanes` on the buffer the translated code passes.
///
/// # Safety
///
/// `p` points to 8 initialised doubles, aligned to 16 bytes, that nothing else accesses during
/// the call: the translated code passes its own stack slot of that size and alignment, every
/// double stored before the call.
unsafe extern "C" fn sin_lanes(p: *mut f64) {
    // SAFETY: see the function's contract.
    let a = unsafe { &mut *p.cast::<[f64; 8]>() };
    super::trig::sin_lanes(a);
}

/// `trig::cos_lanes` on the buffer the translated code passes.
///
/// # Safety
///
/// As [`sin_lanes`].
unsafe extern "C" fn cos_lanes(p: *mut f64) {
    // SAFETY: see the function's contract.
    let a = unsafe { &mut *p.cast::<[f64; 8]>() };
    super::trig::cos_lanes(a);
}

extern "C" fn sin1(x: f64) -> f64 {
    super::trig::sin(x)
}

extern "C" fn cos1(x: f64) -> f64 {
    super::trig::cos(x)
}

/// Emits the function body. The vectors of lanes advance together, instruction by instruction
/// (four independent chains side by side for 8 lanes, which the processor overlaps); `sin` and
/// `cos` store the accumulators to a stack slot and call the lane kernel once for all of them
/// (the kernel's result does not depend on the lane count, so this is the interpreter's value).
#[allow(clippy::too_many_arguments)]
fn emit(
    module: &mut JITModule,
    func: &mut cranelift_codegen::ir::Function,
    fctx: &mut FunctionBuilderContext,
    callees: Callees,
    code: &[Instr],
    ty: Type,
    lanes: usize,
    finish: Option<Finish>,
) {
    let ptr = module.target_config().pointer_type();
    let mut b = FunctionBuilder::new(func, fctx);
    let block = b.create_block();
    b.append_block_params_for_function_params(block);
    b.switch_to_block(block);
    b.seal_block(block);
    let p = b.block_params(block).to_vec();
    let (pt, py, pyd, pc, pout) = (p[0], p[1], p[2], p[3], p[4]);
    let width = ty.lane_count() as usize;
    let chunks = lanes / width;
    // Unaligned, cannot trap (the caller passes valid pointers), not aliased by a store before
    // the loads (the one store is the last instruction).
    let flags = MemFlags::new().with_notrap();
    let konst = |b: &mut FunctionBuilder, x: f64| {
        let s = b.ins().f64const(x);
        if width == 1 {
            s
        } else {
            b.ins().splat(ty, s)
        }
    };
    let off = |v: usize| (v * width * 8) as i32;
    let var = |b: &mut FunctionBuilder, i: u8, v: usize| match i & 3 {
        0 => b.ins().load(ty, flags, pt, off(v)),
        1 => b.ins().load(ty, flags, py, off(v)),
        2 => b.ins().load(ty, flags, pyd, off(v)),
        _ => konst(b, 0.0),
    };
    let coef = |b: &mut FunctionBuilder, i: u32, v: usize| {
        let at = (i as usize * lanes * 8) as i32 + off(v);
        b.ins().load(ty, flags, pc, at)
    };
    // The trig buffer: 8 doubles, 16-byte aligned (`sin_lanes`' contract).
    let slot = b.create_sized_stack_slot(StackSlotData::new(StackSlotKind::ExplicitSlot, 64, 4));
    let trig = [
        callees.sin_lanes,
        callees.cos_lanes,
        callees.sin1,
        callees.cos1,
    ]
    .map(|id| module.declare_func_in_func(id, b.func));
    let mut acc: Vec<Value> = (0..chunks).map(|_| konst(&mut b, 0.0)).collect();
    let mut stack: Vec<Vec<Value>> = Vec::new();
    for ins in code {
        use Instr::*;
        // The right operand of a leaf instruction, per vector.
        let leaf = |b: &mut FunctionBuilder, v: usize| -> Option<Value> {
            Some(match *ins {
                LoadK(x) | PushK(x) | AddK(x) | SubK(x) | RSubK(x) | MulK(x) | DivK(x)
                | RDivK(x) => konst(b, x),
                LoadC(i) | PushC(i) | AddC(i) | SubC(i) | RSubC(i) | MulC(i) | DivC(i)
                | RDivC(i) => coef(b, i, v),
                LoadV(i) | PushV(i) | AddV(i) | SubV(i) | RSubV(i) | MulV(i) | DivV(i)
                | RDivV(i) => var(b, i, v),
                _ => return None,
            })
        };
        let x: Vec<Option<Value>> = (0..chunks).map(|v| leaf(&mut b, v)).collect();
        if matches!(*ins, PushK(_) | PushC(_) | PushV(_)) {
            stack.push(acc.clone());
        }
        let popped = if matches!(*ins, AddS | SubS | MulS | DivS) {
            // The compiler never pops an empty stack; the interpreter reads NaN there.
            Some(match stack.pop() {
                Some(l) => l,
                None => (0..chunks).map(|_| konst(&mut b, f64::NAN)).collect(),
            })
        } else {
            None
        };
        if matches!(*ins, Sin | Cos) {
            let cos = matches!(*ins, Cos);
            if width == 1 {
                let f = trig[2 + usize::from(cos)];
                let call = b.ins().call(f, &[acc[0]]);
                acc[0] = b.inst_results(call)[0];
            } else {
                for (v, a) in acc.iter().enumerate() {
                    b.ins().stack_store(*a, slot, off(v));
                }
                // Fewer than 8 lanes: the rest of the buffer is zeros, so that all 8 are set.
                for v in chunks..8 / width {
                    let z = konst(&mut b, 0.0);
                    b.ins().stack_store(z, slot, off(v));
                }
                let addr = b.ins().stack_addr(ptr, slot, 0);
                b.ins().call(trig[usize::from(cos)], &[addr]);
                for (v, a) in acc.iter_mut().enumerate() {
                    *a = b.ins().stack_load(ty, slot, off(v));
                }
            }
            continue;
        }
        for v in 0..chunks {
            let a = acc[v];
            let l = popped.as_ref().map(|p| p[v]);
            acc[v] = match (*ins, x[v], l) {
                (LoadK(_) | LoadC(_) | LoadV(_), Some(x), _) => x,
                (PushK(_) | PushC(_) | PushV(_), Some(x), _) => x,
                (AddK(_) | AddC(_) | AddV(_), Some(x), _) => b.ins().fadd(a, x),
                (SubK(_) | SubC(_) | SubV(_), Some(x), _) => b.ins().fsub(a, x),
                (RSubK(_) | RSubC(_) | RSubV(_), Some(x), _) => b.ins().fsub(x, a),
                (MulK(_) | MulC(_) | MulV(_), Some(x), _) => b.ins().fmul(a, x),
                (DivK(_) | DivC(_) | DivV(_), Some(x), _) => b.ins().fdiv(a, x),
                (RDivK(_) | RDivC(_) | RDivV(_), Some(x), _) => b.ins().fdiv(x, a),
                (AddS, _, Some(l)) => b.ins().fadd(a, l),
                (SubS, _, Some(l)) => b.ins().fsub(l, a),
                (MulS, _, Some(l)) => b.ins().fmul(a, l),
                (DivS, _, Some(l)) => b.ins().fdiv(l, a),
                (Neg, _, _) => b.ins().fneg(a),
                (Square, _, _) => b.ins().fmul(a, a),
                (Cube, _, _) => {
                    let sq = b.ins().fmul(a, a);
                    b.ins().fmul(sq, a)
                }
                (Powi(n), _, _) => {
                    let one = konst(&mut b, 1.0);
                    powi(&mut b, a, n, one)
                }
                (Sqrt, _, _) => b.ins().sqrt(a),
                (Abs, _, _) => b.ins().fabs(a),
                // `translatable` admitted nothing else.
                _ => konst(&mut b, f64::NAN),
            };
        }
    }
    for (v, &a) in acc.iter().enumerate() {
        let mut a = a;
        if let Some(f) = finish {
            let neg = b.ins().fneg(a);
            a = match f {
                Finish::Neg => neg,
                Finish::NegDivConst(m) => {
                    let m = konst(&mut b, m);
                    b.ins().fdiv(neg, m)
                }
                Finish::NegDivCoef(i) => {
                    let m = coef(&mut b, i, v);
                    b.ins().fdiv(neg, m)
                }
            };
        }
        b.ins().store(flags, a, pout, off(v));
    }
    b.ins().return_(&[]);
    b.finalize();
}

/// `a.powi(n)` as compiler-builtins computes it (`__powidf2`): square-and-multiply from the
/// low bit, the reciprocal at the end for a negative exponent.
fn powi(b: &mut FunctionBuilder, a: Value, n: i32, one: Value) -> Value {
    let mut a = a;
    let mut pow = n.unsigned_abs();
    let mut mul = one;
    loop {
        if pow & 1 != 0 {
            mul = b.ins().fmul(mul, a);
        }
        pow >>= 1;
        if pow == 0 {
            break;
        }
        a = b.ins().fmul(a, a);
    }
    if n < 0 {
        b.ins().fdiv(one, mul)
    } else {
        mul
    }
}

#[cfg(test)]
mod tests {
    use super::super::Model;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Every translated instruction, every mass kind, nested stack use.
    const MODELS: &[&str] = &[
        "ydd + c1*yd + c2*y = 0",
        "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0",
        "2.5*ydd + y^4*c1 - yd^5 + c2/y - 3/yd + y/c1 = t",
        "ydd + sqrt(abs(y))*c1 + y^-2 + yd^-3*c2 + (y - yd)*(c1 - t) - (2 - y)/(yd + c2) + y^7 = 0",
        "ydd - (c1 - y) - c2*(t - yd)/(y*y + 1) + -y^3 + (-yd)^2 + y^12 - yd^-1 = 0",
        "ydd + ((y + c1)*(yd + c2))*((y - 1)*(yd*t + 2)) + 3*(c1*(y + (yd*(t + c2)))) = 1/c2",
        "-3*ydd + (c1 - y^2)*yd + (1 - c2)*y + t/3 - c1/(t + yd) = 2 - y/c2",
        "c1*ydd + c2*yd + c3*y = sin(c2*t) + 2*cos(y)*yd - sin(cos(t + c3))",
        "ydd + (c1 + c2*cos(2*t))*y + c3*yd = 0",
    ];

    fn models() -> Vec<(Model, Model)> {
        MODELS
            .iter()
            .map(|eq| {
                let m = Model::parse(eq, &[("k".to_string(), 81_360.0)])
                    .unwrap_or_else(|e| panic!("{eq}: {e}"));
                if super::super::jit_enabled() {
                    assert!(m.is_compiled(), "{eq} was not translated");
                }
                let mut plain = m.clone();
                plain.jit = None;
                (m, plain)
            })
            .collect()
    }

    /// A draw that reaches zeros, signed zeros, non-finite values and large magnitudes.
    fn draw(rng: &mut ChaCha8Rng) -> f64 {
        match rng.random_range(0..20) {
            0 => 0.0,
            1 => -0.0,
            2 => f64::NAN,
            3 => f64::INFINITY,
            4 => f64::NEG_INFINITY,
            5 => rng.random_range(-1e200..1e200),
            6 => rng.random_range(-1e-200..1e-200),
            _ => rng.random_range(-5.0..5.0),
        }
    }

    /// Equal bits, or both NaN: which NaN an operation on two NaNs returns depends on the
    /// operand order the instruction selector chose, and Rust promises no NaN's bits.
    fn same(a: f64, b: f64) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    #[test]
    fn jit_matches_the_interpreter_bit_for_bit() {
        if !super::super::jit_enabled() {
            // both sides would be the interpreter: say so rather than pass on nothing
            eprintln!("skipped: machine code is off here (GATEWATCH_JIT or the platform)");
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for (m, plain) in models() {
            let eq = m.equation();
            for _ in 0..2000 {
                let (t, y, yd) = (draw(&mut rng), draw(&mut rng), draw(&mut rng));
                let c: Vec<f64> = (0..3).map(|_| draw(&mut rng)).collect();
                let (a, b) = (m.accel(t, y, yd, &c), plain.accel(t, y, yd, &c));
                assert!(same(a, b), "{eq} accel({t}, {y}, {yd}, {c:?}): {a} != {b}");
                let (a, b) = (m.residual(t, y, yd, &c), plain.residual(t, y, yd, &c));
                assert!(
                    same(a, b),
                    "{eq} residual({t}, {y}, {yd}, {c:?}): {a} != {b}"
                );
            }
            for _ in 0..500 {
                lanes::<8>(&m, &plain, &mut rng);
                lanes::<4>(&m, &plain, &mut rng);
                lanes::<1>(&m, &plain, &mut rng);
            }
        }
    }

    fn lanes<const L: usize>(m: &Model, plain: &Model, rng: &mut ChaCha8Rng) {
        let mut v = || std::array::from_fn::<f64, L, _>(|_| draw(rng));
        let (t, y, yd) = (v(), v(), v());
        let c = [v(), v(), v()];
        let (a, b) = (
            m.accel_lanes(&t, &y, &yd, &c),
            plain.accel_lanes(&t, &y, &yd, &c),
        );
        let eq = m.equation();
        let check = |what: &str, a: [f64; L], b: [f64; L]| {
            for l in 0..L {
                assert!(
                    same(a[l], b[l]),
                    "{eq} {what} lane {l} of {L}: {} != {}",
                    a[l],
                    b[l]
                );
            }
        };
        check("accel", a, b);
        check(
            "residual",
            m.residual_lanes(&t, &y, &yd, &c),
            plain.residual_lanes(&t, &y, &yd, &c),
        );
    }

    #[test]
    fn too_few_coefficients_read_as_nan_as_in_the_interpreter() {
        let (m, _) = models().remove(1);
        // The mass is c1 and the damping reads c3: two coefficients are not enough.
        assert!(m.accel(0.0, 1.0, 1.0, &[1.0, 2.0]).is_nan());
        let c = [[1.0; 8], [2.0; 8]];
        assert!(m
            .accel_lanes(&[0.0; 8], &[1.0; 8], &[1.0; 8], &c)
            .iter()
            .all(|a| a.is_nan()));
        assert!(!m.accel(0.0, 1.0, 1.0, &[1.0, 2.0, 3.0]).is_nan());
    }

    #[test]
    fn programs_without_a_translation_stay_with_the_interpreter() {
        for eq in [
            "ydd + c1*yd + c2*exp(t) = 0",
            "ydd + min(y, c1) = 0",
            "ydd + y^c1 = 0",
            "(1 + y^2)*ydd + y = 0",
        ] {
            let m = Model::parse(eq, &[]).unwrap();
            assert!(!m.is_compiled(), "{eq}");
        }
        let long = format!("ydd{} = 0", " + c1*y".repeat(super::MAX_INSTRUCTIONS));
        assert!(!Model::parse(&long, &[]).unwrap().is_compiled());
        let short = format!("ydd{} = 0", " + c1*y".repeat(super::MAX_INSTRUCTIONS / 4));
        assert_eq!(
            Model::parse(&short, &[]).unwrap().is_compiled(),
            super::super::jit_enabled()
        );
    }
}
