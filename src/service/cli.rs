//! Command-line front ends of the daemon: `serve`, `check-config`, `simulate`, `demo`.
//!
//! The integrator wires [`ServeArgs`], [`CheckConfigArgs`] and [`SimulateArgs`] into the main
//! clap enum and calls [`serve`], [`check_config`] and [`simulate`].

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use super::client::{check_stream, simulate_with_source, simulator};
// the simulate client lives in `service::client`; its arguments are re-exported here because
// the main clap enum names them `service::cli::SimulateArgs`.
pub use super::client::{Protocol, Scenario, SimulateArgs};
use super::config::{Config, LogFormat};
pub use super::demo::{demo, DemoArgs};
use super::stdout::errln;

/// `gatewatch serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Configuration file (TOML); without it the embedded example configuration is used.
    #[arg(long, env = "GATEWATCH_CONFIG")]
    pub config: Option<PathBuf>,
}

/// `gatewatch check-config FILE`.
#[derive(Debug, Clone, clap::Args)]
pub struct CheckConfigArgs {
    /// Configuration file to validate.
    pub file: PathBuf,
}

/// Sets up tracing (text or JSON; `RUST_LOG` overrides the configured level).
///
/// Logs go to stderr, as daemons' logs do (journald and container runtimes collect it; stdout
/// stays free for command output). Colour codes only when stderr is a terminal: in a file or
/// journald they are noise that breaks `grep` and log shippers, and JSON never has them.
///
/// An invalid `RUST_LOG` ([`super::rust_log`]) does not stop the start: `log.level` is used and
/// the first line logged is a warning naming `RUST_LOG`, its value and why it is refused.
pub fn init_tracing(config: &Config) {
    use std::io::IsTerminal;
    let configured = || tracing_subscriber::EnvFilter::new(log_filter(&config.log.level));
    let (filter, invalid) = match super::rust_log::read() {
        Ok(Some(f)) => (f, None),
        Ok(None) => (configured(), None),
        Err(invalid) => (configured(), Some(invalid)),
    };
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = match config.log.format {
        LogFormat::Json => builder.json().with_ansi(false).try_init(),
        LogFormat::Text => builder
            .with_ansi(std::io::stderr().is_terminal())
            .try_init(),
    };
    if let Some(bad) = invalid {
        tracing::warn!(
            rust_log = %bad.value,
            error = %bad.reason,
            log_level = %config.log.level,
            "RUST_LOG is invalid and ignored; using log.level"
        );
    }
}

/// The compiler's crates, quiet below `warn` unless the configured filter names them.
const QUIET_TARGETS: [&str; 2] = ["cranelift_jit", "cranelift_codegen"];

/// The filter for `log.level`: the level, with the JIT compiler's crates held at `warn`.
///
/// Why: at `info`, `cranelift_jit` logs every compiled function's IR (about 300 lines, 11 KB, at
/// each start), which is no event an operator wants in journald. A level that names a cranelift
/// target itself (`info,cranelift_jit=debug`) is left as it is, and `RUST_LOG` is never changed.
pub fn log_filter(level: &str) -> String {
    if level.contains("cranelift") {
        return level.to_string();
    }
    let mut filter = level.to_string();
    for t in QUIET_TARGETS {
        filter.push_str(&format!(",{t}=warn"));
    }
    filter
}

/// Loads the configuration `serve` uses: the file or the embedded one, then the environment.
pub fn load_config(path: Option<&std::path::Path>) -> Result<Config, super::config::ConfigError> {
    let mut config = match path {
        Some(p) => Config::from_file(p)?,
        None => Config::from_toml(super::config::EMBEDDED_CONFIG)?,
    };
    config.apply_env(|k| std::env::var(k).ok())?;
    Ok(config)
}

/// The line `serve` and `check-config` print for a configuration error: `gatewatch: FILE:
/// message`, the file named once (a file that cannot be read is named by the error itself).
fn config_error_line(file: Option<&std::path::Path>, e: &super::config::ConfigError) -> String {
    match file {
        Some(f) if !e.names_file() => format!("gatewatch: {}: {e}", f.display()),
        _ => format!("gatewatch: {e}"),
    }
}

