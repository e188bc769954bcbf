//! The model language: an equation of motion as an engineer writes it, compiled once.
//!
//! ```text
//! ydd + (c1 + c2*y + c3*y^2)*yd + y = 0
//! c1*ydd + c2*yd + c3*y = c4*sin(c5*t)
//! ```
//!
//! Symbols `t`, `y`, `yd`, `ydd`, unknown coefficients `c1..cN` and named known constants
//! (`--param k=81360`); operators `+ - * / ^`, unary minus, parentheses; functions
//! `sin cos tan exp ln sqrt abs sign tanh min max step`. The equation must be linear in `ydd`:
//! it is rearranged as `M(t, y, yd) * ydd + R(t, y, yd) = 0` and the engine integrates
//! `ydd = -R / M`.
//!
//! A [`Model`] evaluates without allocation or name lookups, takes `&self` only, and is
//! `Send + Sync`, so one compiled model serves every thread of a parallel search.
//!
//! # Language details
//!
//! - `^` binds tighter than unary minus and is right-associative: `-y^2 = -(y^2)`,
//!   `2^3^2 = 2^9`; unary minus binds tighter than `*` and `/`.
//! - Numbers: `2`, `2.5`, `.5`, `3.`, `1e-3`, `2.5E+4`. `pi` is a constant.
//! - `step(x)` is 1 for `x >= 0` (so `step(0) = 1`), `sign(0) = 0`; `min`/`max` return NaN when
//!   either argument is NaN rather than silently picking the other one.
//! - Nesting (parentheses, calls, unary signs, exponents) is limited to [`MAX_DEPTH`] levels,
//!   the number of coefficients to [`MAX_COEFFS`].
//!
//! # Errors
//!
//! Every [`ModelError`] with a place carries its 1-based character column, also written in the
//! message. For linearity errors (`sin(ydd)`, `ydd*ydd`, `y/ydd`, `ydd^2`) the column is that of
//! the offending `ydd` token (for a product, the `ydd` of the second factor that has one).
//!
//! # Evaluation
//!
//! `M` and `R` are compiled to flat accumulator programs (submodule `program`) after folding
//! params, `pi` and constant subexpressions; integer powers become multiplications or `powi`,
//! and the operand stack is a fixed-size array sized at compile time. When `M` is the constant
//! 1, `accel` skips it entirely.

mod amplitude;
mod jit;
mod lexer;
mod linear;
mod parser;
mod program;
mod program_lanes;
mod scaling;
#[cfg(test)]
mod tests;
pub mod trig;

use crate::ode::System;
use lexer::{Tok, Token};
use parser::{CoefSite, Expr, Facts, Parser};
use program::Program;

pub use program_lanes::BoundLanes;
pub use scaling::{ScaleGroup, MAX_SCALE_SEARCH};

/// A parse or compile error, with the 1-based column where it was found when there is one.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ModelError {
    /// The whole message, e.g. `unknown symbol 'z' at column 14`.
    pub message: String,
    /// 1-based character column in the equation text, when the error has a place.
    pub column: Option<usize>,
}

/// Deepest nesting accepted: parentheses, function calls, unary signs and exponents each open
/// one level. Deeper input is rejected (with the column where the limit is crossed) so that
/// parsing and compiling can never exhaust the stack, whatever the input.
pub const MAX_DEPTH: usize = 64;

/// Highest coefficient number accepted (`c1000`): far above any identifiable model, and it keeps
/// a stray `c99999999` from allocating a huge "seen" table.
pub const MAX_COEFFS: usize = 1000;

/// How `accel` obtains `M`: most models have `ydd` alone (`M = 1`), which saves a division; a
/// gate's force model has a mass coefficient alone (`c1*ydd`), which is read directly instead of
/// running a one-instruction program (half the model evaluations of a step; the same number).
#[derive(Debug, Clone, Copy)]
enum MassKind {
    One,
    Const(f64),
    /// `M = c[i]` (NaN when `c` is too short, as the program would read it).
    Coef(u32),
    Varying,
}

/// Whether models are translated to machine code: yes unless the environment variable
/// `GATEWATCH_JIT` is `off` (or `0`, `false`), read once per process. The switch exists to
/// compare the two evaluators on one binary and as a way out should a host's code generation
/// misbehave; results are bit-identical either way. (`serve` and `check-config` refuse a value
/// [`jit_setting`] does not know; here an unknown value leaves the translation on.)
pub fn jit_enabled() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ON.get_or_init(|| {
        std::env::var("GATEWATCH_JIT")
            .ok()
            .and_then(|v| jit_setting(&v))
            .unwrap_or(true)
    })
}

