//! Unit tests of the model language: values at hand-computed points, the `M`/`R` split,
//! precedence, functions, params and `substitute`; every error message with its column in
//! `errors`.

use super::program::{Leaf, Op};
use super::*;
use approx::assert_relative_eq;

mod errors;

const TOL: f64 = 1e-12;

fn model(eq: &str) -> Model {
    match Model::parse(eq, &[]) {
        Ok(m) => m,
        Err(e) => panic!("{eq:?} should parse, got {e:?}"),
    }
}

fn model_p(eq: &str, params: &[(&str, f64)]) -> Model {
    let params: Vec<(String, f64)> = params.iter().map(|(n, v)| (n.to_string(), *v)).collect();
    match Model::parse(eq, &params) {
        Ok(m) => m,
        Err(e) => panic!("{eq:?} should parse, got {e:?}"),
    }
}

fn fails(eq: &str) -> ModelError {
    match Model::parse(eq, &[]) {
        Ok(_) => panic!("{eq:?} should be rejected"),
        Err(e) => e,
    }
}

fn fails_p(eq: &str, params: &[(&str, f64)]) -> ModelError {
    let params: Vec<(String, f64)> = params.iter().map(|(n, v)| (n.to_string(), *v)).collect();
    match Model::parse(eq, &params) {
        Ok(_) => panic!("{eq:?} with {params:?} should be rejected"),
        Err(e) => e,
    }
}

fn assert_err(eq: &str, message: &str, column: Option<usize>) {
    let e = fails(eq);
    assert_eq!(e.message, message, "message for {eq:?}");
    assert_eq!(e.column, column, "column for {eq:?}");
}

/// `ydd = <expr>` evaluated at `y`: accel is then exactly the expression.
fn value_of(expr: &str, y: f64) -> f64 {
    model(&format!("ydd = {expr}")).accel(0.0, y, 0.0, &[])
}

// ---------- the example equations at hand-computed points ----------

#[test]
fn polynomial_damping_example() {
    let m = model("ydd + (c1 + c2*y + c3*y^2)*yd + y = 0");
    let c = [-0.5, 0.1, 2.0];
    // (-0.5 + 0.15 + 4.5) * (-0.7) + 1.5 = -1.405
    assert_relative_eq!(m.mass(0.3, 1.5, -0.7, &c), 1.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.3, 1.5, -0.7, &c), -1.405, max_relative = TOL);
    assert_relative_eq!(m.accel(0.3, 1.5, -0.7, &c), 1.405, max_relative = TOL);
    assert_eq!(m.n_coeffs(), 3);
    assert!(!m.uses_time());
    assert_eq!(m.equation(), "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0");
}

#[test]
fn forced_linear_example_splits_into_m_and_r() {
    let m = model("c1*ydd + c2*yd + c3*y = c4*sin(c5*t)");
    let c = [2.0, 0.3, 5.0, 1.5, 3.0];
    let (t, y, yd) = (0.4, 0.2, -1.0);
    // M = c1 = 2; R = c2*yd + c3*y - c4*sin(c5*t) = -0.3 + 1.0 - 1.5*sin(1.2)
    let r = -0.3 + 1.0 - 1.5 * 0.932_039_085_967_226_3;
    assert_relative_eq!(m.mass(t, y, yd, &c), 2.0, max_relative = TOL);
    assert_relative_eq!(m.residual(t, y, yd, &c), r, max_relative = TOL);
    assert_relative_eq!(m.accel(t, y, yd, &c), -r / 2.0, max_relative = TOL);
    assert_eq!(m.n_coeffs(), 5);
    assert!(m.uses_time());
}

#[test]
fn state_dependent_mass_example() {
    let m = model("(c1 + c2*y + c3*y^2)*ydd + y = 0");
    let c = [1.0, 0.5, 0.25];
    // M = 1 + 1 + 1 = 3 at y = 2; R = 2
    assert_relative_eq!(m.mass(0.0, 2.0, 7.0, &c), 3.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.0, 2.0, 7.0, &c), 2.0, max_relative = TOL);
    assert_relative_eq!(m.accel(0.0, 2.0, 7.0, &c), -2.0 / 3.0, max_relative = TOL);
}

