//! The compiled form: a flat accumulator-plus-stack program.
//!
//! The value being computed lives in a register (`acc`); most operations combine it with a
//! leaf operand embedded in the instruction (`acc += y`, `acc *= c[2]`), so a polynomial damping
//! term needs no stack traffic at all. Only when the right operand is itself compound is `acc`
//! spilled to a small stack array. The stack's size is computed at compile time and rounded up
//! to one of a few fixed sizes, so evaluation touches no heap and looks up no names.

use super::linear::int_exponent;
use super::parser::{max, min, sign, step, Expr, Func, Var};

/// An operand read directly by an instruction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Leaf {
    Const(f64),
    /// 0-based coefficient index.
    Coef(u32),
    T,
    Y,
    Yd,
}

/// One instruction. `L` variants take their right operand from the instruction, `S` variants
/// pop their left operand from the stack (the right one is `acc`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Op {
    /// `acc = leaf` (acc held nothing live).
    Load(Leaf),
    /// Spill `acc`, then `acc = leaf`.
    Push(Leaf),
    AddL(Leaf),
    SubL(Leaf),
    /// `acc = leaf - acc`.
    RSubL(Leaf),
    MulL(Leaf),
    DivL(Leaf),
    /// `acc = leaf / acc`.
    RDivL(Leaf),
    /// `acc = acc.powf(leaf)`.
    PowL(Leaf),
    AddS,
    SubS,
    MulS,
    DivS,
    PowS,
    MinS,
    MaxS,
    Neg,
    Square,
    Cube,
    Powi(i32),
    Sin,
    Cos,
    Tan,
    Exp,
    Ln,
    Sqrt,
    Abs,
    Sign,
    Tanh,
    Step,
}

/// The executed form of an [`Op`]: the leaf operand's kind is folded into the opcode
/// (`K` constant, `C` coefficient, `V` variable index 0 = t, 1 = y, 2 = yd), so each
/// instruction costs one dispatch instead of two.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Instr {
    LoadK(f64),
    LoadC(u32),
    LoadV(u8),
    PushK(f64),
    PushC(u32),
    PushV(u8),
    AddK(f64),
    AddC(u32),
    AddV(u8),
    SubK(f64),
    SubC(u32),
    SubV(u8),
    RSubK(f64),
    RSubC(u32),
    RSubV(u8),
    MulK(f64),
    MulC(u32),
    MulV(u8),
    DivK(f64),
    DivC(u32),
    DivV(u8),
    RDivK(f64),
    RDivC(u32),
    RDivV(u8),
    PowK(f64),
    PowC(u32),
    PowV(u8),
    AddS,
    SubS,
    MulS,
    DivS,
    PowS,
    MinS,
    MaxS,
    Neg,
    Square,
    Cube,
    Powi(i32),
    Sin,
    Cos,
    Tan,
    Exp,
    Ln,
    Sqrt,
    Abs,
    Sign,
    Tanh,
    Step,
}

fn lower(op: Op) -> Instr {
    macro_rules! by_leaf {
        ($l:expr, $k:ident, $c:ident, $v:ident) => {
            match $l {
                Leaf::Const(x) => Instr::$k(x),
                Leaf::Coef(i) => Instr::$c(i),
                Leaf::T => Instr::$v(0),
                Leaf::Y => Instr::$v(1),
                Leaf::Yd => Instr::$v(2),
            }
        };
    }
    match op {
        Op::Load(l) => by_leaf!(l, LoadK, LoadC, LoadV),
        Op::Push(l) => by_leaf!(l, PushK, PushC, PushV),
        Op::AddL(l) => by_leaf!(l, AddK, AddC, AddV),
        Op::SubL(l) => by_leaf!(l, SubK, SubC, SubV),
        Op::RSubL(l) => by_leaf!(l, RSubK, RSubC, RSubV),
        Op::MulL(l) => by_leaf!(l, MulK, MulC, MulV),
        Op::DivL(l) => by_leaf!(l, DivK, DivC, DivV),
        Op::RDivL(l) => by_leaf!(l, RDivK, RDivC, RDivV),
        Op::PowL(l) => by_leaf!(l, PowK, PowC, PowV),
        Op::AddS => Instr::AddS,
        Op::SubS => Instr::SubS,
        Op::MulS => Instr::MulS,
        Op::DivS => Instr::DivS,
        Op::PowS => Instr::PowS,
        Op::MinS => Instr::MinS,
        Op::MaxS => Instr::MaxS,
        Op::Neg => Instr::Neg,
        Op::Square => Instr::Square,
        Op::Cube => Instr::Cube,
        Op::Powi(n) => Instr::Powi(n),
        Op::Sin => Instr::Sin,
        Op::Cos => Instr::Cos,
        Op::Tan => Instr::Tan,
        Op::Exp => Instr::Exp,
        Op::Ln => Instr::Ln,
        Op::Sqrt => Instr::Sqrt,
        Op::Abs => Instr::Abs,
        Op::Sign => Instr::Sign,
        Op::Tanh => Instr::Tanh,
        Op::Step => Instr::Step,
    }
}

