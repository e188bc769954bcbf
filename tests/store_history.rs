//! The history of the store as users read it, from a REAL SQLite file written by the store:
//! `GET /api/v1/gates/{id}/history` on a real daemon (`server::run` on a loopback port, real
//! HTTP client) and `gatewatch history` (the real binary), including `--plot`.
//!
//! The file holds 200 windows of gate g1, one every 30 s from 2024-05-01T12:00:00Z, with zeta0
//! falling from +2 % through zero (verdict `damped`, then `self_excited`), and 3 of gate g2.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use gatewatch::service::config::Config;
use gatewatch::store::{IdentificationRecord, SqliteStore, Store, WriteBatch, HISTORY_CSV_HEADER};
use serde_json::Value;

use crate::history_common;
use history_common::history;

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
/// 2024-05-01T12:00:00Z.
const T0: f64 = 1_714_564_800.0;
const N: usize = 200;

fn zeta(i: usize) -> f64 {
    0.02 - 0.0003 * i as f64
}

fn record(gate: &str, i: usize) -> IdentificationRecord {
    let z = zeta(i);
    let end = T0 + 30.0 * i as f64;
    IdentificationRecord {
        gate: gate.into(),
        time: end + 1.5,
        window_start: end - 10.0,
        window_end: end,
        equation: format!("ydd + {:.5}*yd + 88.8*y = 0", 2.0 * z * 9.42),
        coefficients: vec![("c1".into(), 2.0 * z * 9.42), ("c3".into(), 88.8)],
        damping: serde_json::json!({"zeta0": z, "zeta0_interval": [z - 0.004, z + 0.004],
            "trusted": i % 10 != 5, "frequency_hz": 1.5}),
        verdict: if z < 0.0 { "self_excited" } else { "damped" }.into(),
        fit_nmae: 0.03,
        path: "full".into(),
    }
}

/// The database: written through the store itself, closed (checkpointed) before use.
fn database(dir: &Path) -> PathBuf {
    let path = dir.join("gw.db");
    let store = SqliteStore::open(&path, 64).expect("open the store");
    store
        .write(&WriteBatch {
            identifications: (0..N)
                .map(|i| record("g1", i))
                .chain((0..3).map(|i| record("g2", i)))
                .collect(),
            ..Default::default()
        })
        .expect("write the history");
    store.checkpoint().expect("checkpoint");
    path
}

// ------------------------------------------------------------------ the HTTP route

struct Daemon {
    url: String,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    client: reqwest::Client,
}

/// The real daemon on `db`. The retention is a century: the rows are from 2024, and the
/// writer's pruning at start would otherwise delete them under the test.
async fn daemon(db: &Path) -> Daemon {
    gatewatch::service::client::ensure_crypto_provider();
    let cfg = Config::from_toml(&format!(
        "[server]\nlisten = \"127.0.0.1:0\"\nworker_threads = 1\nshutdown_grace_seconds = 2.0\n\
         [storage]\npath = \"{}\"\nretention_days = 36500.0\n\
         [defaults.alert]\nstale_after_seconds = 3600.0\n\
         [gates.g1]\n[gates.g2]\n[gates.quiet]\n",
        db.display()
    ))
    .expect("config");
    let (addr, stop, task) = crate::stream_common::run_daemon(cfg).await;
    Daemon {
        url: format!("http://{addr}"),
        stop,
        task,
        client: reqwest::Client::new(),
    }
}

impl Daemon {
    /// `(status, content type, body)` of `GET {path}`, with `Accept: accept` when given.
    async fn get(&self, path: &str, accept: Option<&str>) -> (u16, String, String) {
        let mut req = self.client.get(format!("{}{path}", self.url));
        if let Some(a) = accept {
            req = req.header("accept", a);
        }
        // the daemon opens its store off the executor: retry until it listens
        let resp = tokio::time::timeout(Duration::from_secs(30), async {
            loop {
                match req.try_clone().expect("clonable").send().await {
                    Ok(r) => return r,
                    Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                }
            }
        })
        .await
        .expect("the daemon answers");
        let status = resp.status().as_u16();
        let ct = resp
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        (status, ct, resp.text().await.expect("body"))
    }

