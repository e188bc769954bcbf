//! Tests of the configuration: parsing, validation naming the key, environment overrides.

use super::*;

#[test]
fn embedded_config_is_valid_and_has_the_defaults() {
    let c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    let d = Config::default();
    assert_eq!(c.server, d.server);
    assert_eq!(c.log, d.log);
    assert_eq!(c.ingest, d.ingest);
    assert_eq!(c.defaults, d.defaults);
    assert_eq!(c.notify, NotifyConfig::default());
    assert!(c.gates.is_empty());
}

#[test]
fn the_sample_lead_bound_is_the_largest_max_future_or_none_when_one_is_unbounded() {
    let lead = |text: &str| Config::from_toml(text).unwrap().sample_lead_bound();
    let secs = std::time::Duration::from_secs;
    assert_eq!(lead(""), Some(secs(600)));
    assert_eq!(
        lead("[gates.g1]\nmax_future_seconds = 900\n[gates.g2]\nmax_future_seconds = 5\n"),
        Some(secs(900))
    );
    assert_eq!(lead("[gates.g1]\nmax_future_seconds = 0\n"), None);
    assert_eq!(lead("[defaults]\nmax_future_seconds = 0\n"), None);
}

#[test]
fn notify_targets_parse_and_bad_urls_name_the_section() {
    let c = Config::from_toml(
        "[notify]\nalertmanager_urls = [\"http://am:9093\"]\n\
         [[notify.webhooks]]\nurl = \"http://127.0.0.1:5001/hook\"\n",
    )
    .unwrap();
    assert_eq!(c.notify.webhooks.len(), 1);
    assert_eq!(c.notify.webhooks[0].receiver, "gatewatch");
    assert_eq!(c.notify.alertmanager_urls, ["http://am:9093"]);
    assert!(err("[[notify.webhooks]]\nurl = \"ftp://x\"\n").starts_with("notify.webhooks[0].url: "));
    assert!(err("[notify]\nalertmanager_url = \"http://x\"\n").contains("alertmanager_url"));
    // a list of URLs where tables are expected: told what a target looks like
    let e = err("[notify]\nwebhooks = [\"http://127.0.0.1:5001/hook\"]\n");
    assert!(
        e.contains("webhooks") && e.contains("url = ") && !e.contains("WebhookTarget"),
        "{e}"
    );
}

#[test]
fn gates_merge_defaults_key_by_key() {
    let c = Config::from_toml(
        "[defaults]\nrate_hz = 100.0\n[defaults.alert]\nfire_below = -0.01\n\
         [gates.g1]\nwindow_seconds = 4.0\n[gates.g1.alert]\nfor_windows = 5\n",
    )
    .unwrap();
    let g = &c.gates["g1"];
    assert_eq!(g.rate_hz, 100.0);
    assert_eq!(g.window_seconds, 4.0);
    assert_eq!(g.alert.fire_below, -0.01);
    assert_eq!(g.alert.for_windows, 5);
    assert_eq!(c.gate("g1").unwrap().window_samples(), 400);
    assert_eq!(c.gate("other").unwrap(), &c.defaults);
}

fn err(text: &str) -> String {
    Config::from_toml(text).unwrap_err().message
}

/// `[notify]`'s errors name the key and its line, as every other table's do (they read
/// "notify: timeout_seconds must be ..." with no line, and a bad URL no key at all).
#[test]
fn notify_errors_name_the_key_and_its_line() {
    assert_eq!(
        err("[notify]\ntimeout_seconds = -1\n"),
        "notify.timeout_seconds: timeout_seconds must be a positive finite number, got -1, line 2"
    );
    let e = err("[notify]\nalertmanager_urls = [\"http://am:9093\", \"nope\"]\n");
    assert!(
        e.starts_with("notify.alertmanager_urls[1]: invalid alertmanager URL \"nope\""),
        "{e}"
    );
    assert!(e.ends_with(", line 2"), "{e}");
    let e = err(
        "[[notify.webhooks]]\nurl = \"http://a/\"\n\n[[notify.webhooks]]\nurl = \"not a url\"\n",
    );
    assert!(
        e.starts_with("notify.webhooks[1].url: invalid webhook URL \"not a url\""),
        "{e}"
    );
    assert!(e.ends_with(", line 5"), "{e}");
}

/// Every alert carries `external_url` as its `generatorURL`, and Alertmanager's API answers
/// 422 to an alert whose `generatorURL` is not a URI: a host name without a scheme lost every
/// notification. Empty (the default: no URL) stays allowed.
#[test]
fn the_external_url_is_a_url_or_empty() {
    for bad in ["gatewatch.example.org:9464", "not a url", "ftp://gw/"] {
        let e = err(&format!(
            "[server]\nmax_gates = 4\n\n[notify]\nexternal_url = {bad:?}\n"
        ));
        assert!(
            e.starts_with(&format!(
                "notify.external_url: invalid external URL {bad:?}"
            )),
            "{e}"
        );
        assert!(e.ends_with(", line 5"), "{e}");
    }
    for good in ["", "http://gw:9464", "https://gatewatch.example.org/"] {
        let c = Config::from_toml(&format!("[notify]\nexternal_url = {good:?}\n")).unwrap();
        assert_eq!(c.notify.external_url, good);
    }
}

/// A rule on two settings names the one the file writes, at its line, with both values: a
/// `rate_hz` too low was reported as `defaults.window_seconds`, a key the file did not have, at
/// the table's header; `fire_below` above the default `clear_above` as `alert.clear_above`.
#[test]
fn a_rule_on_two_settings_names_the_one_the_file_writes() {
    for (toml, expected) in [
        (
            "[defaults]\nrate_hz = 1e-300\n",
            "defaults.rate_hz: window_seconds * rate_hz must be >= 16 samples (10 s * 1e-300 Hz), line 2",
        ),
        (
            "[gates.g1]\nrate_hz = 1.0\n",
            "gates.g1.rate_hz: window_seconds * rate_hz must be >= 16 samples (10 s * 1 Hz), line 2",
        ),
        // the gate inherits the rate from [defaults]: that line is named
        (
            "[defaults]\n\nrate_hz = 1e9\n[gates.g1]\nstagger = true\n",
            "defaults.rate_hz: window_seconds * rate_hz must be <= 10000000 samples (10 s * 1000000000 Hz), line 3",
        ),
        // both written: the window is named, as before
        (
            "[defaults]\nrate_hz = 1.0\nwindow_seconds = 2.0\n",
            "defaults.window_seconds: window_seconds * rate_hz must be >= 16 samples (2 s * 1 Hz), line 3",
        ),
        (
            "[server]\nmax_gates = 4\n[defaults]\nrate_hz = 200.0\n[defaults.alert]\nfire_below = 0.1\n",
            "defaults.alert.fire_below: alert.clear_above (0.005) must be >= alert.fire_below (0.1), line 6",
        ),
        (
            "[defaults.alert]\nclear_above = -0.5\n",
            "defaults.alert.clear_above: alert.clear_above (-0.5) must be >= alert.fire_below (0), line 2",
        ),
    ] {
        assert_eq!(err(toml), expected, "{toml}");
    }
}