#[test]
fn parametric_excitation_example() {
    let m = model("ydd + (c1 + c2*sin(c3*t))*y = 0");
    let c = [4.0, 0.5, 2.0];
    // t = pi/4: sin(pi/2) = 1, so (4 + 0.5) * 2 = 9
    let t = std::f64::consts::FRAC_PI_4;
    assert_relative_eq!(m.residual(t, 2.0, 0.0, &c), 9.0, max_relative = TOL);
    assert_relative_eq!(m.accel(t, 2.0, 0.0, &c), -9.0, max_relative = TOL);
    assert!(m.uses_time());
}

#[test]
fn params_example() {
    let m = model_p(
        "m*ydd + (c1 + c2*yd^2)*yd + k*y = 0",
        &[("m", 2.0), ("k", 81360.0)],
    );
    let c = [0.1, 0.01];
    // R = (0.1 + 0.01*9)*3 + 81360*0.001 = 0.57 + 81.36; M = 2
    assert_eq!(m.n_coeffs(), 2);
    assert_relative_eq!(m.mass(0.0, 0.001, 3.0, &c), 2.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.0, 0.001, 3.0, &c), 81.93, max_relative = TOL);
    assert_relative_eq!(m.accel(0.0, 0.001, 3.0, &c), -40.965, max_relative = TOL);
}

// ---------- the M / R split ----------

#[test]
fn split_variants() {
    // ydd/c1: M = 1/c1
    let m = model("ydd/c1 + y = 0");
    assert_relative_eq!(m.mass(0.0, 3.0, 0.0, &[4.0]), 0.25, max_relative = TOL);
    assert_relative_eq!(m.accel(0.0, 3.0, 0.0, &[4.0]), -12.0, max_relative = TOL);
    // -ydd = y: M = -1, R = -y, ydd = -y
    let m = model("-ydd = y");
    assert_relative_eq!(m.mass(0.0, 3.0, 0.0, &[]), -1.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.0, 3.0, 0.0, &[]), -3.0, max_relative = TOL);
    assert_relative_eq!(m.accel(0.0, 3.0, 0.0, &[]), -3.0, max_relative = TOL);
    // 2*(ydd + y) = 0: M = 2, R = 2y
    let m = model("2*(ydd + y) = 0");
    assert_relative_eq!(m.mass(0.0, 3.0, 0.0, &[]), 2.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.0, 3.0, 0.0, &[]), 6.0, max_relative = TOL);
    assert_relative_eq!(m.accel(0.0, 3.0, 0.0, &[]), -3.0, max_relative = TOL);
    // ydd on the right-hand side
    let m = model("0 = ydd + c1*yd + y");
    assert_relative_eq!(m.mass(0.0, 3.0, 2.0, &[0.5]), -1.0, max_relative = TOL);
    assert_relative_eq!(m.accel(0.0, 3.0, 2.0, &[0.5]), -4.0, max_relative = TOL);
    // ydd on both sides: (1 + y)*ydd - y*ydd = -y gives M = 1, ydd = -y
    let m = model("(1 + y)*ydd + yd = y*ydd - y");
    assert_relative_eq!(m.mass(0.0, 3.0, 2.0, &[]), 1.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.0, 3.0, 2.0, &[]), 5.0, max_relative = TOL);
    // ydd inside a product chain with divisions
    let m = model("c1*y*ydd/2 + 1 = 0");
    assert_relative_eq!(m.mass(0.0, 3.0, 0.0, &[4.0]), 6.0, max_relative = TOL);
    assert_relative_eq!(m.residual(0.0, 3.0, 0.0, &[4.0]), 1.0, max_relative = TOL);
}

