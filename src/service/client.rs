//! The simulate client: streams a simulated gate to a running daemon over JSON, HTTP line
//! protocol or raw TCP, honouring `Retry-After`. It talks to the daemon only over the network,
//! never through its modules (as mini-redis keeps `clients/` apart from `server.rs`), so the
//! server side can change without it and it can run against any daemon.
//!
//! The crypto set-up sits here, next to the HTTP client that needs it.

use std::time::Duration;

use super::clock::now_unix;
use crate::number::Num;

/// Scenario of the simulated gate (see [`crate::simulate::ScenarioName`] and `docs/damping.md`,
/// "Scenarios").
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Scenario {
    /// Damping ratio +1 % throughout, shaken by turbulent forcing.
    Stable,
    /// +0.5 % throughout.
    StableLow,
    /// +2 % for 2 min, then linear to -2 % over 20 min, then -2 %.
    SlowDrift,
    /// +2 % for `--onset-hold` s, then a ramp to -2 % over `--onset-ramp` s, then -2 %.
    Onset,
    /// -2 % from the start, on the limit cycle from the first sample.
    LimitCycle,
    /// On the -2 % limit cycle for 2 min, back to +2 % in 60 s.
    Recovery,
    /// +2 % for 2 min, then a step to -2 %.
    Step,
    /// +1 % with a 15 s burst at -3 % every 90 s from 60 s on.
    Bursting,
    /// +1 % while the stiffness falls to 70 % over 10 min (a falling water level).
    WaterLevel,
    /// +1 % with spikes, dropouts, clipping and a DC offset on the sensor.
    SensorFaults,
    /// +1 %, struck about once a minute (debris, ice, a vessel).
    Impacts,
}

/// The simulated gate and its sensor (`gatewatch simulate`).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct GateSensorArgs {
    /// Gate preset: lab (19 kg, 10.4 Hz, 200 Hz), lock (2000 kg, 5 Hz, 100 Hz), barrier
    /// (500 kg, 2 Hz, 50 Hz), surge (10 000 kg, 1 Hz, 20 Hz: the daemon reads 40 s records of
    /// it once it knows its frequency, `window_cycles`). (`--gate` is the gate's id.)
    #[arg(long = "gate-preset", default_value = "lab", value_parser = crate::simulate::GatePreset::parse)]
    pub preset: crate::simulate::GatePreset,
    /// Sensor noise RMS in signal units (N), as a load cell's noise floor is given.
    #[arg(long, conflicts_with = "noise_rel", allow_negative_numbers = true)]
    pub noise_abs: Option<f64>,
    /// Sensor noise RMS as a fraction of the gate's ambient response std at +1 %.
    #[arg(long, allow_negative_numbers = true)]
    pub noise_rel: Option<f64>,
}

/// Protocol the simulator sends with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Protocol {
    /// `POST /api/v1/samples`.
    Json,
    /// `POST /api/v2/write` line protocol.
    Line,
    /// Raw TCP line protocol.
    Tcp,
}