/// The trend spans at most its horizon and `MAX_TREND_POINTS` windows: a longer
/// `trend_min_span_seconds` was accepted and `GateDampingDeclining` could never fire.
#[test]
fn a_minimum_span_the_trend_cannot_reach_is_refused() {
    let e = err("[defaults.alert]\ntrend_min_span_seconds = 1e300\n");
    assert!(
        e.starts_with("defaults.alert.trend_min_span_seconds: alert.trend_min_span_seconds (1e300 s) is longer than the trend can span (600 s"),
        "{e}"
    );
    assert!(e.ends_with("could never fire, line 2"), "{e}");
    // a horizon shortened below the default minimum span is named on its own line
    let e = err("[defaults.alert]\n\ntrend_horizon_seconds = 120.0\n");
    assert!(
        e.starts_with("defaults.alert.trend_horizon_seconds: alert.trend_min_span_seconds (300 s) is longer than the trend can span (120 s"),
        "{e}"
    );
    assert!(e.ends_with(", line 3"), "{e}");
    // 1,023 windows of 0.125 s span 127.875 s, short of the default 300 s, whatever the horizon
    let e = err("[gates.g1]\nidentify_every_seconds = 0.125\n");
    assert!(
        e.starts_with("gates.g1.identify_every_seconds: alert.trend_min_span_seconds (300 s) is longer than the trend can span (127.875 s"),
        "{e}"
    );
    // and the limits themselves: the span equal to the reach passes
    let c = Config::from_toml(
        "[defaults.alert]\ntrend_horizon_seconds = 300.0\ntrend_min_span_seconds = 300.0\n",
    )
    .unwrap();
    assert_eq!(c.defaults.trend_reach_seconds(), 300.0);
    for key in ["trend_horizon_seconds", "warn_lead_seconds"] {
        let e = err(&format!("[defaults.alert]\n{key} = 1e300\n"));
        assert!(
            e.starts_with(&format!(
                "defaults.alert.{key}: must be > 0 and <= 31536000"
            )),
            "{e}"
        );
    }
}

#[test]
fn errors_name_the_key() {
    assert_eq!(
        err("[gates.g1]\nrate_hz = 0.0\n"),
        "gates.g1.rate_hz: must be > 0, line 2"
    );
    assert_eq!(
        err("[defaults]\nwindow_seconds = -1.0\n"),
        "defaults.window_seconds: must be > 0, line 2"
    );
    // fewer cycles than the ambient estimator reads at all would lengthen windows to no use
    for bad in ["8.0", "-1.0", "nan", "1e9"] {
        assert_eq!(
            err(&format!(
                "[gates.g1]\nrate_hz = 20.0\nwindow_cycles = {bad}\n"
            )),
            "gates.g1.window_cycles: must be 0 (off) or in 16..=100000, line 3",
            "{bad}"
        );
    }
    for good in ["0.0", "16.0", "50"] {
        let c = Config::from_toml(&format!("[defaults]\nwindow_cycles = {good}\n")).unwrap();
        assert_eq!(c.defaults.window_cycles, good.parse::<f64>().unwrap());
    }
    assert!(
        err("[gates.g1]\nrte_hz = 1.0\n").starts_with("gates.g1.rte_hz: unknown field `rte_hz`")
    );
    assert!(err("[server]\nlisten_addr = \"x\"\n").contains("unknown field `listen_addr`"));
    assert!(err("[bogus]\n").contains("unknown field `bogus`"));
    // an unknown top-level table names every table a file may have, `[defaults]` and
    // `[gates.*]` too (serde's list left out the two read apart), with its line
    let every =
        "expected one of `server`, `log`, `ingest`, `notify`, `storage`, `defaults`, `gates`";
    assert_eq!(
        err("[defualts]\nrate_hz = 100.0\n"),
        format!("defualts: unknown field `defualts`, {every}, line 1")
    );
    assert_eq!(
        err("# gates\n[gate.g1]\nrate_hz = 100.0\n"),
        format!("gate: unknown field `gate`, {every}, line 2")
    );
    assert_eq!(
        err("bogus = 1\n"),
        format!("bogus: unknown field `bogus`, {every}, line 1")
    );
    assert!(err("[gates.g1.alert]\nfor_windows = 0\n").starts_with("gates.g1.alert.for_windows"));
    assert!(err("[gates.g1.alert]\nsevrity = \"x\"\n").contains("sevrity"));
    // the interval and trend rules name their key
    for (toml, key) in [
        ("fire_probability = 1.0", "gates.g1.alert.fire_probability"),
        (
            "fire_at_once_probability = 0.5",
            "gates.g1.alert.fire_at_once_probability",
        ),
        (
            "fire_at_once_probability = 1.5",
            "gates.g1.alert.fire_at_once_probability",
        ),
        (
            "fire_at_once_min_ratio = 0.5",
            "gates.g1.alert.fire_at_once_min_ratio",
        ),
        (
            "resolve_probability = 1.0",
            "gates.g1.alert.resolve_probability",
        ),
        (
            "resolve_probability = 0.5",
            "gates.g1.alert.resolve_probability",
        ),
        (
            "warn_lead_seconds = 0.0",
            "gates.g1.alert.warn_lead_seconds",
        ),
        (
            "trend_horizon_seconds = -1.0",
            "gates.g1.alert.trend_horizon_seconds",
        ),
        ("warn_for_windows = 0", "gates.g1.alert.warn_for_windows"),
        ("warn_severity = \"\"", "gates.g1.alert.warn_severity"),
        ("severity = \" \"", "gates.g1.alert.severity"),
    ] {
        assert!(
            err(&format!("[gates.g1.alert]\n{toml}\n")).starts_with(key),
            "{toml}"
        );
    }
    // `k` is the stiffness in the equation: a second, different value is refused, the same
    // value passes
    let e = err("[gates.g1]\nstiffness = 81360.0\nparams = { k = 5.0 }\n");
    assert!(
        e.starts_with("gates.g1.params.k: 5 conflicts with stiffness = 81360"),
        "{e}"
    );
    Config::from_toml("[gates.g1]\nstiffness = 81360.0\nparams = { k = 81360.0 }\n").unwrap();
    assert!(err("[server]\nlisten = \"nope\"\n").starts_with("server.listen:"));
    for (http, tcp) in [
        ("127.0.0.1:19477", "127.0.0.1:19477"),
        ("0.0.0.0:9464", "127.0.0.1:9464"),
        ("127.0.0.1:9464", "[::]:9464"),
    ] {
        let e = err(&format!(
            "[server]\nlisten = \"{http}\"\ntcp_listen = \"{tcp}\"\n"
        ));
        assert!(
            e.starts_with("server.tcp_listen:") && e.contains("takes the port"),
            "{e}"
        );
    }
    Config::from_toml("[server]\nlisten = \"127.0.0.1:0\"\ntcp_listen = \"127.0.0.1:0\"\n")
        .unwrap();
    // the health listener: an address or nothing, on a port of its own
    let e = err("[server]\nhealth_listen = \"9465\"\n");
    assert!(
        e.starts_with("server.health_listen: must be empty or an address"),
        "{e}"
    );
    for (other_key, other, health) in [
        ("listen", "0.0.0.0:9464", "127.0.0.1:9464"),
        ("tcp_listen", "127.0.0.1:8094", "0.0.0.0:8094"),
    ] {
        let e = err(&format!(
            "[server]\n{other_key} = \"{other}\"\nhealth_listen = \"{health}\"\n"
        ));
        assert!(
            e.starts_with("server.health_listen:")
                && e.contains(&format!("takes the port of server.{other_key} ({other})")),
            "{e}"
        );
    }
    let c = Config::from_toml(
        "[server]\nlisten = \"0.0.0.0:9464\"\ntcp_listen = \"0.0.0.0:8094\"\nhealth_listen = \"0.0.0.0:9465\"\n",
    )
    .unwrap();
    assert_eq!(c.server.health_listen, "0.0.0.0:9465");
    assert_eq!(Config::default().server.health_listen, "", "off by default");
    Config::from_toml("[server]\nlisten = \"127.0.0.1:9464\"\ntcp_listen = \"127.0.0.2:9464\"\n")
        .unwrap();
    let e = err("[server]\nworker_threads = 100000\n");
    assert!(
        e.starts_with("server.worker_threads: must be at most 256"),
        "{e}"
    );
    assert!(err("[server]\nmax_gates = 0\n").starts_with("server.max_gates:"));
    // each TCP connection buffers one line: 99999999999 accepted defeated the memory bound
    for bytes in ["63", "1048577", "99999999999"] {
        let e = err(&format!("[ingest]\ntcp_max_line_bytes = {bytes}\n"));
        assert!(
            e.starts_with("ingest.tcp_max_line_bytes: must be from 64 to 1048576"),
            "{e}"
        );
    }
    Config::from_toml("[ingest]\ntcp_max_line_bytes = 1048576\n").unwrap();
    assert!(err("[server]\nauth_tokens = [\"short\"]\n").starts_with("server.auth_tokens:"));
    assert!(
        err("[defaults]\nsignal = \"pressure\"\n").starts_with("defaults.signal: unknown variant")
    );
    assert!(err("[gates.g1]\nmodel_interval = \"bootstrap\"\n")
        .starts_with("gates.g1.model_interval: unknown variant `bootstrap`"));
    assert!(err("[gates.g1]\nforce_terms = \"damping\"\n")
        .starts_with("gates.g1.force_terms: unknown variant `damping`"));
    assert!(err("[gates.\"bad id!\"]\n").starts_with("gates.bad id!:"));
    let e = err("[server\n"); // a TOML syntax error is named by its line
    assert!(e.contains("line 1"), "{e}");
    assert!(!err("[gates.g1]\nrate_hz = 0.0\n").contains('\n'));
}

