//! The command line as an operator meets it: clap's hints in usage errors, shell completions,
//! outputs checked before the work, and `check-config` messages that name key and line.

use std::path::Path;
use std::process::{Command, Output, Stdio};

use crate::cli_common;
use cli_common::{gw, text};

/// Runs `gatewatch ARGS`, asserts exit 2 and returns its stderr.
#[track_caller]
fn exit_2(args: &[&str]) -> String {
    let o = gw(args);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    err
}

/// `gatewatch ARGS` is refused as input: exit 2, one stderr line holding `needle`, nothing on
/// stdout (nothing ran).
fn refused_as_input(args: &[&str], needle: &str) {
    let o = gw(args);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(needle), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(o.stdout.is_empty(), "{args:?} ran: {}", text(&o.stdout));
}

#[test]
fn a_mistyped_command_gets_the_did_you_mean_hint_and_the_usage() {
    let err = exit_2(&["identfy", "--input", "x.csv"]);
    let first = err.lines().next().unwrap();
    assert!(
        first.starts_with("gatewatch: ") && first.contains("'identfy'"),
        "{err}"
    );
    assert!(
        err.contains("similar subcommand exists: 'identify'"),
        "{err}"
    );
    assert!(err.contains("Usage: gatewatch"), "{err}");

    let err = exit_2(&["identify", "--inptu", "x.csv"]);
    assert!(err.lines().next().unwrap().contains("'--inptu'"), "{err}");
    assert!(err.contains("--input"), "{err}");
    assert!(err.contains("Usage: gatewatch identify"), "{err}");
}

#[test]
fn missing_arguments_stay_named_on_the_first_line() {
    let err = exit_2(&["identify", "--model", "ydd + c1*y = 0"]);
    let first = err.lines().next().unwrap();
    assert!(first.contains("--input <FILE>"), "{err}");
    assert!(err.contains("Usage: gatewatch identify"), "{err}");
}

/// Runs `shell -c script` if the shell is installed; `None` otherwise.
fn run_shell(shell: &str, args: &[&str]) -> Option<Output> {
    Command::new(shell).args(args).output().ok()
}

#[test]
fn completions_are_generated_for_every_shell_and_bash_loads_them() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let o = gw(&["completions", shell]);
        assert!(o.status.success(), "{shell}: {}", text(&o.stderr));
        let script = text(&o.stdout);
        for word in ["identify", "check-config", "stability-map"] {
            assert!(script.contains(word), "{shell}: {word} missing");
        }
    }
    // bash is on every machine this builds on: source the script and ask it to complete.
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("gatewatch.bash");
    std::fs::write(&script, gw(&["completions", "bash"]).stdout).unwrap();
    let probe = format!(
        "source {}; COMP_WORDS=(gatewatch ide); COMP_CWORD=1; _gatewatch gatewatch ide gatewatch; \
         printf '%s\\n' \"${{COMPREPLY[@]}}\"",
        script.display()
    );
    let o = run_shell("bash", &["-c", &probe]).expect("bash runs");
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(text(&o.stdout).trim(), "identify");

    let o = gw(&["completions", "tcsh"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("'tcsh'"));
}

fn write_series(path: &Path) {
    let mut csv = String::from("t,y\n");
    for i in 0..200 {
        let t = i as f64 * 0.1;
        csv.push_str(&format!("{t},{}\n", (-0.1 * t).exp() * t.cos()));
    }
    std::fs::write(path, csv).unwrap();
}

#[test]
fn an_unwritable_plot_dir_fails_before_the_identification() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d.csv");
    write_series(&data);
    // A regular file where the directory should be: cannot be created, even as root.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, "x").unwrap();
    let target = blocker.join("plots");
    let o = gw(&[
        "identify",
        "--input",
        data.to_str().unwrap(),
        "--model",
        "ydd + c1*yd + c2*y = 0",
        "--json",
        "--plot",
        target.to_str().unwrap(),
    ]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    // Nothing was identified: no JSON on stdout.
    assert!(o.stdout.is_empty(), "stdout: {}", text(&o.stdout));
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("--plot") && err.contains(target.to_str().unwrap()),
        "{err}"
    );
}

fn check_config(toml: &str) -> Output {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("gatewatch.toml");
    std::fs::write(&file, toml).unwrap();
    gw(&["check-config", file.to_str().unwrap()])
}

#[track_caller]
fn config_error(toml: &str, needles: &[&str]) {
    let o = check_config(toml);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{toml}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    for n in needles {
        assert!(err.contains(n), "{toml}: {n:?} missing from {err}");
    }
}

