//! What the command-line tests share: running the built binary and reading what it printed.

#![allow(dead_code)] // each test crate uses its own subset

use std::process::{Command, Output, Stdio};

/// Runs `gatewatch ARGS` to completion with stdin closed (no test waits on a prompt).
pub fn gw(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("gatewatch runs")
}

/// Bytes the binary printed, as text (lossy: a test compares words, not encodings).
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}