/// Binary operations as the compiler sees them.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Bin {
    Add,
    Sub,
    Mul,
    Div,
    Pow,
    Min,
    Max,
}

/// Largest stack a program may need; deeper programs are reported as too deeply nested.
pub(crate) const STACK_CAP: usize = 256;

/// A compiled expression of `t`, `y`, `yd` and the coefficients.
#[derive(Debug, Clone)]
pub(crate) struct Program {
    /// Readable form, kept for inspection.
    ops: Box<[Op]>,
    /// Executed form.
    code: Box<[Instr]>,
    /// Stack slots needed.
    depth: usize,
}

struct Compiler {
    ops: Vec<Op>,
    live: bool,
    depth: usize,
    max: usize,
}

fn leaf(e: &Expr) -> Option<Leaf> {
    match *e {
        Expr::Num(v) => Some(Leaf::Const(v)),
        Expr::Coef(i) => Some(Leaf::Coef(i)),
        Expr::Var(Var::T, _) => Some(Leaf::T),
        Expr::Var(Var::Y, _) => Some(Leaf::Y),
        Expr::Var(Var::Yd, _) => Some(Leaf::Yd),
        // ydd never reaches the compiler (the split removes it); treat it as NaN if it did.
        Expr::Var(Var::Ydd, _) => Some(Leaf::Const(f64::NAN)),
        _ => None,
    }
}

impl Compiler {
    fn load(&mut self, l: Leaf) {
        if self.live {
            self.depth += 1;
            self.max = self.max.max(self.depth);
            self.ops.push(Op::Push(l));
        } else {
            self.live = true;
            self.ops.push(Op::Load(l));
        }
    }

    fn expr(&mut self, e: &Expr) {
        if let Some(l) = leaf(e) {
            self.load(l);
            return;
        }
        match e {
            Expr::Neg(a) => {
                self.expr(a);
                self.ops.push(Op::Neg);
            }
            Expr::Sum(ts) => {
                let rest = match ts.as_slice() {
                    [a, b, rest @ ..] => {
                        match b {
                            Expr::Neg(x) => self.pair(a, x, Bin::Sub),
                            b => self.pair(a, b, Bin::Add),
                        }
                        rest
                    }
                    [a] => {
                        self.expr(a);
                        &[]
                    }
                    [] => {
                        self.load(Leaf::Const(0.0));
                        &[]
                    }
                };
                for t in rest {
                    match t {
                        Expr::Neg(x) => self.apply(x, Bin::Sub),
                        t => self.apply(t, Bin::Add),
                    }
                }
            }
            Expr::Prod(fs) => match fs.as_slice() {
                [(a, _), (b, div), rest @ ..] => {
                    self.pair(a, b, if *div { Bin::Div } else { Bin::Mul });
                    for (f, div) in rest {
                        self.apply(f, if *div { Bin::Div } else { Bin::Mul });
                    }
                }
                [(a, _)] => self.expr(a),
                [] => self.load(Leaf::Const(1.0)),
            },
            Expr::Pow(a, b) => self.pair(a, b, Bin::Pow),
            Expr::Call(f, args, _) => match (f, args.as_slice()) {
                (Func::Min, [a, b]) => self.pair(a, b, Bin::Min),
                (Func::Max, [a, b]) => self.pair(a, b, Bin::Max),
                (f, [a]) => {
                    self.expr(a);
                    self.ops.push(match f {
                        Func::Sin => Op::Sin,
                        Func::Cos => Op::Cos,
                        Func::Tan => Op::Tan,
                        Func::Exp => Op::Exp,
                        Func::Ln => Op::Ln,
                        Func::Sqrt => Op::Sqrt,
                        Func::Abs => Op::Abs,
                        Func::Sign => Op::Sign,
                        Func::Tanh => Op::Tanh,
                        Func::Step => Op::Step,
                        // Arity is checked by the parser; unreachable in practice.
                        Func::Min | Func::Max => Op::Neg,
                    });
                }
                _ => self.load(Leaf::Const(f64::NAN)),
            },
            // Leaves were handled above.
            Expr::Num(_) | Expr::Var(..) | Expr::Coef(_) => {}
        }
    }