#[test]
fn vanishing_mass_gives_non_finite_accel() {
    // A factor of ydd that is the constant zero is refused at parse time (below); one that
    // vanishes at some state or for some coefficient gives a non-finite acceleration there.
    let m = model("y*ydd + 1 = 0");
    assert_eq!(m.mass(0.0, 0.0, 0.0, &[]), 0.0);
    assert!(!m.accel(0.0, 0.0, 0.0, &[]).is_finite());
    let m = model("c1*ydd + y = 0");
    assert!(m.accel(0.0, 0.0, 0.0, &[0.0]).is_nan());
}

/// A factor of ydd that folds to the constant 0 leaves the acceleration undetermined, and a
/// constant that folds to NaN or infinity makes every trial fail: both refused, the first with
/// the column of its ydd.
#[test]
fn a_zero_factor_of_ydd_and_a_non_finite_constant_are_refused() {
    for (eq, col) in [
        ("0*ydd + c1*yd + y = 0", Some(3)),
        ("ydd - ydd + c1*y = 0", Some(1)),
        ("m*ydd + c1*y = 0", Some(3)),
    ] {
        let e = Model::parse(eq, &[("m".to_string(), 0.0)]).unwrap_err();
        assert_eq!(e.column, col, "{eq}: {e}");
        assert!(e.message.contains("factor of ydd"), "{eq}: {e}");
        assert!(e.message.contains("identically zero"), "{eq}: {e}");
    }
    // the function that folds to NaN or infinity is named by its column; a division by a
    // zero constant has none
    for (eq, col) in [
        ("ydd + c1*yd + sqrt(-1)*y = 0", Some(15)),
        ("ydd + c1*yd + 2*ln(0)*y = 0", Some(17)),
        ("ydd + c1*yd + sqrt(1 + ln(0))*y = 0", Some(24)),
        ("ydd + c1*yd + (1/0)*y = 0", None),
        ("ydd/0 + c1*y = 0", None),
    ] {
        let e = Model::parse(eq, &[]).unwrap_err();
        assert!(e.message.contains("evaluates to"), "{eq}: {e}");
        assert_eq!(e.column, col, "{eq}: {e}");
    }
    // A factor that vanishes only for some coefficient or state is the search's business.
    assert!(Model::parse("c2*ydd + c1*y = 0", &[]).is_ok());
    assert!(Model::parse("(1 + y^2)*ydd + c1*y = 0", &[]).is_ok());
}

#[test]
fn short_coefficient_slice_reads_nan() {
    let m = model("ydd + c1*y + c2 = 0");
    assert!(m.accel(0.0, 1.0, 0.0, &[1.0]).is_nan());
    assert!(m.accel(0.0, 1.0, 0.0, &[]).is_nan());
}

// ---------- compiled form ----------

#[test]
fn integer_powers_become_multiplications() {
    let m = model("ydd + (c1 + c2*y + c3*y^2)*yd + y^3 + y^5 + y^-2 = 0");
    let ops = m.residual.ops();
    assert!(ops.contains(&Op::Square));
    assert!(ops.contains(&Op::Cube));
    assert!(ops.contains(&Op::Powi(5)));
    assert!(ops.contains(&Op::Powi(-2)));
    assert!(!ops.iter().any(|o| matches!(o, Op::PowL(_) | Op::PowS)));
    let (y, yd): (f64, f64) = (1.5, -0.7);
    let want = (-0.5 + 0.1 * y + 2.0 * y * y) * yd + y * y * y + y.powi(5) + 1.0 / (y * y);
    assert_relative_eq!(
        m.residual(0.0, y, yd, &[-0.5, 0.1, 2.0]),
        want,
        max_relative = TOL
    );
}

#[test]
fn polynomial_model_is_short_and_needs_no_more_than_one_stack_slot() {
    let m = model("ydd + (c1 + c2*y + c3*y^2)*yd + y = 0");
    let ops = m.residual.ops();
    assert!(ops.len() <= 10, "{ops:?}");
    let pushes = ops.iter().filter(|o| matches!(o, Op::Push(_))).count();
    assert!(pushes <= 1, "{ops:?}");
    assert!(matches!(m.mass_kind, MassKind::One));
}

