//! Command output on stdout that ends quietly when its reader goes away.
//!
//! `println!` panics when stdout is a pipe whose reader has gone (`gatewatch demo | head -1`):
//! Rust ignores SIGPIPE, so the write fails with `BrokenPipe` instead of killing the process as
//! it would a C program, and `println!` turns that failure into a panic (exit 101 and a
//! backtrace). The commands of the service (`demo`, `bench daemon`, `bench soak`, `bench
//! warning`, `bench history`) write with `outln!` instead, which returns the error, and end
//! with [`exit_code`]: a broken pipe is a reader that has what it wanted, so the command ends
//! quietly with success, as the other commands of `gatewatch` do (`cli::main`).

use std::process::ExitCode;

/// `println!` that returns the write's `std::io::Result` instead of panicking.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*)
    }};
}
pub(crate) use outln;

/// `eprintln!` that drops the line when stderr is closed or its reader has gone, where
/// `eprintln!` panics ("failed printing to stderr"): a command's progress and error lines are
/// no reason to crash it (`gatewatch bench warning 2>&- > table.md`).
macro_rules! errln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr().lock(), $($arg)*);
    }};
}
pub(crate) use errln;

/// Whether `e` is, or was caused by, a write to a pipe whose reader has gone.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// The exit code of a command that failed with `e`: success, without a word, when its stdout's
/// reader went away; otherwise `command: error` on stderr and exit 1.
pub fn exit_code(command: &str, e: &anyhow::Error) -> ExitCode {
    if is_broken_pipe(e) {
        return ExitCode::SUCCESS;
    }
    // a closed stderr too must not turn the message into a panic
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "{command}: {e:#}");
    ExitCode::FAILURE
}
