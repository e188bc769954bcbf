//! docs/notebooks.md as a user runs it: every ```python block of the page, as written, in a
//! virtual environment with pandas and matplotlib from PyPI, against a REAL `gatewatch serve`
//! (the binary, bearer tokens on, a real SQLite store) that `gatewatch simulate` fed an onset.
//! What each recipe prints is checked against the daemon's own answers.
//!
//! Without PyPI the test is skipped with a message, except in CI (`CI` set), where it fails.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::python_common;
use python_common::{free_port, venv_python, Daemon};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");
const TOKEN: &str = "notebook-token-0123456789";

/// `GET path` with the token: (status, body).
fn get(port: u16, path: &str) -> Option<(u16, String)> {
    python_common::http_get(port, path, Some(TOKEN))
}

/// The python blocks of docs/notebooks.md, in order.
fn recipes() -> Vec<String> {
    let page = std::fs::read_to_string(Path::new(ROOT).join("docs/notebooks.md")).unwrap();
    let mut blocks = Vec::new();
    let mut current: Option<String> = None;
    for line in page.lines() {
        match (&mut current, line.trim_end()) {
            (None, "```python") => current = Some(String::new()),
            (Some(_), "```") => blocks.push(current.take().unwrap()),
            (Some(b), l) => {
                b.push_str(l);
                b.push('\n');
            }
            (None, _) => {}
        }
    }
    blocks
}

fn run_recipe(python: &Path, dir: &Path, code: &str, env: &[(&str, String)]) -> String {
    let script = dir.join("recipe.py");
    std::fs::write(&script, code).unwrap();
    let out: Output = Command::new(python)
        .arg(&script)
        .current_dir(dir)
        .envs(env.iter().map(|(k, v)| (*k, v.as_str())))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the recipe failed:\n{code}\n--- stderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Starts the daemon, streams an onset into it and waits until its store holds every window
/// identified; the count of stored windows.
fn fed_daemon(dir: &Path, port: u16) -> (Daemon, PathBuf, u64) {
    let db = dir.join("gatewatch.db");
    let cfg = dir.join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{port}\"\nauth_tokens = [\"{TOKEN}\"]\n\
             [storage]\npath = \"{}\"\n[gates.g1]\n[gates.g2]\n",
            db.display()
        ),
    )
    .unwrap();
    let daemon = Daemon(
        Command::new(BIN)
            .args(["serve", "--config"])
            .arg(&cfg)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let deadline = Instant::now() + Duration::from_secs(60);
    while get(port, "/readyz").is_none_or(|(s, _)| s != 200) {
        assert!(Instant::now() < deadline, "the daemon never got ready");
        std::thread::sleep(Duration::from_millis(50));
    }
    let sim = Command::new(BIN)
        .args(["simulate", "--url", &format!("http://127.0.0.1:{port}")])
        .args(["--token", TOKEN, "--gate", "g1", "--scenario", "onset"])
        .args([
            "--onset-hold",
            "30",
            "--onset-ramp",
            "60",
            "--duration",
            "120",
        ])
        .args(["--speed", "20", "--seed", "3"])
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "simulate: {}",
        String::from_utf8_lossy(&sim.stderr)
    );
    // the store is written behind the identifications: wait until the count holds still
    let count = || -> u64 {
        let (_, body) = get(port, "/api/v1/gates/g1/history?format=json").unwrap_or_default();
        serde_json::from_str::<Value>(&body).map_or(0, |v| v["count"].as_u64().unwrap_or(0))
    };
    let (mut last, mut still) = (0, 0);
    let deadline = Instant::now() + Duration::from_secs(120);
    while still < 10 {
        assert!(Instant::now() < deadline, "the history never settled");
        std::thread::sleep(Duration::from_millis(200));
        let n = count();
        (last, still) = if n == last { (n, still + 1) } else { (n, 0) };
    }
    assert!(last >= 10, "{last} windows stored of 120 s of samples");
    (daemon, db, last)
}