/// `gatewatch simulate`.
#[derive(Debug, Clone, clap::Args)]
pub struct SimulateArgs {
    /// Base URL of the daemon.
    #[arg(long, default_value = "http://127.0.0.1:9464")]
    pub url: String,
    /// Address of the raw TCP listener (`--protocol tcp`).
    #[arg(long, default_value = "127.0.0.1:8094")]
    pub tcp_addr: String,
    /// Gate id.
    #[arg(long, default_value = "g1")]
    pub gate: String,
    /// Scenario.
    #[arg(long, value_enum, default_value = "stable")]
    pub scenario: Scenario,
    /// Replay speed (10: ten seconds of samples per second; 0 or less: as fast as possible).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub speed: f64,
    /// Seconds of sample time to send (default: the scenario's length, as `bench warning` runs
    /// it: 1380 s for slow-drift, 300 s for onset; 600 s for an onset shaped by `--onset-*`).
    #[arg(long, allow_negative_numbers = true)]
    pub duration: Option<f64>,
    /// Random seed.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub seed: u64,
    /// Protocol.
    #[arg(long, value_enum, default_value = "json")]
    pub protocol: Protocol,
    /// Sample rate, Hz (0: the preset's, 200 Hz for the lab gate).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub rate: f64,
    /// Bearer token.
    #[arg(long, env = "GATEWATCH_TOKEN")]
    pub token: Option<String>,
    /// Seconds of samples per request.
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    pub chunk_seconds: f64,
    /// Start time, Unix seconds (default: now, or for `--speed` above 1 so far back that the
    /// stream never runs ahead of the wall clock, its last sample timed when it is sent).
    #[arg(long, allow_negative_numbers = true)]
    pub start: Option<f64>,
    /// With --scenario onset only (refused with the others, whose timing is fixed): seconds of
    /// sample time at +2 % damping before the ramp. Without `--onset-hold` and `--onset-ramp`
    /// the onset is `bench warning`'s (120 s, then 60 s of ramp, after a warm-up); with either,
    /// the ramp starts at the first sample's `t = 0` from rest, and the one not given takes the
    /// bench's value.
    #[arg(long, allow_negative_numbers = true)]
    pub onset_hold: Option<f64>,
    /// With --scenario onset only (refused with the others): seconds of sample time of the
    /// ramp from +2 % to -2 % (then -2 %).
    #[arg(long, allow_negative_numbers = true)]
    pub onset_ramp: Option<f64>,
    /// The gate preset and its sensor noise.
    #[command(flatten)]
    pub sensor: GateSensorArgs,
}

/// Highest `--rate` of `gatewatch simulate`, Hz: a thousand times a fast gate's rate; `--rate 1e12`
/// asked for 6e14 samples and streamed for ever.
pub const SIMULATE_MAX_RATE_HZ: f64 = 1e6;

/// Longest stream of `gatewatch simulate`, seconds of sample time (a leap year): `--duration
/// 1e300` streamed for ever, from a start of -1e300.
pub const SIMULATE_MAX_DURATION: f64 = 366.0 * 86_400.0;
/// Most samples of one stream (`--rate` times `--duration`): a year of a gate at 300 Hz.
pub const SIMULATE_MAX_SAMPLES: f64 = 1e10;
/// Largest `--start`, Unix seconds (the year 2286); a start is never negative.
pub const SIMULATE_MAX_START: f64 = 1e10;
/// Largest `--noise-abs` (signal units) and `--noise-rel`: far past any sensor's noise floor,
/// far below the daemon's bound on a sample's size (1e100).
pub const SIMULATE_MAX_NOISE_ABS: f64 = 1e12;
/// See [`SIMULATE_MAX_NOISE_ABS`].
pub const SIMULATE_MAX_NOISE_REL: f64 = 1e6;
/// Longest wait for the daemon's answer to one request: it answers an ingest at once (or 503
/// when full); a daemon that accepts and never answers was waited on 30 s an attempt, three
/// minutes in all without a word.
pub const SIMULATE_REQUEST_TIMEOUT: Duration = Duration::from_secs(10);

/// Retries of one request answered 429/503 or failing to connect.
pub const SIMULATE_MAX_RETRIES: u32 = 5;
/// Longest `Retry-After` honoured, seconds.
pub const SIMULATE_MAX_RETRY_AFTER: u64 = 30;

/// The crate's one rustls set-up lives next to the notifier's HTTP client; the simulate client
/// builds a `reqwest::Client` too, so it calls the same function.
pub use crate::alert::notify::ensure_crypto_provider;

impl Scenario {
    /// The simulator's scenario of the three the library had first; `Onset` holds `+2 %` for
    /// `onset_hold` seconds, then ramps to `-2 %` over `onset_ramp` seconds. The others are
    /// named scenarios ([`Self::named`]); for them this gives the nearest of the three.
    pub fn to_simulation(self, onset_hold: f64, onset_ramp: f64) -> crate::simulate::Scenario {
        match self {
            Scenario::Onset => crate::simulate::Scenario::Onset {
                hold_s: onset_hold,
                ramp_s: onset_ramp,
            },
            Scenario::LimitCycle => crate::simulate::Scenario::LimitCycle,
            _ => crate::simulate::Scenario::Stable,
        }
    }