    async fn json(&self, path: &str) -> Value {
        let (status, _, body) = self.get(path, None).await;
        assert_eq!(status, 200, "{path}: {body}");
        serde_json::from_str(&body).expect("JSON")
    }

    async fn stop(self) {
        let _ = self.stop.send(());
        tokio::time::timeout(Duration::from_secs(30), self.task)
            .await
            .expect("stopped in time")
            .expect("joined")
            .expect("clean exit");
    }
}

fn ends(v: &Value) -> Vec<f64> {
    v["identifications"]
        .as_array()
        .expect("identifications")
        .iter()
        .map(|r| r["window_end"].as_f64().expect("window_end"))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn history_route_serves_json_and_csv_by_time_range_and_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = database(dir.path());
    let d = daemon(&db).await;

    // everything, oldest first, the full record
    let all = d.json("/api/v1/gates/g1/history").await;
    assert_eq!(all["gate"], "g1");
    assert_eq!(all["count"], N);
    let e = ends(&all);
    assert_eq!(e.len(), N);
    assert_eq!(e[0], T0);
    assert!(e.windows(2).all(|w| w[0] < w[1]), "oldest first");
    let first = &all["identifications"][0];
    let stored: Value = serde_json::to_value(record("g1", 0)).expect("record as JSON");
    assert_eq!(first, &stored, "the record as stored");

    // from/to in RFC 3339 and in Unix seconds: inclusive bounds on the window end
    let rfc = d
        .json("/api/v1/gates/g1/history?from=2024-05-01T12:10:00Z&to=2024-05-01T12:20:00Z")
        .await;
    let unix = d
        .json(&format!(
            "/api/v1/gates/g1/history?from={}&to={}",
            T0 + 600.0,
            T0 + 1200.0
        ))
        .await;
    let expected: Vec<f64> = (20..=40).map(|i| T0 + 30.0 * f64::from(i)).collect();
    assert_eq!(ends(&rfc), expected);
    assert_eq!(ends(&unix), expected);
    // a fraction of a second is honoured (window 20 ends at T0 + 600, excluded)
    let frac = d
        .json(&format!("/api/v1/gates/g1/history?from={}", T0 + 600.5))
        .await;
    assert_eq!(ends(&frac).first(), Some(&(T0 + 630.0)));

    // limit: the first rows of the range
    let some = d.json("/api/v1/gates/g1/history?limit=5").await;
    assert_eq!(some["count"], 5, "{some}");
    assert_eq!(some["limit"], 5);
    assert_eq!(ends(&some), &e[..5]);

    // the other gate's rows stay apart; a configured gate without rows answers empty
    assert_eq!(d.json("/api/v1/gates/g2/history").await["count"], 3);
    assert_eq!(d.json("/api/v1/gates/quiet/history").await["count"], 0);

    // CSV with Accept: text/csv
    let (status, ct, body) = d
        .get(
            "/api/v1/gates/g1/history?from=2024-05-01T12:10:00Z&limit=3",
            Some("text/csv"),
        )
        .await;
    assert_eq!(status, 200, "{body}");
    assert!(ct.starts_with("text/csv"), "{ct}");
    let mut csv = csv::Reader::from_reader(body.as_bytes());
    let header: Vec<String> = csv
        .headers()
        .expect("header")
        .iter()
        .map(String::from)
        .collect();
    assert_eq!(header, HISTORY_CSV_HEADER);
    let rows: Vec<csv::StringRecord> = csv.records().map(|r| r.expect("row")).collect();
    assert_eq!(rows.len(), 3);
    let col = |name: &str| HISTORY_CSV_HEADER.iter().position(|h| *h == name).unwrap();
    assert_eq!(rows[0][col("gate")], *"g1");
    assert_eq!(
        rows[0][col("window_end")].parse::<f64>().ok(),
        Some(T0 + 600.0)
    );
    let z = rows[0][col("zeta0")].parse::<f64>().expect("zeta0");
    assert!((z - zeta(20)).abs() < 1e-12, "{z}");
    let low = rows[0][col("zeta0_low")].parse::<f64>().expect("low");
    assert!((low - (zeta(20) - 0.004)).abs() < 1e-12, "{low}");
    assert_eq!(rows[0][col("verdict")], *"damped");
    assert_eq!(rows[0][col("trusted")], *"true");

    // `format=csv` names the format in the URL alone (pandas.read_csv, a browser) and wins
    // over `Accept`; `format=json` wins over `Accept: text/csv`
    let url = "/api/v1/gates/g1/history?from=2024-05-01T12:10:00Z&limit=3";
    let (status, ct, by_query) = d
        .get(&format!("{url}&format=csv"), Some("application/json"))
        .await;
    assert_eq!(status, 200, "{by_query}");
    assert!(ct.starts_with("text/csv"), "{ct}");
    assert_eq!(by_query, body);
    let (status, ct, json) = d.get(&format!("{url}&format=json"), Some("text/csv")).await;
    assert_eq!(status, 200, "{json}");
    assert!(ct.starts_with("application/json"), "{ct}");
    let v: Value = serde_json::from_str(&json).expect("JSON");
    assert_eq!(v["count"], 3);

    d.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn history_route_refuses_bad_parameters_naming_them_and_unknown_gates() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = database(dir.path());
    let d = daemon(&db).await;
    for (query, name) in [
        ("from=yesterday", "from"),
        ("to=2024-13-45T00:00:00Z", "to"),
        ("from=nan", "from"),
        ("limit=0", "limit"),
        ("limit=20001", "limit"),
        ("limit=many", "limit"),
        ("limit=abc", "limit"),
        ("limit=-1", "limit"),
        ("limit=", "limit"),
        ("limit=1.5", "limit"),
        (&*format!("from={}&to={}", T0 + 10.0, T0), "from"),
        ("color=blue", "color"),
        ("from=1&from=2", "from"),
        ("format=csv&format=json", "format"),
        ("format=xlsx", "format"),
    ] {
        let (status, content_type, body) = d
            .get(&format!("/api/v1/gates/g1/history?{query}"), None)
            .await;
        assert_eq!(status, 400, "{query}: {body}");
        // the JSON error of docs/api.md, not axum's text/plain "Failed to deserialize"
        assert!(
            content_type.starts_with("application/json"),
            "{query}: {content_type}: {body}"
        );
        let v: Value = serde_json::from_str(&body).expect("a JSON error");
        assert_eq!(v["field"], name, "{query}: names the parameter: {body}");
        assert!(v["error"].as_str().is_some_and(|e| !e.is_empty()), "{body}");
    }
    let (status, _, body) = d.get("/api/v1/gates/nope/history", None).await;
    assert_eq!(status, 404, "{body}");
    assert!(body.contains("nope"), "{body}");
    d.stop().await;
}

