//! The soak's clients: steady HTTP and TCP gates, slowloris connections and broken requests.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use super::{Shared, CHUNK_SECONDS, SLOW_BYTE_SECONDS, SLOW_LIFETIME_SECONDS};
use crate::service::clock::now_unix;
use crate::simulate::{GateParams, GateSimulator, Scenario};

pub(super) fn simulator(gate: usize, rate: f64) -> GateSimulator {
    let params = GateParams {
        rate_hz: rate,
        ..Default::default()
    };
    GateSimulator::scenario(params, Scenario::Stable, 1000 + gate as u64)
}

fn json_body(gate: &str, start: f64, rate: f64, values: &[f64]) -> String {
    serde_json::json!({"gate": gate, "start": start, "rate_hz": rate, "values": values}).to_string()
}

fn line_body(gate: &str, start: f64, rate: f64, values: &[f64]) -> String {
    let mut out = String::with_capacity(values.len() * 48);
    for (k, v) in values.iter().enumerate() {
        let ns = ((start + k as f64 / rate) * 1e9).round() as i128;
        out.push_str(&format!("gate_force,gate={gate} force={v} {ns}\n"));
    }
    out
}

/// One gate streamed over HTTP.
pub(super) struct HttpGate {
    pub(super) client: reqwest::Client,
    pub(super) base: String,
    pub(super) name: String,
    pub(super) sim: GateSimulator,
    /// Line protocol (`/api/v2/write`) rather than JSON.
    pub(super) line: bool,
    /// When it stops (`None`: at the end of the soak).
    pub(super) until: Option<Instant>,
    /// Whether its latencies and answers count (the steady gates').
    pub(super) record: bool,
}

/// Streams one gate over HTTP until the soak stops or `gate.until`.
pub(super) async fn http_gate(gate: HttpGate, shared: Arc<Shared>) {
    let HttpGate {
        client,
        base,
        name,
        mut sim,
        line,
        until,
        record,
    } = gate;
    let rate = sim.params().rate_hz;
    let n = (rate * CHUNK_SECONDS).round().max(1.0) as usize;
    let mut values = vec![0.0; n];
    let mut next = tokio::time::Instant::now();
    let mut start = now_unix();
    while !shared.stop.load(Ordering::Relaxed) && until.is_none_or(|u| Instant::now() < u) {
        sim.fill(&mut values);
        let (url, ctype, body) = if line {
            let url = format!("{base}/api/v2/write?precision=ns");
            (url, "text/plain", line_body(&name, start, rate, &values))
        } else {
            let url = format!("{base}/api/v1/samples");
            let body = json_body(&name, start, rate, &values);
            (url, "application/json", body)
        };
        start += n as f64 / rate;
        let sent = Instant::now();
        let answer = client
            .post(url)
            .header("content-type", ctype)
            .body(body)
            .send()
            .await;
        let ms = sent.elapsed().as_secs_f64() * 1e3;
        match answer {
            Ok(r) if r.status().is_success() => {
                if record {
                    crate::service::sync::lock(&shared.latencies_ms).push(ms);
                }
            }
            Ok(r) => {
                if record {
                    shared.non_2xx.fetch_add(1, Ordering::Relaxed);
                    *crate::service::sync::lock(&shared.statuses)
                        .entry(r.status().as_u16())
                        .or_default() += 1;
                }
            }
            Err(_) => {
                if record {
                    shared.transport_errors.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        next += Duration::from_secs_f64(CHUNK_SECONDS);
        tokio::time::sleep_until(next).await;
    }
}

/// Streams one gate over the raw TCP listener, reconnecting when the connection is cut.
pub(super) async fn tcp_gate(
    addr: String,
    name: String,
    mut sim: GateSimulator,
    shared: Arc<Shared>,
) {
    let rate = sim.params().rate_hz;
    let n = (rate * CHUNK_SECONDS).round().max(1.0) as usize;
    let mut values = vec![0.0; n];
    let mut next = tokio::time::Instant::now();
    let mut start = now_unix();
    let mut conn: Option<TcpStream> = None;
    while !shared.stop.load(Ordering::Relaxed) {
        sim.fill(&mut values);
        let body = line_body(&name, start, rate, &values);
        start += n as f64 / rate;
        if conn.is_none() {
            conn = TcpStream::connect(&addr).await.ok();
        }
        if let Some(c) = conn.as_mut() {
            if c.write_all(body.as_bytes()).await.is_err() {
                conn = None;
            }
        }
        next += Duration::from_secs_f64(CHUNK_SECONDS);
        tokio::time::sleep_until(next).await;
    }
}

/// A slowloris client: headers a byte at a time, starting over when cut or after a minute.
pub(super) async fn slow_client(addr: String, shared: Arc<Shared>) {
    let head = b"POST /api/v1/samples HTTP/1.1\r\nHost: soak\r\nContent-Type: application/json\r\nX-Slow: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa";
    while !shared.stop.load(Ordering::Relaxed) {
        let Ok(mut c) = TcpStream::connect(&addr).await else {
            tokio::time::sleep(Duration::from_secs(1)).await;
            continue;
        };
        let born = Instant::now();
        for b in head.iter() {
            if shared.stop.load(Ordering::Relaxed)
                || born.elapsed().as_secs_f64() > SLOW_LIFETIME_SECONDS
                || c.write_all(std::slice::from_ref(b)).await.is_err()
            {
                break;
            }
            tokio::time::sleep(Duration::from_secs_f64(SLOW_BYTE_SECONDS)).await;
        }
    }
}

/// One broken request of kind `k`.
pub(super) async fn broken_request(k: u64, http: &str, tcp: &str, client: &reqwest::Client) {
    let addr = http.trim_start_matches("http://");
    match k % 5 {
        0 => {
            // A body cut short: Content-Length promises more than is sent.
            if let Ok(mut c) = TcpStream::connect(addr).await {
                let _ = c
                    .write_all(b"POST /api/v1/samples HTTP/1.1\r\nHost: soak\r\nContent-Type: application/json\r\nContent-Length: 100000\r\n\r\n{\"gate\": \"g")
                    .await;
            }
        }
        1 => {
            let _ = client
                .post(format!("{http}/api/v2/write"))
                .header("content-encoding", "gzip")
                .body(vec![0x1f, 0x8b, 0x08, 0x00, 0xde, 0xad, 0xbe, 0xef])
                .send()
                .await;
        }
        2 => {
            let _ = client
                .post(format!("{http}/api/v1/samples"))
                .header("content-type", "application/json")
                .body("{\"gate\": \"g1\", \"values\": [1, 2,")
                .send()
                .await;
        }
        3 => {
            if let Ok(mut c) = TcpStream::connect(addr).await {
                let _ = c.shutdown().await;
            }
        }
        _ => {
            if let Ok(mut c) = TcpStream::connect(tcp).await {
                let _ = c.write_all(b"not line protocol at all\r\n\x1b[2K").await;
                let mut buf = [0u8; 16];
                let _ = tokio::time::timeout(Duration::from_millis(50), c.read(&mut buf)).await;
            }
        }
    }
}