    /// Emits `a op b`; when `a` is a leaf and `b` is not, computes `b` first and applies `a`
    /// from the instruction (exact: `+`, `*`, min and max commute, `-` and `/` have reversed
    /// forms), which saves a spill.
    fn pair(&mut self, a: &Expr, b: &Expr, op: Bin) {
        if let (Some(la), None) = (leaf(a), leaf(b)) {
            let rev = match op {
                Bin::Add => Some(Op::AddL(la)),
                Bin::Mul => Some(Op::MulL(la)),
                Bin::Sub => Some(Op::RSubL(la)),
                Bin::Div => Some(Op::RDivL(la)),
                Bin::Pow | Bin::Min | Bin::Max => None,
            };
            if let Some(rev) = rev {
                self.expr(b);
                self.ops.push(rev);
                return;
            }
        }
        self.expr(a);
        self.apply(b, op);
    }

    /// Emits `acc = acc op b`.
    fn apply(&mut self, b: &Expr, op: Bin) {
        if op == Bin::Pow {
            if let Expr::Num(p) = b {
                match int_exponent(*p) {
                    Some(1) => {}
                    Some(2) => self.ops.push(Op::Square),
                    Some(3) => self.ops.push(Op::Cube),
                    Some(n) => self.ops.push(Op::Powi(n)),
                    None => self.ops.push(Op::PowL(Leaf::Const(*p))),
                }
                return;
            }
        }
        if let Some(l) = leaf(b) {
            let o = match op {
                Bin::Add => Some(Op::AddL(l)),
                Bin::Sub => Some(Op::SubL(l)),
                Bin::Mul => Some(Op::MulL(l)),
                Bin::Div => Some(Op::DivL(l)),
                Bin::Pow => Some(Op::PowL(l)),
                Bin::Min | Bin::Max => None,
            };
            if let Some(o) = o {
                self.ops.push(o);
                return;
            }
        }
        self.expr(b);
        self.depth -= 1;
        self.ops.push(match op {
            Bin::Add => Op::AddS,
            Bin::Sub => Op::SubS,
            Bin::Mul => Op::MulS,
            Bin::Div => Op::DivS,
            Bin::Pow => Op::PowS,
            Bin::Min => Op::MinS,
            Bin::Max => Op::MaxS,
        });
    }
}

impl Program {
    /// Compiles `e`; `None` (a structural zero) compiles to the constant 0.
    /// Returns `None` when the program would need more than [`STACK_CAP`] stack slots.
    pub fn compile(e: Option<&Expr>) -> Option<Program> {
        let mut c = Compiler {
            ops: Vec::new(),
            live: false,
            depth: 0,
            max: 0,
        };
        match e {
            Some(e) => c.expr(e),
            None => c.load(Leaf::Const(0.0)),
        }
        (c.max <= STACK_CAP).then(|| Program {
            code: c.ops.iter().map(|&op| lower(op)).collect(),
            ops: c.ops.into_boxed_slice(),
            depth: c.max,
        })
    }

    /// The program's value when it is a single constant.
    pub fn constant(&self) -> Option<f64> {
        match *self.ops {
            [Op::Load(Leaf::Const(v))] => Some(v),
            _ => None,
        }
    }

    /// The coefficient index when the program is a single coefficient (`c1*ydd`'s mass).
    pub fn coefficient(&self) -> Option<u32> {
        match *self.ops {
            [Op::Load(Leaf::Coef(i))] => Some(i),
            _ => None,
        }
    }

    /// The executed form and the stack slots it needs, for the lane evaluator
    /// (`super::program_lanes`), which runs the same instructions on `L` candidates at once.
    pub(super) fn code(&self) -> (&[Instr], usize) {
        (&self.code, self.depth)
    }