    /// The named scenario (`None` for `onset`, whose timing the `--onset-*` flags set).
    pub fn named(self) -> Option<crate::simulate::ScenarioName> {
        use crate::simulate::ScenarioName as N;
        Some(match self {
            Scenario::Stable => N::Stable,
            Scenario::StableLow => N::StableLow,
            Scenario::SlowDrift => N::SlowDrift,
            Scenario::Onset => return None,
            Scenario::LimitCycle => N::LimitCycle,
            Scenario::Recovery => N::Recovery,
            Scenario::Step => N::Step,
            Scenario::Bursting => N::Bursting,
            Scenario::WaterLevel => N::WaterLevel,
            Scenario::SensorFaults => N::SensorFaults,
            Scenario::Impacts => N::Impacts,
        })
    }
}

/// `bench warning`'s onset: seconds at +2 % before the ramp, and of the ramp.
const BENCH_ONSET: (f64, f64) = (120.0, 60.0);
/// Sample time an onset shaped by `--onset-*` streams without `--duration`, s.
const SHAPED_ONSET_SECONDS: f64 = 600.0;

impl SimulateArgs {
    /// The named scenario the simulator runs, `None` for an onset shaped by `--onset-*`.
    pub fn named_scenario(&self) -> Option<crate::simulate::ScenarioName> {
        match self.scenario {
            Scenario::Onset if self.onset_hold.is_none() && self.onset_ramp.is_none() => {
                Some(crate::simulate::ScenarioName::Onset)
            }
            s => s.named(),
        }
    }

    /// `--onset-hold` and `--onset-ramp`, each the bench's when not given.
    pub fn onset_shape(&self) -> (f64, f64) {
        (
            self.onset_hold.unwrap_or(BENCH_ONSET.0),
            self.onset_ramp.unwrap_or(BENCH_ONSET.1),
        )
    }

    /// Seconds of sample time to send: `--duration`, or the scenario's length.
    pub fn effective_duration(&self) -> f64 {
        self.duration
            .unwrap_or_else(|| match self.named_scenario() {
                Some(n) => n.def(&self.sensor.preset.params()).duration_s,
                None => SHAPED_ONSET_SECONDS,
            })
    }

    /// The sample rate: `--rate`, or the preset's when it is 0.
    pub fn effective_rate(&self) -> f64 {
        if self.rate == 0.0 {
            self.sensor.preset.params().rate_hz
        } else {
            self.rate
        }
    }
}

/// The simulated gate of `args`: the `--gate-preset` gate (default: the chapter's lab gate,
/// 19.14 kg, 81 360 N/m, 10.4 Hz, force output) sampled at `--rate`, whose damping follows
/// `--scenario`, with `--noise-abs`/`--noise-rel` sensor noise, seeded with `--seed`. Sample 0
/// is the scenario's `t = 0`: the named scenarios' warm-up is run and not sent.
pub fn simulator(args: &SimulateArgs) -> anyhow::Result<crate::simulate::GateSimulator> {
    // before the warm-up, which runs at this rate
    let rate = checked_rate(args)?;
    let (onset_hold, onset_ramp) = args.onset_shape();
    anyhow::ensure!(
        onset_hold >= 0.0 && onset_hold.is_finite(),
        "--onset-hold must be >= 0"
    );
    anyhow::ensure!(
        onset_ramp >= 0.0 && onset_ramp.is_finite(),
        "--onset-ramp must be >= 0"
    );
    for (flag, v, most) in [
        ("--noise-abs", args.sensor.noise_abs, SIMULATE_MAX_NOISE_ABS),
        ("--noise-rel", args.sensor.noise_rel, SIMULATE_MAX_NOISE_REL),
    ] {
        if let Some(v) = v {
            anyhow::ensure!(
                (0.0..=most).contains(&v),
                "{flag} must be >= 0 and at most {most:e}, got {}",
                Num(v)
            );
        }
    }
    let params = crate::simulate::GateParams {
        rate_hz: rate,
        ..args.sensor.preset.params()
    };
    let noise = match (args.sensor.noise_abs, args.sensor.noise_rel) {
        (Some(a), _) => crate::simulate::NoiseLevel::Absolute(a),
        (None, Some(r)) => crate::simulate::NoiseLevel::Relative(r),
        (None, None) => crate::simulate::NoiseLevel::Absolute(0.0),
    };
    match args.named_scenario() {
        Some(name) => {
            let mut sim = name
                .def(&params)
                .simulator(&params, noise, args.seed)
                .map_err(anyhow::Error::msg)?;
            while sim.time() < -0.5 / rate {
                sim.next_sample();
            }
            Ok(sim)
        }
        // an onset shaped by `--onset-*`: the library's first form (no warm-up), as before
        None => Ok(crate::simulate::GateSimulator::scenario(
            crate::simulate::GateParams {
                noise_std: noise.rms(&params),
                ..params
            },
            args.scenario.to_simulation(onset_hold, onset_ramp),
            args.seed,
        )),
    }
}

