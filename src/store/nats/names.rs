//! The names the NATS store gives its streams and subjects, and how a gate name, a target
//! or a fingerprint, which may hold what no subject token may (`.`, `*`, `>`, spaces, any
//! UTF-8), becomes one: the hex of its bytes, reversibly.

/// Whether `prefix` can name a stream and a subject token: not empty, letters,
/// digits, `-` and `_` only.
pub fn valid_prefix(prefix: &str) -> bool {
    !prefix.is_empty()
        && prefix
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

/// A name as a subject token or a key: the lowercase hex of its UTF-8 bytes, `_` for the empty
/// name (hex never holds `_`, so the encoding is reversible, [`decode`]).
pub fn encode(name: &str) -> String {
    if name.is_empty() {
        return "_".to_string();
    }
    name.bytes().map(|b| format!("{b:02x}")).collect()
}

/// The name an [`encode`]d token stands for; `None` when it is not one.
pub fn decode(token: &str) -> Option<String> {
    if token == "_" {
        return Some(String::new());
    }
    if token.is_empty() || token.len() % 2 != 0 {
        return None;
    }
    let bytes = (0..token.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(token.get(i..i + 2)?, 16).ok())
        .collect::<Option<Vec<u8>>>()?;
    String::from_utf8(bytes).ok()
}

/// The names the store uses, from the prefix.
#[derive(Debug, Clone)]
pub(super) struct Names {
    pub(super) history: String,
    pub(super) outbox: String,
    pub(super) alerts: String,
    pub(super) owner: String,
    pub(super) prefix: String,
}

impl Names {
    pub(super) fn new(prefix: &str) -> Names {
        Names {
            history: format!("{prefix}_HISTORY"),
            outbox: format!("{prefix}_OUTBOX"),
            alerts: format!("{prefix}_ALERTS"),
            owner: format!("{prefix}_OWNER"),
            prefix: prefix.to_string(),
        }
    }
    pub(super) fn history_subject(&self, gate: &str) -> String {
        format!("{}.history.{}", self.prefix, encode(gate))
    }
    /// The subject of the owner lease (`lease`).
    pub(super) fn owner_subject(&self) -> String {
        format!("{}.owner", self.prefix)
    }
    pub(super) fn alert_subject(&self, gate: &str) -> String {
        format!("{}.alert.{}", self.prefix, encode(gate))
    }
    pub(super) fn outbox_subject(&self, target: &str, fingerprint: &str) -> String {
        format!(
            "{}.outbox.{}.{}",
            self.prefix,
            encode(target),
            encode(fingerprint)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_encoded_reversibly_into_subject_tokens() {
        for name in ["g1", "a.b c*>/é", "", "_", "00", "gate-7"] {
            let token = encode(name);
            assert!(
                token.bytes().all(|b| b.is_ascii_hexdigit() || b == b'_'),
                "{token}"
            );
            assert_eq!(decode(&token).as_deref(), Some(name));
        }
        assert_eq!(decode("zz"), None);
        assert_eq!(decode("abc"), None);
        assert_eq!(decode("ff"), None, "not UTF-8");
    }

    #[test]
    fn prefixes_that_cannot_name_a_stream_are_refused() {
        assert!(valid_prefix("GATEWATCH"));
        assert!(valid_prefix("site-2_gw"));
        for bad in ["", "a.b", "a b", "a*", "é"] {
            assert!(!valid_prefix(bad), "{bad}");
        }
    }
}
