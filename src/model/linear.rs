//! Splitting an expression into `M * ydd + R` and folding constants.
//!
//! The split is syntactic: `ydd` may appear only in sums, negations and as one factor of a
//! product (not in a divisor). Anything else (`ydd*ydd`, `y/ydd`, `ydd^2`, `sin(ydd)`) is
//! rejected with the column of the offending `ydd`, even where it would cancel out, because
//! an engineer writing it almost certainly made a mistake.

use super::parser::{max, min, Expr, Var};
use super::ModelError;

/// Column of the first `ydd` in `e`, if any.
pub(crate) fn first_ydd(e: &Expr) -> Option<usize> {
    match e {
        Expr::Var(Var::Ydd, col) => Some(*col),
        Expr::Num(_) | Expr::Var(..) | Expr::Coef(_) => None,
        Expr::Neg(a) => first_ydd(a),
        Expr::Sum(ts) => ts.iter().find_map(first_ydd),
        Expr::Prod(fs) => fs.iter().find_map(|(f, _)| first_ydd(f)),
        Expr::Pow(a, b) => first_ydd(a).or_else(|| first_ydd(b)),
        Expr::Call(_, args, _) => args.iter().find_map(first_ydd),
    }
}

/// The first constant of the folded `e` that is NaN or infinite, if any.
pub(crate) fn first_non_finite(e: &Expr) -> Option<f64> {
    match e {
        Expr::Num(v) => (!v.is_finite()).then_some(*v),
        Expr::Var(..) | Expr::Coef(_) => None,
        Expr::Neg(a) => first_non_finite(a),
        Expr::Sum(ts) => ts.iter().find_map(first_non_finite),
        Expr::Prod(fs) => fs.iter().find_map(|(f, _)| first_non_finite(f)),
        Expr::Pow(a, b) => first_non_finite(a).or_else(|| first_non_finite(b)),
        Expr::Call(_, args, _) => args.iter().find_map(first_non_finite),
    }
}

/// The column of the innermost function call whose arguments are constants and whose value
/// folds to NaN or infinity (`sqrt(-1)`, `ln(0)`), if any, for the error that names it.
pub(crate) fn first_non_finite_call(e: &Expr) -> Option<usize> {
    match e {
        Expr::Num(_) | Expr::Var(..) | Expr::Coef(_) => None,
        Expr::Neg(a) => first_non_finite_call(a),
        Expr::Sum(ts) => ts.iter().find_map(first_non_finite_call),
        Expr::Prod(fs) => fs.iter().find_map(|(f, _)| first_non_finite_call(f)),
        Expr::Pow(a, b) => first_non_finite_call(a).or_else(|| first_non_finite_call(b)),
        Expr::Call(_, args, col) => args.iter().find_map(first_non_finite_call).or_else(|| {
            matches!(simplify(e.clone()), Expr::Num(v) if !v.is_finite()).then_some(*col)
        }),
    }
}

fn nonlinear(what: &str, col: usize) -> ModelError {
    ModelError {
        message: format!("{what} at column {col}: the equation must be linear in ydd"),
        column: Some(col),
    }
}

/// `(M, R)` with `e = M * ydd + R`; `None` stands for a structural zero.
pub(crate) type Split = (Option<Expr>, Option<Expr>);

/// Splits `e` into the factor of `ydd` and the rest.
pub(crate) fn split(e: &Expr) -> Result<Split, ModelError> {
    if first_ydd(e).is_none() {
        return Ok((None, Some(e.clone())));
    }
    match e {
        Expr::Var(Var::Ydd, _) => Ok((Some(Expr::Num(1.0)), None)),
        Expr::Num(_) | Expr::Var(..) | Expr::Coef(_) => Ok((None, Some(e.clone()))),
        Expr::Neg(a) => {
            let (m, r) = split(a)?;
            Ok((m.map(neg), r.map(neg)))
        }
        Expr::Sum(ts) => {
            let mut ms = Vec::new();
            let mut rs = Vec::new();
            for t in ts {
                let (m, r) = split(t)?;
                ms.extend(m);
                rs.extend(r);
            }
            Ok((sum(ms), sum(rs)))
        }
        Expr::Prod(fs) => {
            let mut k = None;
            for (i, (f, div)) in fs.iter().enumerate() {
                if let Some(col) = first_ydd(f) {
                    if *div {
                        return Err(nonlinear("ydd appears in a denominator", col));
                    }
                    if k.is_some() {
                        return Err(nonlinear("ydd is multiplied by ydd", col));
                    }
                    k = Some(i);
                }
            }
            let Some(k) = k else {
                return Ok((None, Some(e.clone())));
            };
            let (m, r) = split(&fs[k].0)?;
            let with = |x: Expr| {
                let mut v = fs.clone();
                v[k].0 = x;
                Expr::Prod(v)
            };
            Ok((m.map(with), r.map(with)))
        }
        Expr::Pow(a, b) => {
            let col = first_ydd(a).or_else(|| first_ydd(b)).unwrap_or(0);
            Err(nonlinear("ydd appears in a power", col))
        }
        Expr::Call(f, args, _) => {
            let col = args.iter().find_map(first_ydd).unwrap_or(0);
            Err(nonlinear(
                &format!("ydd appears inside {}()", f.name()),
                col,
            ))
        }
    }
}

