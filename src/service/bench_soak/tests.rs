use super::*;

#[test]
fn quantile_is_nearest_rank() {
    let v: Vec<f64> = (1..=100).map(f64::from).collect();
    assert_eq!(quantile(&v, 0.99), 99.0);
    assert_eq!(quantile(&v, 0.5), 50.0);
    assert_eq!(quantile(&[3.0], 0.99), 3.0);
    assert!(quantile(&[], 0.5).is_nan());
}

#[test]
fn slope_of_a_line_is_its_gradient() {
    let xs = [0.0, 1.0, 2.0, 3.0];
    let ys = [5.0, 7.0, 9.0, 11.0];
    assert!((slope(&xs, &ys) - 2.0).abs() < 1e-12);
    assert_eq!(slope(&[1.0], &[1.0]), 0.0);
}

#[test]
fn metric_sum_adds_a_family_and_no_other() {
    let text = "# HELP x\ngatewatch_identification_jobs_replaced_total{gate=\"a\"} 3\n\
                gatewatch_identification_jobs_replaced_total{gate=\"b\"} 4\n\
                gatewatch_identification_jobs_replaced_total_other 100\n";
    assert_eq!(
        metric_sum(text, "gatewatch_identification_jobs_replaced_total"),
        7.0
    );
}

fn tick(t: f64, rss: f64, fds: usize, p99: f64) -> Tick {
    Tick {
        t,
        rss_mib: rss,
        hwm_mib: rss,
        fds,
        requests: 10,
        p50_ms: p99 / 2.0,
        p99_ms: p99,
        non_2xx: 0,
        transport_errors: 0,
        jobs_replaced: 0.0,
    }
}

fn args() -> BenchSoakArgs {
    BenchSoakArgs {
        minutes: 30.0,
        gates: 8,
        tcp_gates: 2,
        churn_gates: 16,
        slow_clients: 4,
        broken_per_second: 2.0,
        rate: 200.0,
        interval: 60.0,
        warmup: 120.0,
        worker_threads: 1,
        rss_bound_mib: 512.0,
        extra_config: None,
        json: false,
    }
}

#[test]
fn a_growing_rss_fails_and_a_flat_one_passes() {
    let a = args();
    let flat: Vec<Tick> = (0..31)
        .map(|m| tick(m as f64 * 60.0, 100.0, 40, 5.0))
        .collect();
    let lat = vec![(600.0, vec![2.0; 100])];
    let s = summarise(&a, &flat, &lat, 0, true, Some(0));
    assert!(s.targets.iter().all(|(_, ok)| *ok), "{:?}", s.targets);
    // No latency measured after the warm-up: the latency target cannot pass.
    let s = summarise(&a, &flat, &[], 0, true, Some(0));
    assert!(!s.targets[3].1, "{:?}", s.targets);
    // 2 MiB a minute: 56 MiB over the measured 28 minutes, more than 5 % of 100 MiB.
    let leak: Vec<Tick> = (0..31)
        .map(|m| tick(m as f64 * 60.0, 100.0 + 2.0 * m as f64, 40, 5.0))
        .collect();
    let s = summarise(&a, &leak, &[], 0, true, Some(0));
    assert!(!s.targets[0].1, "{:?}", s.targets);
    assert!((s.rss_slope_mib_per_hour - 120.0).abs() < 1e-6);
}

#[test]
fn descriptor_growth_panics_and_latency_are_judged() {
    let a = args();
    let ticks: Vec<Tick> = (0..31)
        .map(|m| tick(m as f64 * 60.0, 100.0, 40 + 10 * m, 5.0))
        .collect();
    let lat = vec![(
        600.0,
        vec![1.0; 98].into_iter().chain([70.0, 80.0]).collect(),
    )];
    let s = summarise(&a, &ticks, &lat, 1, true, Some(0));
    let failed: Vec<&str> = s
        .targets
        .iter()
        .filter(|(_, ok)| !ok)
        .map(|(n, _)| n.as_str())
        .collect();
    assert!(failed.contains(&"no descriptor growth"), "{failed:?}");
    assert!(failed.contains(&"no panic"), "{failed:?}");
    assert!(
        failed.iter().any(|n| n.starts_with("p99")),
        "{failed:?}, p99 {}",
        s.p99_ms
    );
}
