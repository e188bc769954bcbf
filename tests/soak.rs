//! A short `gatewatch bench soak`: the real daemon as a child process under steady, slowloris,
//! broken and transient clients. Asserts survival and the bookkeeping, never speed (the
//! 30-minute soak and its latency target are in docs/benchmarks.md).

use std::process::Command;

#[test]
fn a_short_soak_keeps_the_daemon_alive_and_records_every_interval() {
    let out = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args([
            "bench",
            "soak",
            "--minutes",
            "0.3",
            "--interval",
            "3",
            "--warmup",
            "6",
            "--slow-clients",
            "8",
            "--broken-per-second",
            "5",
            "--json",
        ])
        .output()
        .expect("running gatewatch bench soak");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let v: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("not JSON ({e}): {stdout}\nstderr: {stderr}"));
    let ticks = v["ticks"].as_array().expect("ticks");
    let s = &v["summary"];
    assert!(ticks.len() >= 4, "{} records in 18 s at 3 s", ticks.len());
    for t in ticks {
        assert!(t["rss_mib"].as_f64().unwrap() > 1.0, "{t}");
        assert!(t["fds"].as_u64().unwrap() > 3, "{t}");
    }
    assert_eq!(s["survived"], true, "{s}");
    assert_eq!(s["panics"], 0, "{s}");
    // SIGTERM at the end: the daemon's graceful exit.
    assert_eq!(s["exit_code"], 0, "{s}");
    assert!(s["requests"].as_u64().unwrap() > 0, "{s}");
    // A memory bound, not a speed: the shipped Kubernetes limit.
    assert!(s["rss_peak_mib"].as_f64().unwrap() < 512.0, "{s}");
}
