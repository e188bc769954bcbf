//! Recursive-descent parser from tokens to an expression tree.
//!
//! Sums and products are n-ary (`Sum`, `Prod`) rather than binary chains, so a long flat
//! equation (`y + y + y + ...`) gives a shallow tree; the tree depth is bounded by the
//! nesting limit [`MAX_DEPTH`](super::MAX_DEPTH), so later recursive passes cannot overflow the
//! stack whatever the input.

use super::lexer::{Tok, Token};
use super::{ModelError, MAX_COEFFS, MAX_DEPTH};

/// The state variables a model may refer to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Var {
    T,
    Y,
    Yd,
    Ydd,
}

/// Built-in functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Func {
    Sin,
    Cos,
    Tan,
    Exp,
    Ln,
    Sqrt,
    Abs,
    Sign,
    Tanh,
    Min,
    Max,
    Step,
}

/// Every function name, for lookups and for rejecting params named like one.
pub(crate) const FUNCS: [(&str, Func); 12] = [
    ("sin", Func::Sin),
    ("cos", Func::Cos),
    ("tan", Func::Tan),
    ("exp", Func::Exp),
    ("ln", Func::Ln),
    ("sqrt", Func::Sqrt),
    ("abs", Func::Abs),
    ("sign", Func::Sign),
    ("tanh", Func::Tanh),
    ("min", Func::Min),
    ("max", Func::Max),
    ("step", Func::Step),
];

impl Func {
    pub fn name(self) -> &'static str {
        FUNCS
            .iter()
            .find(|(_, f)| *f == self)
            .map_or("?", |(n, _)| n)
    }

    pub fn arity(self) -> usize {
        match self {
            Func::Min | Func::Max => 2,
            _ => 1,
        }
    }

    /// The one-argument functions' values; shared by constant folding and evaluation so both
    /// give bit-identical results.
    #[inline(always)]
    pub fn apply1(self, x: f64) -> f64 {
        match self {
            Func::Sin => super::trig::sin(x),
            Func::Cos => super::trig::cos(x),
            Func::Tan => x.tan(),
            Func::Exp => x.exp(),
            Func::Ln => x.ln(),
            Func::Sqrt => x.sqrt(),
            Func::Abs => x.abs(),
            Func::Sign => sign(x),
            Func::Tanh => x.tanh(),
            Func::Step => step(x),
            Func::Min | Func::Max => f64::NAN,
        }
    }
}

/// `sign(0) = 0` (unlike `f64::signum`), NaN stays NaN.
#[inline(always)]
pub(crate) fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        x * 0.0 // 0 for ±0, NaN for NaN
    }
}

/// Heaviside with `step(0) = 1`; NaN stays NaN.
#[inline(always)]
pub(crate) fn step(x: f64) -> f64 {
    if x >= 0.0 {
        1.0
    } else if x < 0.0 {
        0.0
    } else {
        f64::NAN
    }
}

/// `min` propagating NaN (a NaN state must not be silently replaced by the other argument).
#[inline(always)]
pub(crate) fn min(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b < a {
        b
    } else {
        a
    }
}

/// `max` propagating NaN.
#[inline(always)]
pub(crate) fn max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b > a {
        b
    } else {
        a
    }
}

/// Expression tree. `Var` and `Call` keep the column of their token for error messages.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Expr {
    Num(f64),
    Var(Var, usize),
    /// 0-based coefficient index (`c1` is 0).
    Coef(u32),
    Neg(Box<Expr>),
    /// At least two terms, added left to right.
    Sum(Vec<Expr>),
    /// At least two factors, left to right; `true` means divide by the factor.
    /// The first factor is never a divisor.
    Prod(Vec<(Expr, bool)>),
    Pow(Box<Expr>, Box<Expr>),
    Call(Func, Vec<Expr>, usize),
}

/// A `cK` token, remembered for `substitute`.
#[derive(Debug, Clone)]
pub(crate) struct CoefSite {
    pub start: usize,
    pub end: usize,
    pub index: u32,
    /// Whether a negative value needs parentheses at this place.
    pub wrap_negative: bool,
}

/// What the parser learned besides the tree.
#[derive(Debug, Default)]
pub(crate) struct Facts {
    pub uses_time: bool,
    pub has_ydd: bool,
    pub coef_sites: Vec<CoefSite>,
    /// Indices of coefficients seen (0-based).
    pub coefs_seen: Vec<bool>,
    /// Names of the known constants (`--param`) the equation names, each once.
    pub params_used: Vec<String>,
}

