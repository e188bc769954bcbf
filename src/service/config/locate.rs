//! Where a configuration error is: the full key path (`server.listen`) and the line of the file.
//!
//! The configuration is deserialised from `toml::Value` tables (the `[defaults]` table is merged
//! into every gate first), which carry no positions. So the key path comes from
//! `serde_path_to_error`, and the line from looking that path up in the text parsed with spans.

use super::ConfigError;
use serde::de::DeserializeOwned;
use toml::de::{DeTable, DeValue};

/// Deserialises `value` into `T`; an error names the full key path (`prefix` first, e.g.
/// `gates.g1`) and, when `text` holds the key, its line: `server.listen: invalid type: integer
/// `5`, expected a string, line 2`. `fallback` is where to look for the line when the key is not
/// under `prefix` in the text (a gate's value inherited from `[defaults]`).
pub(super) fn deserialize<T: DeserializeOwned>(
    value: toml::Value,
    text: &str,
    prefix: &[&str],
    fallback: &[&str],
) -> Result<T, ConfigError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let mut path: Vec<String> = prefix.iter().map(|s| s.to_string()).collect();
        for segment in e.path().iter() {
            match segment {
                serde_path_to_error::Segment::Map { key } => path.push(key.clone()),
                serde_path_to_error::Segment::Seq { index } => path.push(index.to_string()),
                serde_path_to_error::Segment::Enum { variant } => path.push(variant.clone()),
                serde_path_to_error::Segment::Unknown => {}
            }
        }
        let message = e.inner().message().trim().to_string();
        // An unknown key is reported on its table; name the key itself (`server.foo`).
        if let Some(unknown) = unknown_field(&message) {
            if path.last().map(String::as_str) != Some(unknown) {
                path.push(unknown.to_string());
            }
        }
        let rel = &path[prefix.len()..];
        let line = line_of(text, &path).or_else(|| {
            let alt: Vec<String> = fallback
                .iter()
                .map(|s| s.to_string())
                .chain(rel.iter().cloned())
                .collect();
            line_of(text, &alt)
        });
        let key = dotted(&path);
        let mut out = if key.is_empty() {
            message
        } else {
            format!("{key}: {message}")
        };
        if let Some(line) = line {
            out.push_str(&format!(", line {line}"));
        }
        ConfigError::new(out)
    })
}

/// `a.b[0].c` from the segments `a`, `b`, `0`, `c`.
fn dotted(path: &[String]) -> String {
    let mut out = String::new();
    for seg in path {
        if seg.bytes().all(|b| b.is_ascii_digit()) && !out.is_empty() {
            out.push_str(&format!("[{seg}]"));
        } else {
            if !out.is_empty() {
                out.push('.');
            }
            out.push_str(seg);
        }
    }
    out
}

/// The segments of a key as [`dotted`] writes it: `ingest.value_fields[1]` is `ingest`,
/// `value_fields`, `1`, so that [`line_of`] finds an entry of an array, not only its table.
pub(super) fn key_path(key: &str) -> Vec<String> {
    let mut out = Vec::new();
    for part in key.split('.') {
        // the trailing `[digits]`, read from the end; anything else stays part of the name
        let mut name = part;
        let mut indices = Vec::new();
        while let Some((before, index)) = name.strip_suffix(']').and_then(|h| h.rsplit_once('[')) {
            if index.is_empty() || !index.bytes().all(|b| b.is_ascii_digit()) {
                break;
            }
            indices.push(index.to_string());
            name = before;
        }
        out.push(name.to_string());
        out.extend(indices.into_iter().rev());
    }
    out
}

/// The key of serde's "unknown field `foo`, expected ..." message.
fn unknown_field(message: &str) -> Option<&str> {
    let rest = message.strip_prefix("unknown field `")?;
    rest.split_once('`').map(|(key, _)| key)
}

/// The 1-based line of the key at `path` in `text`, or of the deepest part of it that exists.
pub(super) fn line_of(text: &str, path: &[String]) -> Option<usize> {
    find(text, path).map(|(line, _)| line)
}

/// The 1-based line of the key at `path` in `text` when the text has that very key.
pub(super) fn exact_line_of(text: &str, path: &[String]) -> Option<usize> {
    find(text, path)
        .filter(|&(_, depth)| depth == path.len())
        .map(|(line, _)| line)
}

/// The line of the deepest part of `path` that `text` has, and how many segments that is.
fn find(text: &str, path: &[String]) -> Option<(usize, usize)> {
    let root = DeTable::parse(text).ok()?;
    let mut table: &DeTable = root.get_ref();
    let mut array: Option<&[toml::Spanned<DeValue>]> = None;
    let mut found = None;
    let mut depth = 0;
    for seg in path {
        let value = if let Some(items) = array.take() {
            let Some(item) = seg.parse::<usize>().ok().and_then(|i| items.get(i)) else {
                break;
            };
            // an entry of a list written over several lines is on its own line; a table of an
            // array of tables (`[[notify.webhooks]]`) is found by its keys below
            if !matches!(item.get_ref(), DeValue::Table(_)) {
                found = Some(item.span().start);
            }
            item
        } else {
            let Some((key, value)) = table
                .iter()
                .find(|(k, _)| k.get_ref().as_ref() == seg.as_str())
            else {
                break;
            };
            found = Some(key.span().start);
            value
        };
        depth += 1;
        match value.get_ref() {
            DeValue::Table(t) => table = t,
            DeValue::Array(a) => array = Some(a),
            _ => break,
        }
    }
    found.map(|offset| (text[..offset].matches('\n').count() + 1, depth))
}