/// `gatewatch serve`: exit 0 after a clean shutdown, 2 on a configuration error, 1 otherwise.
pub fn serve(args: ServeArgs) -> ExitCode {
    let mut config = match load_config(args.config.as_deref()) {
        Ok(c) => c,
        Err(e) => {
            let line = config_error_line(args.config.as_deref(), &e);
            match format_before_the_config() {
                LogFormat::Text => errln!("{line}"),
                LogFormat::Json => {
                    let why = line.strip_prefix("gatewatch: ").unwrap_or(&line);
                    start_line(
                        LogFormat::Json,
                        "ERROR",
                        "gatewatch failed: the configuration",
                        Some(why),
                    );
                }
            }
            return ExitCode::from(2);
        }
    };
    // a relative storage.path is relative to the configuration file, like Prometheus does
    let base = args.config.as_deref().and_then(std::path::Path::parent);
    config.storage.path = config.storage.resolve(base).display().to_string();
    // From here the log format is known: what serve says on stderr follows it.
    let format = config.log.format;
    let env = super::config::unknown_env_warnings(
        std::env::vars_os().filter_map(|(k, _)| k.into_string().ok()),
    );
    for w in config.warnings().into_iter().chain(env) {
        start_line(format, "WARN", &w, None);
    }
    init_tracing(&config);
    // before the runtime's threads: the memory bound of docs/design.md depends on it
    super::malloc::return_large_buffers_to_the_os();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            let e = format!("cannot start the runtime: {e}");
            start_line(format, "ERROR", "gatewatch failed", Some(&e));
            return ExitCode::FAILURE;
        }
    };
    // whether GATEWATCH_STORAGE_PATH set the store's path, read as `apply_env` read it
    let storage_from_env = config.storage.backend == crate::store::StorageBackend::Sqlite
        && std::env::var("GATEWATCH_STORAGE_PATH").is_ok();
    let result = rt
        .block_on(async move {
            let listeners = super::server::Listeners::bind(&config).await?;
            super::server::run(config, listeners, super::shutdown::signal()).await
        })
        .map_err(|e| name_the_storage_variable(e, storage_from_env));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if format == LogFormat::Text {
                tracing::error!(error = %e, "gatewatch failed");
            }
            start_line(format, "ERROR", "gatewatch failed", Some(&format!("{e:#}")));
            ExitCode::FAILURE
        }
    }
}

/// `e` naming `GATEWATCH_STORAGE_PATH` and the key it sets when the variable set the path
/// (`from_env`) of the SQLite store that `e` says cannot be opened, as `check-config` names it
/// ([`Config::check_store_location`]): `GATEWATCH_STORAGE_PATH (sets storage.path) /x/gw.db:
/// its directory /x does not exist ...`. Why: `serve` said `storage file /x/gw.db: ...`, and an
/// operator looked for the fault in the file's `storage.path`, which may say something else.
/// Any other error is returned as it is.
fn name_the_storage_variable(e: anyhow::Error, from_env: bool) -> anyhow::Error {
    match e.downcast_ref::<crate::store::StoreError>() {
        Some(crate::store::StoreError::Open { path, message })
            if from_env && !path.starts_with("NATS ") =>
        {
            anyhow::anyhow!("GATEWATCH_STORAGE_PATH (sets storage.path) {path}: {message}")
        }
        _ => e,
    }
}

/// The log format of a configuration that could not be read: JSON when `GATEWATCH_LOG_FORMAT`
/// says `json` (how a container's log is parsed is set there, not in a file), else text. Why:
/// with JSON logs the one line saying why the daemon did not start was the only line a log
/// shipper could not parse.
fn format_before_the_config() -> LogFormat {
    match std::env::var("GATEWATCH_LOG_FORMAT").as_deref() {
        Ok("json") => LogFormat::Json,
        _ => LogFormat::Text,
    }
}