/// The sample rate of `args` (`--rate`, 0 for the preset's), refused naming `--rate` when it is
/// not positive and finite or above [`SIMULATE_MAX_RATE_HZ`].
fn checked_rate(args: &SimulateArgs) -> anyhow::Result<f64> {
    let rate = args.effective_rate();
    anyhow::ensure!(
        rate > 0.0 && rate.is_finite(),
        "--rate must be > 0 (or 0 for the preset's rate), got {}",
        Num(args.rate)
    );
    anyhow::ensure!(
        rate <= SIMULATE_MAX_RATE_HZ,
        "--rate must be at most {SIMULATE_MAX_RATE_HZ} Hz, got {}",
        Num(rate)
    );
    Ok(rate)
}

/// Checks the flags of the stream ([`simulate_with_source`], which runs it first); the error
/// names the flag. `gatewatch simulate` runs it before anything else, so that a bad flag is
/// refused as input (exit 2), not as a failure of the stream (exit 1).
pub fn check_stream(args: &SimulateArgs) -> anyhow::Result<()> {
    checked_rate(args)?;
    check_onset_flags(args)?;
    let duration = args.effective_duration();
    anyhow::ensure!(
        duration > 0.0 && duration <= SIMULATE_MAX_DURATION,
        "--duration must be > 0 and at most {} seconds (366 days), got {}",
        Num(SIMULATE_MAX_DURATION),
        Num(duration)
    );
    let samples = duration * args.effective_rate();
    anyhow::ensure!(
        samples <= SIMULATE_MAX_SAMPLES,
        "--duration times --rate must be at most {:e} samples, got {:e} ({} s at {} Hz)",
        SIMULATE_MAX_SAMPLES,
        samples,
        Num(duration),
        Num(args.effective_rate())
    );
    anyhow::ensure!(
        crate::service::config::valid_gate_id(&args.gate),
        "--gate '{}': {}",
        args.gate.escape_debug(),
        crate::service::config::GATE_ID_RULE
    );
    anyhow::ensure!(
        args.chunk_seconds > 0.0 && args.chunk_seconds.is_finite(),
        "--chunk-seconds must be > 0, got {}",
        Num(args.chunk_seconds)
    );
    anyhow::ensure!(
        !args.speed.is_nan(),
        "--speed must be a number (<= 0: as fast as possible), got {}",
        Num(args.speed)
    );
    // the stream paces itself on `Duration`s of wall time, which a tiny speed overflowed
    anyhow::ensure!(
        args.speed <= 0.0 || duration / args.speed <= SIMULATE_MAX_DURATION,
        "--speed {}: --duration {} s would take more than {} s (366 days) of wall time",
        Num(args.speed),
        Num(duration),
        Num(SIMULATE_MAX_DURATION)
    );
    anyhow::ensure!(
        args.start
            .is_none_or(|s| (0.0..=SIMULATE_MAX_START).contains(&s)),
        "--start must be Unix seconds from 0 to {:e} (the year 2286), got {}",
        SIMULATE_MAX_START,
        Num(args.start.unwrap_or(f64::NAN))
    );
    // The raw TCP protocol does not use the URL.
    if args.protocol != Protocol::Tcp {
        check_url(&args.url)?;
    } else {
        check_tcp_addr(&args.tcp_addr)?;
    }
    Ok(())
}