#[test]
fn constants_and_params_are_folded() {
    let m = model_p(
        "ydd + (2*pi*f)^2*y + sin(pi/2)*k = 0",
        &[("f", 0.5), ("k", 3.0)],
    );
    let ops = m.residual.ops();
    let w2 = (2.0 * std::f64::consts::PI * 0.5).powi(2);
    assert_eq!(
        ops,
        &[
            Op::Load(Leaf::Const(w2)),
            Op::MulL(Leaf::Y),
            Op::AddL(Leaf::Const(3.0))
        ][..]
    );
    assert_relative_eq!(
        m.accel(0.0, 2.0, 0.0, &[]),
        -(w2 * 2.0 + 3.0),
        max_relative = TOL
    );
    // constant mass other than one
    let m = model("(1 + 1)*ydd = -y");
    assert!(matches!(m.mass_kind, MassKind::Const(v) if v == 2.0));
    assert_relative_eq!(m.accel(0.0, 4.0, 0.0, &[]), -2.0, max_relative = TOL);
}

#[test]
fn deep_but_allowed_nesting_evaluates() {
    // 64 levels of parentheses is the limit and is accepted.
    let eq = format!("ydd = {}y{}", "(".repeat(64), ")".repeat(64));
    assert_relative_eq!(
        model(&eq).accel(0.0, 2.5, 0.0, &[]),
        2.5,
        max_relative = TOL
    );
    // right-nested sums need a stack slot per level.
    let mut e = String::from("y");
    for _ in 0..60 {
        e = format!("(y + {e})");
    }
    let m = model(&format!("ydd = {e}"));
    assert_relative_eq!(m.accel(0.0, 1.5, 0.0, &[]), 61.0 * 1.5, max_relative = TOL);
    let mut e = String::from("y");
    for _ in 0..30 {
        e = format!("(y*2 + min(y, {e}))");
    }
    // innermost 2*1 + min(1, 1) = 3, and every outer level is 2 + min(1, 3) = 3
    let m = model(&format!("ydd = {e}"));
    assert_relative_eq!(m.accel(0.0, 1.0, 0.0, &[]), 3.0, max_relative = TOL);
    assert_relative_eq!(
        m.accel(0.0, -1.0, 0.0, &[]),
        -3.0 - 30.0 * 2.0 + 2.0,
        max_relative = TOL
    );
}

#[test]
fn long_flat_equation() {
    let eq = format!("ydd{} = 0", " + c1*y".repeat(100_000));
    let m = model(&eq);
    assert_relative_eq!(
        m.accel(0.0, 2.0, 0.0, &[0.5]),
        -100_000.0,
        max_relative = 1e-9
    );
}

#[test]
fn model_is_send_sync_clone_debug() {
    fn check<T: Send + Sync + Clone + std::fmt::Debug>() {}
    check::<Model>();
    let m = model("ydd + y = 0");
    let m2 = m.clone();
    assert_eq!(m2.accel(0.0, 3.0, 0.0, &[]), -3.0);
    assert!(format!("{m:?}").contains("ydd + y = 0"));
}

#[test]
fn bound_gives_velocity_and_acceleration() {
    let m = model("ydd + c1*yd + c2*y = 0");
    let c = [0.5, 4.0];
    let b = Bound {
        model: &m,
        coeffs: &c,
    };
    let mut ds = [0.0; 2];
    b.rhs(0.0, &[2.0, -1.0], &mut ds);
    // ydd = -(0.5*(-1) + 4*2) = -7.5
    assert_eq!(ds[0], -1.0);
    assert_relative_eq!(ds[1], -7.5, max_relative = TOL);
}

// ---------- operators ----------

