//! Every error message of the model language, with its column.

use super::*;

#[test]
fn error_unknown_symbol() {
    assert_err(
        "ydd + c1*y + z = 0",
        "unknown symbol 'z' at column 14",
        Some(14),
    );
    assert_err("ydd + Y = 0", "unknown symbol 'Y' at column 7", Some(7));
    assert_err("ydd + c1y = 0", "unknown symbol 'c1y' at column 7", Some(7));
}

#[test]
fn error_ydd_inside_function() {
    assert_err(
        "ydd + y + c1*sin(t*ydd) = 0",
        "ydd appears inside sin() at column 20: the equation must be linear in ydd",
        Some(20),
    );
    assert_err(
        "abs(ydd) + y = 0",
        "ydd appears inside abs() at column 5: the equation must be linear in ydd",
        Some(5),
    );
    assert_err(
        "ydd = max(y, 2*ydd)",
        "ydd appears inside max() at column 16: the equation must be linear in ydd",
        Some(16),
    );
}

#[test]
fn error_nonlinear_ydd() {
    assert_err(
        "ydd*ydd + y = 0",
        "ydd is multiplied by ydd at column 5: the equation must be linear in ydd",
        Some(5),
    );
    assert_err(
        "(ydd + y)*(2*ydd) = 0",
        "ydd is multiplied by ydd at column 14: the equation must be linear in ydd",
        Some(14),
    );
    assert_err(
        "ydd + y/ydd = 0",
        "ydd appears in a denominator at column 9: the equation must be linear in ydd",
        Some(9),
    );
    assert_err(
        "ydd^2 + y = 0",
        "ydd appears in a power at column 1: the equation must be linear in ydd",
        Some(1),
    );
    assert_err(
        "ydd + 2^ydd = 0",
        "ydd appears in a power at column 9: the equation must be linear in ydd",
        Some(9),
    );
}

#[test]
fn error_coefficient_numbering() {
    assert_err(
        "ydd + c1*yd + c2*y + c4 = 0",
        "coefficients must be numbered c1..cN: c3 is missing",
        None,
    );
    assert_err(
        "ydd + c2*y = 0",
        "coefficients must be numbered c1..cN: c1 is missing",
        None,
    );
    assert_err(
        "ydd + c0*y = 0",
        "invalid coefficient name 'c0' at column 7: coefficients are numbered c1, c2, c3, ... without leading zeros",
        Some(7),
    );
    assert_err(
        "ydd + c1001*y = 0",
        "coefficient 'c1001' at column 7 is beyond the limit of 1000 coefficients",
        Some(7),
    );
}

#[test]
fn error_parentheses() {
    assert_err(
        "ydd + yd) = 0",
        "unbalanced parenthesis at column 9",
        Some(9),
    );
    assert_err(
        "ydd + (y*(yd + 1 = 0",
        "unbalanced parenthesis at column 10",
        Some(10),
    );
    // balanced overall but across the '='
    assert_err("(ydd = y)", "unbalanced parenthesis at column 1", Some(1));
    assert_err("ydd + () = 0", "unexpected ')' at column 8", Some(8));
}

#[test]
fn error_equation_shape() {
    assert_err("", "empty equation", None);
    assert_err("  \t ", "empty equation", None);
    assert_err(
        "ydd + y",
        "missing '=': write the equation as left = right, e.g. ydd + y = 0",
        None,
    );
    assert_err(
        "ydd = y = 0",
        "more than one '=' (the second is at column 9)",
        Some(9),
    );
    assert_err("= ydd", "nothing before '=' at column 1", Some(1));
    assert_err("ydd + y =", "nothing after '=' at column 9", Some(9));
    assert_err(
        "y + yd = 0",
        "the equation does not contain ydd: it must give the acceleration, e.g. ydd + c1*yd + c2*y = 0",
        None,
    );
}