/// `--tcp-addr` as `host:port` (a name is resolved when the stream connects).
fn check_tcp_addr(addr: &str) -> anyhow::Result<()> {
    let port = addr.rsplit_once(':').and_then(|(host, port)| {
        let host = host.trim_start_matches('[').trim_end_matches(']');
        (!host.is_empty())
            .then(|| port.parse::<u16>().ok())
            .flatten()
    });
    anyhow::ensure!(
        port.is_some_and(|p| p > 0),
        "--tcp-addr '{}': expected host:port, e.g. 127.0.0.1:8094",
        addr.escape_debug()
    );
    Ok(())
}

/// Refuses `--onset-hold`/`--onset-ramp` with a scenario other than `onset`: the other
/// scenarios' timing is fixed ([`Scenario::to_simulation`] ignores the shape), and `--scenario
/// stable --onset-hold 10` streamed a stable gate without a word.
fn check_onset_flags(args: &SimulateArgs) -> anyhow::Result<()> {
    if args.scenario == Scenario::Onset {
        return Ok(());
    }
    for (flag, v) in [
        ("--onset-hold", args.onset_hold),
        ("--onset-ramp", args.onset_ramp),
    ] {
        if v.is_some() {
            let name = clap::ValueEnum::to_possible_value(&args.scenario).map_or_else(
                || format!("{:?}", args.scenario),
                |p| p.get_name().to_string(),
            );
            anyhow::bail!(
                "{flag} shapes the onset scenario's ramp: it needs --scenario onset (got {name}, whose timing is fixed)"
            );
        }
    }
    Ok(())
}

/// The stream's first sample time when `--start` is not given: now for a stream in real time
/// or slower; for a faster one, so far back that its last sample's time is the wall time at
/// which it is sent (`speed <= 0`, as fast as possible: the whole stream in the past). Why: a
/// stream that started now ran ahead of the daemon's clock at `speed` > 1 and was refused past
/// `max_future_seconds` (600 s by default) — the README's 1380 s slow drift at 20x stopped at
/// 600 s, before its zero crossing. Every sample time then lies between `now - duration` and
/// the wall time it is sent at.
fn default_start(now: f64, duration: f64, speed: f64) -> f64 {
    if speed > 0.0 {
        now - (duration - duration / speed).max(0.0)
    } else {
        now - duration
    }
}

/// A refused sample rate names what the daemon needs for this preset's gate: a gate the
/// daemon does not know takes its `[defaults]` (the lab gate's 200 Hz and stiffness), so the
/// README's lock-gate stream was refused at once with "sample rate 100 Hz disagrees with the
/// configured 200 Hz", which did not say what to configure.
fn preset_hint(e: anyhow::Error, args: &SimulateArgs, rate: f64) -> anyhow::Error {
    if !e.to_string().contains("\"field\":\"rate_hz\"") {
        return e;
    }
    let p = args.sensor.preset.params();
    anyhow::anyhow!(
        "{e}; the daemon's configuration needs a table for this gate ({} preset): \
         [gates.{}] with rate_hz = {rate} and stiffness = {:.1}",
        args.sensor.preset.as_str(),
        args.gate,
        p.stiffness
    )
}

/// `--url` is an absolute http(s) URL with a host: "notaurl" failed at the first request, as
/// "builder error: relative URL without a base", naming no flag.
fn check_url(url: &str) -> anyhow::Result<()> {
    let example = "e.g. http://127.0.0.1:9464";
    match reqwest::Url::parse(url) {
        Ok(u) if matches!(u.scheme(), "http" | "https") && u.host().is_some() => Ok(()),
        Ok(u) => anyhow::bail!(
            "--url: '{url}' is not an http(s) URL of the daemon (scheme '{}'); {example}",
            u.scheme()
        ),
        Err(e) => anyhow::bail!("--url: '{url}' is not a URL ({e}); {example}"),
    }
}

