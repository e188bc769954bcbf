//! The reference in docs/api.md keeps up with the code: every metric the daemon registers and
//! every field of the damping report it serves is named there (a reader of the API should not
//! have to read the source to learn what a field means).

use std::path::Path;

use gatewatch::analysis::DampingReport;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn read(p: &str) -> String {
    std::fs::read_to_string(Path::new(ROOT).join(p)).unwrap_or_else(|e| panic!("{p}: {e}"))
}

/// The `"gatewatch_..."` string literals of a source file.
fn metric_names(source: &str) -> Vec<String> {
    let mut names: Vec<String> = source
        .split('"')
        .skip(1)
        .step_by(2)
        .filter(|s| {
            s.starts_with("gatewatch_") && s.chars().all(|c| c.is_ascii_lowercase() || c == '_')
        })
        .map(str::to_string)
        .collect();
    names.sort();
    names.dedup();
    names
}

#[test]
fn every_registered_metric_is_in_the_api_reference() {
    let api = read("docs/api.md");
    let names = metric_names(&read("src/service/metrics.rs"));
    assert!(names.len() >= 20, "found only {names:?}");
    let missing: Vec<&String> = names
        .iter()
        .filter(|n| !api.contains(n.as_str()) && !named_as_a_pair(&api, n))
        .collect();
    assert!(missing.is_empty(), "docs/api.md does not name {missing:?}");
}

#[test]
fn every_damping_report_field_is_in_the_api_reference() {
    let api = read("docs/api.md");
    // the required fields; every optional one serializes as null
    let report: DampingReport = serde_json::from_str(
        r#"{"agrees": true, "fit_nmae": 0.1, "trusted": true, "verdict": "damped"}"#,
    )
    .expect("a minimal report");
    let value = serde_json::to_value(&report).unwrap();
    let fields = value.as_object().expect("an object");
    assert!(fields.len() >= 25, "{fields:?}");
    let missing: Vec<&String> = fields
        .keys()
        .filter(|k| !api.contains(&format!("`{k}`")))
        .collect();
    assert!(
        missing.is_empty(),
        "docs/api.md does not name the damping fields {missing:?}"
    );
}

/// Whether `doc` names `name` as the second of a pair, `` `head_a`/`_b` `` for `head_b`
/// (`gatewatch_damping_ratio_lower`/`_upper`): the shortened name must follow a full name with
/// the same head, so that any `` `_upper` `` elsewhere does not count.
fn named_as_a_pair(doc: &str, name: &str) -> bool {
    let Some((head, tail)) = name.rsplit_once('_') else {
        return false;
    };
    let short = format!("`/`_{tail}`");
    doc.match_indices(&short).any(|(i, _)| {
        let before = &doc[..i];
        before
            .rfind('`')
            .is_some_and(|q| before[q + 1..].starts_with(&format!("{head}_")))
    })
}

#[test]
fn a_pair_counts_only_after_its_full_name() {
    let doc = "`gatewatch_damping_ratio_lower`/`_upper` and `gatewatch_other_min`/`_max`";
    assert!(named_as_a_pair(doc, "gatewatch_damping_ratio_upper"));
    assert!(named_as_a_pair(doc, "gatewatch_other_max"));
    assert!(!named_as_a_pair(doc, "gatewatch_something_upper"));
    assert!(!named_as_a_pair(doc, "gatewatch_damping_ratio_max"));
    assert!(!named_as_a_pair(
        "`_upper`",
        "gatewatch_damping_ratio_upper"
    ));
}

#[test]
fn the_metric_scan_reads_literals_only() {
    let src = r#"let a = "gatewatch_x_total"; let b = "not_ours"; let c = "gatewatch_Bad";"#;
    assert_eq!(metric_names(src), vec!["gatewatch_x_total".to_string()]);
}

/// The row of `metric` in docs/api.md's metric table names every label value the code
/// exports at start-up (a reason added in code and not in the table leaves operators guessing
/// what it means).
#[test]
fn the_metric_table_names_every_reason_of_the_code() {
    use gatewatch::service::metrics::*;
    let api = read("docs/api.md");
    let row = |metric: &str| {
        let head = format!("| `{metric}` |");
        api.lines()
            .find(|l| l.starts_with(&head))
            .unwrap_or_else(|| panic!("docs/api.md has no row for {metric}"))
            .to_string()
    };
    let samples: Vec<&str> = RejectReason::ALL
        .iter()
        .filter(|r| !r.is_request())
        .map(|r| r.as_str())
        .collect();
    let requests: Vec<&str> = RejectReason::ALL
        .iter()
        .filter(|r| r.is_request())
        .map(|r| r.as_str())
        .collect();
    for (metric, values) in [
        (
            "gatewatch_tcp_connections_rejected_total",
            TCP_CONNECTION_REJECT_REASONS,
        ),
        ("gatewatch_samples_rejected_total", &samples[..]),
        ("gatewatch_ingest_requests_rejected_total", &requests[..]),
        (
            "gatewatch_identification_failures_total",
            IDENTIFICATION_FAILURES,
        ),
        ("gatewatch_notifications_total", NOTIFICATION_OUTCOMES),
        ("gatewatch_store_write_errors_total", STORE_WRITE_ERRORS),
        ("gatewatch_store_pruned_rows_total", STORE_PRUNE_REASONS),
    ] {
        let row = row(metric);
        for v in values {
            assert!(
                row.contains(&format!("`{v}`")),
                "{metric} lacks `{v}`: {row}"
            );
        }
    }
}

/// Cargo.toml turns `autotests` off (tests/integration.rs says why), so a new file in `tests/`
/// would compile into nothing and its tests would never run. Every one must be a module of the
/// integration binary or a `[[test]]` target of its own.
#[test]
fn every_test_file_is_compiled_into_a_test_binary() {
    let integration = read("tests/integration.rs");
    let manifest = read("Cargo.toml");
    let mut files = 0;
    let mut left_out = Vec::new();
    for entry in std::fs::read_dir(Path::new(ROOT).join("tests")).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        let Some(stem) = name.strip_suffix(".rs") else {
            continue;
        };
        files += 1;
        let module = integration
            .lines()
            .any(|l| l.trim() == format!("mod {stem};"));
        let target = manifest.contains(&format!("path = \"tests/{name}\""));
        if !module && !target {
            left_out.push(name);
        }
    }
    assert!(files >= 40, "found only {files} files in tests/");
    assert!(left_out.is_empty(), "not in any test binary: {left_out:?}");
}