#[test]
fn precedence_and_associativity() {
    assert_relative_eq!(value_of("2 + 3*4^2", 0.0), 50.0, max_relative = TOL);
    assert_relative_eq!(value_of("2^3^2", 0.0), 512.0, max_relative = TOL);
    assert_relative_eq!(value_of("(2^3)^2", 0.0), 64.0, max_relative = TOL);
    assert_relative_eq!(value_of("-y^2", 3.0), -9.0, max_relative = TOL);
    assert_relative_eq!(value_of("(-y)^2", 3.0), 9.0, max_relative = TOL);
    assert_relative_eq!(value_of("-2^2", 0.0), -4.0, max_relative = TOL);
    assert_relative_eq!(value_of("2^-1", 0.0), 0.5, max_relative = TOL);
    assert_relative_eq!(value_of("y^-1", 4.0), 0.25, max_relative = TOL);
    assert_relative_eq!(value_of("y - 1 - 2", 10.0), 7.0, max_relative = TOL);
    assert_relative_eq!(value_of("y - (1 - 2)", 10.0), 11.0, max_relative = TOL);
    assert_relative_eq!(value_of("y/2/5", 10.0), 1.0, max_relative = TOL);
    assert_relative_eq!(value_of("y/(2/5)", 10.0), 25.0, max_relative = TOL);
    assert_relative_eq!(value_of("1/y*2", 4.0), 0.5, max_relative = TOL);
    assert_relative_eq!(value_of("--y", 4.0), 4.0, max_relative = TOL);
    assert_relative_eq!(value_of("+y", 4.0), 4.0, max_relative = TOL);
    assert_relative_eq!(value_of("-y*2", 4.0), -8.0, max_relative = TOL);
    assert_relative_eq!(value_of("y*-2", 4.0), -8.0, max_relative = TOL);
    assert_relative_eq!(value_of("3 - -y", 4.0), 7.0, max_relative = TOL);
    assert_relative_eq!(value_of("(y + 1)*(y - 1)", 4.0), 15.0, max_relative = TOL);
    assert_relative_eq!(value_of("1 - y*2", 4.0), -7.0, max_relative = TOL);
    assert_relative_eq!(value_of("1/(y*2)", 4.0), 0.125, max_relative = TOL);
    assert_relative_eq!(value_of("y^0.5", 4.0), 2.0, max_relative = TOL);
    assert_relative_eq!(value_of("2^(y - 1)", 4.0), 8.0, max_relative = TOL);
    assert_relative_eq!(value_of("y^y", 2.0), 4.0, max_relative = TOL);
}

#[test]
fn numbers_and_pi() {
    assert_relative_eq!(value_of("1e-3", 0.0), 0.001, max_relative = TOL);
    assert_relative_eq!(value_of("2.5E+4", 0.0), 25000.0, max_relative = TOL);
    assert_relative_eq!(value_of(".5", 0.0), 0.5, max_relative = TOL);
    assert_relative_eq!(value_of("3.", 0.0), 3.0, max_relative = TOL);
    assert_relative_eq!(value_of("1.5e2*y", 2.0), 300.0, max_relative = TOL);
    assert_relative_eq!(
        value_of("pi", 0.0),
        std::f64::consts::PI,
        max_relative = TOL
    );
    assert_relative_eq!(
        value_of("2*pi*y", 0.5),
        std::f64::consts::PI,
        max_relative = TOL
    );
}