#[test]
fn the_notebook_recipes_run_as_written_against_a_real_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let Some(python) = venv_python(dir.path(), &["pandas", "matplotlib"]) else {
        return;
    };
    let recipes = recipes();
    assert_eq!(
        recipes.len(),
        4,
        "docs/notebooks.md has four python recipes"
    );
    let port = free_port();
    let (_daemon, db, windows) = fed_daemon(dir.path(), port);

    let record = dir.path().join("force.csv");
    let generated = Command::new(BIN)
        .args(["bench", "generate", "--case", "gate_example", "--output"])
        .arg(&record)
        .status()
        .unwrap();
    assert!(generated.success());
    let plot = dir.path().join("damping.png");
    let env = [
        ("GATEWATCH_URL", format!("http://127.0.0.1:{port}")),
        ("GATEWATCH_GATE", "g1".to_string()),
        ("GATEWATCH_TOKEN", TOKEN.to_string()),
        ("GATEWATCH_BIN", BIN.to_string()),
        ("GATEWATCH_CSV", record.display().to_string()),
        ("GATEWATCH_DB", db.display().to_string()),
        ("GATEWATCH_PLOT", plot.display().to_string()),
    ];

    // 1. the history as a DataFrame, and its picture
    let out = run_recipe(&python, dir.path(), &recipes[0], &env);
    let (_, json) = get(port, "/api/v1/gates/g1/history").unwrap();
    let json: Value = serde_json::from_str(&json).unwrap();
    let trusted = json["identifications"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["damping"]["trusted"] == true)
        .count();
    assert!(
        out.contains(&format!("windows {windows}, trusted {trusted}")),
        "{out}"
    );
    assert!(trusted > 0, "{out}");
    let png = std::fs::read(&plot).expect("the recipe saved its picture");
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    assert!(png.len() > 10_000, "a {}-byte picture", png.len());
    // and on the configured g2, which has no window yet (a header alone: its `trusted` column
    // was read as an empty object column, and `h[h["trusted"]]` raised KeyError)
    let mut env_g2 = env.clone();
    env_g2[1].1 = "g2".to_string();
    let out = run_recipe(&python, dir.path(), &recipes[0], &env_g2);
    assert!(out.contains("windows 0, trusted 0"), "{out}");

    // 2. every gate: the configured g2 without data too, the fed g1 with its samples
    let out = run_recipe(&python, dir.path(), &recipes[1], &env);
    let (_, page) = get(port, "/api/v1/gates").unwrap();
    let page: Value = serde_json::from_str(&page).unwrap();
    let samples = page["gates"][0]["samples"]
        .as_u64()
        .expect("samples")
        .to_string();
    assert_eq!(page["gates"][0]["gate"], "g1", "{page}");
    let g1 = out
        .lines()
        .find(|l| l.starts_with("g1 "))
        .unwrap_or_else(|| panic!("no row of g1:\n{out}"));
    assert!(
        g1.split_whitespace().any(|w| w == samples),
        "g1's samples {samples}: {g1}"
    );
    assert!(out.lines().any(|l| l.starts_with("g2 ")), "{out}");

    // 3. identify from Python prints what `identify --json` says
    let out = run_recipe(&python, dir.path(), &recipes[2], &env);
    let cli = Command::new(BIN)
        .args(["identify", "--input"])
        .arg(&record)
        .args([
            "--signal",
            "force",
            "--stiffness",
            "81360",
            "--seed",
            "1",
            "--json",
        ])
        .args(["--model", "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0"])
        .output()
        .unwrap();
    let fit: Value = serde_json::from_slice(&cli.stdout).unwrap();
    let z = fit["damping"]["zeta0"].as_f64().unwrap();
    assert!(out.contains(fit["equation"].as_str().unwrap()), "{out}");
    assert!(out.contains(&format!("zeta0 {:+.3} %", 100.0 * z)), "{out}");
    assert!(z < 0.0, "the chapter's gate is self-excited: {z}");

    // 4. the store, offline, through `gatewatch history`
    let out = run_recipe(&python, dir.path(), &recipes[3], &env);
    assert!(
        out.contains(&format!("{windows} windows of g1 in ")),
        "{out}"
    );
}
