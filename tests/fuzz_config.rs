//! Fuzz target of the configuration loader (proptest; see `tests/fuzz_common`). Properties:
//! `Config::from_toml` never panics; an error is one line, names a key (`section.key: ...`) or
//! a line (`line N: ...`), and a line it names exists in the file; a config that loads keeps
//! every duration in range (so `serve` cannot panic on it, the 1e300 bug); and the server, log
//! and ingest sections round-trip through TOML.

use crate::fuzz_common;

use gatewatch::service::config::{Config, EMBEDDED_CONFIG, MAX_SECONDS};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// Values a key may be given: right and wrong types, extremes, broken syntax.
const VALUES: &[&str] = &[
    "0",
    "1",
    "-1",
    "1e300",
    "-1e300",
    "nan",
    "inf",
    "-inf",
    "0.0",
    "1.5",
    "65536",
    "1024",
    "18446744073709551616",
    "\"\"",
    "\"x\"",
    "\"127.0.0.1:0\"",
    "\"ns\"",
    "\"xs\"",
    "\"force\"",
    "\"c1*ydd + c2*yd + k*y = 0\"",
    "\"c1*ydd + ((c2*yd\"",
    "\"ydd^2\"",
    "true",
    "[]",
    "[1]",
    "[\"aaaaaaaaaaaaaaaa\"]",
    "{}",
    "{ m = 1.0 }",
    "1979-05-27T07:32:00Z",
    "",
    "\"unclosed",
    "[",
    "= 3",
    "\"é\"",
];

/// The embedded config with some values replaced, lines duplicated or dropped, or junk lines
/// inserted: every key the loader knows is reached, with every kind of wrong value.
fn mutated() -> impl Strategy<Value = String> {
    let lines: Vec<String> = EMBEDDED_CONFIG.lines().map(String::from).collect();
    let n = lines.len();
    let edit = prop_oneof![
        (0..n, 0..VALUES.len()).prop_map(|(l, v)| (0u8, l, v)),
        (0..n, 0..VALUES.len()).prop_map(|(l, v)| (1u8, l, v)),
        (0..n, 0..VALUES.len()).prop_map(|(l, v)| (2u8, l, v)),
        (0..n, 0..VALUES.len()).prop_map(|(l, v)| (3u8, l, v)),
    ];
    proptest::collection::vec(edit, 1..6).prop_map(move |edits| {
        let mut out = lines.clone();
        for (kind, l, v) in edits {
            let l = l.min(out.len().saturating_sub(1));
            if out.is_empty() {
                break;
            }
            match kind {
                // replace the value of a `key = value` line
                0 => {
                    if let Some((k, _)) = out[l].split_once(" = ") {
                        out[l] = format!("{k} = {}", VALUES[v]);
                    }
                }
                // duplicate a line (duplicate keys and tables)
                1 => {
                    let copy = out[l].clone();
                    out.insert(l, copy);
                }
                // drop a line
                2 => {
                    out.remove(l);
                }
                // a junk line, or a gate table
                _ => {
                    let junk = [
                        "[gates.g1]",
                        "[gates.\"bad id\"]",
                        "[defaults.alert]",
                        "bogus = 1",
                        "[[notify.webhooks]]",
                        "url = \"http://127.0.0.1:1/x\"",
                        VALUES[v],
                    ];
                    out.insert(l, junk[v % junk.len()].to_string());
                }
            }
        }
        out.join("\n")
    })
}

fn check(text: &str) -> Result<(), TestCaseError> {
    match Config::from_toml(text) {
        Ok(c) => {
            // everything that becomes a Duration is in range
            for v in [
                c.server.request_timeout_seconds,
                c.server.shutdown_grace_seconds,
                c.defaults.alert.stale_after_seconds,
                c.notify.timeout_seconds,
            ] {
                prop_assert!(v.is_finite() && (0.0..=MAX_SECONDS).contains(&v), "{v}");
            }
            // round trip of the serialisable sections
            let again = Config::from_toml(&toml::to_string(&c).unwrap()).unwrap();
            prop_assert_eq!(&again.server, &c.server);
            prop_assert_eq!(&again.log, &c.log);
            prop_assert_eq!(&again.ingest, &c.ingest);
        }
        Err(e) => {
            let m = &e.message;
            prop_assert!(!m.is_empty() && !m.contains('\n'), "{m:?}");
            // a key (`a.b: ...` or `key: ...`) or a line is named
            let named = m.split_once(": ").is_some_and(|(head, _)| !head.is_empty());
            prop_assert!(named, "{m:?}");
            // a line it names exists
            for part in m.split("line ").skip(1) {
                let digits: String = part.chars().take_while(char::is_ascii_digit).collect();
                if let Ok(line) = digits.parse::<usize>() {
                    prop_assert!(line >= 1 && line <= text.lines().count().max(1), "{m:?}");
                }
            }
        }
    }
    Ok(())
}

proptest! {
    #[test]
    fn mutated_configs_never_panic_and_errors_name_key_or_line(text in mutated()) {
        check(&text)?;
    }

    #[test]
    fn arbitrary_text_never_panics(text in any::<String>()) {
        let _ = Config::from_toml(&text);
    }

    #[test]
    fn toml_shaped_text_never_panics(text in "[\\[\\]a-z_.=\" 0-9\n-]{0,120}") {
        check(&text)?;
    }
}

#[test]
#[ignore = "long fuzz run: FUZZ_SECONDS (600) per target"]
fn fuzz_long_config() {
    fuzz_common::long_run("config", mutated(), |t| check(&t));
}