/// A line `serve` writes to stderr itself, once the configuration is read: a warning of
/// [`Config::warnings`] (before the logs are set up) or the fatal error it exits with.
///
/// Text: `gatewatch: warning: ...` or `gatewatch: <error with its causes>`, as before. JSON: one
/// object in the shape of the JSON logs (timestamp, level, fields with `message` and `error`,
/// target), written here rather than through the log filter, so that a log shipper that parses
/// each line gets these too and a `log.level` or `RUST_LOG` that mutes this module cannot drop
/// the reason the daemon stopped. (A configuration that cannot be read is reported in
/// `GATEWATCH_LOG_FORMAT`'s format, [`format_before_the_config`].)
fn start_line(format: LogFormat, level: &str, message: &str, error: Option<&str>) {
    let line = match (format, error) {
        (LogFormat::Text, Some(e)) => format!("gatewatch: {e}"),
        (LogFormat::Text, None) => format!("gatewatch: warning: {message}"),
        (LogFormat::Json, _) => {
            let mut fields = serde_json::json!({ "message": message });
            if let Some(e) = error {
                fields["error"] = e.into();
            }
            serde_json::json!({
                "timestamp": humantime::format_rfc3339_micros(std::time::SystemTime::now())
                    .to_string(),
                "level": level,
                "fields": fields,
                "target": module_path!(),
            })
            .to_string()
        }
    };
    // a closed stderr must not turn the message into a panic
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// `gatewatch check-config FILE`: exit 0 when valid, 2 with a one-line message naming the key
/// (and its line when the file has it).
///
/// It runs exactly what `serve` runs before binding its listeners, [`load_config`]: the file,
/// the `GATEWATCH_*` environment overrides, every validation (the models are compiled, every
/// duration is bounded); and the checks of the store's location that `serve` makes when it
/// opens the store ([`crate::store::check_location`]: its directory exists and is writable). The systemd unit runs it as `ExecStartPre` with the same environment,
/// so a config it passes does not make `serve` fail at start-up.
pub fn check_config(args: CheckConfigArgs) -> ExitCode {
    match load_config(Some(&args.file)) {
        Ok(config) => {
            // The store's location, resolved as `serve` resolves it: `serve` does not create
            // a missing directory, it stops (exit 1), so a path it cannot open is refused here
            // (naming `GATEWATCH_STORAGE_PATH` when the variable set it, not the file).
            if let Err(e) =
                config.check_store_location(args.file.parent(), |k| std::env::var(k).ok())
            {
                errln!("{}", config_error_line(Some(&args.file), &e));
                return ExitCode::from(2);
            }
            for w in config.warnings() {
                errln!("{}: warning: {w}", args.file.display());
            }
            for w in super::config::unknown_env_warnings(
                std::env::vars_os().filter_map(|(k, _)| k.into_string().ok()),
            ) {
                errln!("gatewatch: warning: {w}");
            }
            // what `serve` will log at start with the same environment (the unit's ExecStartPre)
            if let Err(bad) = super::rust_log::read() {
                errln!(
                    "gatewatch: warning: RUST_LOG={:?} is invalid and ignored ({}); serve will use \
                     log.level = {:?}",
                    bad.value, bad.reason, config.log.level
                );
            }
            // `check-config FILE | head -1`: a closed stdout ends the output, not in a panic
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{}: ok", args.file.display());
            // How the models will run (docs/operations.md, "Machine code and
            // MemoryDenyWriteExecute"): the systemd unit runs this under the daemon's own
            // restrictions, so its log shows what `serve` will do.
            if let Ok(map) = super::worker::AnalyzerMap::from_config(&config) {
                let (compiled, interpreted) = map.compiled_counts();
                let _ = writeln!(
                    out,
                    "models: {compiled} compiled to machine code, {interpreted} interpreted"
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            errln!("{}", config_error_line(Some(&args.file), &e));
            ExitCode::from(2)
        }
    }
}

/// `gatewatch simulate`: streams a [`crate::simulate::GateSimulator`] (see
/// [`super::client::simulator`]).
pub fn simulate(args: SimulateArgs) -> ExitCode {
    let mut sim = match check_stream(&args).and_then(|()| simulator(&args)) {
        Ok(s) => s,
        Err(e) => {
            errln!("gatewatch simulate: {e:#}");
            return ExitCode::from(2);
        }
    };
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            errln!("gatewatch: {e}");
            return ExitCode::FAILURE;
        }
    };
    match rt.block_on(simulate_with_source(&args, |b: &mut [f64]| sim.fill(b))) {
        Ok(n) => {
            // the samples are sent: a closed stdout changes nothing (and must not panic)
            let _ = writeln!(std::io::stdout(), "sent {n} samples");
            ExitCode::SUCCESS
        }
        Err(e) => {
            errln!("gatewatch simulate: {e:#}");
            ExitCode::FAILURE
        }
    }
}
