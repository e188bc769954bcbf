//! What the `gatewatch history` tests share (`store_history` on the SQLite file,
//! `store_nats_history` on NATS): the command run as a user runs it.

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");

/// `gatewatch history ARGS`: (exit code, stdout, stderr).
pub fn history(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(BIN)
        .arg("history")
        .args(args)
        .output()
        .expect("run gatewatch history");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