/// A `GATEWATCH_JIT` value: `on`, `true`, `1` or `off`, `false`, `0`; `None` for anything else.
pub fn jit_setting(v: &str) -> Option<bool> {
    match v.trim() {
        "on" | "true" | "1" => Some(true),
        "off" | "false" | "0" => Some(false),
        _ => None,
    }
}

/// A compiled equation of motion `M(t, y, yd) * ydd + R(t, y, yd) = 0`.
///
/// `M` and `R` are flat programs (see the `program` submodule): constants and params are folded
/// in at parse time, integer powers become multiplications, and evaluation uses a register plus
/// a small fixed-size stack array, so `accel` allocates nothing and takes `&self` only.
#[derive(Debug, Clone)]
pub struct Model {
    equation: String,
    n_coeffs: usize,
    uses_time: bool,
    params_used: Vec<String>,
    mass: Program,
    residual: Program,
    mass_kind: MassKind,
    sites: Vec<CoefSite>,
    /// `R` and `-R / M` as machine code (submodule `jit`), shared by the clones; `None` when
    /// the program has an instruction without a translation, the host has no backend, or
    /// `GATEWATCH_JIT=off`.
    jit: Option<std::sync::Arc<jit::Compiled>>,
}

fn error<T>(message: String, column: Option<usize>) -> Result<T, ModelError> {
    Err(ModelError { message, column })
}

/// Column of the first `ydd` of the equation, left side first.
fn first_ydd_col(lhs: &Expr, rhs: &Expr) -> Option<usize> {
    linear::first_ydd(lhs).or_else(|| linear::first_ydd(rhs))
}

/// Rejects params that could never be referenced or would shadow a built-in name.
fn check_params(params: &[(String, f64)]) -> Result<(), ModelError> {
    for (i, (name, value)) in params.iter().enumerate() {
        let valid = name
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !valid {
            return error(
                format!("invalid param name '{}': a name is a letter or '_' followed by letters, digits or '_'", name.escape_debug()),
                None,
            );
        }
        let reserved = matches!(name.as_str(), "y" | "yd" | "ydd" | "t" | "pi")
            || parser::coef_digits(name).is_some()
            || parser::FUNCS.iter().any(|(f, _)| f == name);
        if reserved {
            return error(
                format!("param name '{name}' is reserved (y, yd, ydd, t, c1, c2, ..., pi and function names cannot be params)"),
                None,
            );
        }
        if !value.is_finite() {
            return error(
                format!("param '{name}' has the non-finite value {value}"),
                None,
            );
        }
        if params[..i].iter().any(|(n, _)| n == name) {
            return error(format!("param '{name}' is given more than once"), None);
        }
    }
    Ok(())
}

/// Reports the first parenthesis without a partner in `toks`, which is one side of the equation.
fn check_parens(toks: &[Token]) -> Result<(), ModelError> {
    let mut open = Vec::new();
    for t in toks {
        match t.tok {
            Tok::LParen => open.push(t.col),
            Tok::RParen if open.pop().is_none() => {
                return error(
                    format!("unbalanced parenthesis at column {}", t.col),
                    Some(t.col),
                );
            }
            _ => {}
        }
    }
    match open.last() {
        Some(&col) => error(format!("unbalanced parenthesis at column {col}"), Some(col)),
        None => Ok(()),
    }
}

/// Formats a coefficient for `substitute`: six significant digits, trailing zeros trimmed,
/// scientific notation outside `[1e-4, 1e6)`.
fn format_value(v: f64) -> String {
    if v == 0.0 {
        return "0".to_string();
    }
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if (1e-4..1e6).contains(&a) {
        let magnitude = a.log10().floor() as i32;
        let decimals = (5 - magnitude).clamp(0, 9) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let s = format!("{v:.5e}");
        match s.split_once('e') {
            Some((mantissa, exp)) if mantissa.contains('.') => {
                let m = mantissa.trim_end_matches('0').trim_end_matches('.');
                format!("{m}e{exp}")
            }
            _ => s,
        }
    }
}

