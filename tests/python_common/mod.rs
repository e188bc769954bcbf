//! A Python virtual environment with packages from PyPI, for the tests that drive real Python
//! clients (`influx_clients.rs`, `python_notebooks.rs`).

use std::path::{Path, PathBuf};
use std::process::Command;

/// Skips (outside CI) or fails (in CI) for a missing component.
pub fn missing(what: &str) {
    assert!(
        std::env::var_os("CI").is_none(),
        "{what} is required in CI (see .ci/run)"
    );
    eprintln!("SKIP: {what}");
}

/// The python of a new virtual environment under `dir` with `packages` installed, or `None`
/// (after [`missing`]) when python3's venv module or PyPI is out of reach.
pub fn venv_python(dir: &Path, packages: &[&str]) -> Option<PathBuf> {
    let venv = dir.join("venv");
    let made = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&venv)
        .status();
    if !made.is_ok_and(|s| s.success()) {
        missing("python3 with the venv module");
        return None;
    }
    let pip = Command::new(venv.join("bin/pip"))
        .args(["install", "--quiet", "--disable-pip-version-check"])
        .args(packages)
        .output()
        .unwrap();
    if !pip.status.success() {
        missing(&format!(
            "pip install {} (PyPI unreachable?): {}",
            packages.join(" "),
            String::from_utf8_lossy(&pip.stderr)
        ));
        return None;
    }
    Some(venv.join("bin/python"))
}