#[test]
fn environment_overrides() {
    let mut c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    let env = |k: &str| match k {
        "GATEWATCH_LISTEN" => Some("127.0.0.1:1234".to_string()),
        "GATEWATCH_TCP_LISTEN" => Some("127.0.0.1:8094".to_string()),
        "GATEWATCH_HEALTH_LISTEN" => Some("0.0.0.0:9465".to_string()),
        "GATEWATCH_AUTH_TOKENS" => Some("aaaaaaaaaaaaaaaa, bbbbbbbbbbbbbbbb".to_string()),
        "GATEWATCH_LOG_FORMAT" => Some("json".to_string()),
        "GATEWATCH_WORKER_THREADS" => Some("3".to_string()),
        "GATEWATCH_ACCEPT_UNKNOWN_GATES" => Some("false".to_string()),
        _ => None,
    };
    c.apply_env(env).unwrap();
    assert_eq!(c.server.listen, "127.0.0.1:1234");
    assert_eq!(c.server.tcp_listen, "127.0.0.1:8094");
    assert_eq!(c.server.health_listen, "0.0.0.0:9465");
    assert_eq!(c.server.auth_tokens.len(), 2);
    assert_eq!(c.log.format, LogFormat::Json);
    assert_eq!(c.server.effective_worker_threads(), 3);
    assert!(!c.server.accept_unknown_gates);
    let e = c
        .apply_env(|k| (k == "GATEWATCH_LOG_FORMAT").then(|| "xml".to_string()))
        .unwrap_err();
    assert!(e.message.starts_with("GATEWATCH_LOG_FORMAT"));
}

/// `log.level` is checked with `EnvFilter`'s own parser, and a bare word that is not a level
/// is refused: `EnvFilter` reads `debugg` as a target name, and every log went silent while
/// `check-config` said ok.
#[test]
fn an_invalid_log_level_is_refused_naming_the_key_line_and_the_levels() {
    let e = err("[server]\nmax_gates = 8\n[log]\nlevel = \"debugg\"\n");
    assert!(e.starts_with("log.level: `debugg` is not a level"), "{e}");
    assert!(e.ends_with(", line 4"), "{e}");
    for level in [
        "off",
        "error",
        "warn",
        "info",
        "debug",
        "trace",
        "target=level",
    ] {
        assert!(e.contains(level), "{level}: {e}");
    }
    // a directive's level is parsed by EnvFilter itself
    let e = err("[log]\nlevel = \"info,gatewatch=verbose\"\n");
    assert!(
        e.starts_with("log.level: `info,gatewatch=verbose`: "),
        "{e}"
    );
    assert!(e.ends_with(", line 2"), "{e}");
    assert!(err("[log]\nlevel = \"\"\n").starts_with("log.level: must not be empty"));
    for ok in [
        "info",
        "WARN",
        "debug,cranelift_jit=warn",
        "gatewatch::service=debug",
        "0",
    ] {
        let c = Config::from_toml(&format!("[log]\nlevel = \"{ok}\"\n"));
        assert!(c.is_ok(), "{ok}: {c:?}");
    }
    let mut c = Config::default();
    let e = c
        .apply_env(|k| (k == "GATEWATCH_LOG_LEVEL").then(|| "inf".to_string()))
        .unwrap_err();
    assert!(
        e.message
            .starts_with("GATEWATCH_LOG_LEVEL: `inf` is not a level"),
        "{e}"
    );
    assert_eq!(c.log.level, "info");
}

/// `GATEWATCH_TCP_ALLOWED_NETWORKS` sets the allow-list (comma-separated, validated), and a
/// TCP listener beyond loopback with a loopback-only list warns: the Dockerfile's own example
/// (`GATEWATCH_TCP_LISTEN=0.0.0.0:8094` alone) refused every client through the published port.
#[test]
fn tcp_allowed_networks_from_the_environment_and_the_loopback_only_warning() {
    let warned = |c: &Config| {
        c.warnings()
            .iter()
            .any(|w| w.contains("tcp_allowed_networks"))
    };
    let mut c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    assert!(
        !warned(&c),
        "the embedded config listens on loopback or not at all"
    );
    c.apply_env(|k| (k == "GATEWATCH_TCP_LISTEN").then(|| "0.0.0.0:8094".to_string()))
        .unwrap();
    assert!(warned(&c), "{:?}", c.warnings());
    c.apply_env(|k| {
        (k == "GATEWATCH_TCP_ALLOWED_NETWORKS").then(|| " 10.20.0.0/16, 172.17.0.1,".to_string())
    })
    .unwrap();
    assert_eq!(
        c.server.tcp_allowed_networks,
        ["10.20.0.0/16", "172.17.0.1"]
    );
    assert!(!warned(&c), "{:?}", c.warnings());
    let e = c
        .apply_env(|k| (k == "GATEWATCH_TCP_ALLOWED_NETWORKS").then(|| "10.0.0/8".to_string()))
        .unwrap_err();
    assert!(
        e.message
            .starts_with("GATEWATCH_TCP_ALLOWED_NETWORKS (sets server.tcp_allowed_networks): "),
        "{}",
        e.message
    );
    // a listener on loopback needs no warning, whatever the list
    let mut c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    c.apply_env(|k| (k == "GATEWATCH_TCP_LISTEN").then(|| "127.0.0.1:8094".to_string()))
        .unwrap();
    assert!(!warned(&c));
}