pub(crate) struct Parser<'a> {
    src: &'a str,
    toks: &'a [Token],
    /// All tokens of the equation, for neighbour inspection.
    all: &'a [Token],
    /// Offset of `toks[0]` in `all`.
    base: usize,
    pos: usize,
    depth: usize,
    /// Column reported for "end of expression".
    end_col: usize,
    params: &'a [(String, f64)],
    pub facts: &'a mut Facts,
}

fn err<T>(message: String, col: usize) -> Result<T, ModelError> {
    Err(ModelError {
        message,
        column: Some(col),
    })
}

impl<'a> Parser<'a> {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        src: &'a str,
        all: &'a [Token],
        range: std::ops::Range<usize>,
        end_col: usize,
        params: &'a [(String, f64)],
        facts: &'a mut Facts,
    ) -> Self {
        Parser {
            src,
            toks: &all[range.clone()],
            all,
            base: range.start,
            pos: 0,
            depth: 0,
            end_col,
            params,
            facts,
        }
    }

    fn peek(&self) -> Option<&'a Token> {
        self.toks.get(self.pos)
    }

    fn unexpected<T>(&self) -> Result<T, ModelError> {
        match self.peek() {
            Some(t) => err(
                format!("unexpected '{}' at column {}", t.text(self.src), t.col),
                t.col,
            ),
            None => err(
                format!("expected an expression at column {}", self.end_col),
                self.end_col,
            ),
        }
    }

    fn enter(&mut self, col: usize) -> Result<(), ModelError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return err(
                format!(
                    "expression too deeply nested at column {col} (the limit is {MAX_DEPTH} levels)"
                ),
                col,
            );
        }
        Ok(())
    }

    /// Parses the whole token range as one expression.
    pub fn parse_all(&mut self) -> Result<Expr, ModelError> {
        let e = self.sum()?;
        if self.peek().is_some() {
            return self.unexpected();
        }
        Ok(e)
    }

    fn sum(&mut self) -> Result<Expr, ModelError> {
        let first = self.prod()?;
        let mut terms = vec![first];
        while let Some(t) = self.peek() {
            let neg = match t.tok {
                Tok::Plus => false,
                Tok::Minus => true,
                _ => break,
            };
            self.pos += 1;
            let term = self.prod()?;
            terms.push(if neg { Expr::Neg(Box::new(term)) } else { term });
        }
        Ok(if terms.len() == 1 {
            terms.pop().unwrap_or(Expr::Num(0.0))
        } else {
            Expr::Sum(terms)
        })
    }

    fn prod(&mut self) -> Result<Expr, ModelError> {
        let first = self.unary()?;
        let mut factors = vec![(first, false)];
        while let Some(t) = self.peek() {
            let div = match t.tok {
                Tok::Star => false,
                Tok::Slash => true,
                _ => break,
            };
            self.pos += 1;
            factors.push((self.unary()?, div));
        }
        Ok(if factors.len() == 1 {
            factors.pop().map_or(Expr::Num(0.0), |(f, _)| f)
        } else {
            Expr::Prod(factors)
        })
    }

    fn unary(&mut self) -> Result<Expr, ModelError> {
        match self.peek() {
            Some(t) if matches!(t.tok, Tok::Minus | Tok::Plus) => {
                self.pos += 1;
                self.enter(t.col)?;
                let inner = self.unary()?;
                self.depth -= 1;
                Ok(if t.tok == Tok::Minus {
                    Expr::Neg(Box::new(inner))
                } else {
                    inner
                })
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Expr, ModelError> {
        let base = self.primary()?;
        match self.peek() {
            Some(t) if t.tok == Tok::Caret => {
                self.pos += 1;
                self.enter(t.col)?;
                let exp = self.unary()?;
                self.depth -= 1;
                Ok(Expr::Pow(Box::new(base), Box::new(exp)))
            }
            _ => Ok(base),
        }
    }

    fn primary(&mut self) -> Result<Expr, ModelError> {
        let Some(t) = self.peek() else {
            return self.unexpected();
        };
        match t.tok {
            Tok::Num(v) => {
                self.pos += 1;
                Ok(Expr::Num(v))
            }
            Tok::LParen => {
                self.pos += 1;
                self.enter(t.col)?;
                let e = self.sum()?;
                match self.peek() {
                    Some(c) if c.tok == Tok::RParen => self.pos += 1,
                    _ => return self.unexpected(),
                }
                self.depth -= 1;
                Ok(e)
            }
            Tok::Ident => {
                self.pos += 1;
                self.ident(t)
            }
            _ => self.unexpected(),
        }
    }

    fn ident(&mut self, t: &'a Token) -> Result<Expr, ModelError> {
        let name = t.text(self.src);
        let col = t.col;
        let next_is_paren = self.peek().is_some_and(|n| n.tok == Tok::LParen);
        let func = FUNCS.iter().find(|(n, _)| *n == name).map(|&(_, f)| f);
        if let Some(f) = func {
            if !next_is_paren {
                return err(
                    format!("function '{name}' at column {col} needs its argument in parentheses, e.g. {name}(t)"),
                    col,
                );
            }
            return self.call(f, col);
        }
        if next_is_paren {
            return err(format!("unknown function '{name}' at column {col}"), col);
        }
        let var = match name {
            "t" => Some(Var::T),
            "y" => Some(Var::Y),
            "yd" => Some(Var::Yd),
            "ydd" => Some(Var::Ydd),
            _ => None,
        };
        if let Some(v) = var {
            match v {
                Var::T => self.facts.uses_time = true,
                Var::Ydd => self.facts.has_ydd = true,
                _ => {}
            }
            return Ok(Expr::Var(v, col));
        }
        if name == "pi" {
            return Ok(Expr::Num(std::f64::consts::PI));
        }
        if let Some(digits) = coef_digits(name) {
            let index = self.coef_index(name, digits, col)?;
            let abs = self.base + self.pos - 1;
            let prev = abs.checked_sub(1).and_then(|i| self.all.get(i));
            let next = self.all.get(abs + 1);
            let safe_before =
                prev.is_none_or(|p| matches!(p.tok, Tok::LParen | Tok::Comma | Tok::Eq));
            let safe_after = next.is_none_or(|n| {
                matches!(
                    n.tok,
                    Tok::Plus | Tok::Minus | Tok::RParen | Tok::Comma | Tok::Eq
                )
            });
            self.facts.coef_sites.push(CoefSite {
                start: t.start,
                end: t.end,
                index,
                wrap_negative: !(safe_before && safe_after),
            });
            let i = index as usize;
            if self.facts.coefs_seen.len() <= i {
                self.facts.coefs_seen.resize(i + 1, false);
            }
            self.facts.coefs_seen[i] = true;
            return Ok(Expr::Coef(index));
        }
        if let Some((_, v)) = self.params.iter().find(|(n, _)| n == name) {
            if !self.facts.params_used.iter().any(|n| n == name) {
                self.facts.params_used.push(name.to_string());
            }
            return Ok(Expr::Num(*v));
        }
        err(format!("unknown symbol '{name}' at column {col}"), col)
    }

    fn coef_index(&self, name: &str, digits: &str, col: usize) -> Result<u32, ModelError> {
        if digits.starts_with('0') {
            return err(
                format!("invalid coefficient name '{name}' at column {col}: coefficients are numbered c1, c2, c3, ... without leading zeros"),
                col,
            );
        }
        match digits.parse::<u32>() {
            Ok(k) if (k as usize) <= MAX_COEFFS => Ok(k - 1),
            _ => err(
                format!("coefficient '{name}' at column {col} is beyond the limit of {MAX_COEFFS} coefficients"),
                col,
            ),
        }
    }

    fn call(&mut self, f: Func, col: usize) -> Result<Expr, ModelError> {
        // The caller checked that the next token is '('.
        self.pos += 1;
        self.enter(col)?;
        let mut args = Vec::new();
        if self.peek().is_some_and(|t| t.tok == Tok::RParen) {
            self.pos += 1;
        } else {
            loop {
                args.push(self.sum()?);
                match self.peek() {
                    Some(t) if t.tok == Tok::Comma => self.pos += 1,
                    Some(t) if t.tok == Tok::RParen => {
                        self.pos += 1;
                        break;
                    }
                    _ => return self.unexpected(),
                }
            }
        }
        self.depth -= 1;
        let want = f.arity();
        if args.len() != want {
            let name = f.name();
            let plural = if want == 1 { "argument" } else { "arguments" };
            return err(
                format!(
                    "{name}() takes {want} {plural} but was given {} at column {col}",
                    args.len()
                ),
                col,
            );
        }
        Ok(Expr::Call(f, args, col))
    }
}

/// `Some(digits)` when `name` is `c` followed by one or more ASCII digits.
pub(crate) fn coef_digits(name: &str) -> Option<&str> {
    let digits = name.strip_prefix('c')?;
    (!digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())).then_some(digits)
}