impl Model {
    /// Parses and compiles `equation`. `params` are the known named constants.
    ///
    /// Never panics, whatever the input. Linearity errors report the column of the offending
    /// `ydd` (for `ydd*ydd`, the second one; for `sin(ydd)`, the `ydd` inside the call), since
    /// that is the token the engineer has to move.
    pub fn parse(equation: &str, params: &[(String, f64)]) -> Result<Model, ModelError> {
        check_params(params)?;
        let toks = lexer::lex(equation)?;
        if toks.is_empty() {
            return error("empty equation".to_string(), None);
        }
        let eqs: Vec<usize> = (0..toks.len())
            .filter(|&i| toks[i].tok == Tok::Eq)
            .collect();
        let eq = match eqs.as_slice() {
            [] => {
                return error(
                    "missing '=': write the equation as left = right, e.g. ydd + y = 0".to_string(),
                    None,
                )
            }
            [eq] => *eq,
            [_, second, ..] => {
                let col = toks[*second].col;
                return error(
                    format!("more than one '=' (the second is at column {col})"),
                    Some(col),
                );
            }
        };
        let eq_col = toks[eq].col;
        check_parens(&toks[..eq])?;
        check_parens(&toks[eq + 1..])?;
        if eq == 0 {
            return error(
                format!("nothing before '=' at column {eq_col}"),
                Some(eq_col),
            );
        }
        if eq + 1 == toks.len() {
            return error(
                format!("nothing after '=' at column {eq_col}"),
                Some(eq_col),
            );
        }
        let end_col = equation.chars().count() + 1;
        let mut facts = Facts::default();
        let lhs = Parser::new(equation, &toks, 0..eq, eq_col, params, &mut facts).parse_all()?;
        let rhs = Parser::new(
            equation,
            &toks,
            eq + 1..toks.len(),
            end_col,
            params,
            &mut facts,
        )
        .parse_all()?;

        if let Some(k) = facts.coefs_seen.iter().position(|seen| !seen) {
            return error(
                format!(
                    "coefficients must be numbered c1..cN: c{} is missing",
                    k + 1
                ),
                None,
            );
        }
        if !facts.has_ydd {
            return error(
                "the equation does not contain ydd: it must give the acceleration, e.g. ydd + c1*yd + c2*y = 0"
                    .to_string(),
                None,
            );
        }
        let (ml, rl) = linear::split(&lhs)?;
        let (mr, rr) = linear::split(&rhs)?;
        let combine = |l: Option<Expr>, r: Option<Expr>| match (l, r) {
            (l, None) => l,
            (None, Some(r)) => Some(linear::neg(r)),
            (Some(l), Some(r)) => Some(Expr::Sum(vec![l, linear::neg(r)])),
        };
        let m = combine(ml, mr).map(linear::simplify);
        let r = combine(rl, rr).map(linear::simplify);
        let too_deep = || ModelError {
            message: format!("expression too deeply nested (the limit is {MAX_DEPTH} levels)"),
            column: None,
        };
        // A constant part that folds to NaN or infinity (`sqrt(-1)`, `1/0`) makes every trial
        // of an identification fail to integrate; refused here, where the text is at hand,
        // rather than reported minutes later as a fit that never started.
        if let Some(v) = [&m, &r]
            .into_iter()
            .flatten()
            .find_map(linear::first_non_finite)
        {
            // the function that makes it, where one does (`sqrt(-1)`, `ln(0)`); a division by
            // a zero constant has no column of its own
            let col =
                linear::first_non_finite_call(&lhs).or_else(|| linear::first_non_finite_call(&rhs));
            return error(
                format!(
                    "a constant part of the equation{} evaluates to {v} (a division by zero, or the root or logarithm of a negative number?): no trial could be simulated",
                    col.map_or(String::new(), |c| format!(" (the function at column {c})"))
                ),
                col,
            );
        }
        let mass = Program::compile(m.as_ref()).ok_or_else(too_deep)?;
        // `M * ydd + R = 0` gives the acceleration only where `M` is not zero: a factor of ydd
        // that is the constant 0 (`0*ydd`, `ydd - ydd`) leaves it undetermined, and every trial
        // of an identification divides by it.
        if mass.constant().is_some_and(|v| v == 0.0) {
            let col = first_ydd_col(&lhs, &rhs);
            return error(
                format!(
                    "the factor of ydd{} is identically zero: the equation does not determine the acceleration",
                    col.map_or(String::new(), |c| format!(" (at column {c})"))
                ),
                col,
            );
        }
        let residual = Program::compile(r.as_ref()).ok_or_else(too_deep)?;
        let mass_kind = match (mass.constant(), mass.coefficient()) {
            (Some(1.0), _) => MassKind::One,
            (Some(v), _) => MassKind::Const(v),
            (None, Some(i)) => MassKind::Coef(i),
            (None, None) => MassKind::Varying,
        };
        let finish = match mass_kind {
            MassKind::One => Some(jit::Finish::Neg),
            MassKind::Const(m) => Some(jit::Finish::NegDivConst(m)),
            MassKind::Coef(i) => Some(jit::Finish::NegDivCoef(i)),
            MassKind::Varying => None,
        };
        let jit = match finish {
            Some(f) if jit_enabled() => jit::Compiled::new(&residual, f).map(std::sync::Arc::new),
            _ => None,
        };
        Ok(Model {
            equation: equation.to_string(),
            n_coeffs: facts.coefs_seen.len(),
            uses_time: facts.uses_time,
            params_used: facts.params_used,
            mass,
            residual,
            mass_kind,
            sites: facts.coef_sites,
            jit,
        })
    }