/// `GATEWATCH_TCP_ALLOWED_NETWORKS` set to no network (empty, blanks, commas) is refused naming
/// the variable, and the file's list stays: it replaced the list with none, every TCP client
/// was refused at accept, and `check-config` said ok.
#[test]
fn tcp_allowed_networks_from_the_environment_that_hold_no_network_are_refused() {
    let file =
        "[server]\ntcp_listen = \"127.0.0.1:8094\"\ntcp_allowed_networks = [\"10.0.0.0/8\"]\n";
    for bad in ["", " ", ",", " , ,", "\t"] {
        let mut c = Config::from_toml(file).unwrap();
        let e = c
            .apply_env(|k| (k == "GATEWATCH_TCP_ALLOWED_NETWORKS").then(|| bad.to_string()))
            .unwrap_err();
        assert!(
            e.message.starts_with(&format!(
                "GATEWATCH_TCP_ALLOWED_NETWORKS (sets server.tcp_allowed_networks): {bad:?} \
                 holds no network"
            )),
            "{bad:?}: {}",
            e.message
        );
        assert!(e.message.contains("unset the variable"), "{}", e.message);
        assert!(e.names_file(), "{bad:?}: blamed on the file");
        assert!(!e.message.contains('\n'), "{}", e.message);
        assert_eq!(c.server.tcp_allowed_networks, ["10.0.0.0/8"], "{bad:?}");
    }
    // refused also with the listener off: an empty variable is a deployment's mistake
    let mut c = Config::default();
    let e = c
        .apply_env(|k| (k == "GATEWATCH_TCP_ALLOWED_NETWORKS").then(String::new))
        .unwrap_err();
    assert!(e.message.contains("holds no network"), "{}", e.message);
}

/// An empty `tcp_allowed_networks` in the file is refused while the raw TCP listener is on
/// (from the file or `GATEWATCH_TCP_LISTEN`): it let no client in, silently. With the listener
/// off the list is unused and accepted.
#[test]
fn an_empty_tcp_allow_list_in_the_file_is_refused_when_the_listener_is_on() {
    let e = err("[server]\ntcp_listen = \"127.0.0.1:8094\"\ntcp_allowed_networks = []\n");
    assert!(
        e.starts_with(
            "server.tcp_allowed_networks: empty, so the raw TCP listener (server.tcp_listen = \
             \"127.0.0.1:8094\") would refuse every client"
        ),
        "{e}"
    );
    assert!(e.contains("tcp_listen = \"\""), "{e}");
    assert!(e.ends_with(", line 3"), "{e}");
    let off = "[server]\ntcp_allowed_networks = []\n";
    let mut c = Config::from_toml(off).unwrap();
    let e = c
        .apply_env(|k| (k == "GATEWATCH_TCP_LISTEN").then(|| "0.0.0.0:8094".to_string()))
        .unwrap_err();
    assert!(
        e.message
            .starts_with("server.tcp_allowed_networks: empty, so the raw TCP listener"),
        "{}",
        e.message
    );
    assert!(!e.names_file(), "the empty list is the file's");
}

#[test]
fn worker_threads_default_is_at_least_one() {
    assert!(ServerConfig::default().effective_worker_threads() >= 1);
}

#[test]
fn the_four_toml_errors_name_key_and_line() {
    // syntax error: the line and its text
    let e = err("[server]\nlisten = \"127.0.0.1:1\"\n[ingest\n");
    assert!(e.starts_with("line 3: "), "{e}");
    assert!(e.contains("[ingest"), "{e}");
    // duplicate key
    assert_eq!(
        err("[server]\nmax_gates = 3\nmax_gates = 4\n"),
        "server.max_gates: duplicate key, line 3"
    );
    // ... by its full path, in a nested table, after a multi-line array whose lines start with
    // `[`, and at the top level
    assert_eq!(
        err("[defaults.alert]\nfor_windows = 2\n[gates.g1.alert]\nfor_windows = 2\nfor_windows = 3\n"),
        "gates.g1.alert.for_windows: duplicate key, line 5"
    );
    assert_eq!(
        err("[server]\ntcp_allowed_networks = [\n\"10.0.0.0/8\",\n]\nlisten = \"a\"\nlisten = \"b\"\n"),
        "server.listen: duplicate key, line 6"
    );
    assert_eq!(
        err("[[notify.webhooks]]\nurl = \"http://a\"\nurl = \"http://b\"\n"),
        "notify.webhooks.url: duplicate key, line 3"
    );
    // a top-level table given a value
    assert_eq!(err("\ngates = 5\n"), "gates: must be a table, line 2");
    assert_eq!(
        err("defaults = \"x\"\n"),
        "defaults: must be a table, line 1"
    );
    // wrong type under [defaults], directly and in a nested table
    let e = err("[defaults]\nsignal = \"force\"\nrate_hz = \"fast\"\n");
    assert!(e.starts_with("defaults.rate_hz: invalid type"), "{e}");
    assert!(e.ends_with(", line 3"), "{e}");
    let e = err("[defaults.alert]\nfor_windows = \"x\"\n");
    assert!(e.starts_with("defaults.alert.for_windows: "), "{e}");
    assert!(e.ends_with(", line 2"), "{e}");
    // a gate's bad value inherited from [defaults] is found there
    let e = err("[defaults]\n\nrate_hz = \"fast\"\n[gates.g1]\nwindow_seconds = 4.0\n");
    assert!(e.contains("rate_hz") && e.ends_with(", line 3"), "{e}");
    // tcp_precision
    let e = err("[ingest]\ngate_tag = \"gate\"\ntcp_precision = \"xs\"\n");
    assert!(
        e.starts_with("ingest.tcp_precision: unknown variant `xs`"),
        "{e}"
    );
    assert!(e.ends_with(", line 3"), "{e}");
}

#[test]
fn models_are_compiled_as_serve_compiles_them() {
    for bad in [
        "c1*ydd + ((c2*yd",
        "ydd^2 + c1*y = 0",
        "c1*ydd + c2*yd + q*y = 0",
        "c1*yd + c2*y = 0",
    ] {
        let e = err(&format!("[defaults]\nmodel = \"{bad}\"\n"));
        assert!(e.starts_with("defaults.model: "), "{bad}: {e}");
        assert!(e.ends_with(", line 2"), "{bad}: {e}");
        let e = err(&format!("[gates.g1]\nmodel = \"{bad}\"\n"));
        assert!(e.starts_with("gates.g1.model: "), "{bad}: {e}");
    }
}