/// One line on stderr, for a retry the user would otherwise wait through without a word.
fn notice(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "gatewatch simulate: {line}");
}

/// A request's failure in words, the timeout named with its length.
fn request_error(e: &reqwest::Error) -> String {
    if e.is_timeout() {
        format!("no answer within {} s", SIMULATE_REQUEST_TIMEOUT.as_secs())
    } else {
        format!("{e:#}")
    }
}

async fn send_http(
    client: &reqwest::Client,
    url: &str,
    token: Option<&str>,
    content_type: &str,
    body: String,
) -> anyhow::Result<()> {
    let mut attempt = 0;
    loop {
        let mut req = client
            .post(url)
            .header("content-type", content_type)
            .body(body.clone());
        if let Some(t) = token {
            req = req.bearer_auth(t);
        }
        let wait = match req.send().await {
            Ok(r) if r.status().is_success() => return Ok(()),
            Ok(r) if r.status().as_u16() == 429 || r.status().as_u16() == 503 => {
                let secs = r
                    .headers()
                    .get("retry-after")
                    .and_then(|v| v.to_str().ok())
                    .and_then(|v| v.parse::<u64>().ok())
                    .unwrap_or(1)
                    .min(SIMULATE_MAX_RETRY_AFTER);
                Duration::from_secs(secs)
            }
            Ok(r) => {
                let status = r.status();
                let text = r.text().await.unwrap_or_default();
                anyhow::bail!("{url}: {status}: {text}");
            }
            Err(e) if attempt < SIMULATE_MAX_RETRIES => {
                // said where the user sees it: the command has no log (tracing showed nothing)
                notice(&format!(
                    "{url}: {}; retry {} of {SIMULATE_MAX_RETRIES} in 0.5 s",
                    request_error(&e),
                    attempt + 1
                ));
                Duration::from_millis(500)
            }
            Err(e) => {
                anyhow::bail!(
                    "{url}: {} (after {} attempts)",
                    request_error(&e),
                    attempt + 1
                )
            }
        };
        attempt += 1;
        if attempt > SIMULATE_MAX_RETRIES {
            anyhow::bail!("{url}: still overloaded after {SIMULATE_MAX_RETRIES} retries");
        }
        if wait >= Duration::from_secs(1) {
            notice(&format!(
                "{url}: the daemon is busy (429/503); retry {attempt} of {SIMULATE_MAX_RETRIES} in {} s",
                wait.as_secs()
            ));
        }
        tokio::time::sleep(wait).await;
    }
}