// ------------------------------------------------------------------ gatewatch history

/// `gatewatch history --db DB --gate GATE --plot SVG EXTRA`, asserted to exit 0: the picture
/// it wrote and its stderr.
fn plot(db: impl AsRef<Path>, gate: &str, svg: &Path, extra: &[&str]) -> (String, String) {
    let db = db.as_ref().to_str().unwrap();
    let args = [
        &["--db", db, "--gate", gate, "--plot", svg.to_str().unwrap()][..],
        extra,
    ]
    .concat();
    let (code, _, err) = history(&args);
    assert_eq!(code, 0, "{err}");
    (std::fs::read_to_string(svg).expect("the picture"), err)
}

/// A minimal XML well-formedness check (no XML crate in the tree): every element closes in
/// order, attributes are quoted, nothing follows the root. Enough to catch a truncated or
/// garbled file.
fn well_formed(svg: &str) -> Result<(), String> {
    let mut stack: Vec<String> = Vec::new();
    let mut rest = svg.trim_start();
    if let Some(r) = rest.strip_prefix("<?xml") {
        rest = &r[r.find("?>").ok_or("unterminated XML declaration")? + 2..];
    }
    let mut seen_root = false;
    while let Some(open) = rest.find('<') {
        if stack.is_empty() && seen_root && !rest[..open].trim().is_empty() {
            return Err("text after the root element".into());
        }
        rest = &rest[open + 1..];
        let close = rest.find('>').ok_or("unterminated tag")?;
        let tag = &rest[..close];
        rest = &rest[close + 1..];
        if tag.starts_with("!--") {
            continue;
        }
        if tag.matches('"').count() % 2 != 0 {
            return Err(format!("unbalanced quotes in <{tag}>"));
        }
        if let Some(name) = tag.strip_prefix('/') {
            match stack.pop() {
                Some(open) if open == name.trim() => {}
                other => return Err(format!("</{name}> closes {other:?}")),
            }
        } else if !tag.ends_with('/') {
            let name = tag.split_whitespace().next().ok_or("empty tag")?;
            stack.push(name.to_string());
            seen_root = true;
        } else {
            seen_root = true;
        }
    }
    if stack.is_empty() && seen_root {
        Ok(())
    } else {
        Err(format!("unclosed elements {stack:?}"))
    }
}