#[test]
fn durations_are_bounded_not_panicking() {
    for (text, key) in [
        (
            "[server]\nrequest_timeout_seconds = 1e300\n",
            "server.request_timeout_seconds",
        ),
        (
            "[server]\nshutdown_grace_seconds = 1e300\n",
            "server.shutdown_grace_seconds",
        ),
        (
            "[server]\nshutdown_grace_seconds = inf\n",
            "server.shutdown_grace_seconds",
        ),
        ("[notify]\ntimeout_seconds = 1e300\n", "notify"),
        (
            "[notify]\nresend_interval_seconds = 1e300\n",
            "notify.resend_interval_seconds",
        ),
        (
            "[defaults.alert]\nstale_after_seconds = 1e300\n",
            "defaults.alert.stale_after_seconds",
        ),
        (
            "[defaults]\nidentify_every_seconds = 1e300\n",
            "defaults.identify_every_seconds",
        ),
        (
            "[defaults]\nmax_future_seconds = -1\n",
            "defaults.max_future_seconds",
        ),
        (
            "[defaults]\nmax_past_seconds = 1e300\n",
            "defaults.max_past_seconds",
        ),
        (
            "[server]\nidentification_timeout_seconds = 1e300\n",
            "server.identification_timeout_seconds: must be > 0",
        ),
        (
            "[server]\nidentification_timeout_seconds = 0\n",
            "server.identification_timeout_seconds: must be > 0",
        ),
        (
            "[server]\nidentification_timeout_seconds = nan\n",
            "server.identification_timeout_seconds: must be > 0",
        ),
    ] {
        let e = err(text);
        assert!(e.starts_with(key), "{text}: {e}");
    }
    // the bound itself is accepted
    Config::from_toml(&format!(
        "[server]\nrequest_timeout_seconds = {MAX_SECONDS}\n"
    ))
    .unwrap();
    let c = Config::from_toml(&format!(
        "[server]\nidentification_timeout_seconds = {MAX_SECONDS}\n"
    ))
    .unwrap();
    assert_eq!(c.server.identification_timeout().as_secs_f64(), MAX_SECONDS);
    assert_eq!(
        Config::from_toml("")
            .unwrap()
            .server
            .identification_timeout()
            .as_secs_f64(),
        DEFAULT_IDENTIFICATION_TIMEOUT_SECONDS
    );
}

#[test]
fn model_interval_defaults_to_newey_west_and_reads_forcing() {
    use crate::analysis::ModelInterval;
    let config = Config::embedded();
    assert_eq!(config.defaults.model_interval, ModelInterval::NeweyWest);
    let text = "[defaults]\nmodel_interval = \"forcing\"\n[gates.g1]\nrate_hz = 100.0\n";
    let config = Config::from_toml(text).expect("valid");
    let g1 = config.gate("g1").expect("gate g1");
    assert_eq!(
        g1.analysis_settings().model_interval,
        ModelInterval::Forcing
    );
}

#[test]
fn ssi_reference_defaults_to_lagged_and_reads_common_per_gate() {
    use crate::analysis::SsiReference;
    assert_eq!(
        Config::embedded().defaults.ssi_reference,
        SsiReference::Lagged
    );
    let text = "[gates.g1]\nssi_reference = \"common\"\n[gates.g2]\n";
    let config = Config::from_toml(text).expect("valid");
    let setting = |id: &str| {
        config
            .gate(id)
            .expect("gate")
            .analysis_settings()
            .ssi_reference
    };
    assert_eq!(setting("g1"), SsiReference::Common);
    assert_eq!(setting("g2"), SsiReference::Lagged);
    assert!(err("[defaults]\nssi_reference = \"forward\"\n")
        .starts_with("defaults.ssi_reference: unknown variant `forward`"));
}

#[test]
fn force_terms_default_to_all_and_read_stiffness_per_gate() {
    use crate::analysis::ForceTerms;
    assert_eq!(Config::embedded().defaults.force_terms, ForceTerms::All);
    let text = "[gates.g1]\nforce_terms = \"stiffness\"\n[gates.g2]\n";
    let config = Config::from_toml(text).expect("valid");
    let settings = |g: &str| config.gate(g).expect("gate").analysis_settings();
    assert_eq!(settings("g1").force_terms, ForceTerms::Stiffness);
    assert_eq!(settings("g2").force_terms, ForceTerms::All);
}

/// Every option of `Config::default()` is shown in `config/gatewatch.toml` (set or commented
/// out, `# key = value`) under its section: the file says "every option is shown with its
/// default", and the comparison of the parsed file with the defaults above cannot see a key
/// that is missing from the file (serde fills it in). Options without a default value
/// (`Option` fields, absent by default) are not demanded, nor `[notify]`'s, which has no
/// serialized form (it holds tokens) and whose options the file lists in comments.
#[test]
fn the_shipped_file_shows_every_option() {
    fn paths(prefix: &str, v: &toml::Value, out: &mut Vec<String>) {
        if let toml::Value::Table(t) = v {
            for (k, v) in t {
                let path = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match v {
                    toml::Value::Table(_) => paths(&path, v, out),
                    _ => out.push(path),
                }
            }
        }
    }
    let mut wanted = Vec::new();
    paths(
        "",
        &toml::Value::try_from(Config::default()).unwrap(),
        &mut wanted,
    );
    // `defaults` is resolved into each gate and not serialized with the rest
    paths(
        "defaults",
        &toml::Value::try_from(GateConfig::default()).unwrap(),
        &mut wanted,
    );
    assert!(
        wanted
            .iter()
            .any(|p| p == "defaults.alert.warn_lead_seconds")
            && wanted.iter().any(|p| p == "defaults.pooling.min_cycles"),
        "{wanted:?}"
    );
    let mut shown = std::collections::BTreeSet::new();
    let mut section = String::new();
    for line in EMBEDDED_CONFIG.lines() {
        let l = line.trim_start_matches('#').trim();
        if let Some(h) = l.strip_prefix("[[").and_then(|h| h.strip_suffix("]]")) {
            shown.insert(h.to_string());
            section = h.to_string();
        } else if let Some(h) = l.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
            if !h.contains(' ') && !h.contains('"') {
                section = h.to_string();
            }
        } else if let Some((k, _)) = l.split_once(" = ") {
            if !k.contains(' ') {
                shown.insert(format!("{section}.{k}").trim_start_matches('.').to_string());
            }
        }
    }
    let missing: Vec<&String> = wanted.iter().filter(|p| !shown.contains(*p)).collect();
    assert!(
        missing.is_empty(),
        "options not shown in config/gatewatch.toml: {missing:?}"
    );
}