#[test]
fn error_tokens() {
    assert_err("ydd + * y = 0", "unexpected '*' at column 7", Some(7));
    assert_err("ydd y = 0", "unexpected 'y' at column 5", Some(5));
    assert_err("ydd + 2y = 0", "unexpected 'y' at column 8", Some(8));
    assert_err(
        "ydd + y + = 0",
        "expected an expression at column 11",
        Some(11),
    );
    assert_err("ydd = y +", "expected an expression at column 10", Some(10));
    assert_err(
        "ydd + y # 2 = 0",
        "unexpected character '#' at column 9",
        Some(9),
    );
    assert_err(
        "ydd + é = 0",
        "unexpected character 'é' at column 7",
        Some(7),
    );
    assert_err(
        "é + ydd + § = 0",
        "unexpected character 'é' at column 1",
        Some(1),
    );
    assert_err("ydd + 2e = 0", "malformed number '2e' at column 7", Some(7));
    assert_err(
        "ydd + 1e999 = 0",
        "number '1e999' at column 7 is too large",
        Some(7),
    );
    assert_err("ydd + y, = 0", "unexpected ',' at column 8", Some(8));
    assert_err(
        "ydd + . = 0",
        "unexpected character '.' at column 7",
        Some(7),
    );
}

#[test]
fn error_functions() {
    assert_err(
        "ydd + sin(y, t) = 0",
        "sin() takes 1 argument but was given 2 at column 7",
        Some(7),
    );
    assert_err(
        "ydd + min(y) = 0",
        "min() takes 2 arguments but was given 1 at column 7",
        Some(7),
    );
    assert_err(
        "ydd + exp() = 0",
        "exp() takes 1 argument but was given 0 at column 7",
        Some(7),
    );
    assert_err(
        "ydd + foo(y) = 0",
        "unknown function 'foo' at column 7",
        Some(7),
    );
    assert_err(
        "ydd + y(2) = 0",
        "unknown function 'y' at column 7",
        Some(7),
    );
    assert_err(
        "ydd + sin y = 0",
        "function 'sin' at column 7 needs its argument in parentheses, e.g. sin(t)",
        Some(7),
    );
}

#[test]
fn error_params() {
    for name in [
        "y", "yd", "ydd", "t", "c1", "c12", "pi", "sin", "step", "max",
    ] {
        let e = fails_p("ydd + y = 0", &[(name, 1.0)]);
        assert_eq!(
            e.message,
            format!("param name '{name}' is reserved (y, yd, ydd, t, c1, c2, ..., pi and function names cannot be params)")
        );
        assert_eq!(e.column, None);
    }
    let e = fails_p("ydd + k*y = 0", &[("k", f64::NAN)]);
    assert_eq!(e.message, "param 'k' has the non-finite value NaN");
    let e = fails_p("ydd + k*y = 0", &[("k", f64::INFINITY)]);
    assert_eq!(e.message, "param 'k' has the non-finite value inf");
    let e = fails_p("ydd + k*y = 0", &[("k", 1.0), ("k", 2.0)]);
    assert_eq!(e.message, "param 'k' is given more than once");
    let e = fails_p("ydd + y = 0", &[("2k", 1.0)]);
    assert_eq!(
        e.message,
        "invalid param name '2k': a name is a letter or '_' followed by letters, digits or '_'"
    );
    assert!(fails_p("ydd + y = 0", &[("", 1.0)])
        .message
        .starts_with("invalid param name ''"));
    // "c" alone and "cx" are not coefficient names, so they are fine as params
    let m = model_p("ydd + c*y + cx = 0", &[("c", 2.0), ("cx", 1.0)]);
    assert_relative_eq!(m.accel(0.0, 3.0, 0.0, &[]), -7.0, max_relative = TOL);
}

#[test]
fn error_too_deep() {
    // ydd = (((...y...))) with 65 levels: "ydd = " is 6 characters, the 65th '(' is column 71.
    let eq = format!("ydd = {}y{}", "(".repeat(65), ")".repeat(65));
    assert_err(
        &eq,
        "expression too deeply nested at column 71 (the limit is 64 levels)",
        Some(71),
    );
    let eq = format!("ydd = {}y", "-".repeat(100_000));
    assert_eq!(fails(&eq).column, Some(71));
    let eq = format!("ydd = {}y{}", "sin(".repeat(65), ")".repeat(65));
    assert_eq!(fails(&eq).column, Some(6 + 64 * 4 + 1));
    let eq = format!("ydd = y{}", "^y".repeat(65));
    assert_eq!(fails(&eq).column, Some(8 + 64 * 2));
    // unbalanced deep input is caught before parsing
    let eq = format!("ydd = {}", "(".repeat(1_000_000));
    assert_eq!(
        fails(&eq).message,
        "unbalanced parenthesis at column 1000006"
    );
}