/// `serve` does not create the store's directory: it stops (exit 1) naming the file. A
/// configuration `check-config` passed (exit 0) did that to the systemd unit after its
/// `ExecStartPre`; now `check-config` refuses it (exit 2) naming `storage.path`, the path as
/// `serve` resolves it (relative to the file) and the same reason.
#[test]
fn check_config_refuses_a_store_serve_cannot_open() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("gatewatch.toml");
    let missing = dir.path().join("no-such-dir");
    std::fs::create_dir(dir.path().join("a-dir")).unwrap();
    for (path, resolved, reason) in [
        (
            "no-such-dir/gw.db".to_string(),
            missing.join("gw.db"),
            format!(
                "its directory {} does not exist or is not a directory",
                missing.display()
            ),
        ),
        (
            missing.join("gw.db").display().to_string(),
            missing.join("gw.db"),
            format!(
                "its directory {} does not exist or is not a directory",
                missing.display()
            ),
        ),
        (
            "a-dir".to_string(),
            dir.path().join("a-dir"),
            "is a directory".to_string(),
        ),
    ] {
        std::fs::write(
            &file,
            format!("[server]\nlisten = \"127.0.0.1:0\"\n[storage]\npath = {path:?}\n"),
        )
        .unwrap();
        let o = gw(&["check-config", file.to_str().unwrap()]);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{path}: {err}");
        assert_eq!(
            err.trim_end(),
            format!(
                "gatewatch: {}: storage.path {}: {reason}",
                file.display(),
                resolved.display()
            )
        );
        assert!(o.stdout.is_empty(), "{}", text(&o.stdout));
        // serve stops on the same reason
        let o = gw(&["serve", "--config", file.to_str().unwrap()]);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{path}: {err}");
        assert!(err.contains(&reason), "{path}: {err}");
    }
    assert!(!missing.exists(), "nothing creates the directory");
    // the directory there: both accept it
    std::fs::create_dir(&missing).unwrap();
    std::fs::write(&file, "[storage]\npath = \"no-such-dir/gw.db\"\n").unwrap();
    let o = gw(&["check-config", file.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
}

/// `GATEWATCH_STORAGE_PATH` pointing where `serve` cannot open the store is refused by
/// `check-config` naming the variable and the key it sets, not the file: the file's
/// `storage.path` may say something else, and the line blamed the file for the environment's
/// value.
#[test]
fn check_config_names_the_variable_that_set_a_store_serve_cannot_open() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("main.toml");
    std::fs::write(&file, "[server]\nlisten = \"127.0.0.1:0\"\n").unwrap();
    let missing = dir.path().join("no-such-dir");
    let o = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(["check-config", file.to_str().unwrap()])
        .env("GATEWATCH_STORAGE_PATH", missing.join("x.db"))
        .output()
        .unwrap();
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(
        err.trim_end(),
        format!(
            "gatewatch: GATEWATCH_STORAGE_PATH (sets storage.path) {}: its directory {} does \
             not exist or is not a directory",
            missing.join("x.db").display(),
            missing.display()
        )
    );
    assert!(o.stdout.is_empty(), "{}", text(&o.stdout));
}

/// `serve` stopping on a store `GATEWATCH_STORAGE_PATH` put where it cannot be opened names the
/// variable and the key it sets, as `check-config` does (it said `storage file PATH: ...`, and
/// the operator looked for the fault in the file's `storage.path`). A path from the file:
/// `check_config_refuses_a_store_serve_cannot_open`.
#[test]
fn serve_names_the_variable_that_set_a_store_it_cannot_open() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("main.toml");
    std::fs::write(
        &file,
        "[server]\nlisten = \"127.0.0.1:0\"\n[storage]\npath = \"gw.db\"\n",
    )
    .unwrap();
    let missing = dir.path().join("no-such-dir");
    let o = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(["serve", "--config", file.to_str().unwrap()])
        .env("GATEWATCH_STORAGE_PATH", missing.join("x.db"))
        .env("GATEWATCH_LOG_FORMAT", "text")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let expected = format!(
        "gatewatch: GATEWATCH_STORAGE_PATH (sets storage.path) {}: its directory {} does not \
         exist or is not a directory",
        missing.join("x.db").display(),
        missing.display()
    );
    assert!(err.lines().any(|l| l == expected), "{err}");
    assert!(!err.contains("storage file"), "{err}");
    assert!(
        !dir.path().join("gw.db").exists(),
        "the file's store was not opened"
    );
}