/// `(x, text)` of every `<text>` element.
fn texts(svg: &str) -> Vec<String> {
    svg.split("<text ")
        .skip(1)
        .filter_map(|t| {
            let body = &t[t.find('>')? + 1..];
            Some(body[..body.find("</text>")?].trim().to_string())
        })
        .collect()
}

/// The number of points of each zeta0 line (a polyline of the series' blue, 2 px), the
/// legend's 2-point sample left out.
fn zeta0_lines(svg: &str) -> Vec<usize> {
    svg.split("<polyline ")
        .skip(1)
        .filter(|p| p.contains("stroke=\"#0072B2\" stroke-width=\"2\""))
        .filter_map(|p| p.split("points=\"").nth(1)?.split('"').next())
        .map(|p| p.split_whitespace().count())
        .filter(|&n| n > 2)
        .collect()
}

/// The attributes of every `<tag .../>` element.
fn elements<'a>(svg: &'a str, tag: &str) -> Vec<&'a str> {
    svg.split(&format!("<{tag} "))
        .skip(1)
        .map(|e| &e[..e.find("/>").unwrap_or(e.len())])
        .collect()
}

/// The number of pieces of the interval band (filled polygons).
fn polygons(svg: &str) -> usize {
    svg.matches("<polygon ").count()
}