/// Streams [`SimulateArgs::effective_duration`] seconds of samples from `source` in chunks of `args.chunk_seconds`,
/// paced at real time / `args.speed` (`speed <= 0`: as fast as possible). Returns the number of
/// samples sent.
pub async fn simulate_with_source(
    args: &SimulateArgs,
    mut source: impl FnMut(&mut [f64]),
) -> anyhow::Result<u64> {
    check_stream(args)?;
    let rate = args.effective_rate();
    let duration = args.effective_duration();
    let start = args
        .start
        .unwrap_or_else(|| default_start(now_unix(), duration, args.speed));
    let total = (duration * rate).round() as u64;
    // never more than the whole stream in one buffer (--chunk-seconds 1e9 asked for 1.6 TB)
    let chunk = ((args.chunk_seconds * rate).round() as usize).clamp(1, total.max(1) as usize);
    ensure_crypto_provider();
    let client = reqwest::Client::builder()
        .timeout(SIMULATE_REQUEST_TIMEOUT)
        .build()?;
    let base = args.url.trim_end_matches('/');
    let mut tcp = if args.protocol == Protocol::Tcp {
        let connect = tokio::net::TcpStream::connect(&args.tcp_addr);
        match tokio::time::timeout(SIMULATE_REQUEST_TIMEOUT, connect).await {
            Ok(stream) => Some(stream.map_err(|e| anyhow::anyhow!("{}: {e}", args.tcp_addr))?),
            Err(_) => anyhow::bail!(
                "{}: no connection within {} s",
                args.tcp_addr,
                SIMULATE_REQUEST_TIMEOUT.as_secs()
            ),
        }
    } else {
        None
    };
    let began = tokio::time::Instant::now();
    let mut sent = 0u64;
    let mut buf = vec![0.0; chunk];
    while sent < total {
        let n = chunk.min((total - sent) as usize);
        source(&mut buf[..n]);
        let t0 = start + sent as f64 / rate;
        match args.protocol {
            Protocol::Json => {
                let body = serde_json::json!({
                    "gate": args.gate, "start": t0, "rate_hz": rate, "values": &buf[..n],
                });
                send_http(
                    &client,
                    &format!("{base}/api/v1/samples"),
                    args.token.as_deref(),
                    "application/json",
                    body.to_string(),
                )
                .await
                .map_err(|e| preset_hint(e, args, rate))?;
            }
            Protocol::Line | Protocol::Tcp => {
                let mut body = String::with_capacity(n * 48);
                for (i, v) in buf[..n].iter().enumerate() {
                    let ns = ((start + (sent + i as u64) as f64 / rate) * 1e9).round() as i64;
                    body.push_str(&format!("gate,gate={} force={v} {ns}\n", args.gate));
                }
                if let Some(s) = tcp.as_mut() {
                    tcp_write(s, &args.tcp_addr, body.as_bytes(), SIMULATE_REQUEST_TIMEOUT).await?;
                } else {
                    send_http(
                        &client,
                        &format!("{base}/api/v2/write?precision=ns"),
                        args.token.as_deref(),
                        "text/plain",
                        body,
                    )
                    .await?;
                }
            }
        }
        sent += n as u64;
        if args.speed > 0.0 {
            let due = Duration::from_secs_f64(sent as f64 / rate / args.speed);
            tokio::time::sleep_until(began + due).await;
        }
    }
    if let Some(mut s) = tcp {
        use tokio::io::AsyncWriteExt;
        match tokio::time::timeout(SIMULATE_REQUEST_TIMEOUT, s.shutdown()).await {
            Ok(r) => r.map_err(|e| anyhow::anyhow!("{}: {e}", args.tcp_addr))?,
            Err(_) => anyhow::bail!(
                "{}: the connection did not close within {} s",
                args.tcp_addr,
                SIMULATE_REQUEST_TIMEOUT.as_secs()
            ),
        }
    }
    Ok(sent)
}