#[test]
fn the_storage_backend_and_its_nats_keys_are_checked_naming_the_key() {
    let c = Config::from_toml(
        "[storage]\nbackend = \"nats\"\nnats_url = \"nats://10.0.0.5:4222\"\nnats_prefix = \"SITE_2\"\n",
    )
    .unwrap();
    assert_eq!(c.storage.backend, crate::store::StorageBackend::Nats);
    assert_eq!(c.storage.nats_url, "nats://10.0.0.5:4222");
    assert_eq!(
        Config::default().storage.backend,
        crate::store::StorageBackend::Sqlite
    );
    assert!(err("[storage]\nbackend = \"redis\"\n").starts_with("storage.backend"));
    assert!(err("[storage]\nnats_prefix = \"a.b\"\n").starts_with("storage.nats_prefix"));
    assert!(err("[storage]\nnats_prefix = \"\"\n").starts_with("storage.nats_prefix"));
    assert!(err("[storage]\nnats_url = \"\"\n").starts_with("storage.nats_url"));
    assert_eq!(
        Config::default().storage.nats_lease(),
        crate::store::NATS_LEASE_TTL
    );
    let c = Config::from_toml("[storage]\nnats_lease_seconds = 2.5\n").unwrap();
    assert_eq!(
        c.storage.nats_lease(),
        std::time::Duration::from_millis(2500)
    );
    for bad in ["0.5", "0.0", "-3.0", "nan"] {
        assert!(
            err(&format!("[storage]\nnats_lease_seconds = {bad}\n"))
                .starts_with("storage.nats_lease_seconds"),
            "{bad}"
        );
    }
}

#[test]
fn refusing_unknown_gates_without_any_configured_gate_is_warned() {
    let warned = |c: &Config| {
        c.warnings()
            .iter()
            .any(|w| w.contains("every sample is refused"))
    };
    let c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    assert!(!warned(&c), "{:?}", c.warnings());
    let c = Config::from_toml("[server]\naccept_unknown_gates = false\n").unwrap();
    assert!(warned(&c), "{:?}", c.warnings());
    let c = Config::from_toml("[server]\naccept_unknown_gates = false\n[gates.g1]\n").unwrap();
    assert!(!warned(&c), "{:?}", c.warnings());
}

/// `GATEWATCH_STORAGE_BACKEND`, `GATEWATCH_NATS_URL`, `GATEWATCH_NATS_PREFIX` and
/// `GATEWATCH_NATS_LEASE_SECONDS` set the store without a configuration file (a Kubernetes pod on NATS); a bad value is refused naming the
/// variable (and for the backend the values it takes), and leaves the setting as it was.
#[test]
fn the_storage_backend_and_the_nats_server_from_the_environment() {
    let mut c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    assert_eq!(c.storage.backend, crate::store::StorageBackend::Sqlite);
    let env = |k: &str| match k {
        "GATEWATCH_STORAGE_BACKEND" => Some("nats".to_string()),
        "GATEWATCH_NATS_URL" => Some("nats://nats.monitoring.svc:4222".to_string()),
        "GATEWATCH_NATS_PREFIX" => Some("DAM_7".to_string()),
        _ => None,
    };
    c.apply_env(env).unwrap();
    assert_eq!(c.storage.backend, crate::store::StorageBackend::Nats);
    assert_eq!(c.storage.nats_url, "nats://nats.monitoring.svc:4222");
    assert_eq!(c.storage.nats_prefix, "DAM_7");
    // and back
    c.apply_env(|k| (k == "GATEWATCH_STORAGE_BACKEND").then(|| "sqlite".to_string()))
        .unwrap();
    assert_eq!(c.storage.backend, crate::store::StorageBackend::Sqlite);

    for bad in ["NATS", "jetstream", "", " nats"] {
        let e = c
            .apply_env(|k| (k == "GATEWATCH_STORAGE_BACKEND").then(|| bad.to_string()))
            .unwrap_err();
        assert!(
            e.message.starts_with("GATEWATCH_STORAGE_BACKEND: "),
            "{bad:?}: {e}"
        );
        assert!(
            e.message.contains("\"sqlite\"") && e.message.contains("\"nats\""),
            "{bad:?}: {e}"
        );
        assert!(e.message.contains(&format!("{bad:?}")), "{bad:?}: {e}");
        assert!(!e.message.contains('\n'), "{e}");
        assert_eq!(c.storage.backend, crate::store::StorageBackend::Sqlite);
    }
    for bad in ["", "  ", "nats://a:4222 nats://b:4222"] {
        let e = c
            .apply_env(|k| (k == "GATEWATCH_NATS_URL").then(|| bad.to_string()))
            .unwrap_err();
        assert!(
            e.message.starts_with("GATEWATCH_NATS_URL: "),
            "{bad:?}: {e}"
        );
        assert_eq!(c.storage.nats_url, "nats://nats.monitoring.svc:4222");
    }
    for bad in ["", "DAM.7", "DAM 7", "DAM>"] {
        let e = c
            .apply_env(|k| (k == "GATEWATCH_NATS_PREFIX").then(|| bad.to_string()))
            .unwrap_err();
        assert!(
            e.message.starts_with("GATEWATCH_NATS_PREFIX: "),
            "{bad:?}: {e}"
        );
        assert_eq!(c.storage.nats_prefix, "DAM_7");
    }
    c.apply_env(|k| (k == "GATEWATCH_NATS_LEASE_SECONDS").then(|| " 45 ".to_string()))
        .unwrap();
    assert_eq!(c.storage.nats_lease_seconds, 45.0);
    for bad in ["", "0.5", "-30", "NaN", "inf", "30s", "1e300"] {
        let e = c
            .apply_env(|k| (k == "GATEWATCH_NATS_LEASE_SECONDS").then(|| bad.to_string()))
            .unwrap_err();
        assert!(
            e.message.starts_with("GATEWATCH_NATS_LEASE_SECONDS: ")
                && e.message.contains(&format!("{bad:?}")),
            "{bad:?}: {e}"
        );
        assert_eq!(c.storage.nats_lease_seconds, 45.0);
    }
}

/// `nats_lease_seconds` below 3 x the NATS operation timeout (30 s) is warned about with the
/// `nats` backend: a renewal is then given up after a third of the lease, shorter than the
/// operation timeout, so a server slower than that but within the timeout lets the lease expire.
#[test]
fn a_nats_lease_shorter_than_three_operation_timeouts_is_warned_about() {
    use crate::store::{nats_lease_renew_interval, NATS_OPERATION_TIMEOUT};
    let lease = |backend: &str, seconds: f64| {
        Config::from_toml(&format!(
            "[storage]\nbackend = \"{backend}\"\nnats_lease_seconds = {seconds:?}\n"
        ))
        .unwrap()
        .warnings()
        .into_iter()
        .filter(|w| w.starts_with("storage.nats_lease_seconds"))
        .collect::<Vec<_>>()
    };
    let w = lease("nats", 9.0);
    assert_eq!(w.len(), 1, "{w:?}");
    let w = &w[0];
    for part in [
        "storage.nats_lease_seconds = 9 is below 30",
        "operation timeout of 10 s",
        "renewed every 3.0 s",
        "expire",
    ] {
        assert!(w.contains(part), "{part:?} not in {w}");
    }
    assert!(!w.contains('\n'), "{w}");
    // the boundary: a third of the lease against the operation timeout, as `lease::keep` bounds
    // a renewal by the shorter of the two
    assert_eq!(lease("nats", 29.9).len(), 1);
    assert!(lease("nats", 30.0).is_empty());
    assert!(lease("nats", 120.0).is_empty());
    for seconds in [1.0, 5.0, 15.0, 29.0, 29.99, 30.0, 30.01, 45.0, 600.0] {
        let interval = nats_lease_renew_interval(std::time::Duration::from_secs_f64(seconds));
        assert_eq!(
            lease("nats", seconds).len() == 1,
            interval < NATS_OPERATION_TIMEOUT,
            "{seconds} s"
        );
    }
    // the default lease is not warned about, nor a short one the sqlite backend does not use
    assert!(Config::from_toml("[storage]\nbackend = \"nats\"\n")
        .unwrap()
        .warnings()
        .is_empty());
    assert!(lease("sqlite", 9.0).is_empty());
}