#[test]
fn functions() {
    assert_eq!(value_of("step(y)", 0.0), 1.0);
    assert_eq!(value_of("step(y)", -0.0), 1.0);
    assert_eq!(value_of("step(y)", -1e-300), 0.0);
    assert_eq!(value_of("step(y)", 2.0), 1.0);
    assert_eq!(value_of("sign(y)", 0.0), 0.0);
    assert_eq!(value_of("sign(y)", -3.0), -1.0);
    assert_eq!(value_of("sign(y)", 2.0), 1.0);
    assert_eq!(value_of("step(0)", 9.0), 1.0); // folded at compile time
    assert_eq!(value_of("sign(0)", 9.0), 0.0);
    assert_eq!(value_of("min(y, 2)", 3.0), 2.0);
    assert_eq!(value_of("min(y, 2)", -3.0), -3.0);
    assert_eq!(value_of("max(y, 2)", 3.0), 3.0);
    assert_eq!(value_of("max(y, 2)", -3.0), 2.0);
    assert_eq!(value_of("max(2, y*y)", -3.0), 9.0);
    assert_eq!(value_of("min(1 + y, y*y)", 3.0), 4.0);
    assert!(value_of("min(y, 2)", f64::NAN).is_nan());
    assert_eq!(value_of("abs(y)", -3.5), 3.5);
    assert_relative_eq!(value_of("sqrt(y)", 6.25), 2.5, max_relative = TOL);
    assert_relative_eq!(
        value_of("exp(y)", 1.0),
        std::f64::consts::E,
        max_relative = TOL
    );
    assert_relative_eq!(
        value_of("ln(y)", std::f64::consts::E),
        1.0,
        max_relative = TOL
    );
    assert_relative_eq!(
        value_of("sin(y)", std::f64::consts::FRAC_PI_6),
        0.5,
        max_relative = 1e-9
    );
    assert_relative_eq!(
        value_of("cos(y)", std::f64::consts::FRAC_PI_3),
        0.5,
        max_relative = 1e-9
    );
    assert_relative_eq!(
        value_of("tan(y)", std::f64::consts::FRAC_PI_4),
        1.0,
        max_relative = 1e-9
    );
    assert_relative_eq!(
        value_of("tanh(y)", 0.5),
        0.462_117_157_260_009_8,
        max_relative = 1e-12
    );
    assert_relative_eq!(value_of("sin(pi/6)", 0.0), 0.5, max_relative = 1e-9);
}

#[test]
fn time_dependence() {
    let m = model("ydd + y = sin(t)");
    assert!(m.uses_time());
    assert_relative_eq!(
        m.accel(std::f64::consts::FRAC_PI_2, 1.0, 0.0, &[]),
        0.0,
        epsilon = 1e-12
    );
    assert!(!model("ydd + y = sin(2)").uses_time());
}

#[test]
fn params_fold_and_coefficients_count() {
    let m = model_p("ydd + k*y = c2*yd - c1", &[("k", 81360.0), ("_damp2", 1.0)]);
    assert_eq!(m.n_coeffs(), 2);
    // R = k*y - (c2*yd - c1) = 81.36 - (2*1 - 3) = 82.36
    assert_relative_eq!(
        m.residual(0.0, 0.001, 1.0, &[3.0, 2.0]),
        82.36,
        max_relative = TOL
    );
    assert_eq!(model("ydd + y = 0").n_coeffs(), 0);
}

// ---------- substitute ----------

#[test]
fn substitute_keeps_layout() {
    let m = model("ydd + (c1 + c2*y)*yd + y = 0");
    assert_eq!(
        m.substitute(&[-0.1434, 0.0001]),
        "ydd + (-0.1434 + 0.0001*y)*yd + y = 0"
    );
    assert_eq!(m.substitute(&[0.0, 2.5]), "ydd + (0 + 2.5*y)*yd + y = 0");
    let m = model("ydd +   c1*y  =c2");
    assert_eq!(m.substitute(&[-2.0, -3.0]), "ydd +   (-2)*y  =-3");
    let m = model("c1*ydd = -c2 + c3^2 - c4");
    assert_eq!(
        m.substitute(&[-2.0, -1.0, -3.0, -4.0]),
        "(-2)*ydd = -(-1) + (-3)^2 - (-4)"
    );
    let m = model("ydd + max(c1, y)*c2 = 0");
    assert_eq!(m.substitute(&[-1.5, 1.0]), "ydd + max(-1.5, y)*1 = 0");
    let m = model("ydd + (c1*y + c2) = c3");
    assert_eq!(
        m.substitute(&[-1.0, -2.0, -3.0]),
        "ydd + ((-1)*y + (-2)) = -3"
    );
}