#[test]
fn history_plot_draws_the_damping_over_time_from_a_real_database() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = database(dir.path());
    let cfg = dir.path().join("gatewatch.toml");
    std::fs::write(
        &cfg,
        "[defaults.alert]\nfire_below = 0.0\nclear_above = 0.005\n\
         [gates.g1.alert]\nfire_below = -0.002\nclear_above = 0.008\n",
    )
    .expect("config");
    let svg_path = dir.path().join("g1.svg");
    let (svg, err) = plot(&db, "g1", &svg_path, &["--config", cfg.to_str().unwrap()]);
    assert!(err.contains("200 windows"), "{err}");
    well_formed(&svg).expect("well-formed SVG");
    let t = texts(&svg);
    let has = |s: &str| t.iter().any(|x| x.contains(s));
    // the series and the gate's own thresholds (not the defaults)
    // every tenth window untrusted: off the line, hollow grey circles, named as such
    assert!(has("zeta0, trusted (180 windows)"), "{t:?}");
    assert!(
        has("zeta0, untrusted (20 windows): not fed to the alerts"),
        "{t:?}"
    );
    let hollow = svg
        .split("<circle ")
        .skip(1)
        .filter(|c| c.contains("fill=\"none\"") && c.contains("stroke=\"#5A5A5A\""))
        .count();
    assert_eq!(hollow, 20 + 1, "20 windows and the legend's sample");
    assert!(has("95 % interval of zeta0"), "{t:?}");
    assert!(has("fire below -0.2 %"), "{t:?}");
    assert!(has("clear above 0.8 %"), "{t:?}");
    // one verdict change: damped to self_excited where zeta0 crosses 0 (window 67)
    assert!(has("verdict change (1)"), "{t:?}");
    assert!(has("self_excited"), "{t:?}");
    // the verdict labels stay inside the plot, clear of the legend (upper left): at the
    // bottom, a label right of the middle ending at its mark
    let label = svg
        .split("<text ")
        .find(|e| e.contains("self_excited"))
        .expect("the verdict label");
    let attr = |name: &str| -> f64 {
        let v = label.split(&format!("{name}=\"")).nth(1).unwrap();
        v[..v.find('"').unwrap()].parse().unwrap()
    };
    assert!(attr("y") > 400.0, "a label at the bottom: {label}");
    assert!(attr("x") < 980.0, "{label}");
    // the time axis spans the rows: 199 windows of 30 s = 99.5 min, named in its title
    assert!(
        has("min since 2024-05-01T12:00:00Z (to 2024-05-01T13:39:30Z, 200 windows)"),
        "{t:?}"
    );
    let ticks: Vec<f64> = t.iter().filter_map(|x| x.parse::<f64>().ok()).collect();
    assert!(ticks.contains(&0.0), "{ticks:?}");
    assert!(
        ticks.iter().any(|v| (90.0..=99.5).contains(v)),
        "a tick near the end of the 99.5 min: {ticks:?}"
    );
    // the zeta0 line, broken at each untrusted window (5, 15, ..., 195): 21 polylines of the
    // series' blue with a point per window (0-4, 6-14, ..., 186-194, 196-199), no gap in time
    let mut lines = zeta0_lines(&svg);
    lines.sort_unstable();
    assert_eq!(
        lines,
        [vec![4, 5], vec![9; 19]].concat(),
        "points per zeta0 line"
    );
    assert_eq!(polygons(&svg), 21, "band pieces");
    assert!(!has("no windows for over"), "{t:?}");

    // without --config: no thresholds
    let (svg, _) = plot(&db, "g2", &svg_path, &[]);
    well_formed(&svg).expect("well-formed SVG");
    assert!(!svg.contains("fire below"));
    assert!(svg.contains("zeta0 (3 windows)"));
}

/// Gate `gap`, one window every 30 s, with what a line must not cross: a 1 h hole (the daemon
/// down), three untrusted windows in a row, a 10 min hole (the gate silent); and one missed
/// window (60 s: a window replaced under load) that must not break it. Window numbers, from
/// T0 + 30 s * number:
/// - A: 0..40, trusted;
/// - 1 h without rows;
/// - B: 160..200, windows 170, 171, 172 untrusted;
/// - 10 min without rows;
/// - C: 220..250 without 235 (the missed one).
fn gappy_database(dir: &Path) -> PathBuf {
    let path = dir.join("gaps.db");
    let store = SqliteStore::open(&path, 64).expect("open the store");
    let windows = (0..40)
        .chain(160..200)
        .chain((220..250).filter(|&i| i != 235));
    let rows: Vec<IdentificationRecord> = windows
        .map(|i| {
            let mut r = record("gap", i);
            r.damping["trusted"] = Value::Bool(!(170..=172).contains(&i));
            r
        })
        .collect();
    assert_eq!(rows.len(), 40 + 40 + 29);
    store
        .write(&WriteBatch {
            identifications: rows,
            ..Default::default()
        })
        .expect("write the history");
    store.checkpoint().expect("checkpoint");
    path
}

