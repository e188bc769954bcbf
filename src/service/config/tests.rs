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
fn notify_targets_parse_and_bad_urls_name_the_section() {
    let c = Config::from_toml(
        "[notify]\nalertmanager_urls = [\"http://am:9093\"]\n\
         [[notify.webhooks]]\nurl = \"http://127.0.0.1:5001/hook\"\n",
    )
    .unwrap();
    assert_eq!(c.notify.webhooks.len(), 1);
    assert_eq!(c.notify.webhooks[0].receiver, "gatewatch");
    assert_eq!(c.notify.alertmanager_urls, ["http://am:9093"]);
    assert!(err("[[notify.webhooks]]\nurl = \"ftp://x\"\n").starts_with("notify: "));
    assert!(err("[notify]\nalertmanager_url = \"http://x\"\n").contains("alertmanager_url"));
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

#[test]
fn errors_name_the_key() {
    assert_eq!(
        err("[gates.g1]\nrate_hz = 0.0\n"),
        "gates.g1.rate_hz: must be > 0"
    );
    assert_eq!(
        err("[defaults]\nwindow_seconds = -1.0\n"),
        "defaults.window_seconds: must be > 0"
    );
    assert!(
        err("[gates.g1]\nrte_hz = 1.0\n").starts_with("gates.g1.rte_hz: unknown field `rte_hz`")
    );
    assert!(err("[server]\nlisten_addr = \"x\"\n").contains("unknown field `listen_addr`"));
    assert!(err("[bogus]\n").contains("unknown field `bogus`"));
    assert!(err("[gates.g1.alert]\nfor_windows = 0\n").starts_with("gates.g1.alert.for_windows"));
    assert!(err("[gates.g1.alert]\nsevrity = \"x\"\n").contains("sevrity"));
    // the interval and trend rules name their key
    for (toml, key) in [
        ("fire_probability = 1.0", "gates.g1.alert.fire_probability"),
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
    ] {
        assert!(
            err(&format!("[gates.g1.alert]\n{toml}\n")).starts_with(key),
            "{toml}"
        );
    }
    assert!(err("[server]\nlisten = \"nope\"\n").starts_with("server.listen:"));
    assert!(err("[server]\nmax_gates = 0\n").starts_with("server.max_gates:"));
    assert!(err("[server]\nauth_tokens = [\"short\"]\n").starts_with("server.auth_tokens:"));
    assert!(
        err("[defaults]\nsignal = \"pressure\"\n").starts_with("defaults.signal: unknown variant")
    );
    assert!(err("[gates.\"bad id!\"]\n").starts_with("gates.bad id!:"));
    assert!(err("[server\n").contains("invalid") || !err("[server\n").is_empty());
    assert!(!err("[gates.g1]\nrate_hz = 0.0\n").contains('\n'));
}

#[test]
fn environment_overrides() {
    let mut c = Config::from_toml(EMBEDDED_CONFIG).unwrap();
    let env = |k: &str| match k {
        "GATEWATCH_LISTEN" => Some("127.0.0.1:1234".to_string()),
        "GATEWATCH_TCP_LISTEN" => Some("127.0.0.1:8094".to_string()),
        "GATEWATCH_AUTH_TOKENS" => Some("aaaaaaaaaaaaaaaa, bbbbbbbbbbbbbbbb".to_string()),
        "GATEWATCH_LOG_FORMAT" => Some("json".to_string()),
        "GATEWATCH_WORKER_THREADS" => Some("3".to_string()),
        "GATEWATCH_ACCEPT_UNKNOWN_GATES" => Some("false".to_string()),
        _ => None,
    };
    c.apply_env(env).unwrap();
    assert_eq!(c.server.listen, "127.0.0.1:1234");
    assert_eq!(c.server.tcp_listen, "127.0.0.1:8094");
    assert_eq!(c.server.auth_tokens.len(), 2);
    assert_eq!(c.log.format, LogFormat::Json);
    assert_eq!(c.server.effective_worker_threads(), 3);
    assert!(!c.server.accept_unknown_gates);
    let e = c
        .apply_env(|k| (k == "GATEWATCH_LOG_FORMAT").then(|| "xml".to_string()))
        .unwrap_err();
    assert!(e.message.starts_with("GATEWATCH_LOG_FORMAT"));
}

#[test]
fn worker_threads_default_is_at_least_one() {
    assert!(ServerConfig::default().effective_worker_threads() >= 1);
}
