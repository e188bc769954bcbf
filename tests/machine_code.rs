//! The models as machine code (`model::jit`), seen from outside: `check-config` says how the
//! shipped configuration's models will run; a host that refuses executable memory (what
//! systemd's `MemoryDenyWriteExecute=yes` does, here through Linux's `PR_SET_MDWE`) and
//! `GATEWATCH_JIT=off` make them interpreted, and the identification gives the same numbers
//! either way.

use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/gatewatch.toml");

/// How the binary is started.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Host {
    Plain,
    JitOff,
    /// Under `prctl(PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN)`, which survives `execve`.
    RefusesExecutableMemory,
}

fn run(host: Host, args: &[&str]) -> Output {
    let mut cmd = match host {
        Host::RefusesExecutableMemory => {
            let mut c = Command::new("python3");
            c.arg("-c").arg(
                "import ctypes, os, sys\n\
                 if ctypes.CDLL(None, use_errno=True).prctl(65, 1, 0, 0, 0) != 0:\n\
                 \x20   sys.exit(77)\n\
                 os.execv(sys.argv[1], sys.argv[1:])",
            );
            c.arg(BIN);
            c
        }
        _ => Command::new(BIN),
    };
    cmd.args(args).env_remove("GATEWATCH_JIT");
    if host == Host::JitOff {
        cmd.env("GATEWATCH_JIT", "off");
    }
    cmd.output().expect("run gatewatch")
}

/// Whether this kernel can refuse executable memory to a process (Linux 6.3 and later); the
/// tests that need it say so and return where it cannot.
fn mdwe_available() -> bool {
    if Command::new("python3").arg("--version").output().is_err() {
        // CI installs python3-venv, and python3 with it
        assert!(
            std::env::var_os("CI").is_none(),
            "CI must have python3 (to set PR_SET_MDWE with)"
        );
        eprintln!("skipped: no python3 to set PR_SET_MDWE with");
        return false;
    }
    let out = run(Host::RefusesExecutableMemory, &["--version"]);
    match out.status.code() {
        Some(0) => true,
        Some(77) => {
            eprintln!("skipped: this kernel has no PR_SET_MDWE (Linux 6.3 or later)");
            false
        }
        other => panic!(
            "python3 wrapper failed ({other:?}): {}",
            String::from_utf8_lossy(&out.stderr)
        ),
    }
}

fn models_line(host: Host) -> String {
    let out = run(host, &["check-config", CONFIG]);
    assert!(out.status.success(), "{host:?}: {out:?}");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    stdout
        .lines()
        .find(|l| l.starts_with("models: "))
        .unwrap_or_else(|| panic!("{host:?}: no models line in {stdout:?}"))
        .to_string()
}

#[test]
fn check_config_says_how_the_models_will_run() {
    // The shipped configuration's defaults: the polynomial model of the lab gate.
    assert_eq!(
        models_line(Host::Plain),
        "models: 1 compiled to machine code, 0 interpreted"
    );
    assert_eq!(
        models_line(Host::JitOff),
        "models: 0 compiled to machine code, 1 interpreted"
    );
    if mdwe_available() {
        assert_eq!(
            models_line(Host::RefusesExecutableMemory),
            "models: 0 compiled to machine code, 1 interpreted"
        );
    }
}

/// The section 8.5 gate identified twice: every column but the seconds.
fn gate_example(host: Host) -> Vec<String> {
    let out = run(host, &["bench", "gate-example", "--runs", "2"]);
    assert!(out.status.success(), "{host:?}: {out:?}");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let rows: Vec<String> = stdout
        .lines()
        .filter(|l| l.starts_with("| 1 ") || l.starts_with("| 2 "))
        .map(|l| l.rsplitn(3, '|').nth(2).unwrap_or(l).to_string())
        .collect();
    assert_eq!(rows.len(), 2, "{host:?}: {stdout}");
    rows
}

#[test]
fn interpreted_models_give_the_same_identification() {
    let plain = gate_example(Host::Plain);
    assert_eq!(gate_example(Host::JitOff), plain);
    if mdwe_available() {
        assert_eq!(gate_example(Host::RefusesExecutableMemory), plain);
    }
}

#[test]
fn an_unknown_gatewatch_jit_value_is_refused_by_name() {
    let out = Command::new(BIN)
        .args(["check-config", CONFIG])
        .env("GATEWATCH_JIT", "of")
        .output()
        .expect("run gatewatch");
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("GATEWATCH_JIT: must be on or off") && stderr.contains("\"of\""),
        "{stderr}"
    );
}