/// A bad value from a variable names the variable and the key it sets, and is not blamed on the
/// file (`GATEWATCH_LISTEN=foo` read as the file's `server.listen`); a variable gatewatch does
/// not read is warned about.
#[test]
fn environment_errors_name_the_variable_and_unknown_variables_are_warned() {
    for (var, value, want) in [
        (
            "GATEWATCH_LISTEN",
            "foo",
            "GATEWATCH_LISTEN (sets server.listen): must be an address",
        ),
        (
            "GATEWATCH_MAX_GATES",
            "0",
            "GATEWATCH_MAX_GATES (sets server.max_gates): must be in",
        ),
        (
            "GATEWATCH_AUTH_TOKENS",
            "short",
            "GATEWATCH_AUTH_TOKENS (sets server.auth_tokens): ",
        ),
        (
            "GATEWATCH_LOG_FORMAT",
            "xml",
            "GATEWATCH_LOG_FORMAT: must be",
        ),
    ] {
        let mut c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
        let e = c
            .apply_env(|k| (k == var).then(|| value.to_string()))
            .unwrap_err();
        assert!(e.message.starts_with(want), "{var}: {}", e.message);
        assert!(e.names_file(), "{var}: not prefixed with the file's name");
    }
    let w = unknown_env_warnings(
        [
            "GATEWATCH_LISTEN_ADDR",
            "GATEWATCH_LISTEN",
            "HOME",
            "GATEWATCH_CONFIG",
        ]
        .into_iter()
        .map(String::from),
    );
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].contains("GATEWATCH_LISTEN_ADDR is not one gatewatch reads"),
        "{w:?}"
    );
}

/// `GATEWATCH_AUTH_TOKENS` set to no token (empty, blanks, commas: an empty Secret, a
/// `GATEWATCH_AUTH_TOKENS=` left in an env file) is refused naming the variable, and the file's
/// tokens stay: it replaced them with none, which turned authentication off while
/// `check-config` said ok.
#[test]
fn auth_tokens_from_the_environment_that_hold_no_token_are_refused() {
    let file = "[server]\nauth_tokens = [\"0123456789abcdef0123\"]\n";
    for bad in ["", " ", ",", " , ,", "\t"] {
        let mut c = Config::from_toml(file).unwrap();
        let e = c
            .apply_env(|k| (k == "GATEWATCH_AUTH_TOKENS").then(|| bad.to_string()))
            .unwrap_err();
        assert!(
            e.message.starts_with(&format!(
                "GATEWATCH_AUTH_TOKENS (sets server.auth_tokens): {bad:?} holds no token"
            )),
            "{bad:?}: {}",
            e.message
        );
        // how to keep the file's tokens, and the one way to run without authentication
        assert!(e.message.contains("unset the variable"), "{}", e.message);
        assert!(
            e.message.contains("server.auth_tokens = [] in the file"),
            "{}",
            e.message
        );
        assert!(e.names_file(), "{bad:?}: blamed on the file");
        assert!(!e.message.contains('\n'), "{}", e.message);
        assert_eq!(c.server.auth_tokens, ["0123456789abcdef0123"], "{bad:?}");
    }
    // tokens in the variable still replace the file's, blanks and empty items dropped
    let mut c = Config::from_toml(file).unwrap();
    c.apply_env(|k| (k == "GATEWATCH_AUTH_TOKENS").then(|| ",aaaaaaaaaaaaaaaa ,".to_string()))
        .unwrap();
    assert_eq!(c.server.auth_tokens, ["aaaaaaaaaaaaaaaa"]);
}

/// A store `GATEWATCH_STORAGE_PATH` put where `serve` cannot open it is refused naming the
/// variable, not the file (the file's `storage.path` may say something else); the file's own
/// path is still named as the file's key.
#[test]
fn a_store_location_from_the_environment_names_the_variable() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-such-dir");
    let reason = format!(
        "its directory {} does not exist or is not a directory",
        missing.display()
    );
    let mut c = Config::from_toml("[storage]\npath = \"gw.db\"\n").unwrap();
    let env = |k: &str| {
        (k == "GATEWATCH_STORAGE_PATH").then(|| missing.join("x.db").display().to_string())
    };
    c.apply_env(env).unwrap();
    let e = c.check_store_location(Some(dir.path()), env).unwrap_err();
    assert_eq!(
        e.message,
        format!(
            "GATEWATCH_STORAGE_PATH (sets storage.path) {}: {reason}",
            missing.join("x.db").display()
        )
    );
    assert!(e.names_file(), "blamed on the file");
    // from the file: the key, and the caller names the file
    let c = Config::from_toml("[storage]\npath = \"no-such-dir/x.db\"\n").unwrap();
    let e = c
        .check_store_location(Some(dir.path()), |_| None)
        .unwrap_err();
    assert_eq!(
        e.message,
        format!("storage.path {}: {reason}", missing.join("x.db").display())
    );
    assert!(!e.names_file());
    // a directory that exists passes, and a NATS store has no file to check
    std::fs::create_dir(&missing).unwrap();
    c.check_store_location(Some(dir.path()), |_| None).unwrap();
    let nats =
        Config::from_toml("[storage]\nbackend = \"nats\"\npath = \"/nonexist/x.db\"\n").unwrap();
    nats.check_store_location(None, |_| None).unwrap();
}

/// A param the model language refuses by itself (a reserved or invalid name) is named by its
/// own key, `params.NAME`, at its line: it was reported as `model`, at the line of the
/// table's header, or at line 1.
#[test]
fn a_bad_param_names_its_own_key_and_line() {
    for (toml, starts, line) in [
        (
            "[server]\nmax_gates = 4\n\n[defaults]\nrate_hz = 200.0\nparams = { yd = 2.0 }\n",
            "defaults.params.yd: param name 'yd' is reserved",
            6,
        ),
        (
            "[gates.g1]\nrate_hz = 100.0\nparams = { c1 = 2.0 }\n",
            "gates.g1.params.c1: param name 'c1' is reserved",
            3,
        ),
        (
            "[defaults]\nparams = { \"a b\" = 2.0 }\n",
            "defaults.params.a b: invalid param name 'a b'",
            2,
        ),
        // over several lines: the line of the param itself
        (
            "[defaults.params]\nm = 2.0\nsin = 1.0\n",
            "defaults.params.sin: param name 'sin'",
            3,
        ),
    ] {
        let e = err(toml);
        assert!(e.starts_with(starts), "{e}");
        assert!(e.ends_with(&format!(", line {line}")), "{e}");
    }
    // a param the equation uses is fine, and a fault of the equation is still the model's
    Config::from_toml("[defaults]\nmodel = \"m*ydd + c1*yd + k*y = 0\"\nparams = { m = 2.0 }\n")
        .unwrap();
    let e = err("[defaults]\nmodel = \"m*ydd + c1*yd + q*y = 0\"\nparams = { m = 2.0 }\n");
    assert!(e.starts_with("defaults.model: "), "{e}");
    assert!(e.ends_with(", line 2"), "{e}");
}