/// `history --plot` breaks the zeta0 line and its band at the gaps in time and at the
/// untrusted windows, and at nothing else; the untrusted windows are the hollow circles, as
/// many as the CSV has `false` in its `trusted` column. It drew one line through them all.
#[test]
fn history_plot_breaks_the_line_at_gaps_and_untrusted_windows() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = gappy_database(dir.path());
    let db = db.to_str().unwrap();
    let svg_path = dir.path().join("gap.svg");
    let (svg, err) = plot(db, "gap", &svg_path, &[]);
    assert!(err.contains("109 windows"), "{err}");
    well_formed(&svg).expect("well-formed SVG");
    let t = texts(&svg);
    let has = |s: &str| t.iter().any(|x| x.contains(s));

    // four pieces: A (40 windows), B before the untrusted ones (10), B after them (27), C
    // whole across its missed window (29)
    let mut lines = zeta0_lines(&svg);
    lines.sort_unstable();
    assert_eq!(lines, [10, 27, 29, 40], "points per zeta0 line");
    assert_eq!(polygons(&svg), 4, "band pieces");
    // the two holes shaded and named, with the threshold: 3 x the median spacing of 30 s
    assert!(
        has("no windows for over 1m 30s (3x the median spacing, 30s): 2 gaps"),
        "{t:?}"
    );
    let shaded: Vec<&str> = elements(&svg, "rect")
        .into_iter()
        .filter(|r| r.contains("fill=\"#000000\""))
        .collect();
    assert_eq!(
        shaded.len(),
        2 + 1,
        "2 gaps and the legend's sample: {shaded:#?}"
    );

    // the untrusted windows as the CSV reports them, and as the plot draws them
    let (code, csv, err) = history(&["--db", db, "--gate", "gap", "--csv"]);
    assert_eq!(code, 0, "{err}");
    let column = HISTORY_CSV_HEADER
        .iter()
        .position(|h| *h == "trusted")
        .expect("trusted column");
    let untrusted = csv
        .lines()
        .skip(1)
        .filter(|l| l.split(',').nth(column) == Some("false"))
        .count();
    assert_eq!(untrusted, 3, "{csv}");
    assert!(has("zeta0, trusted (106 windows)"), "{t:?}");
    assert!(
        has("zeta0, untrusted (3 windows): not fed to the alerts"),
        "{t:?}"
    );
    let hollow = elements(&svg, "circle")
        .iter()
        .filter(|c| c.contains("fill=\"none\"") && c.contains("stroke=\"#5A5A5A\""))
        .count();
    assert_eq!(
        hollow,
        untrusted + 1,
        "the untrusted windows and the legend's sample"
    );

    // a trusted window alone between an untrusted one and a gap is a dot, not lost
    let lone = dir.path().join("lone.db");
    {
        let store = SqliteStore::open(&lone, 64).expect("open the store");
        let rows = [0, 1, 2, 3, 4, 100]
            .into_iter()
            .map(|i| {
                let mut r = record("gap", i);
                r.damping["trusted"] = Value::Bool(i != 3);
                r
            })
            .collect();
        store
            .write(&WriteBatch {
                identifications: rows,
                ..Default::default()
            })
            .expect("write");
        store.checkpoint().expect("checkpoint");
    }
    let (svg, _) = plot(&lone, "gap", &svg_path, &[]);
    assert_eq!(zeta0_lines(&svg), [3], "windows 0-2");
    let dots = elements(&svg, "circle")
        .iter()
        .filter(|c| c.contains("fill=\"#0072B2\""))
        .count();
    assert_eq!(dots, 2, "windows 4 and 100, each alone");
}