pub(crate) fn neg(e: Expr) -> Expr {
    Expr::Neg(Box::new(e))
}

fn sum(mut ts: Vec<Expr>) -> Option<Expr> {
    match ts.len() {
        0 => None,
        1 => ts.pop(),
        _ => Some(Expr::Sum(ts)),
    }
}

/// Exponents that are evaluated as repeated multiplication (`powi`) rather than `powf`.
pub(crate) fn int_exponent(b: f64) -> Option<i32> {
    (b.fract() == 0.0 && b.abs() <= 64.0).then_some(b as i32)
}

/// `a^b` exactly as the compiled program computes it, so folding changes no bits.
pub(crate) fn pow(a: f64, b: f64) -> f64 {
    match int_exponent(b) {
        Some(1) => a,
        Some(2) => a * a,
        Some(3) => a * a * a,
        Some(n) => a.powi(n),
        None => a.powf(b),
    }
}

/// Folds constant subtrees without reordering any floating-point operation: fully constant
/// subtrees, leading constant runs of sums and products, `x*1`, `x/1`, `1*x`, `x + 0`, `--x`.
pub(crate) fn simplify(e: Expr) -> Expr {
    match e {
        Expr::Num(_) | Expr::Var(..) | Expr::Coef(_) => e,
        Expr::Neg(a) => match simplify(*a) {
            Expr::Num(v) => Expr::Num(-v),
            Expr::Neg(b) => *b,
            a => neg(a),
        },
        Expr::Sum(ts) => {
            let mut out: Vec<Expr> = Vec::with_capacity(ts.len());
            for (i, t) in ts.into_iter().enumerate() {
                let t = simplify(t);
                if i == 0 {
                    // A leading sum is the same left fold flattened.
                    match t {
                        Expr::Sum(inner) => out.extend(inner),
                        t => out.push(t),
                    }
                    continue;
                }
                match (out.as_slice(), &t) {
                    ([Expr::Num(a)], Expr::Num(b)) => out[0] = Expr::Num(a + b),
                    (_, Expr::Num(b)) if *b == 0.0 => {}
                    _ => out.push(t),
                }
            }
            if out.len() == 1 {
                out.pop().unwrap_or(Expr::Num(0.0))
            } else {
                Expr::Sum(out)
            }
        }
        Expr::Prod(fs) => {
            let mut out: Vec<(Expr, bool)> = Vec::with_capacity(fs.len());
            for (i, (f, div)) in fs.into_iter().enumerate() {
                let f = simplify(f);
                if i == 0 {
                    match f {
                        Expr::Prod(inner) => out.extend(inner),
                        f => out.push((f, false)),
                    }
                    continue;
                }
                match (out.as_slice(), &f) {
                    ([(Expr::Num(a), _)], Expr::Num(b)) => {
                        out[0].0 = Expr::Num(if div { a / b } else { a * b });
                    }
                    (_, Expr::Num(b)) if *b == 1.0 => {}
                    ([(Expr::Num(a), _)], _) if *a == 1.0 && !div => out[0].0 = f,
                    _ => out.push((f, div)),
                }
            }
            if out.len() == 1 {
                out.pop().map_or(Expr::Num(0.0), |(f, _)| f)
            } else {
                Expr::Prod(out)
            }
        }
        Expr::Pow(a, b) => match (simplify(*a), simplify(*b)) {
            (Expr::Num(x), Expr::Num(p)) => Expr::Num(pow(x, p)),
            (a, Expr::Num(1.0)) => a,
            (a, b) => Expr::Pow(Box::new(a), Box::new(b)),
        },
        Expr::Call(f, args, col) => {
            let args: Vec<Expr> = args.into_iter().map(simplify).collect();
            match args.as_slice() {
                [Expr::Num(x)] => Expr::Num(f.apply1(*x)),
                [Expr::Num(a), Expr::Num(b)] => Expr::Num(match f {
                    super::parser::Func::Min => min(*a, *b),
                    _ => max(*a, *b),
                }),
                _ => Expr::Call(f, args, col),
            }
        }
    }
}