/// Every entry of `ingest.value_fields` (and `ingest.gate_tag`) must be a key a line of line
/// protocol can carry: `value_fields = [""]` passed, and every write was then refused with
/// `missing field, expected one of [""]`. The error names the entry and its line.
#[test]
fn line_protocol_keys_no_line_can_carry_are_refused_naming_the_entry() {
    let e = err("[server]\nmax_gates = 4\n[ingest]\nvalue_fields = [\"\"]\n");
    assert_eq!(
        e,
        "ingest.value_fields[0]: must not be empty: a line-protocol key has at least one \
         character, line 4"
    );
    let e = err("[ingest]\nvalue_fields = [\n  \"force\",\n  \"value\\\\\",\n]\n");
    assert!(
        e.starts_with("ingest.value_fields[1]: \"value\\\\\" ends with a backslash"),
        "{e}"
    );
    assert!(e.ends_with(", line 4"), "{e}");
    let e = err("[ingest]\nvalue_fields = [\"force\", \"a\\nb\"]\n");
    assert!(
        e.starts_with("ingest.value_fields[1]: \"a\\nb\" holds a newline"),
        "{e}"
    );
    assert!(err("[ingest]\nvalue_fields = []\n").starts_with("ingest.value_fields: must not"));
    assert!(err("[ingest]\ngate_tag = \"\"\n").starts_with("ingest.gate_tag: must not be empty"));
    assert!(err("[ingest]\ngate_tag = \"g\\\\\"\n").starts_with("ingest.gate_tag: \"g\\\\\" ends"));
    // what is accepted is what a line carries, escaped where line protocol escapes
    use crate::service::ingest::line_protocol::{parse_line, FieldValue};
    for (key, written) in [
        ("force", "force"),
        ("a b", "a\\ b"),
        ("a,b=c", "a\\,b\\=c"),
        ("a\\b", "a\\b"),
        ("ü", "ü"),
    ] {
        let c = Config::from_toml(&format!(
            "[ingest]\ngate_tag = {key:?}\nvalue_fields = [{key:?}]\n"
        ))
        .unwrap();
        let line = parse_line(&format!("m,{written}=g1 {written}=1.5"), 1)
            .unwrap()
            .unwrap();
        assert_eq!(line.tags, [(c.ingest.gate_tag.clone(), "g1".to_string())]);
        assert_eq!(
            line.fields,
            [(c.ingest.value_fields[0].clone(), FieldValue::Float(1.5))]
        );
    }
    // and what is refused is not: a trailing backslash escapes the `=`
    assert!(parse_line("m,gate=g1 value\\=1.5", 1).is_err());
    let line = parse_line("m,gate=g1 value\\\\=1.5", 1);
    assert!(
        !matches!(&line, Ok(Some(l)) if l.fields.iter().any(|(k, _)| k == "value\\")),
        "{line:?}"
    );
}

/// [`TOP_LEVEL_TABLES`] is `Config`'s tables: each is accepted alone, and serde's own list of
/// the fields it reads (what an unknown key would otherwise be told) is in it.
#[test]
fn the_top_level_tables_are_the_config_fields() {
    for table in TOP_LEVEL_TABLES {
        Config::from_toml(&format!("[{table}]\n")).unwrap();
    }
    let doc: toml::Table = "unknown_table = 1".parse().unwrap();
    let serde_err = locate::deserialize::<Config>(toml::Value::Table(doc), "", &[], &[])
        .unwrap_err()
        .message;
    let (_, listed) = serde_err.split_once("expected one of ").unwrap();
    for name in listed.split(", ") {
        let name = name.trim_matches('`');
        assert!(TOP_LEVEL_TABLES.contains(&name), "{name} in {serde_err}");
    }
    assert_eq!(listed.split(", ").count() + 2, TOP_LEVEL_TABLES.len());
}

#[test]
fn same_port_says_what_the_kernel_does() {
    // Each pair bound for real: the first on a port the system chooses, the second on that
    // port; `same_port` must say "clash" exactly when the second bind fails with "address in
    // use". A pair whose address this machine lacks (no IPv6 in a container) is skipped, but
    // the IPv4 pairs always run.
    use std::net::{SocketAddr, TcpListener};
    let pairs = [
        ("127.0.0.1", "127.0.0.1", true),
        ("127.0.0.1", "0.0.0.0", true),
        ("0.0.0.0", "127.0.0.2", true),
        ("127.0.0.1", "127.0.0.2", false),
        ("[::]", "127.0.0.1", true),
        ("127.0.0.1", "[::]", true),
        ("0.0.0.0", "[::1]", false),
        ("[::1]", "0.0.0.0", false),
        ("[::ffff:127.0.0.1]", "127.0.0.1", true),
        ("0.0.0.0", "[::ffff:127.0.0.1]", true),
        ("[::1]", "[::]", true),
        ("[::1]", "127.0.0.1", false),
    ];
    // a machine set to bind IPv6 only (`bindv6only = 1`) keeps the families apart; the
    // rule states the default
    let v6only =
        std::fs::read_to_string("/proc/sys/net/ipv6/bindv6only").is_ok_and(|s| s.trim() == "1");
    let mut checked_v4 = 0;
    for (a, b, clash) in pairs {
        if v6only && a.starts_with('[') != b.starts_with('[') {
            continue;
        }
        let Ok(first) = TcpListener::bind(format!("{a}:0")) else {
            continue;
        };
        let port = first.local_addr().unwrap().port();
        let a: SocketAddr = format!("{a}:{port}").parse().unwrap();
        let b: SocketAddr = format!("{b}:{port}").parse().unwrap();
        let in_use = match TcpListener::bind(b) {
            Ok(_) => false,
            Err(e) if e.kind() == std::io::ErrorKind::AddrInUse => true,
            Err(_) => continue, // the address is not on this machine
        };
        // the table states the Linux default (bindv6only = 0) and the kernel agrees
        assert_eq!(in_use, clash, "{a} then {b}: the kernel");
        assert_eq!(super::same_port(a, b), clash, "{a} and {b}");
        assert_eq!(super::same_port(b, a), clash, "{b} and {a}");
        checked_v4 += usize::from(a.is_ipv4() && b.is_ipv4());
    }
    assert_eq!(checked_v4, 4, "every IPv4 pair was bound");
    // port 0 is the system's choice: never a clash
    let z: SocketAddr = "127.0.0.1:0".parse().unwrap();
    assert!(!super::same_port(z, z));
}