/// `GATEWATCH_AUTH_TOKENS` set to no token (empty, blanks, only commas) stops `serve` and
/// `check-config` (exit 2, one line naming the variable): it replaced the file's tokens with
/// none, `check-config` said ok, and `serve` answered the API without authentication.
#[test]
fn an_auth_tokens_variable_without_a_token_is_refused_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("tok.toml");
    std::fs::write(
        &file,
        "[server]\nlisten = \"127.0.0.1:0\"\nauth_tokens = [\"0123456789abcdef0123\"]\n\
         [storage]\npath = \"gw.db\"\n",
    )
    .unwrap();
    let file = file.to_str().unwrap();
    let run = |args: &[&str], tokens: &str| {
        let mut child = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
            .args(args)
            .env("GATEWATCH_AUTH_TOKENS", tokens)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // a guard against a daemon that started, not a timing assertion
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
        while child.try_wait().unwrap().is_none() {
            if std::time::Instant::now() > deadline {
                let _ = child.kill();
                let _ = child.wait();
                panic!("{args:?} with GATEWATCH_AUTH_TOKENS={tokens:?} started");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        child.wait_with_output().unwrap()
    };
    for tokens in ["", " ", ",", " , "] {
        for args in [vec!["check-config", file], vec!["serve", "--config", file]] {
            let o = run(&args, tokens);
            let err = text(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{args:?} {tokens:?}: {err}");
            assert_eq!(err.trim_end().lines().count(), 1, "{err}");
            assert!(
                err.starts_with(&format!(
                    "gatewatch: GATEWATCH_AUTH_TOKENS (sets server.auth_tokens): {tokens:?} \
                     holds no token"
                )),
                "{args:?}: {err}"
            );
            assert!(!err.contains("tok.toml"), "blamed on the file: {err}");
        }
    }
    // a token in the variable passes
    let o = run(&["check-config", file], "aaaaaaaaaaaaaaaa");
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
}

#[test]
fn check_config_names_the_key_and_the_line() {
    config_error(
        "# gatewatch\n[server]\nlisten = 5\n",
        &["server.listen: invalid type: integer `5`", "line 3"],
    );
    config_error(
        "[server]\nlisten = \"127.0.0.1:9464\"\nfoo = 1\n",
        &["server.foo: unknown field `foo`", "line 3"],
    );
    config_error(
        "[log]\n\nbar = true\n",
        &["log.bar: unknown field", "line 3"],
    );
    config_error(
        "[notify]\n[[notify.webhooks]]\nurl = \"http://x\"\n[[notify.webhooks]]\nurl = 7\n",
        &["notify.webhooks[1].url: invalid type", "line 5"],
    );
    config_error(
        "[defaults]\nwindow_seconds = \"long\"\n",
        &["defaults.window_seconds: invalid type", "line 2"],
    );
    // Under a gate's table: the gate's full path.
    config_error(
        "[gates.g1]\n\n[gates.g2]\nwindow_secondz = 3\n",
        &["gates.g2.window_secondz: unknown field", "line 4"],
    );
}

#[test]
fn a_resend_interval_beyond_alertmanagers_resolve_timeout_is_accepted_with_a_warning() {
    let base = "[notify]\nalertmanager_urls = [\"http://127.0.0.1:9093\"]\n";
    let o = check_config(&format!("{base}resend_interval_seconds = 600\n"));
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(
        err.contains("warning") && err.contains("resend_interval_seconds") && err.contains("300"),
        "{err}"
    );
    let o = check_config(&format!("{base}resend_interval_seconds = 120\n"));
    assert_eq!(o.status.code(), Some(0));
    assert!(o.stderr.is_empty(), "{}", text(&o.stderr));
}

#[test]
fn serve_prints_the_same_warning_at_start() {
    // A port already taken: serve warns, then fails to bind and exits, without running.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("gatewatch.toml");
    std::fs::write(
        &file,
        format!(
            "[server]\nlisten = \"127.0.0.1:{port}\"\n[notify]\nalertmanager_urls = \
             [\"http://127.0.0.1:9093\"]\nresend_interval_seconds = 900\n"
        ),
    )
    .unwrap();
    let o = gw(&["serve", "--config", file.to_str().unwrap()]);
    let err = text(&o.stderr);
    assert_ne!(o.status.code(), Some(0), "{err}");
    assert!(
        err.contains("warning") && err.contains("resend_interval_seconds = 900"),
        "{err}"
    );
}

/// A configuration `serve` cannot read is reported in the log format `GATEWATCH_LOG_FORMAT`
/// asks for: with `json`, one JSON object naming the file, the key and the line (a log shipper
/// that parses every line of a pod got this one, the reason it did not start, as plain text);
/// without it, the plain line. Exit 2 either way.
#[test]
fn serve_reports_an_unreadable_configuration_in_the_environments_log_format() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("gatewatch.toml");
    std::fs::write(&file, "[server]\nlisten = 5\n").unwrap();
    let run = |format: Option<&str>| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_gatewatch"));
        c.args(["serve", "--config", file.to_str().unwrap()])
            .env_remove("GATEWATCH_LOG_FORMAT");
        if let Some(f) = format {
            c.env("GATEWATCH_LOG_FORMAT", f);
        }
        c.output().unwrap()
    };
    let o = run(Some("json"));
    assert_eq!(o.status.code(), Some(2));
    let err = text(&o.stderr);
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "{err}");
    let v: serde_json::Value = serde_json::from_str(lines[0]).expect("a JSON line");
    assert_eq!(v["level"], "ERROR", "{err}");
    let why = v["fields"]["error"].as_str().unwrap_or_default();
    assert!(
        why.contains("gatewatch.toml: server.listen: invalid type") && why.ends_with("line 2"),
        "{err}"
    );
    for format in [None, Some("text"), Some("xml")] {
        let o = run(format);
        assert_eq!(o.status.code(), Some(2));
        let err = text(&o.stderr);
        assert!(err.starts_with("gatewatch: "), "{format:?}: {err}");
        assert!(!err.contains('{'), "{format:?}: {err}");
    }
}