#[test]
fn substitute_formats_compactly() {
    let m = model("ydd + c1*y = 0");
    assert_eq!(m.substitute(&[1.0 / 3.0]), "ydd + 0.333333*y = 0");
    assert_eq!(m.substitute(&[81360.0]), "ydd + 81360*y = 0");
    assert_eq!(m.substitute(&[123456.789]), "ydd + 123457*y = 0");
    assert_eq!(m.substitute(&[0.00123456789]), "ydd + 0.00123457*y = 0");
    assert_eq!(m.substitute(&[1.5e-7]), "ydd + 1.5e-7*y = 0");
    assert_eq!(m.substitute(&[-1.234567e9]), "ydd + (-1.23457e9)*y = 0");
    assert_eq!(m.substitute(&[2e10]), "ydd + 2e10*y = 0");
    // too few values: the remaining tokens stay as written
    assert_eq!(
        model("ydd + c1*y + c2 = 0").substitute(&[2.0]),
        "ydd + 2*y + c2 = 0"
    );
}

#[test]
fn substituted_equation_reparses_to_the_same_model() {
    let eq = "c1*ydd + (c2 + c3*y^2)*yd + c4*y = c5*sin(c6*t) - c2";
    let c = [2.0, -0.5, 0.25, -4.0, 1.5, -3.0];
    let m = model(eq);
    let text = m.substitute(&c);
    let m2 = model(&text);
    assert_eq!(m2.n_coeffs(), 0);
    for &(t, y, yd) in &[(0.1, 0.5, -1.0), (2.0, -1.5, 3.0)] {
        assert_relative_eq!(
            m.accel(t, y, yd, &c),
            m2.accel(t, y, yd, &[]),
            max_relative = TOL
        );
    }
}

#[test]
fn a_coefficient_mass_is_read_directly_with_the_programs_value() {
    // The gate's force model: M = c1, read without running the mass program.
    let m = model_p("c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0", &[("k", 81360.0)]);
    assert!(
        matches!(m.mass_kind, MassKind::Coef(0)),
        "{:?}",
        m.mass_kind
    );
    for (c, y, yd) in [
        ([19.0, -225.9, 5.8e7], 1e-4, 0.01),
        ([0.0, 1.0, 2.0], 0.5, -0.25),
        ([-2.5, f64::NAN, 1.0], 1.0, 1.0),
    ] {
        let want = -m.residual(0.0, y, yd, &c) / m.mass(0.0, y, yd, &c);
        let got = m.accel(0.0, y, yd, &c);
        assert!(
            got.to_bits() == want.to_bits() || got.is_nan() && want.is_nan(),
            "{got} vs {want}"
        );
        let lanes = m.accel_lanes(&[0.0; 4], &[y; 4], &[yd; 4], &c.map(|v| [v; 4]));
        assert!(lanes
            .iter()
            .all(|v| v.to_bits() == got.to_bits() || v.is_nan() && got.is_nan()));
    }
    // a missing coefficient reads NaN, as the program would
    assert!(m.accel(0.0, 1.0, 1.0, &[]).is_nan());
    assert!(m
        .accel_lanes(&[0.0; 4], &[1.0; 4], &[1.0; 4], &[])
        .iter()
        .all(|v| v.is_nan()));
}

/// `trig::sin` / `cos` against the C library's: within 2 units in the last place of the larger of
/// the result and 2^-53 for `|x|` up to the reduction limit (near a zero of the function the
/// reduction's absolute error, not the result's size, is what a model sees), exact agreement
/// beyond it and for NaN and infinities, and lanes equal to the scalar routine bit for bit.
mod trig_accuracy {
    use crate::model::trig;
    use rand::{RngExt, SeedableRng};