    /// The instructions (for tests and debugging).
    #[cfg(test)]
    pub fn ops(&self) -> &[Op] {
        &self.ops
    }

    /// Evaluates the program. A missing coefficient (`c` too short) reads as NaN.
    #[inline]
    pub fn eval(&self, t: f64, y: f64, yd: f64, c: &[f64]) -> f64 {
        // Fixed stack sizes keep the zeroing of the array trivial for ordinary models.
        if self.depth <= 4 {
            run::<4>(&self.code, t, y, yd, c)
        } else if self.depth <= 32 {
            run::<32>(&self.code, t, y, yd, c)
        } else {
            run::<STACK_CAP>(&self.code, t, y, yd, c)
        }
    }
}

#[inline(always)]
fn run<const N: usize>(code: &[Instr], t: f64, y: f64, yd: f64, c: &[f64]) -> f64 {
    let vars = [t, y, yd, 0.0];
    let mut st = [0.0f64; N];
    let mut sp = 0usize;
    let mut acc = 0.0f64;
    macro_rules! var {
        ($i:expr) => {
            vars[($i & 3) as usize]
        };
    }
    macro_rules! coef {
        ($i:expr) => {
            match c.get($i as usize) {
                Some(v) => *v,
                None => f64::NAN,
            }
        };
    }
    macro_rules! push {
        ($v:expr) => {{
            if let Some(s) = st.get_mut(sp) {
                *s = acc;
            }
            sp += 1;
            acc = $v;
        }};
    }
    macro_rules! pop {
        () => {{
            sp = sp.wrapping_sub(1);
            match st.get(sp) {
                Some(v) => *v,
                None => f64::NAN,
            }
        }};
    }
    use super::linear::pow;
    for ins in code {
        match *ins {
            Instr::LoadK(x) => acc = x,
            Instr::LoadC(i) => acc = coef!(i),
            Instr::LoadV(i) => acc = var!(i),
            Instr::PushK(x) => push!(x),
            Instr::PushC(i) => push!(coef!(i)),
            Instr::PushV(i) => push!(var!(i)),
            Instr::AddK(x) => acc += x,
            Instr::AddC(i) => acc += coef!(i),
            Instr::AddV(i) => acc += var!(i),
            Instr::SubK(x) => acc -= x,
            Instr::SubC(i) => acc -= coef!(i),
            Instr::SubV(i) => acc -= var!(i),
            Instr::RSubK(x) => acc = x - acc,
            Instr::RSubC(i) => acc = coef!(i) - acc,
            Instr::RSubV(i) => acc = var!(i) - acc,
            Instr::MulK(x) => acc *= x,
            Instr::MulC(i) => acc *= coef!(i),
            Instr::MulV(i) => acc *= var!(i),
            Instr::DivK(x) => acc /= x,
            Instr::DivC(i) => acc /= coef!(i),
            Instr::DivV(i) => acc /= var!(i),
            Instr::RDivK(x) => acc = x / acc,
            Instr::RDivC(i) => acc = coef!(i) / acc,
            Instr::RDivV(i) => acc = var!(i) / acc,
            Instr::PowK(x) => acc = pow(acc, x),
            Instr::PowC(i) => acc = pow(acc, coef!(i)),
            Instr::PowV(i) => acc = pow(acc, var!(i)),
            Instr::AddS => acc += pop!(),
            Instr::SubS => acc = pop!() - acc,
            Instr::MulS => acc *= pop!(),
            Instr::DivS => acc = pop!() / acc,
            Instr::PowS => acc = pow(pop!(), acc),
            Instr::MinS => acc = min(pop!(), acc),
            Instr::MaxS => acc = max(pop!(), acc),
            Instr::Neg => acc = -acc,
            Instr::Square => acc *= acc,
            Instr::Cube => acc = acc * acc * acc,
            Instr::Powi(n) => acc = acc.powi(n),
            Instr::Sin => acc = super::trig::sin(acc),
            Instr::Cos => acc = super::trig::cos(acc),
            Instr::Tan => acc = acc.tan(),
            Instr::Exp => acc = acc.exp(),
            Instr::Ln => acc = acc.ln(),
            Instr::Sqrt => acc = acc.sqrt(),
            Instr::Abs => acc = acc.abs(),
            Instr::Sign => acc = sign(acc),
            Instr::Tanh => acc = acc.tanh(),
            Instr::Step => acc = step(acc),
        }
    }
    acc
}