#[test]
fn history_refuses_bad_input_naming_it_with_exit_code_2() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = database(dir.path());
    let db = db.to_str().unwrap();
    let svg = dir.path().join("out.svg");
    let svg = svg.to_str().unwrap();
    let missing = dir.path().join("missing.db");
    let missing = missing.to_str().unwrap();
    let pdf = svg.replace(".svg", ".pdf");
    // an empty file is a valid, empty SQLite database: not a gatewatch store, not an old one
    let empty = dir.path().join("empty.db");
    std::fs::write(&empty, b"").unwrap();
    let empty = empty.to_str().unwrap();
    let cases: Vec<(Vec<&str>, Vec<&str>)> = vec![
        (
            vec!["--db", empty, "--gate", "g1"],
            vec!["empty.db", "is not a gatewatch store"],
        ),
        (
            vec!["--db", missing, "--gate", "g1"],
            vec!["missing.db", "no such file"],
        ),
        (
            vec!["--db", missing, "--gate", "g1", "--plot", svg],
            vec!["missing.db"],
        ),
        (
            vec!["--db", db, "--gate", "nope", "--plot", svg],
            vec!["unknown gate `nope`", "g1, g2"],
        ),
        (
            vec!["--db", db, "--gate", "nope"],
            vec!["unknown gate `nope`"],
        ),
        (
            vec![
                "--db",
                db,
                "--gate",
                "g1",
                "--from",
                "2030-01-01T00:00:00Z",
                "--plot",
                svg,
            ],
            vec![
                "no identification between 2030-01-01T00:00:00Z",
                "nothing to plot",
            ],
        ),
        (
            vec!["--db", db, "--gate", "g1", "--from", "noon", "--plot", svg],
            vec!["--from", "noon"],
        ),
        (
            vec!["--db", db, "--gate", "g1", "--to", "12:00"],
            vec!["--to", "12:00"],
        ),
        (
            vec![
                "--db",
                db,
                "--gate",
                "g1",
                "--from",
                "1714568400",
                "--to",
                "1714564800",
            ],
            vec!["--from", "after --to"],
        ),
        (
            vec!["--db", db, "--gate", "g1", "--limit", "0"],
            vec!["--limit"],
        ),
        (
            vec!["--db", db, "--gate", "g1", "--plot", &pdf],
            vec!["out.pdf", "svg or .png"],
        ),
        (
            vec![
                "--db", db, "--gate", "g1", "--plot", svg, "--config", missing,
            ],
            vec!["--config", "missing.db"],
        ),
    ];
    for (args, wanted) in cases {
        let (code, out, err) = history(&args);
        assert_eq!(code, 2, "{args:?}: exit code; stderr {err}");
        assert!(out.is_empty(), "{args:?}: nothing on stdout: {out}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        for w in wanted {
            assert!(err.contains(w), "{args:?}: stderr names `{w}`: {err}");
        }
    }
    // an empty range exits 2 with or without --plot, as docs/operations.md says (it exited 0
    // with no output, which reads like "no windows" and like "wrong range" alike)
    let (code, out, err) = history(&["--db", db, "--gate", "g1", "--from", "2099-01-01T00:00:00Z"]);
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(
        err.contains("no identification between 2099-01-01T00:00:00Z") && err.contains("gw.db"),
        "{err}"
    );
    // a directory is called one, not "no such file"
    let d = dir.path().to_str().unwrap();
    let (code, _, err) = history(&["--db", d, "--gate", "g1"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("is a directory"), "{err}");
    // a device is not a missing file either; nor is a directory given as --config
    let (code, _, err) = history(&["--db", "/dev/null", "--gate", "g1"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("not a regular file"), "{err}");
    let svg = dir.path().join("d.svg");
    let (code, _, err) = history(&[
        "--db",
        db,
        "--gate",
        "g1",
        "--plot",
        svg.to_str().unwrap(),
        "--config",
        d,
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("a directory, not a configuration file"),
        "{err}"
    );
    // an RFC 3339 offset is the same instant as its UTC time: 14:00+02:00 is T0
    let (code, out, err) = history(&[
        "--db",
        db,
        "--gate",
        "g1",
        "--from",
        "2024-05-01T14:00:00+02:00",
        "--to",
        "2024-05-01T12:00:00Z",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 1, "{out}");
    // and the plain listing works on the same file: JSON lines, oldest first
    let (code, out, err) = history(&["--db", db, "--gate", "g2"]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON line"))
        .collect();
    assert_eq!(lines.len(), 3);
    assert_eq!(lines[0]["window_end"], T0);
}

/// A full page says that the range holds more, and where the next page starts: a day and a
/// half of a gate printed its first 20 000 rows, exit 0, without a word. The page that holds
/// the range's last window, even at exactly `--limit` rows, says nothing.
#[test]
fn history_says_when_the_limit_cut_the_range_and_where_to_go_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = database(dir.path());
    let db = db.to_str().unwrap();
    let (code, out, err) = history(&["--db", db, "--gate", "g1", "--csv", "--limit", "5"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 6, "{out}");
    let next = T0 + 30.0 * 4.0;
    assert!(
        err.contains("more than --limit 5 windows of gate g1")
            && err.contains(&format!("--from {next}")),
        "{err}"
    );
    // following the note pages on: the first row again, then the next four
    let from = next.to_string();
    let (code, out, err) = history(&[
        "--db", db, "--gate", "g1", "--csv", "--limit", "5", "--from", &from,
    ]);
    assert_eq!(code, 0, "{err}");
    let first = out.lines().nth(1).expect("a row");
    assert!(first.starts_with(&format!("g1,{},", next + 1.5)), "{first}");
    // the whole range in one page, and the last page at exactly the limit: no note
    for args in [
        vec!["--db", db, "--gate", "g1", "--limit", &N.to_string()],
        vec!["--db", db, "--gate", "g2", "--limit", "3"],
    ] {
        let (code, _, err) = history(&args);
        assert_eq!(code, 0, "{err}");
        assert!(err.is_empty(), "{args:?}: {err}");
    }
}

/// Many gates: the "unknown gate" message names the first 10 and counts the rest, on one line.
#[test]
fn history_unknown_gate_lists_at_most_ten_gates() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    {
        let store = SqliteStore::open(&path, 64).expect("open");
        store
            .write(&WriteBatch {
                identifications: (0..25).map(|g| record(&format!("gate{g:02}"), 0)).collect(),
                ..Default::default()
            })
            .expect("write");
    }
    let (code, _, err) = history(&["--db", path.to_str().unwrap(), "--gate", "nope"]);
    assert_eq!(code, 2, "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("gate00, gate01") && err.contains("gate09"),
        "{err}"
    );
    assert!(!err.contains("gate10"), "{err}");
    assert!(err.contains("and 15 more"), "{err}");
}

/// A WAL-mode copy in a directory the user cannot write (SQLite cannot create its `-shm`
/// there) is still read, as docs/operations.md promises ("opens the file read-only"); with a
/// non-empty `-wal` beside it the copy is refused naming that file, not read without it.
/// Root writes anywhere, so as root the command runs as `nobody` (setpriv).
#[test]
fn history_reads_a_copy_in_a_directory_it_cannot_write() {
    use std::os::unix::fs::PermissionsExt;
    let root =
        String::from_utf8_lossy(&Command::new("id").arg("-u").output().expect("id -u").stdout)
            .trim()
            == "0";
    let dir = tempfile::tempdir().expect("tempdir");
    let src = database(dir.path());
    let ro = dir.path().join("ro");
    std::fs::create_dir(&ro).expect("mkdir");
    std::fs::copy(&src, ro.join("gw.db")).expect("copy");
    // a live store's WAL: rows written but not checkpointed
    let live = dir.path().join("live");
    std::fs::create_dir(&live).expect("mkdir");
    let ro_wal = dir.path().join("ro_wal");
    std::fs::create_dir(&ro_wal).expect("mkdir");
    {
        let store = SqliteStore::open(&live.join("gw.db"), 64).expect("open");
        store
            .write(&WriteBatch {
                identifications: vec![record("g1", 0)],
                ..Default::default()
            })
            .expect("write");
        std::fs::copy(live.join("gw.db"), ro_wal.join("gw.db")).expect("copy");
        std::fs::copy(live.join("gw.db-wal"), ro_wal.join("gw.db-wal")).expect("copy wal");
    }
    for d in [dir.path(), &ro, &ro_wal] {
        std::fs::set_permissions(d, std::fs::Permissions::from_mode(0o555)).expect("chmod");
    }
    let run = |db: &Path| {
        let mut cmd = if root {
            let mut c = Command::new("setpriv");
            c.args(["--reuid=65534", "--regid=65534", "--clear-groups", BIN]);
            c
        } else {
            Command::new(BIN)
        };
        let out = cmd
            .args(["history", "--gate", "g2", "--db"])
            .arg(db)
            .output()
            .expect("run gatewatch history");
        (
            out.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, out, err) = run(&ro.join("gw.db"));
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 3, "the 3 windows of g2: {out}");
    assert!(!ro.join("gw.db-shm").exists());
    let (code, _, err) = run(&ro_wal.join("gw.db"));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("gw.db-wal") && err.contains("not writable"),
        "{err}"
    );
    for d in [dir.path(), &ro, &ro_wal] {
        std::fs::set_permissions(d, std::fs::Permissions::from_mode(0o755)).expect("chmod back");
    }
}