    /// Whether `R` and the acceleration run as machine code (see [`jit_enabled`]).
    pub fn is_compiled(&self) -> bool {
        self.jit.is_some()
    }

    /// The equation text as given.
    pub fn equation(&self) -> &str {
        &self.equation
    }

    /// Number of unknown coefficients `N` (`c1..cN`).
    pub fn n_coeffs(&self) -> usize {
        self.n_coeffs
    }

    /// Whether `t` appears in the equation (the system is non-autonomous).
    pub fn uses_time(&self) -> bool {
        self.uses_time
    }

    /// Whether the equation names the known constant `name` (given by `--param`): a constant
    /// given but not named is folded nowhere, and a command whose option only sets it (identify's
    /// `--stiffness` on a displacement record, as `k`) refuses the option rather than ignore it.
    pub fn uses_param(&self, name: &str) -> bool {
        self.params_used.iter().any(|n| n == name)
    }

    /// `M(t, y, yd)`, the factor of `ydd`. `c.len()` must be `n_coeffs()` (a missing
    /// coefficient reads as NaN rather than panicking).
    #[inline]
    pub fn mass(&self, t: f64, y: f64, yd: f64, c: &[f64]) -> f64 {
        self.mass.eval(t, y, yd, c)
    }

    /// `R(t, y, yd)`, everything else moved to the left-hand side.
    #[inline]
    pub fn residual(&self, t: f64, y: f64, yd: f64, c: &[f64]) -> f64 {
        let mut out = [0.0];
        if let Some(j) = &self.jit {
            if j.residual::<1>(&[t], &[y], &[yd], c, &mut out) {
                return out[0];
            }
        }
        self.residual.eval(t, y, yd, c)
    }

    /// `ydd = -R / M` (NaN or infinite when `M` vanishes; the integrators report that).
    #[inline]
    pub fn accel(&self, t: f64, y: f64, yd: f64, c: &[f64]) -> f64 {
        let mut out = [0.0];
        if let Some(j) = &self.jit {
            if j.accel::<1>(&[t], &[y], &[yd], c, &mut out) {
                return out[0];
            }
        }
        let r = self.residual.eval(t, y, yd, c);
        match self.mass_kind {
            MassKind::One => -r,
            MassKind::Const(m) => -r / m,
            MassKind::Coef(i) => -r / c.get(i as usize).copied().unwrap_or(f64::NAN),
            MassKind::Varying => -r / self.mass.eval(t, y, yd, c),
        }
    }

    /// The equation with the coefficients' values put in, e.g.
    /// `ydd + (-0.1434 + 0*y)*yd + y = 0`, for reports.
    ///
    /// The user's layout is kept; each `cK` becomes its value with six significant digits
    /// (scientific notation when tiny or huge). A negative value is put in parentheses unless it
    /// stands alone as a term: after `(`, `,`, `=` or the start, and before `+`, `-`, `)`, `,`,
    /// `=` or the end; so `c1*y` becomes `(-2)*y` and `(c1 + y)` becomes `(-2 + y)`. A missing value
    /// (`c` too short) leaves the `cK` token as it was.
    pub fn substitute(&self, c: &[f64]) -> String {
        let mut out = String::with_capacity(self.equation.len() + 8 * self.sites.len());
        let mut at = 0;
        for site in &self.sites {
            let Some(&v) = c.get(site.index as usize) else {
                continue;
            };
            out.push_str(self.equation.get(at..site.start).unwrap_or(""));
            let s = format_value(v);
            if s.starts_with('-') && site.wrap_negative {
                out.push('(');
                out.push_str(&s);
                out.push(')');
            } else {
                out.push_str(&s);
            }
            at = site.end;
        }
        out.push_str(self.equation.get(at..).unwrap_or(""));
        out
    }
}

/// A model with a coefficient vector bound to it: the first-order system `[y, yd]' = [yd, ydd]`.
#[derive(Debug, Clone, Copy)]
pub struct Bound<'a> {
    /// The compiled model.
    pub model: &'a Model,
    /// Its coefficients `c1..cN`.
    pub coeffs: &'a [f64],
}

impl System<2> for Bound<'_> {
    #[inline]
    fn rhs(&self, t: f64, s: &[f64; 2], ds: &mut [f64; 2]) {
        ds[0] = s[1];
        ds[1] = self.model.accel(t, s[0], s[1], self.coeffs);
    }
}
