//! `Model::parse` must return `Ok` or `Err` on any input, never panic, and a model that parses
//! must evaluate without panicking. Inputs: arbitrary strings (unicode included), printable
//! ASCII strings, and random sequences of the language's own tokens, which reach far deeper
//! into the parser than random characters do.

use crate::fuzz_common;

use gatewatch::model::{Model, ModelError};
use proptest::prelude::*;

const TOKENS: &[&str] = &[
    "y", "yd", "ydd", "t", "c1", "c2", "c3", "c4", "c0", "c01", "k", "pi", "z", "+", "-", "*", "/",
    "^", "(", ")", ",", "=", "=", "0", "1", "2.5", ".5", "1e-3", "2.5E+4", "1e999", "2e", "sin",
    "cos", "tan", "exp", "ln", "sqrt", "abs", "sign", "tanh", "min", "max", "step", "foo", " ",
    "#", "é", "∂",
];

fn check(eq: &str) -> Result<Model, ModelError> {
    let params = vec![("k".to_string(), 2.0)];
    let result = Model::parse(eq, &params);
    match &result {
        Ok(m) => {
            assert_eq!(m.equation(), eq);
            let c: Vec<f64> = (0..m.n_coeffs()).map(|i| 0.5 + i as f64).collect();
            // Values may be anything (NaN included); evaluation must simply not panic.
            let _ = m.accel(0.3, -1.2, 0.7, &c);
            let _ = m.mass(0.3, -1.2, 0.7, &c);
            let _ = m.residual(0.3, -1.2, 0.7, &[]);
            let text = m.substitute(&c);
            // Substituting finite values gives an equation without coefficients that parses.
            let again = Model::parse(&text, &params);
            assert!(
                again.as_ref().is_ok_and(|m2| m2.n_coeffs() == 0),
                "{eq:?} -> {text:?} -> {again:?}"
            );
        }
        Err(e) => {
            assert!(!e.message.is_empty());
            if let Some(col) = e.column {
                assert!(col >= 1 && col <= eq.chars().count() + 1, "{eq:?}: {e:?}");
            }
        }
    }
    result
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn arbitrary_strings_never_panic(s in any::<String>()) {
        let _ = check(&s);
    }

    #[test]
    fn printable_strings_never_panic(s in "[ -~]{0,80}") {
        let _ = check(&s);
    }

    #[test]
    fn token_sequences_never_panic(idx in proptest::collection::vec(0..TOKENS.len(), 0..60)) {
        let eq: String = idx.iter().map(|&i| TOKENS[i]).collect::<Vec<_>>().join(" ");
        let _ = check(&eq);
        let tight: String = idx.iter().map(|&i| TOKENS[i]).collect();
        let _ = check(&tight);
    }

    #[test]
    fn valid_prefix_with_random_tail_never_panics(
        idx in proptest::collection::vec(0..TOKENS.len(), 0..30)
    ) {
        let tail: String = idx.iter().map(|&i| TOKENS[i]).collect::<Vec<_>>().join(" ");
        let _ = check(&format!("ydd + c1*yd + {tail} = 0"));
        let _ = check(&format!("ydd = ({tail})"));
    }
}

#[test]
fn pathological_inputs_never_panic() {
    let cases = [
        "(".repeat(200_000),
        ")".repeat(200_000),
        format!("ydd = {}y{}", "(".repeat(100_000), ")".repeat(100_000)),
        format!("ydd = {}y", "-".repeat(200_000)),
        format!("ydd = y{}", "^y".repeat(100_000)),
        format!("ydd = {}y{}", "sin(".repeat(50_000), ")".repeat(50_000)),
        format!("ydd{} = 0", " + y".repeat(200_000)),
        format!("ydd{} = 0", "*y".repeat(200_000)),
        "=".repeat(1000),
        "\u{0}\u{feff}ydd = y".to_string(),
        "c99999999999999999999999 + ydd = 0".to_string(),
        "ydd = 1e-400".to_string(),
    ];
    for eq in &cases {
        let _ = check(eq);
    }
    assert!(check(&format!("ydd{} = 0", " + y".repeat(200_000))).is_ok());
}

/// The long run (see `tests/fuzz_common`): token sequences, the strategy that reaches deepest.
#[test]
#[ignore = "long fuzz run: FUZZ_SECONDS (600) per target"]
fn fuzz_long_model() {
    let strategy = proptest::collection::vec(0..TOKENS.len(), 0..60);
    fuzz_common::long_run("model language", strategy, |idx| {
        let eq: String = idx.iter().map(|&i| TOKENS[i]).collect::<Vec<_>>().join(" ");
        let _ = check(&eq);
        let tight: String = idx.iter().map(|&i| TOKENS[i]).collect();
        let _ = check(&tight);
        Ok(())
    });
}