/// Writes `bytes` to the raw TCP listener at `addr`, failing when the listener takes none of
/// them for `stall` (a daemon that stopped reading: stuck, or a port that accepts and never
/// reads): an error naming the address, where `simulate` used to wait for ever. A slow reader
/// that takes some bytes in every `stall` is not cut.
async fn tcp_write(
    s: &mut tokio::net::TcpStream,
    addr: &str,
    mut bytes: &[u8],
    stall: Duration,
) -> anyhow::Result<()> {
    use tokio::io::AsyncWriteExt;
    while !bytes.is_empty() {
        match tokio::time::timeout(stall, s.write(bytes)).await {
            Ok(Ok(0)) => anyhow::bail!("{addr}: the connection was closed"),
            Ok(Ok(n)) => bytes = &bytes[n..],
            Ok(Err(e)) => anyhow::bail!("{addr}: {e}"),
            Err(_) => anyhow::bail!(
                "{addr}: the listener took no byte for {} s (the daemon is not reading)",
                stall.as_secs_f64()
            ),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: SimulateArgs,
    }

    fn parse(flags: &[&str]) -> Result<SimulateArgs, clap::Error> {
        let argv = std::iter::once("simulate").chain(flags.iter().copied());
        Cli::try_parse_from(argv).map(|c| c.args)
    }

    /// A listener that accepts and never reads: the write fails after the stall, naming the
    /// address, instead of waiting for ever; a reader gets every byte.
    #[tokio::test]
    async fn a_tcp_write_to_a_listener_that_never_reads_fails_naming_it() {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let mut s = tokio::net::TcpStream::connect(&addr).await.unwrap();
        let (_held, _) = listener.accept().await.unwrap();
        // far more than the socket buffers of both ends hold
        let bytes = vec![b'x'; 64 << 20];
        let e = tcp_write(&mut s, &addr, &bytes, Duration::from_millis(300))
            .await
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!("{addr}: the listener took no byte for 0.3 s (the daemon is not reading)")
        );
        // a listener that reads gets it all
        let mut s = tokio::net::TcpStream::connect(&addr).await.unwrap();
        let (mut peer, _) = listener.accept().await.unwrap();
        let read = tokio::spawn(async move {
            let mut all = Vec::new();
            tokio::io::AsyncReadExt::read_to_end(&mut peer, &mut all)
                .await
                .unwrap();
            all.len()
        });
        tcp_write(&mut s, &addr, &bytes[..8 << 20], Duration::from_secs(10))
            .await
            .unwrap();
        drop(s);
        assert_eq!(read.await.unwrap(), 8 << 20);
    }

    #[test]
    fn scenario_preset_and_absolute_noise_flags_reach_the_simulator() {
        let args = parse(&[
            "--scenario",
            "slow-drift",
            "--gate-preset",
            "lock",
            "--noise-abs",
            "50",
        ])
        .unwrap();
        assert_eq!(args.sensor.preset, crate::simulate::GatePreset::Lock);
        // --rate defaults to the preset's
        assert!((args.effective_rate() - 100.0).abs() < 1e-12);
        let mut sim = simulator(&args).unwrap();
        // the warm-up is not sent: the first sample is the scenario's t = 0
        assert!(sim.time().abs() < 1e-9, "starts at {}", sim.time());
        assert!(sim.true_zeta(720.0).abs() < 1e-12);
        let mut sq = 0.0;
        let n = 20_000;
        for _ in 0..n {
            let v = sim.next_sample();
            sq += (v - sim.last_clean()).powi(2);
        }
        let rms = (sq / n as f64).sqrt();
        assert!((rms / 50.0 - 1.0).abs() < 0.03, "noise rms {rms}");
        // the lab gate stays the default, at 200 Hz
        let lab = parse(&["--scenario", "stable"]).unwrap();
        assert!((lab.effective_rate() - 200.0).abs() < 1e-12);
    }

    #[test]
    fn a_fast_stream_starts_in_the_past_and_never_runs_ahead() {
        let now = 1.0e9;
        // real time or slower: now
        assert_eq!(default_start(now, 1380.0, 1.0), now);
        assert_eq!(default_start(now, 1380.0, 0.5), now);
        // as fast as possible: the whole stream in the past
        assert_eq!(default_start(now, 1380.0, 0.0), now - 1380.0);
        // 20x: the last sample (start + 1380) is timed when it is sent (now + 69 s), and at
        // every wall second w before, the sample time start + 20 w is at most now + w
        let start = default_start(now, 1380.0, 20.0);
        assert!((start + 1380.0 - (now + 69.0)).abs() < 1e-6, "{start}");
        for w in [0.0, 10.0, 34.5, 69.0] {
            assert!(start + 20.0 * w <= now + w + 1e-6, "{w}");
        }
    }

    #[test]
    fn bad_scenario_flags_are_refused_naming_them() {
        assert!(parse(&["--gate-preset", "weir"])
            .unwrap_err()
            .to_string()
            .contains("weir"));
        assert!(parse(&["--scenario", "nope"]).is_err());
        assert!(parse(&["--noise-abs", "1", "--noise-rel", "0.1"]).is_err());
        let neg = parse(&["--noise-abs=-1"]).unwrap();
        let e = simulator(&neg).unwrap_err().to_string();
        assert!(e.contains("--noise-abs"), "{e}");
    }
}
