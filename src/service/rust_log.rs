//! `RUST_LOG`, read and checked: an invalid value is reported, not silently ignored.
//!
//! `RUST_LOG` overrides `log.level` (a tracing `EnvFilter` directive). `log.level` is validated
//! with the configuration and refused naming the key; `RUST_LOG` comes from the environment at
//! start, so an invalid one cannot stop the daemon (a typo in a unit's `Environment=` must not
//! take monitoring down). It was silently replaced by `log.level`, and a misspelt level was worse:
//! `RUST_LOG=debugg` is valid syntax for "every level of the target `debugg`", which silences
//! every line of gatewatch, errors included. Now [`read`] tells the caller, which falls back to
//! `log.level` and logs a warning naming `RUST_LOG`, its value and the reason.

use tracing_subscriber::EnvFilter;

/// The level names `EnvFilter` accepts (case-insensitive).
const LEVELS: [&str; 6] = ["trace", "debug", "info", "warn", "error", "off"];

/// A `RUST_LOG` that is not used, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Invalid {
    /// The value (lossy when it is not Unicode).
    pub value: String,
    /// Why it is refused.
    pub reason: String,
}

/// `RUST_LOG` from the environment: `Ok(None)` when unset or empty (an empty value would
/// otherwise filter out every line), `Ok(Some)` when usable, `Err` when invalid.
pub fn read() -> Result<Option<EnvFilter>, Invalid> {
    match std::env::var_os("RUST_LOG") {
        None => Ok(None),
        Some(v) => match v.into_string() {
            Ok(s) => parse(&s),
            Err(v) => Err(Invalid {
                value: v.to_string_lossy().into_owned(),
                reason: "not valid Unicode".into(),
            }),
        },
    }
}

/// A `RUST_LOG` value: `Ok(None)` when blank, the filter, or why it is refused.
pub fn parse(value: &str) -> Result<Option<EnvFilter>, Invalid> {
    if value.trim().is_empty() {
        return Ok(None);
    }
    let invalid = |reason: String| Invalid {
        value: value.to_string(),
        reason,
    };
    if let Some(word) = value.split(',').find(|d| misspelt_level(d)) {
        return Err(invalid(format!(
            "`{word}` is not a level ({}); as a directive it would enable only the target \
             `{word}` and silence everything else",
            LEVELS.join(", ")
        )));
    }
    // directive by directive first, to name the one refused (EnvFilter's own error does not)
    for d in value.split(',').filter(|d| !d.is_empty()) {
        if let Err(e) = EnvFilter::builder().parse(d) {
            return Err(invalid(format!("`{d}`: {e}")));
        }
    }
    EnvFilter::builder()
        .parse(value)
        .map(Some)
        .map_err(|e| invalid(e.to_string()))
}

/// Whether a directive is a bare word (a target, to `EnvFilter`) that is no level but close to
/// one: `debugg`, `inof`, `warning`, `err`. Targets gatewatch's logs come from (`gatewatch`,
/// `tower_http`, `hyper`, `cranelift_jit`, ...) are not close to any level; a word is "close"
/// when it starts with a level or is the start of one (3 letters or more), or is one edit away
/// (two from 6 letters on; a swap of neighbours is one edit).
fn misspelt_level(directive: &str) -> bool {
    let word = directive.trim().to_ascii_lowercase();
    if word.is_empty()
        || !word.chars().all(|c| c.is_ascii_alphabetic())
        || LEVELS.contains(&word.as_str())
    {
        return false;
    }
    LEVELS.iter().any(|level| {
        let prefix = *level != "off"
            && word.len() >= 3
            && (word.starts_with(level) || level.starts_with(word.as_str()));
        let max = if word.len() >= 6 { 2 } else { 1 };
        prefix || edit_distance(&word, level) <= max
    })
}

/// Optimal string alignment distance (Levenshtein with adjacent swaps) of two ASCII words.
fn edit_distance(a: &str, b: &str) -> usize {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            let mut v = (d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1)
                .min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                v = v.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = v;
        }
    }
    d[a.len()][b.len()]
}

#[cfg(test)]
mod tests {
    use super::parse;

    #[test]
    fn levels_targets_and_directives_are_accepted() {
        for ok in [
            "info",
            "DEBUG",
            "warn,gatewatch=debug",
            "gatewatch",
            "tower_http=trace",
            "cranelift_jit",
            "hyper,mio",
            "off",
            "gatewatch::service=info",
        ] {
            assert!(matches!(parse(ok), Ok(Some(_))), "{ok}");
        }
        assert!(matches!(parse(""), Ok(None)));
        assert!(matches!(parse("  "), Ok(None)));
    }

    #[test]
    fn misspelt_levels_and_bad_directives_are_refused_with_the_reason() {
        for bad in ["debugg", "inof", "warning", "err", "info,wran", "trce"] {
            let e = parse(bad).err().unwrap_or_else(|| panic!("{bad} accepted"));
            assert_eq!(e.value, bad);
            assert!(e.reason.contains("is not a level"), "{bad}: {}", e.reason);
        }
        let e = parse("info,gatewatch=lol").expect_err("refused");
        assert!(
            e.reason
                .starts_with("`gatewatch=lol`: error parsing level filter"),
            "{}",
            e.reason
        );
    }
}