/// `simulate` refuses what it cannot stream before it connects: a rate of 1e12 Hz (6e14 samples,
/// streamed for ever), a chunk of 1e9 s (one buffer of the whole stream, which aborted the
/// process), a NaN speed or start.
#[test]
fn simulate_refuses_impossible_streams_before_connecting() {
    // nothing listens on port 9: a refusal must come from the checks, not the connection
    let url = "http://127.0.0.1:9";
    for (args, needle) in [
        (vec!["--rate", "1e12"], "--rate must be at most"),
        (vec!["--speed", "NaN"], "--speed must be a number"),
        (vec!["--start", "NaN"], "--start must be Unix seconds"),
        (
            vec!["--chunk-seconds", "inf"],
            "--chunk-seconds must be > 0",
        ),
    ] {
        let mut all = vec!["simulate", "--url", url, "--duration", "1"];
        all.extend(args.iter());
        let o = gw(&all);
        let err = text(&o.stderr);
        assert_ne!(o.status.code(), Some(0), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

/// A chunk longer than the stream is the whole stream: `--chunk-seconds 1e9` used to allocate
/// for 1e9 s of samples and abort; now it fails on the absent daemon like any other run.
#[test]
fn a_chunk_longer_than_the_stream_does_not_abort() {
    let o = gw(&[
        "simulate",
        "--url",
        "http://127.0.0.1:9",
        "--duration",
        "1",
        "--chunk-seconds",
        "1e9",
    ]);
    let err = text(&o.stderr);
    assert!(o.status.code().is_some(), "killed by a signal: {err}");
    assert!(!err.contains("memory allocation"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// Bad stream flags are input (exit 2, one line naming the flag), refused before connecting:
/// `--duration 0`, `--speed nan` exited 1, and `--url notaurl` failed at the first request as
/// "builder error: relative URL without a base", naming no flag. `--duration 1e300`, a start of
/// 1e300, noise of 1e300 and gate ids the daemon refuses were streamed.
#[test]
fn simulate_refuses_bad_stream_flags_as_input_naming_them() {
    for (args, needle) in [
        (&["--duration", "0"][..], "--duration must be > 0"),
        (&["--duration=-5"][..], "--duration must be > 0"),
        (&["--duration", "nan"][..], "--duration must be > 0"),
        (&["--speed", "nan"][..], "--speed must be a number"),
        (&["--url", "notaurl"][..], "--url: 'notaurl' is not a URL"),
        (&["--url", "ftp://host/"][..], "--url: 'ftp://host/'"),
        // streams without end, or of values the daemon refuses (the stream ran until killed,
        // from a start of -1e300)
        (
            &["--duration", "1e300"][..],
            "--duration must be > 0 and at most",
        ),
        (
            &["--rate", "1e6", "--duration", "1e9"][..],
            "--duration must be > 0 and at most",
        ),
        (
            &["--rate", "1e6", "--duration", "1e6"][..],
            "--duration times --rate must be at most 1e10 samples, got 1e12",
        ),
        (
            &["--start", "1e300"][..],
            "--start must be Unix seconds from 0",
        ),
        (&["--start=-5"][..], "--start must be Unix seconds from 0"),
        (
            &["--noise-rel", "1e300"][..],
            "--noise-rel must be >= 0 and at most 1e6",
        ),
        (&["--gate", ""][..], "--gate '': gate id must be"),
        (&["--gate", "a b"][..], "--gate 'a b': gate id must be"),
        // a negative number is the flag's value, refused by its own check (clap said
        // "unexpected argument '-1' found", naming no flag)
        (
            &["--noise-abs", "-1"][..],
            "--noise-abs must be >= 0 and at most 1e12, got -1",
        ),
    ] {
        let mut all = vec!["simulate"];
        if !args[0].starts_with("--url") {
            all.extend(["--url", "http://127.0.0.1:9"]);
        }
        all.extend(args);
        refused_as_input(&all, needle);
    }
}

/// A daemon that takes the connection and never answers: `simulate` waited 30 s an attempt, six
/// attempts, three minutes without a word on stderr (its retries went to a log it has not).
/// Each retry is now said, the wait named (`SIMULATE_REQUEST_TIMEOUT`, 10 s).
#[test]
fn simulate_says_so_when_the_daemon_does_not_answer() {
    use std::io::BufRead;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    // accepts and holds every connection, never answering
    std::thread::spawn(move || {
        let held: Vec<_> = listener.incoming().collect();
        drop(held);
    });
    let mut child = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(["simulate", "--url", &url, "--speed", "0", "--duration", "2"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gatewatch runs");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = std::io::BufReader::new(stderr).read_line(&mut line);
        let _ = tx.send(line);
    });
    // the bound only catches silence: the notice comes after the 10 s timeout
    let line = rx.recv_timeout(std::time::Duration::from_secs(60));
    let _ = child.kill();
    let _ = child.wait();
    let line = line.expect("a notice on stderr within 60 s");
    assert!(
        line.starts_with("gatewatch simulate: ")
            && line.contains("no answer within 10 s; retry 1 of 5"),
        "{line}"
    );
}

/// `--onset-hold`/`--onset-ramp` shape the onset scenario only: with another scenario they were
/// ignored (`--scenario stable --onset-hold 10` streamed a stable gate without a word). Refused
/// as input before connecting, naming the flag; the help says so.
#[test]
fn simulate_refuses_the_onset_shape_with_another_scenario() {
    for (args, needle) in [
        (&["--onset-hold", "10"][..], "--onset-hold shapes the onset"),
        (
            &["--scenario", "limit-cycle", "--onset-ramp", "5"][..],
            "--onset-ramp shapes the onset scenario's ramp: it needs --scenario onset (got limit-cycle",
        ),
    ] {
        let mut all = vec!["simulate", "--url", "http://127.0.0.1:9", "--duration", "1"];
        all.extend(args);
        refused_as_input(&all, needle);
    }
    // with the onset they pass the checks, and the run fails only on the absent daemon
    let o = gw(&[
        "simulate",
        "--url",
        "http://127.0.0.1:9",
        "--duration",
        "1",
        "--scenario",
        "onset",
        "--onset-hold",
        "10",
    ]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("--onset-hold"), "{err}");
    let help = text(&gw(&["simulate", "--help"]).stdout);
    assert_eq!(
        help.matches("With --scenario onset only").count(),
        2,
        "{help}"
    );
}

/// `demo` refuses a negative onset shape as `simulate` does (`--onset-hold -1` ran).
#[test]
fn demo_refuses_a_negative_onset_shape_naming_the_flag() {
    for (args, needle) in [
        (
            &["--onset-hold", "-1"][..],
            "--onset-hold must be >= 0 seconds and at most 31622400, got -1",
        ),
        (
            &["--onset-ramp", "nan"][..],
            "--onset-ramp must be >= 0 seconds",
        ),
        (&["--speed", "0"][..], "--speed must be > 0"),
    ] {
        let mut all = vec!["demo"];
        all.extend(args);
        refused_as_input(&all, needle);
    }
}

/// `demo` keeps its store in a temporary directory of its own and removes it when it ends:
/// until stop 67 every run left its database and the `-wal`, `-shm` and `.lock` files beside it
/// in the temporary directory (44 runs on the development machine had left 176 files).
#[test]
fn the_demo_leaves_no_files_behind() {
    let tmp = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(["demo", "--duration", "2"])
        .env("TMPDIR", tmp.path())
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = text(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        text(&out.stdout).starts_with("gatewatch demo: daemon on "),
        "{}",
        text(&out.stdout)
    );
    let left: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}; {err}");
}

/// `stability-map --t-end 1e12`: the solver's smallest step grows with the horizon and was above
/// every trial's first step; the step size underflow drew all 200 trials unstable (exit 0). It
/// is the solver's failure, refused as the horizons 1e9..1e11 are.
#[test]
fn stability_map_refuses_a_horizon_where_the_step_underflows() {
    let o = gw(&[
        "stability-map",
        "--model",
        "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0",
        "--range",
        "c1=-3:3",
        "--range",
        "c2=-3:3",
        "--fix",
        "c3=1",
        "--t-end",
        "1e12",
        "--samples",
        "200",
    ]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("none of the 200 trials reached the horizon"),
        "{err}"
    );
    assert!(o.stdout.is_empty(), "{}", text(&o.stdout));
}

/// `stability-map --output map.svg --plot ./map.svg`: the picture was written over the table
/// (exit 0, the CSV lost); one file named twice, however spelled, is refused before the trials.
#[test]
fn stability_map_refuses_one_file_for_the_table_and_the_picture() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("map.svg");
    let also = dir.path().join("sub").join("..").join("map.svg");
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    let args = |output: &std::path::Path, plot: &std::path::Path| {
        gw(&[
            "stability-map",
            "--model",
            "ydd + c1*yd + c2*y = 0",
            "--range",
            "c1=-1:1",
            "--range",
            "c2=0.1:2",
            "--samples",
            "20",
            "--output",
            output.to_str().unwrap(),
            "--plot",
            plot.to_str().unwrap(),
        ])
    };
    for plot in [&map, &also] {
        let o = args(&map, plot);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(
            err.contains("--output and --plot name the same file"),
            "{err}"
        );
        assert!(!map.exists(), "a file was written: {err}");
    }
    let csv = dir.path().join("map.csv");
    let o = args(&csv, &map);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    assert!(std::fs::read_to_string(&csv).unwrap().starts_with("c1,"));
    assert!(std::fs::read_to_string(&map).unwrap().starts_with("<svg"));
}

/// `gatewatch ... | head -1`: a reader that goes away ends the command quietly with exit 0, as
/// ripgrep does; it was exit 1 "Broken pipe", and a panic (exit 101) with stderr piped too.
#[test]
fn a_closed_stdout_ends_the_command_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("vdp.csv");
    let data = data.to_str().unwrap();
    let o = gw(&[
        "bench",
        "generate",
        "--case",
        "van_der_pol_2",
        "--output",
        data,
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let vdp = "ydd + (c1 + c2*y^2)*yd + y = 0";
    for args in [
        &["identify", "--input", data, "--model", vdp][..],
        &["identify", "--input", data, "--model", vdp, "--json"][..],
        &[
            "stability-map",
            "--model",
            "ydd + c1*yd + c2*y = 0",
            "--range",
            "c1=-1:1",
            "--range",
            "c2=0.1:2",
            "--samples",
            "2000",
        ][..],
        &["bench", "generate", "--case", "van_der_pol_2"][..],
        &["completions", "bash"][..],
    ] {
        let o = with_stdout_closed(args);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{args:?}: {err}");
        assert!(err.is_empty(), "{args:?}: {err}");
    }
}

/// `gatewatch ARGS` whose stdout's reader goes away at once, before the output is written (at
/// worst after it: exit 0 too).
fn with_stdout_closed(args: &[&str]) -> std::process::Output {
    with_reader_gone(args, |c| drop(c.stdout.take()))
}

/// `gatewatch ARGS` with its stdout and stderr piped, `close` dropping one reader at once.
fn with_reader_gone(
    args: &[&str],
    close: impl FnOnce(&mut std::process::Child),
) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gatewatch runs");
    close(&mut child);
    child.wait_with_output().unwrap()
}

/// The same for the commands of the service, which printed with `println!` and panicked (exit
/// 101, "failed printing to stdout: Broken pipe"): `demo` ends (its daemon stopped) when the
/// reader goes away, long before its `--duration`; the benches end at their first line.
#[test]
fn a_closed_stdout_ends_the_service_commands_quietly() {
    for args in [
        &["demo", "--duration", "600"][..],
        &[
            "bench",
            "history",
            "--gates",
            "1",
            "--hours",
            "0.1",
            "--queries",
            "1",
        ][..],
        &[
            "bench",
            "daemon",
            "--samples",
            "2000",
            "--senders",
            "1",
            "--skip",
            "latency",
            "--skip",
            "capacity",
        ][..],
    ] {
        let began = std::time::Instant::now();
        let o = with_stdout_closed(args);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{args:?}: {err}");
        // `demo` may say its port is busy; nothing else is written
        assert!(
            err.lines().all(|l| l.contains("is busy")),
            "{args:?}: {err}"
        );
        // not a timing test: the demo would otherwise run its 600 s
        assert!(began.elapsed().as_secs() < 120, "{args:?} ran on");
    }
}

/// `gatewatch ARGS` whose stderr's reader goes away at once.
fn with_stderr_closed(args: &[&str]) -> std::process::Output {
    with_reader_gone(args, |c| drop(c.stderr.take()))
}

/// Progress and error lines on a stderr whose reader has gone (a log collector restarted, `2>`
/// into a closed pipe) are dropped, not a panic: `bench warning` printed its progress with
/// `eprintln!` and ended with exit 101 and no table; a refused configuration exits 2, as with
/// a stderr to read (it too was 101).
#[test]
fn a_closed_stderr_does_not_crash_the_service_commands() {
    let o = with_stderr_closed(&[
        "bench",
        "warning",
        "--seeds",
        "1",
        "--gates",
        "lab",
        "--scenarios",
        "step",
    ]);
    assert_eq!(o.status.code(), Some(0));
    let table = text(&o.stdout);
    assert!(
        table.contains("| step | lab | GateNegativeDamping |"),
        "{table}"
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[server]\nmax_gates = 0\n").unwrap();
    let o = with_stderr_closed(&["check-config", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
}

/// `bench generate --output` names an unwritable path and exits 2, like stability-map's.
#[test]
fn generate_names_an_unwritable_output() {
    let err = exit_2(&[
        "bench",
        "generate",
        "--case",
        "van_der_pol_2",
        "--output",
        "/proc/nope/x.csv",
    ]);
    assert!(
        err.starts_with("gatewatch: --output: /proc/nope/x.csv: "),
        "{err}"
    );
}

/// stability-map checks --plot and --output before the trials: nothing on stdout.
#[test]
fn stability_map_checks_its_outputs_before_the_trials() {
    for flag in ["--plot", "--output"] {
        let path = if flag == "--plot" {
            "/proc/nope/x.svg"
        } else {
            "/proc/nope/x.csv"
        };
        let o = gw(&[&SMALL_MAP[..], &["--samples", "50", flag, path]].concat());
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(
            o.stdout.is_empty(),
            "ran before refusing: {}",
            text(&o.stdout)
        );
        assert!(
            err.starts_with(&format!("gatewatch: {flag}: {path}: ")),
            "{err}"
        );
    }
}

/// A small stability map, for the tests of its options.
const SMALL_MAP: [&str; 7] = [
    "stability-map",
    "--model",
    "ydd + c1*yd + c2*y = 0",
    "--range",
    "c1=-1:1",
    "--range",
    "c2=0.5:2",
];

/// A missing configuration file is named once, after `gatewatch:`, without the OS's code.
#[test]
fn a_missing_config_is_named_once() {
    let dir = tempfile::tempdir().unwrap();
    let nope = dir.path().join("nope.toml");
    let nope = nope.to_str().unwrap();
    for args in [vec!["check-config", nope], vec!["serve", "--config", nope]] {
        let err = exit_2(&args);
        assert_eq!(
            err.trim_end(),
            format!("gatewatch: {nope}: No such file or directory"),
            "{args:?}"
        );
    }
}

/// --periods and --t-end conflict; negative numbers reach the range checks instead of clap's
/// "unexpected argument '-1'".
#[test]
fn numeric_options_take_negative_numbers_to_their_range_checks() {
    let map = [&SMALL_MAP[..], &["--samples", "10"]].concat();
    let err = exit_2(&[&map[..], &["--periods", "3", "--t-end", "5"]].concat());
    assert!(
        err.contains("--t-end") && err.contains("--periods"),
        "{err}"
    );
    for (args, flag) in [
        (vec!["--t-end", "-1"], "t-end"),
        (vec!["--periods", "-1"], "periods"),
    ] {
        let err = exit_2(&[&map[..], &args[..]].concat());
        assert!(!err.contains("unexpected argument"), "{args:?}: {err}");
        assert!(err.contains(flag), "{args:?}: {err}");
    }
    let err = exit_2(&["simulate", "--rate", "-5"]);
    assert!(
        !err.contains("unexpected argument") && err.contains("--rate"),
        "{err}"
    );
    for cmd in ["warning", "history"] {
        let o = gw(&["bench", cmd, "--hours", "-1"]);
        let err = text(&o.stderr);
        assert_ne!(o.status.code(), Some(0), "{cmd}: {err}");
        assert!(
            !err.contains("unexpected argument") && err.contains("--hours"),
            "{cmd}: {err}"
        );
    }
    let help = text(&gw(&["simulate", "--help"]).stdout);
    assert!(help.contains("as fast as possible"), "{help}");
}

/// The benches take negative numbers to their range checks and refuse them as input (exit 2,
/// one `gatewatch bench NAME:` line naming the flag) before they start anything: before,
/// `bench history --hours -1` printed clap's `error:` and exited 1, `bench soak --rate -5` and
/// `bench daemon --seconds -1` stopped at clap's "unexpected argument", and `bench daemon
/// --skip ingset` skipped nothing, silently.
#[test]
fn benches_refuse_out_of_range_numbers_as_input() {
    for (args, needle) in [
        (
            &["bench", "history", "--hours", "-1"][..],
            "gatewatch bench history: --hours must be > 0 and at most 8760 (a year), got -1",
        ),
        (
            &["bench", "history", "--every-seconds", "0"][..],
            "gatewatch bench history: --every-seconds must be > 0",
        ),
        (
            &["bench", "history", "--gates", "0"][..],
            "gatewatch bench history: --gates must be >= 1",
        ),
        (
            &["bench", "soak", "--rate", "-5"][..],
            "gatewatch bench soak: --minutes, --interval, --rate",
        ),
        (
            &["bench", "soak", "--warmup", "-1"][..],
            "--broken-per-second and --warmup >= 0",
        ),
        (
            &["bench", "daemon", "--seconds", "-1"][..],
            "gatewatch bench daemon: --seconds must be > 0, got -1",
        ),
        (
            &["bench", "daemon", "--skip", "ingset"][..],
            "gatewatch bench daemon: --skip ingset: unknown measurement",
        ),
        (
            &["bench", "daemon", "--gates", "8,0"][..],
            "gatewatch bench daemon: --gates: every gate count must be >= 1",
        ),
        (
            &["simulate", "--url", "http://127.0.0.1:9", "--rate", "-5"][..],
            "--rate must be > 0 (or 0 for the preset's rate), got -5",
        ),
        // Past the bounds a `Duration` holds: these panicked (exit 101), `bench soak` leaving
        // its daemon running; `bench warning --worker-threads 100000` spawned threads until
        // the process aborted.
        (
            &["bench", "history", "--hours", "1e300"][..],
            "gatewatch bench history: --hours must be > 0 and at most 8760 (a year), got 1e300",
        ),
        (
            &["bench", "history", "--db", "/nonexistent/dir/x.db"][..],
            "--db /nonexistent/dir/x.db: its directory /nonexistent/dir does not exist",
        ),
        (
            &["bench", "soak", "--minutes", "1e300"][..],
            "(--minutes and --interval at most a year)",
        ),
        (
            &["bench", "soak", "--interval", "1e300"][..],
            "(--minutes and --interval at most a year)",
        ),
        (
            &["bench", "warning", "--worker-threads", "100000"][..],
            "--worker-threads must be at most 256",
        ),
        (
            &["bench", "warning", "--hours", "1e300"][..],
            "--hours must be > 0 and at most 744",
        ),
        (
            &["demo", "--duration", "1e300"][..],
            "gatewatch demo: --duration must be > 0 and at most 31536000 seconds (a year), got 1e300",
        ),
        (
            &["simulate", "--url", "http://127.0.0.1:9", "--speed", "1e-30"][..],
            "--speed 1e-30: --duration",
        ),
        (
            &["simulate", "--protocol", "tcp", "--tcp-addr", "notanaddr"][..],
            "--tcp-addr 'notanaddr': expected host:port",
        ),
        // a negative number reaches the flag's own range check (clap refused it as "unexpected
        // argument '-1'", naming no flag)
        (
            &["simulate", "--url", "http://127.0.0.1:9", "--start", "-1"][..],
            "--start must be Unix seconds from 0",
        ),
        (
            &["bench", "warning", "--trend-min-span-seconds", "-1"][..],
            "--trend-min-span-seconds must be a number >= 0",
        ),
    ] {
        refused_as_input(args, needle);
    }
    // a negative count is clap's invalid value, naming the flag
    for (args, flag) in [
        (
            &["bench", "warning", "--seeds", "-1"][..],
            "'--seeds <SEEDS>'",
        ),
        (&["bench", "soak", "--gates", "-2"][..], "'--gates <GATES>'"),
    ] {
        let o = gw(args);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("invalid value '-") && err.contains(flag),
            "{args:?}: {err}"
        );
    }
}

/// Sizes past their documented bounds are refused at once, naming the flag and the bound (exit
/// 2): `identify --population 100000000` grew to gigabytes heading for an out-of-memory kill
/// without a word, `--generations`/`--runs 1e11` aborted on a failed allocation, and
/// `stability-map --samples 100000000` ran for hours.
#[test]
fn absurd_sizes_are_refused_naming_the_flag_and_its_bound() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d.csv");
    write_series(&data);
    let data = data.to_str().unwrap();
    let identify = |flag: &str, value: &str| {
        vec![
            "identify".to_string(),
            "--input".into(),
            data.into(),
            "--model".into(),
            "ydd + c1*yd + c2*y = 0".into(),
            flag.into(),
            value.into(),
        ]
    };
    let owned = |args: &[&str]| args.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    for (args, needle) in [
        (
            identify("--population", "100000000"),
            "--population must be at most 10000, got 100000000",
        ),
        (
            identify("--generations", "100000000000"),
            "--generations must be at most 100000, got 100000000000",
        ),
        (
            identify("--runs", "100000000000"),
            "--runs must be at most 1000, got 100000000000",
        ),
        (
            owned(&[
                "stability-map",
                "--model",
                "ydd + c1*yd + c2*y = 0",
                "--range",
                "c1=-1:1",
                "--range",
                "c2=0.1:2",
                "--samples",
                "100000000",
            ]),
            "--samples must be at most 1000000, got 100000000",
        ),
        (
            owned(&["bench", "seed-cases", "--runs", "100000"]),
            "--runs must be at most 1000, got 100000",
        ),
        (
            owned(&["bench", "gate-example", "--population", "100000"]),
            "--population must be at most 10000, got 100000",
        ),
        (
            owned(&["bench", "gate-example", "--generations", "1000000"]),
            "--generations must be at most 100000, got 1000000",
        ),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refused_as_input(&args, needle);
    }
    // A size within its bound still runs (checked on the cheapest command).
    let o = gw(&[
        "stability-map",
        "--model",
        "ydd + c1*yd + c2*y = 0",
        "--range",
        "c1=-1:1",
        "--range",
        "c2=0.1:2",
        "--samples",
        "1000",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    // The daemon's configuration is held to the same bounds when it is loaded.
    config_error(
        "[defaults]\npopulation = 100000\n",
        &["population", "must be <= 10000"],
    );
}

/// A huge or tiny number the user gave is quoted in scientific form (`1e300`), not as the 301
/// digits Rust's `{}` prints: in option errors (`simulate`, `stability-map`, `bench
/// seed-cases`) and in `check-config`'s (a gate's `params.k`, `storage`, `notify`).
#[test]
fn huge_and_tiny_numbers_are_quoted_in_scientific_form() {
    let model = "ydd + c1*yd + c2*y = 0";
    let map = |flag: &str, value: &str| {
        [
            "stability-map",
            "--model",
            model,
            "--range",
            "c1=-1:1",
            "--range",
            "c2=1:2",
        ]
        .into_iter()
        .map(String::from)
        .chain([format!("{flag}={value}")])
        .collect::<Vec<_>>()
    };
    let owned = |args: &[&str]| args.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    for (args, needle) in [
        (
            owned(&["simulate", "--url", "http://127.0.0.1:9", "--rate", "1e300"]),
            "--rate must be at most 1000000 Hz, got 1e300",
        ),
        (
            owned(&[
                "simulate",
                "--url",
                "http://127.0.0.1:9",
                "--duration=-1e300",
            ]),
            "--duration must be > 0 and at most 31622400 seconds (366 days), got -1e300",
        ),
        (
            owned(&[
                "simulate",
                "--url",
                "http://127.0.0.1:9",
                "--noise-abs=-1e-300",
            ]),
            "--noise-abs must be >= 0 and at most 1e12, got -1e-300",
        ),
        (
            map("--t-end", "-1e300"),
            "--t-end must be positive, got -1e300",
        ),
        (
            map("--periods", "1e300"),
            "--periods must be between 1 and 100000, got 1e300",
        ),
        (
            owned(&["bench", "seed-cases", "--rtol", "1e300"]),
            "--rtol must be in [1e-14, 1), got 1e300",
        ),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refused_as_input(&args, needle);
        let err = text(&gw(&args).stderr);
        assert!(!err.contains("0000000000"), "{args:?}: {err}");
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("num.toml");
    for (toml, needle) in [
        (
            "[defaults]\nstiffness = 1e300\n[defaults.params]\nk = 2e300\n",
            "defaults.params.k: 2e300 conflicts with stiffness = 1e300",
        ),
        (
            "[storage]\nnats_lease_seconds = -1e300\n",
            "storage.nats_lease_seconds: -1e300 must be at least 1",
        ),
        (
            "[notify]\ntimeout_seconds = -1e300\n",
            "notify.timeout_seconds: timeout_seconds must be a positive finite number, got -1e300, line 2",
        ),
    ] {
        std::fs::write(&file, toml).unwrap();
        let err = exit_2(&["check-config", file.to_str().unwrap()]);
        assert!(err.contains(needle), "{toml}: {err}");
        assert!(!err.contains("0000000000"), "{toml}: {err}");
    }
}