    fn ulps(got: f64, want: f64) -> f64 {
        let unit = f64::EPSILON * want.abs().max(1.0 / 2f64.powi(53) / f64::EPSILON);
        (got - want).abs() / unit
    }

    #[test]
    fn within_two_ulps_of_the_c_library_inside_the_reduction_limit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut worst = (0.0f64, 0.0f64);
        for scale in [1.0, 10.0, 1e3, 1e6] {
            for _ in 0..100_000 {
                let x: f64 = rng.random_range(-scale..scale);
                worst.0 = worst.0.max(ulps(trig::sin(x), x.sin()));
                worst.1 = worst.1.max(ulps(trig::cos(x), x.cos()));
            }
        }
        // The quadrant boundaries and the zeros of sin and cos, where the reduction cancels.
        for k in -2000i32..=2000 {
            let x = f64::from(k) * std::f64::consts::FRAC_PI_4;
            for x in [x, x.next_up(), x.next_down()] {
                worst.0 = worst.0.max(ulps(trig::sin(x), x.sin()));
                worst.1 = worst.1.max(ulps(trig::cos(x), x.cos()));
            }
        }
        eprintln!("worst ulps (sin, cos): {worst:?}");
        assert!(worst.0 <= 2.0 && worst.1 <= 2.0, "worst ulps {worst:?}");
    }

    #[test]
    fn outside_the_limit_and_on_non_finite_input_it_is_the_c_library() {
        for x in [
            trig::REDUCTION_LIMIT.next_up(),
            -2e6,
            1e15,
            -3.7e300,
            f64::MAX,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert_eq!(trig::sin(x).to_bits(), x.sin().to_bits(), "sin({x})");
            assert_eq!(trig::cos(x).to_bits(), x.cos().to_bits(), "cos({x})");
        }
        assert!(trig::sin(f64::NAN).is_nan() && trig::cos(f64::NAN).is_nan());
        assert_eq!(trig::sin(0.0), 0.0);
        assert_eq!(trig::cos(0.0), 1.0);
    }

    #[test]
    fn every_lane_width_gives_the_scalar_value_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        for _ in 0..2000 {
            let mut x = [0.0f64; 8];
            for v in &mut x {
                // Mostly in range, some far outside and some non-finite.
                *v = match rng.random_range(0..10) {
                    0 => rng.random_range(-1e9..1e9),
                    1 => f64::NAN,
                    _ => rng.random_range(-50.0..50.0),
                };
            }
            let (mut s8, mut c8) = (x, x);
            trig::sin_lanes(&mut s8);
            trig::cos_lanes(&mut c8);
            let mut s5 = [x[0], x[1], x[2], x[3], x[4]];
            trig::sin_lanes(&mut s5);
            for l in 0..8 {
                assert_eq!(
                    s8[l].to_bits(),
                    trig::sin(x[l]).to_bits(),
                    "sin lane {l} of {x:?}"
                );
                assert_eq!(
                    c8[l].to_bits(),
                    trig::cos(x[l]).to_bits(),
                    "cos lane {l} of {x:?}"
                );
            }
            for l in 0..5 {
                assert_eq!(s5[l].to_bits(), s8[l].to_bits(), "5 lanes, lane {l}");
            }
        }
    }
}

#[test]
fn the_constants_named_are_known() {
    let p = |names: &[&str]| -> Vec<(String, f64)> {
        names.iter().map(|n| (n.to_string(), 2.0)).collect()
    };
    let m = Model::parse("m*ydd + c1*yd + k*y + k*y^3 = 0", &p(&["m", "k", "g"])).unwrap();
    assert!(m.uses_param("m") && m.uses_param("k"));
    assert!(!m.uses_param("g"), "given, not named");
    assert!(!m.uses_param("c1") && !m.uses_param("y"), "not constants");
    let m = Model::parse("ydd + c1*yd + c2*y = 0", &p(&["k"])).unwrap();
    assert!(!m.uses_param("k"));
}
