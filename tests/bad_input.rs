//! The bad-input suite: the real `gatewatch` binary is started and fed malformed requests over
//! real sockets (JSON, line protocol over HTTP and raw TCP, query strings, headers, methods,
//! encodings, gzip bombs, huge numbers, unicode, empty bodies), and `check-config` and `serve`
//! are given malformed configurations. Every case asserts its answer class (status code and the
//! field, index or line named; for TCP the rejection reason counted), `/healthz` answers after
//! each, and the daemon's stderr never says "panicked". The classes are listed in docs/api.md
//! ("Bad-input suite").
//!
//! Requests are written by hand on a `TcpStream` (HTTP/1.1, `Connection: close`): an HTTP client
//! library would refuse to send most of them.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use flate2::write::GzEncoder;
use flate2::Compression;
use serde_json::{json, Value};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// A running daemon; killed on drop, its stderr kept in a file.
struct Daemon {
    child: Child,
    http: SocketAddr,
    tcp: SocketAddr,
    stderr: PathBuf,
    _dir: tempfile::TempDir,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Daemon {
    /// Starts `gatewatch serve` on ports chosen by the system; `extra` goes into `[server]`.
    fn start(extra: &str) -> Daemon {
        let dir = tempfile::tempdir().unwrap();
        let cfg = dir.path().join("gatewatch.toml");
        std::fs::write(
            &cfg,
            format!(
                "[server]\nlisten = \"127.0.0.1:0\"\ntcp_listen = \"127.0.0.1:0\"\n\
                 worker_threads = 1\nbody_limit_bytes = 65536\n{extra}\n\
                 [log]\nformat = \"json\"\n\
                 [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n\
                 population = 4\ngenerations = 1\n"
            ),
        )
        .unwrap();
        let stderr = dir.path().join("stderr.log");
        let child = Command::new(BIN)
            .args(["serve", "--config"])
            .arg(&cfg)
            .env_remove("RUST_LOG")
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(60);
        let (mut http, mut tcp) = (None, None);
        while Instant::now() < deadline && (http.is_none() || tcp.is_none()) {
            let log = std::fs::read_to_string(&stderr).unwrap_or_default();
            for line in log.lines() {
                let Ok(v) = serde_json::from_str::<Value>(line) else {
                    continue;
                };
                let f = &v["fields"];
                let addr = f["addr"].as_str().and_then(|a| a.parse().ok());
                match f["message"].as_str() {
                    Some("HTTP listener up") => http = addr,
                    Some("line protocol TCP listener up") => tcp = addr,
                    _ => {}
                }
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let d = Daemon {
            child,
            http: http.expect("HTTP listener address in the log"),
            tcp: tcp.expect("TCP listener address in the log"),
            stderr,
            _dir: dir,
        };
        // /healthz answers once the router runs
        for _ in 0..100 {
            if d.try_request(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
                .is_some_and(|r| r.status == 200)
            {
                return d;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!("daemon did not answer /healthz");
    }

    fn try_request(&self, raw: &[u8]) -> Option<Reply> {
        let mut s = TcpStream::connect(self.http).ok()?;
        s.set_read_timeout(Some(Duration::from_secs(30))).ok()?;
        // the server may answer and close before the whole body is written (413, 415)
        let _ = s.write_all(raw);
        let mut out = Vec::new();
        let _ = s.read_to_end(&mut out);
        Reply::parse(&out)
    }

    fn request(&self, raw: &[u8]) -> Reply {
        self.try_request(raw)
            .unwrap_or_else(|| panic!("no HTTP answer to {:?}", preview(raw)))
    }

    fn post(&self, path: &str, headers: &[(&str, &str)], body: &[u8]) -> Reply {
        self.request(&raw_request("POST", path, headers, body))
    }

    fn healthy(&self) -> bool {
        self.try_request(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .is_some_and(|r| r.status == 200 && r.body == b"ok\n")
    }

    fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    fn get_json(&self, path: &str) -> Value {
        let r = self.request(&raw_request("GET", path, &[], b""));
        serde_json::from_slice(&r.body).unwrap_or(Value::Null)
    }

    /// Every rejection counted, requests and samples, from /metrics.
    fn rejections(&self) -> f64 {
        let r = self.request(&raw_request("GET", "/metrics", &[], b""));
        String::from_utf8_lossy(&r.body)
            .lines()
            .filter(|l| {
                l.starts_with("gatewatch_samples_rejected_total{")
                    || l.starts_with("gatewatch_ingest_requests_rejected_total{")
            })
            .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
            .sum()
    }

    /// `gatewatch_samples_rejected_total{reason}` from /metrics.
    fn rejected(&self, reason: &str) -> f64 {
        let r = self.request(&raw_request("GET", "/metrics", &[], b""));
        let text = String::from_utf8_lossy(&r.body).to_string();
        let prefix = format!("gatewatch_samples_rejected_total{{reason=\"{reason}\"}} ");
        text.lines()
            .find_map(|l| l.strip_prefix(&prefix))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0.0)
    }
}

fn preview(raw: &[u8]) -> String {
    String::from_utf8_lossy(&raw[..raw.len().min(200)]).into_owned()
}

fn raw_request(method: &str, path: &str, headers: &[(&str, &str)], body: &[u8]) -> Vec<u8> {
    let mut out = format!("{method} {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n");
    let mut has_length = false;
    for (k, v) in headers {
        has_length |=
            k.eq_ignore_ascii_case("content-length") || k.eq_ignore_ascii_case("transfer-encoding");
        out.push_str(&format!("{k}: {v}\r\n"));
    }
    if !has_length {
        out.push_str(&format!("Content-Length: {}\r\n", body.len()));
    }
    out.push_str("\r\n");
    let mut out = out.into_bytes();
    out.extend_from_slice(body);
    out
}

#[derive(Debug)]
struct Reply {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Reply {
    fn parse(raw: &[u8]) -> Option<Reply> {
        let end = raw.windows(4).position(|w| w == b"\r\n\r\n")?;
        let head = std::str::from_utf8(&raw[..end]).ok()?;
        let mut lines = head.split("\r\n");
        let status = lines.next()?.split(' ').nth(1)?.parse().ok()?;
        let headers: Vec<(String, String)> = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
            .collect();
        let mut body = raw[end + 4..].to_vec();
        if headers
            .iter()
            .any(|(k, v)| k == "transfer-encoding" && v.contains("chunked"))
        {
            body = dechunk(&body);
        }
        Some(Reply {
            status,
            headers,
            body,
        })
    }

    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or(Value::Null)
    }

    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(i) = b.windows(2).position(|w| w == b"\r\n") {
        let size = usize::from_str_radix(std::str::from_utf8(&b[..i]).unwrap_or("0").trim(), 16)
            .unwrap_or(0);
        if size == 0 || b.len() < i + 2 + size {
            break;
        }
        out.extend_from_slice(&b[i + 2..i + 2 + size]);
        b = &b[(i + 4 + size).min(b.len())..];
    }
    out
}

/// What a case must answer.
#[derive(Debug, Clone)]
enum Want {
    /// The status alone.
    Status(u16),
    /// 400 naming this `field` (JSON `field` member).
    Field(&'static str),
    /// 400 naming this field and `index`.
    FieldIndex(&'static str, u64),
    /// 400 naming this `line`.
    Line(u64),
    /// 400 naming this field and `line`.
    FieldLine(&'static str, u64),
    /// 400 with `line` and `column` (a syntax error).
    LineColumn,
    /// 400 naming this field, whose error says this (a hint that names the fix).
    FieldSays(&'static str, &'static str),
    /// This status, with a JSON `error` that says this.
    StatusSays(u16, &'static str),
}

struct Case {
    class: &'static str,
    raw: Vec<u8>,
    want: Want,
}

/// The ingestion routes: a 400 there refused samples, so it must show in a rejection counter.
const INGEST_ROUTES: [&str; 3] = ["/api/v1/samples", "/api/v2/write", "/write"];

/// Whether a case is a well-formed HTTP request to an ingestion route (a request hyper refuses
/// before routing never reaches a handler that could count it).
fn to_ingest_route(raw: &[u8]) -> bool {
    let line = raw.split(|b| *b == b'\r').next().unwrap_or_default();
    let text = String::from_utf8_lossy(line);
    let mut parts = text.split(' ');
    let (Some("POST"), Some(target), Some("HTTP/1.1")) = (parts.next(), parts.next(), parts.next())
    else {
        return false;
    };
    let path = target.split('?').next().unwrap_or_default();
    INGEST_ROUTES.contains(&path) && raw.windows(4).any(|w| w == b"\r\n\r\n")
}

fn check(d: &Daemon, cases: &[Case]) {
    let mut failures = Vec::new();
    for c in cases {
        let counted = to_ingest_route(&c.raw).then(|| d.rejections());
        let r = d.request(&c.raw);
        let v = r.json();
        // a refused ingestion request is counted (a request or its samples), and no answer
        // echoes the input whole (`ingest::EXCERPT_CHARS`, `MAX_ERROR_CHARS`)
        // (hyper answers a malformed header itself, with an empty 400 no handler saw)
        if let (Some(before), 400, true) = (counted, r.status, v["error"].is_string()) {
            let after = d.rejections();
            if after <= before {
                failures.push(format!("{}: a 400 no rejection counter shows", c.class));
            }
        }
        if r.status >= 400 && r.body.len() > 2048 {
            failures.push(format!("{}: a {}-byte error answer", c.class, r.body.len()));
        }
        let ok = match &c.want {
            Want::Status(s) => r.status == *s,
            Want::Field(f) => r.status == 400 && v["field"] == *f,
            Want::FieldIndex(f, i) => r.status == 400 && v["field"] == *f && v["index"] == *i,
            Want::Line(l) => r.status == 400 && v["line"] == *l,
            Want::FieldLine(f, l) => r.status == 400 && v["field"] == *f && v["line"] == *l,
            Want::LineColumn => r.status == 400 && v["line"].is_u64() && v["column"].is_u64(),
            Want::FieldSays(f, says) => {
                r.status == 400
                    && v["field"] == *f
                    && v["error"].as_str().is_some_and(|e| e.contains(says))
            }
            Want::StatusSays(s, says) => {
                r.status == *s && v["error"].as_str().is_some_and(|e| e.contains(says))
            }
        };
        if !ok {
            failures.push(format!(
                "{}: want {:?}, got {} {}",
                c.class,
                c.want,
                r.status,
                String::from_utf8_lossy(&r.body)
            ));
        }
        assert!(d.healthy(), "/healthz failed after {}", c.class);
    }
    assert!(
        !d.stderr().contains("panicked"),
        "the daemon panicked:\n{}",
        d.stderr()
    );
    assert!(
        failures.is_empty(),
        "{} cases failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

fn json_case(class: &'static str, body: impl Into<Vec<u8>>, want: Want) -> Case {
    Case {
        class,
        raw: raw_request(
            "POST",
            "/api/v1/samples",
            &[("Content-Type", "application/json")],
            &body.into(),
        ),
        want,
    }
}

fn lp_case(class: &'static str, path: &str, body: impl Into<Vec<u8>>, want: Want) -> Case {
    Case {
        class,
        raw: raw_request("POST", path, &[], &body.into()),
        want,
    }
}

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::best());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

/// A valid uniform JSON batch for gate `g` starting now.
fn good(g: &str) -> Value {
    json!({"gate": g, "start": now(), "rate_hz": 100, "values": [1.0, 2.0]})
}

fn json_cases() -> Vec<Case> {
    let t = now();
    let s = |v: Value| v.to_string().into_bytes();
    let good_then = |k: &str, v: Value| {
        let mut o = good("g1");
        o[k] = v;
        s(o)
    };
    let mut c = vec![
        // syntax
        json_case("JSON: trailing comma", "[1,]", Want::LineColumn),
        json_case("JSON: unclosed object", "{", Want::LineColumn),
        json_case("JSON: lone closing brace", "}", Want::LineColumn),
        json_case("JSON: missing value", r#"{"gate":}"#, Want::LineColumn),
        json_case(
            "JSON: trailing garbage",
            format!("{} x", good("g1")),
            Want::LineColumn,
        ),
        json_case(
            "JSON: NaN literal",
            format!(r#"{{"gate":"g1","start":{t},"rate_hz":100,"values":[NaN]}}"#),
            Want::LineColumn,
        ),
        json_case(
            "JSON: Infinity literal",
            format!(r#"{{"gate":"g1","start":{t},"rate_hz":100,"values":[Infinity]}}"#),
            Want::LineColumn,
        ),
        json_case(
            "JSON: number out of range (1e999)",
            format!(r#"{{"gate":"g1","start":{t},"rate_hz":100,"values":[1e999]}}"#),
            Want::LineColumn,
        ),
        json_case("JSON: lone minus", "-", Want::LineColumn),
        json_case("JSON: single quotes", "{'gate': 'g1'}", Want::LineColumn),
        json_case("JSON: comment", "// c\n{}", Want::LineColumn),
        json_case(
            "JSON: byte order mark",
            b"\xef\xbb\xbf{}".to_vec(),
            Want::LineColumn,
        ),
        json_case(
            "JSON: invalid UTF-8 in a string",
            b"{\"gate\": \"g\xff\"}".to_vec(),
            Want::LineColumn,
        ),
        json_case(
            "JSON: lone surrogate escape",
            r#"{"gate": "\ud800"}"#,
            Want::LineColumn,
        ),
        json_case(
            "JSON: control character in a string",
            "{\"gate\": \"g\u{1}\"}",
            Want::LineColumn,
        ),
        json_case(
            "JSON: 10 000 nested arrays",
            "[".repeat(10_000),
            Want::LineColumn,
        ),
        json_case(
            "JSON: unterminated string",
            r#"{"gate": "g1"#,
            Want::LineColumn,
        ),
        json_case(
            "JSON: syntax error on line 3",
            "{\n\"gate\": \"g1\",\n,}",
            Want::Line(3),
        ),
        // empty and wrong top level
        json_case("JSON: empty body", "", Want::LineColumn),
        json_case("JSON: whitespace only", " \n\t ", Want::LineColumn),
        json_case("JSON: empty array", "[]", Want::Status(400)),
        json_case("JSON: top-level string", r#""g1""#, Want::Status(400)),
        json_case("JSON: top-level number", "42", Want::Status(400)),
        json_case("JSON: top-level null", "null", Want::Status(400)),
        json_case("JSON: top-level true", "true", Want::Status(400)),
        json_case(
            "JSON: array item a number",
            format!("[{}, 5]", good("g1")),
            Want::Field("[1]"),
        ),
        json_case("JSON: empty object", "{}", Want::Field("gate")),
        // gate
        json_case(
            "JSON: gate a number",
            good_then("gate", json!(7)),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate null",
            good_then("gate", Value::Null),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate an array",
            good_then("gate", json!(["g1"])),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate empty",
            good_then("gate", json!("")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate 65 characters",
            good_then("gate", json!("g".repeat(65))),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate with a slash",
            good_then("gate", json!("../etc")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate with unicode",
            good_then("gate", json!("gäte")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate with a NUL",
            good_then("gate", json!("g\u{0}")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate with RTL override",
            good_then("gate", json!("g\u{202e}1")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate with a newline",
            good_then("gate", json!("g\n1")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate `.`",
            good_then("gate", json!(".")),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: gate `..`",
            good_then("gate", json!("..")),
            Want::Field("gate"),
        ),
        // start
        json_case(
            "JSON: start not a time",
            good_then("start", json!("yesterday")),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start RFC 3339 without offset",
            good_then("start", json!("2026-11-23T03:00:00")),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start RFC 3339 with a numeric offset",
            good_then("start", json!("2026-11-23T03:00:00+01:00")),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start date only",
            good_then("start", json!("2026-11-23")),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start a boolean",
            good_then("start", json!(true)),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start null",
            good_then("start", Value::Null),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start an object",
            good_then("start", json!({"s": 1})),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start 1e300 (far future)",
            good_then("start", json!(1e300)),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start -1e300",
            good_then("start", json!(-1e300)),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start 0 (1970)",
            good_then("start", json!(0)),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start in 1971",
            good_then("start", json!("1971-06-01T00:00:00Z")),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start in 33658",
            good_then("start", json!(1.0e12)),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start 1e6 s ahead",
            good_then("start", json!(t + 1e6)),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start 2 h behind",
            good_then("start", json!(t - 7200.0)),
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start in milliseconds (hint: JSON times are Unix seconds)",
            good_then("start", json!((t * 1000.0).round())),
            Want::FieldSays("start", "is it in ms? JSON times are Unix seconds"),
        ),
        json_case(
            "JSON: a value beyond +-1e100 (1e308 at index 2)",
            good_then("values", json!([1.0, 2.0, 1e308])),
            Want::FieldIndex("values", 2),
        ),
        json_case(
            "JSON: a samples pair's value beyond +-1e100",
            s(json!({"gate": "g", "samples": [[t, 1.0], [t + 0.01, -1e101]]})),
            Want::FieldIndex("samples", 1),
        ),
        json_case(
            "JSON: start u64::MAX",
            r#"{"gate":"g1","start":18446744073709551615,"rate_hz":100,"values":[1]}"#,
            Want::FieldIndex("start", 0),
        ),
        json_case(
            "JSON: start year 99999 string",
            good_then("start", json!("99999-01-01T00:00:00Z")),
            Want::Field("start"),
        ),
        json_case(
            "JSON: start a 1 MB-free long string",
            good_then("start", json!("9".repeat(5000))),
            Want::Field("start"),
        ),
        // rate
        json_case(
            "JSON: rate_hz 0",
            good_then("rate_hz", json!(0)),
            Want::Field("rate_hz"),
        ),
        json_case(
            "JSON: rate_hz negative",
            good_then("rate_hz", json!(-100)),
            Want::Field("rate_hz"),
        ),
        json_case(
            "JSON: rate_hz a string",
            good_then("rate_hz", json!("100")),
            Want::Field("rate_hz"),
        ),
        json_case(
            "JSON: rate_hz 1e308",
            good_then("rate_hz", json!(1e308)),
            Want::Field("rate_hz"),
        ),
        json_case(
            "JSON: rate_hz 2 % off",
            good_then("rate_hz", json!(102)),
            Want::Field("rate_hz"),
        ),
        json_case(
            "JSON: rate_hz tiny (5e-324)",
            good_then("rate_hz", json!(5e-324)),
            Want::Status(400),
        ),
        // values
        json_case(
            "JSON: values not an array",
            good_then("values", json!(1.0)),
            Want::Field("values"),
        ),
        json_case(
            "JSON: values empty",
            good_then("values", json!([])),
            Want::Field("values"),
        ),
        json_case(
            "JSON: values with a string",
            good_then("values", json!([1, "x", 3])),
            Want::FieldIndex("values", 1),
        ),
        json_case(
            "JSON: values with null",
            good_then("values", json!([1, null])),
            Want::FieldIndex("values", 1),
        ),
        json_case(
            "JSON: values with a boolean",
            good_then("values", json!([true])),
            Want::FieldIndex("values", 0),
        ),
        json_case(
            "JSON: values nested",
            good_then("values", json!([[1]])),
            Want::FieldIndex("values", 0),
        ),
        json_case(
            "JSON: values an object",
            good_then("values", json!({"0": 1})),
            Want::Field("values"),
        ),
        // samples
        json_case(
            "JSON: samples pair of three",
            s(json!({"gate": "g1", "samples": [[t, 1, 2]]})),
            Want::FieldIndex("samples", 0),
        ),
        json_case(
            "JSON: samples pair of one",
            s(json!({"gate": "g1", "samples": [[t]]})),
            Want::FieldIndex("samples", 0),
        ),
        json_case(
            "JSON: samples not an array",
            s(json!({"gate": "g1", "samples": 5})),
            Want::Field("samples"),
        ),
        json_case(
            "JSON: samples empty",
            s(json!({"gate": "g1", "samples": []})),
            Want::Field("samples"),
        ),
        json_case(
            "JSON: samples time a string",
            s(json!({"gate": "g1", "samples": [["now", 1]]})),
            Want::FieldIndex("samples", 0),
        ),
        json_case(
            "JSON: samples time far future",
            s(json!({"gate": "g1", "samples": [[t, 1], [t + 1e6, 1]]})),
            Want::FieldIndex("samples", 1),
        ),
        json_case(
            "JSON: samples time 1970",
            s(json!({"gate": "g1", "samples": [[1.0, 1]]})),
            Want::FieldIndex("samples", 0),
        ),
        json_case(
            "JSON: samples with start",
            s(json!({"gate": "g1", "start": t, "samples": [[t, 1]]})),
            Want::Field("start"),
        ),
        json_case(
            "JSON: values and samples",
            s(json!({"gate": "g1", "values": [1], "samples": [[t, 1]]})),
            Want::Field("samples"),
        ),
        json_case(
            "JSON: samples spacing implies 50 Hz",
            s(json!({"gate": "g1", "samples": [[t, 1], [t + 0.02, 1], [t + 0.04, 1]]})),
            Want::Field("samples"),
        ),
        // fields
        json_case(
            "JSON: missing gate",
            s(json!({"start": t, "rate_hz": 100, "values": [1]})),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: missing start",
            s(json!({"gate": "g1", "rate_hz": 100, "values": [1]})),
            Want::Field("start"),
        ),
        json_case(
            "JSON: missing rate_hz",
            s(json!({"gate": "g1", "start": t, "values": [1]})),
            Want::Field("rate_hz"),
        ),
        json_case(
            "JSON: missing values",
            s(json!({"gate": "g1", "start": t, "rate_hz": 100})),
            Want::Field("values"),
        ),
        json_case(
            "JSON: unknown member",
            good_then("colour", json!(1)),
            Want::Field("colour"),
        ),
        json_case(
            "JSON: 70 new gates, max_gates 64: the 65th named by its element",
            serde_json::to_vec(
                &(0..70)
                    .map(|i| json!({"gate": format!("n{i}"), "start": t, "rate_hz": 100, "values": [1.0]}))
                    .collect::<Vec<_>>(),
            )
            .unwrap(),
            Want::Field("[64].gate"),
        ),
        json_case(
            "JSON: a 60 000-character unknown member",
            good_then(&"x".repeat(60_000), json!(1)),
            Want::Status(400),
        ),
        json_case(
            "JSON: unknown unicode member",
            good_then("gäte", json!(1)),
            Want::Field("gäte"),
        ),
        json_case(
            "JSON: duplicate gate key",
            format!(r#"{{"gate":"g1","start":{t},"rate_hz":100,"values":[1],"gate":"g2"}}"#),
            Want::Field("gate"),
        ),
        json_case(
            "JSON: duplicate values key",
            format!(r#"{{"gate":"g1","start":{t},"rate_hz":100,"values":[1],"values":[2]}}"#),
            Want::Field("values"),
        ),
        json_case(
            "JSON: duplicate key in the 2nd batch",
            format!(r#"[{},{{"gate":"g1","gate":"g1"}}]"#, good("g1")),
            Want::Field("[1].gate"),
        ),
        json_case(
            "JSON: 2nd batch bad, nothing applied",
            s(json!([good("g1"), {"gate": "g2", "start": t, "rate_hz": 100, "values": [1, "x"]}])),
            Want::FieldIndex("[1].values", 1),
        ),
        json_case(
            "JSON: 2nd batch wrong rate",
            s(json!([good("g1"), {"gate": "g2", "start": t, "rate_hz": 200, "values": [1]}])),
            Want::Field("[1].rate_hz"),
        ),
        json_case(
            "JSON: 2nd batch in the future",
            s(json!([good("g1"), {"gate": "g2", "start": t + 1e6, "rate_hz": 100, "values": [1]}])),
            Want::FieldIndex("[1].start", 0),
        ),
    ];
    // huge numbers of digits
    c.push(json_case(
        "JSON: a value of 400 digits",
        format!(
            r#"{{"gate":"g1","start":{t},"rate_hz":100,"values":[{}]}}"#,
            "9".repeat(400)
        ),
        Want::LineColumn,
    ));
    c
}

fn now_ns() -> i128 {
    (now() * 1e9) as i128
}

fn lp_cases() -> Vec<Case> {
    let ns = now_ns();
    let v2 = "/api/v2/write";
    let v1 = "/write";
    vec![
        lp_case(
            "LP: missing value field",
            v2,
            format!("m,gate=g1 other=1 {ns}"),
            Want::FieldLine("force", 1),
        ),
        lp_case(
            "LP: missing gate tag",
            v2,
            format!("m force=1 {ns}"),
            Want::FieldLine("gate", 1),
        ),
        lp_case(
            "LP: string value",
            v2,
            format!("m,gate=g1 force=\"x\" {ns}"),
            Want::FieldLine("force", 1),
        ),
        lp_case(
            "LP: boolean value",
            v2,
            format!("m,gate=g1 force=true {ns}"),
            Want::FieldLine("force", 1),
        ),
        lp_case(
            "LP: bad number",
            v2,
            format!("m,gate=g1 force=1.2.3 {ns}"),
            Want::Line(1),
        ),
        lp_case(
            "LP: NaN",
            v2,
            format!("m,gate=g1 force=NaN {ns}"),
            Want::Line(1),
        ),
        lp_case(
            "LP: inf",
            v2,
            format!("m,gate=g1 force=inf {ns}"),
            Want::Line(1),
        ),
        lp_case(
            "LP: 1e999",
            v2,
            format!("m,gate=g1 force=1e999 {ns}"),
            Want::Line(1),
        ),
        lp_case(
            "LP: empty field value",
            v2,
            format!("m,gate=g1 force= {ns}"),
            Want::Line(1),
        ),
        lp_case("LP: no fields", v2, "m,gate=g1", Want::Line(1)),
        lp_case(
            "LP: unterminated string field",
            v2,
            "m,gate=g1 note=\"abc",
            Want::Line(1),
        ),
        lp_case(
            "LP: timestamp not a number",
            v2,
            "m,gate=g1 force=1 yesterday",
            Want::Line(1),
        ),
        lp_case(
            "LP: timestamp beyond i64",
            v2,
            "m,gate=g1 force=1 99999999999999999999",
            Want::Line(1),
        ),
        lp_case(
            "LP: timestamp 1e6 s ahead",
            v2,
            format!("m,gate=g1 force=1 {}", ns + 1_000_000_000_000_000),
            Want::FieldLine("timestamp", 1),
        ),
        lp_case(
            "LP: a value beyond +-1e100 on line 2",
            v1,
            format!(
                "m,gate=g1 force=1 {ns}\nm,gate=g1 force=-1e300 {}",
                ns + 10_000_000
            ),
            Want::FieldLine("force", 2),
        ),
        lp_case(
            "LP: timestamps in ms without precision (hint: ?precision=ms)",
            v2,
            format!("m,gate=g1 force=1 {}", ns / 1_000_000),
            Want::FieldSays("timestamp", "?precision=ms"),
        ),
        lp_case(
            "LP: timestamp in 1971",
            v2,
            "m,gate=g1 force=1 40000000000000000",
            Want::FieldLine("timestamp", 1),
        ),
        lp_case(
            "LP: timestamp 0",
            v2,
            "m,gate=g1 force=1 0",
            Want::FieldLine("timestamp", 1),
        ),
        lp_case(
            "LP: negative timestamp",
            v2,
            "m,gate=g1 force=1 -5",
            Want::FieldLine("timestamp", 1),
        ),
        lp_case(
            "LP: year 33658 at precision s",
            &format!("{v2}?precision=s"),
            "m,gate=g1 force=1 1000000000000",
            Want::FieldLine("timestamp", 1),
        ),
        lp_case(
            "LP: future on line 3 of 3",
            v2,
            format!(
                "m,gate=g1 force=1 {ns}\nm,gate=g1 force=1 {}\nm,gate=g1 force=1 {}",
                ns + 10_000_000,
                ns + (1u64 << 62) as i128
            ),
            Want::FieldLine("timestamp", 3),
        ),
        lp_case(
            "LP: NaN on line 2 of 2",
            v2,
            format!(
                "m,gate=g1 force=1 {ns}\nm,gate=g1 force=NaN {}",
                ns + 10_000_000
            ),
            Want::Line(2),
        ),
        lp_case(
            "LP: not UTF-8 (named by its line and column, as other syntax errors)",
            v2,
            b"m,gate=g1 force=1\nm,gate=g\xff force=1".to_vec(),
            Want::LineColumn,
        ),
        lp_case("LP: empty body", v2, "", Want::Status(400)),
        lp_case("LP: only a comment", v2, "# nothing\n", Want::Status(400)),
        lp_case("LP: only blank lines", v2, "\n\n\n", Want::Status(400)),
        lp_case(
            "LP: invalid gate id",
            v2,
            format!("m,gate=a/b force=1 {ns}"),
            Want::FieldLine("gate", 1),
        ),
        lp_case(
            "LP: gate id with unicode",
            v2,
            format!("m,gate=gäte force=1 {ns}"),
            Want::FieldLine("gate", 1),
        ),
        lp_case(
            "LP: gate id `..`",
            v1,
            format!("m,gate=.. force=1 {ns}"),
            Want::FieldLine("gate", 1),
        ),
        lp_case(
            "LP: gate id `.` on line 2",
            v2,
            format!(
                "m,gate=g1 force=1 {ns}\nm,gate=. force=1 {}",
                ns + 10_000_000
            ),
            Want::FieldLine("gate", 2),
        ),
        lp_case("LP: trailing backslash", v2, "m,gate=g1\\", Want::Line(1)),
        lp_case("LP: tag without value", v2, "m,gate force=1", Want::Line(1)),
        lp_case(
            "LP: space before tags",
            v2,
            " ,gate=g1 force=1",
            Want::Line(1),
        ),
        lp_case(
            "LP: carriage return inside",
            v2,
            "m,gate=g1 force=1\r5",
            Want::Line(1),
        ),
        lp_case(
            "LP: integer overflow 99999999999999999999i",
            v2,
            "m,gate=g1 force=99999999999999999999i",
            Want::Line(1),
        ),
        lp_case(
            "LP: unsigned negative -1u",
            v2,
            "m,gate=g1 force=-1u",
            Want::Line(1),
        ),
        lp_case(
            "LP: /write precision=d",
            &format!("{v1}?precision=d"),
            "m,gate=g1 force=1 1",
            Want::Field("precision"),
        ),
        lp_case(
            "LP: precision empty",
            &format!("{v2}?precision="),
            "m,gate=g1 force=1 1",
            Want::Field("precision"),
        ),
        lp_case(
            "LP: precision uppercase NS",
            &format!("{v2}?precision=NS"),
            "m,gate=g1 force=1 1",
            Want::Field("precision"),
        ),
        lp_case(
            "LP: precision twice",
            &format!("{v2}?precision=s&precision=ns"),
            format!("m,gate=g1 force=1 {ns}"),
            Want::Field("precision"),
        ),
        lp_case(
            "LP: precision twice (same value)",
            &format!("{v1}?precision=ns&db=x&precision=ns"),
            format!("m,gate=g1 force=1 {ns}"),
            Want::Field("precision"),
        ),
        lp_case(
            "LP: precision percent-encoded twice",
            &format!("{v2}?precision=s&%70recision=ms"),
            format!("m,gate=g1 force=1 {ns}"),
            Want::Field("precision"),
        ),
        lp_case(
            "LP: precision bad percent-encoding",
            &format!("{v2}?precision=%ZZ"),
            "m,gate=g1 force=1 1",
            Want::Field("precision"),
        ),
        lp_case(
            "LP: JSON sent to the line protocol route",
            v2,
            good("g1").to_string(),
            Want::Line(1),
        ),
        lp_case(
            "LP: 70 new gates, max_gates 64: the 65th named by its line",
            v2,
            (0..70)
                .map(|i| format!("m,gate=n{i} force=1 {ns}\n"))
                .collect::<String>(),
            Want::FieldLine("gate", 65),
        ),
        lp_case(
            "LP: gate tag twice",
            v2,
            format!("m,gate=g1,gate=g2 force=1 {ns}"),
            Want::LineColumn,
        ),
        lp_case(
            "LP: value field twice, the second NaN",
            v1,
            format!("m,gate=g1 force=1,force=NaN {ns}"),
            Want::LineColumn,
        ),
        lp_case(
            "LP: a 60 000-digit value",
            v2,
            format!("m,gate=g1 force={}x {ns}", "9".repeat(60_000)),
            Want::LineColumn,
        ),
        lp_case(
            "LP: a 60 000-character tag key",
            v2,
            format!("m,gate=g1,{} force=1 {ns}", "k".repeat(60_000)),
            Want::LineColumn,
        ),
        lp_case(
            "LP: 257 tags",
            v2,
            format!(
                "m,gate=g1{} force=1 {ns}",
                (0..256).map(|i| format!(",t{i}=v")).collect::<String>()
            ),
            Want::LineColumn,
        ),
        lp_case(
            "LP: a 20 000-character precision",
            &format!("{v2}?precision={}", "s".repeat(20_000)),
            format!("m,gate=g1 force=1 {ns}"),
            Want::Field("precision"),
        ),
    ]
}

fn http_cases() -> Vec<Case> {
    let raw = |class: &'static str, raw: &[u8], want: Want| Case {
        class,
        raw: raw.to_vec(),
        want,
    };
    let big_lines: Vec<u8> = "m,gate=g1 force=1\n".repeat(1 << 20).into_bytes();
    let bomb = gzip(&big_lines);
    let gz_good = gzip(good("g1").to_string().as_bytes());
    let with = |class: &'static str,
                method: &str,
                path: &str,
                headers: &[(&str, &str)],
                body: &[u8],
                want: Want| Case {
        class,
        raw: raw_request(method, path, headers, body),
        want,
    };
    let g = good("g1").to_string();
    // a gate id that is client input in the path: quoted as an excerpt (`ingest::EXCERPT_CHARS`)
    let long_view = format!("/api/v1/gates/{}", "a".repeat(60_000));
    let long_history = format!("{long_view}/history");
    vec![
        with("HTTP: unknown route", "GET", "/nope", &[], b"", Want::Status(404)),
        with("HTTP: path traversal", "GET", "/api/v1/../../etc/passwd", &[], b"", Want::Status(404)),
        with("HTTP: unknown gate view", "GET", "/api/v1/gates/%2e%2e", &[], b"", Want::Status(404)),
        with("HTTP: a 60 000-character gate id", "GET", &long_view, &[], b"", Want::StatusSays(404, "... (60000 bytes)`")),
        with("HTTP: a 60 000-character gate id's history", "GET", &long_history, &[], b"", Want::StatusSays(404, "... (60000 bytes)`")),
        with("HTTP: gate id not UTF-8 (%ff%fe)", "GET", "/api/v1/gates/%ff%fe", &[], b"", Want::Field("id")),
        with("HTTP: gate id not UTF-8 in the history (%ff)", "GET", "/api/v1/gates/%ff/history", &[], b"", Want::Field("id")),
        // it decoded to U+FFFD and ended the paging with an empty page
        with("HTTP: gate list cursor not a gate id (%ff)", "GET", "/api/v1/gates?after=%ff", &[], b"", Want::Field("after")),
        with("HTTP: GET on the ingestion route", "GET", "/api/v1/samples", &[], b"", Want::Status(405)),
        with("HTTP: PUT on /write", "PUT", "/write", &[], b"m,gate=g1 force=1", Want::Status(405)),
        with("HTTP: PATCH on a gate", "PATCH", "/api/v1/gates/g1", &[], b"", Want::Status(405)),
        with("HTTP: DELETE of a gate that does not exist", "DELETE", "/api/v1/gates/nobody", &[], b"", Want::StatusSays(404, "`nobody`")),
        with("HTTP: POST /healthz", "POST", "/healthz", &[], b"", Want::Status(405)),
        with("HTTP: extension method", "BREW", "/api/v1/samples", &[], b"", Want::Status(405)),
        with("HTTP: Content-Encoding br", "POST", "/api/v1/samples", &[("Content-Encoding", "br")], g.as_bytes(), Want::Status(415)),
        with("HTTP: Content-Encoding deflate", "POST", "/api/v2/write", &[("Content-Encoding", "deflate")], b"m,gate=g1 force=1", Want::Status(415)),
        with("HTTP: Content-Encoding zstd", "POST", "/write", &[("Content-Encoding", "zstd")], b"m,gate=g1 force=1", Want::Status(415)),
        with("HTTP: Content-Encoding gzip, gzip", "POST", "/api/v1/samples", &[("Content-Encoding", "gzip, gzip")], &gz_good, Want::Status(415)),
        with("HTTP: gzip header on a plain body", "POST", "/api/v1/samples", &[("Content-Encoding", "gzip")], g.as_bytes(), Want::Status(400)),
        with("HTTP: truncated gzip", "POST", "/api/v1/samples", &[("Content-Encoding", "gzip")], &gz_good[..gz_good.len() / 2], Want::Status(400)),
        with("HTTP: gzip bomb (18 MiB of lines) on /api/v2/write", "POST", "/api/v2/write", &[("Content-Encoding", "gzip")], &bomb, Want::Status(413)),
        with("HTTP: gzip bomb on /api/v1/samples", "POST", "/api/v1/samples", &[("Content-Encoding", "gzip")], &bomb, Want::Status(413)),
        with("HTTP: body over the limit", "POST", "/api/v1/samples", &[], &vec![b' '; 70_000], Want::Status(413)),
        with("HTTP: /query without q", "GET", "/query", &[], b"", Want::Field("q")),
        with("HTTP: /query SHOW DATABASES", "GET", "/query?q=SHOW%20DATABASES", &[], b"", Want::Field("q")),
        with("HTTP: /query empty q", "GET", "/query?q=", &[], b"", Want::Field("q")),
        raw("HTTP: garbage request line", b"GARBAGE\r\n\r\n", Want::Status(400)),
        raw("HTTP: non-numeric Content-Length", b"POST /api/v1/samples HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\nConnection: close\r\n\r\n", Want::Status(400)),
        raw("HTTP: two different Content-Lengths", b"POST /api/v1/samples HTTP/1.1\r\nHost: x\r\nContent-Length: 2\r\nContent-Length: 3\r\nConnection: close\r\n\r\n{}", Want::Status(400)),
        raw("HTTP: bad chunked encoding", b"POST /api/v1/samples HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\nzz\r\n{}\r\n0\r\n\r\n", Want::Status(400)),
        raw("HTTP: header without colon", b"GET /healthz HTTP/1.1\r\nHost: x\r\nnocolon\r\nConnection: close\r\n\r\n", Want::Status(400)),
        raw("HTTP: header name with a space", b"GET /healthz HTTP/1.1\r\nHost: x\r\nBad Name: 1\r\nConnection: close\r\n\r\n", Want::Status(400)),
        with("HTTP: chunked JSON that is bad", "POST", "/api/v1/samples", &[("Transfer-Encoding", "chunked")], b"3\r\n[1,\r\n1\r\n]\r\n0\r\n\r\n", Want::LineColumn),
        with("HTTP: Content-Type text/plain on JSON route (ignored, body bad)", "POST", "/api/v1/samples", &[("Content-Type", "text/plain")], b"{", Want::LineColumn),
        with("HTTP: NUL in a header value", "POST", "/api/v1/samples", &[("Authorization", "Bearer \u{0}")], b"{", Want::Status(400)),
        with("HTTP: Authorization without tokens configured (ignored)", "POST", "/api/v1/samples", &[("Authorization", "Bearer x")], b"{", Want::LineColumn),
        with("HTTP: query string on the JSON route (ignored, body bad)", "POST", "/api/v1/samples?precision=s&precision=ns", &[], b"[]", Want::Status(400)),
    ]
}

#[test]
fn malformed_requests_get_their_answer_and_the_daemon_keeps_serving() {
    let d = Daemon::start("");
    let mut cases = json_cases();
    cases.extend(lp_cases());
    cases.extend(http_cases());
    assert!(cases.len() >= 140, "{} cases", cases.len());
    println!("{} malformed requests", cases.len());
    check(&d, &cases);
    // nothing of the refused requests reached a window
    let gates = d.get_json("/api/v1/gates");
    assert_eq!(gates["gates"], json!([]), "{gates}");
}

/// TCP lines and the rejection reason each must be counted under.
fn tcp_cases() -> Vec<(&'static str, String, &'static str)> {
    let ns = now_ns();
    vec![
        ("TCP: garbage", "garbage".into(), "bad_line"),
        (
            "TCP: NaN",
            format!("m,gate=t1 force=NaN {ns}"),
            "non_finite",
        ),
        (
            "TCP: string value",
            format!("m,gate=t1 force=\"x\" {ns}"),
            "bad_line",
        ),
        (
            "TCP: missing gate tag",
            format!("m force=1 {ns}"),
            "bad_line",
        ),
        (
            "TCP: invalid gate id",
            format!("m,gate=a/b force=1 {ns}"),
            "bad_line",
        ),
        (
            "TCP: gate id `..`",
            format!("m,gate=.. force=1 {ns}"),
            "bad_line",
        ),
        (
            "TCP: timestamp beyond i64",
            "m,gate=t1 force=1 99999999999999999999".into(),
            "bad_line",
        ),
        (
            "TCP: far future",
            format!("m,gate=t1 force=1 {}", ns + 1_000_000_000_000_000),
            "too_far_in_future",
        ),
        (
            "TCP: year 2200 (the last years i64 nanoseconds reach)",
            "m,gate=t1 force=1 7258118400000000000".into(),
            "too_far_in_future",
        ),
        (
            "TCP: year 33658 (beyond i64 nanoseconds)",
            format!(
                "m,gate=t1 force=1 {}",
                1_000_000_000_000i128 * 1_000_000_000
            ),
            "bad_line",
        ),
        (
            "TCP: year 1971",
            "m,gate=t1 force=1 40000000000000000".into(),
            "too_old",
        ),
        ("TCP: timestamp 0", "m,gate=t1 force=1 0".into(), "too_old"),
        (
            "TCP: over-long line",
            format!("m,gate=t1 force=1,pad=\"{}\" {ns}", "x".repeat(70_000)),
            "bad_line",
        ),
        (
            "TCP: carriage return and ANSI escape",
            "m,gate=t1 force=1\r\x1b[2KFAKE".into(),
            "bad_line",
        ),
        (
            "TCP: unicode gate",
            format!("m,gate=gäte force=1 {ns}"),
            "bad_line",
        ),
    ]
}

#[test]
fn malformed_tcp_lines_are_counted_and_the_connection_kept() {
    let d = Daemon::start("");
    let mut s = TcpStream::connect(d.tcp).unwrap();
    let mut ns = now_ns();
    let mut good_lines = 0u64;
    for (class, line, reason) in tcp_cases() {
        let before = d.rejected(reason);
        s.write_all(format!("{line}\n").as_bytes()).unwrap();
        // a good line after each bad one, on the same connection
        ns += 10_000_000;
        s.write_all(format!("m,gate=t1 force=1 {ns}\n").as_bytes())
            .unwrap();
        good_lines += 1;
        let deadline = Instant::now() + Duration::from_secs(20);
        while d.rejected(reason) < before + 1.0 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(d.rejected(reason), before + 1.0, "{class}: reason {reason}");
        assert!(d.healthy(), "/healthz failed after {class}");
    }
    let deadline = Instant::now() + Duration::from_secs(20);
    let total = || d.get_json("/api/v1/gates/t1")["window"]["samples_total"].as_u64();
    while total() != Some(good_lines) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(total(), Some(good_lines), "every good line ingested");
    assert_eq!(d.rejected("out_of_order"), 0.0, "no good line dropped");
    assert!(!d.stderr().contains("panicked"), "{}", d.stderr());
}

/// Raw TCP lines come one sample at a time, so no request says its rate: a source at 125 Hz on a
/// 100 Hz gate (every spacing 0.8 of a period, within the jitter tolerated) used to fill windows
/// read as 100 Hz and identified as trusted but wrong. The window's own rate check refuses them
/// (counted, logged), and the first window identified after the source is fixed lies after the
/// fix.
#[test]
fn tcp_samples_at_another_rate_are_not_identified() {
    let d = Daemon::start("");
    let mut s = TcpStream::connect(d.tcp).unwrap();
    let ns0 = now_ns() - 20_000_000_000;
    let line = |ns: i128| format!("m,gate=r1 force={} {ns}\n", (ns as f64 * 6e-8).sin());
    let wrong: String = (0..400).map(|i| line(ns0 + i * 8_000_000)).collect();
    s.write_all(wrong.as_bytes()).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while d.rejected("rate_mismatch") < 1.0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        d.rejected("rate_mismatch") >= 100.0,
        "the stretch is counted"
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    while !d.stderr().contains("another sample rate") && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(d.stderr().contains("another sample rate"), "{}", d.stderr());
    // the refusal is logged as soon as a window of them is read, while the connection's later
    // lines may still be on their way in (CI's integration binary runs other tests beside it)
    let deadline = Instant::now() + Duration::from_secs(20);
    let taken = || d.get_json("/api/v1/gates/r1")["window"]["samples_total"].as_u64();
    while taken() != Some(400) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let view = d.get_json("/api/v1/gates/r1");
    assert_eq!(
        view["window"]["samples_total"], 400,
        "the samples were taken"
    );
    assert!(
        view["analysed_until"].is_null(),
        "no window at 125 Hz identified: {view}"
    );

    // the source is fixed: 100 Hz from 10 ms after its last sample
    let switch = ns0 + 399 * 8_000_000 + 10_000_000;
    let right: String = (0..300).map(|i| line(switch + i * 10_000_000)).collect();
    s.write_all(right.as_bytes()).unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let analysed = || d.get_json("/api/v1/gates/r1")["analysed_until"].as_f64();
    while analysed().is_none() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    let until = analysed().expect("a window identified once the rate is right");
    // its window (1 s) lies after the switch: its samples imply 100 Hz within 1 %, so at most a
    // few (5 of 100) are 125 Hz samples from before it
    assert!(
        until >= switch as f64 / 1e9 + 0.9,
        "window ending {until} reaches before the switch at {}",
        switch as f64 / 1e9
    );
    assert!(!d.stderr().contains("panicked"));
}

/// Issue 12 point 5: one sample 1e6 s ahead used to be answered 204, restart the window there,
/// and make the next 1,999 good samples "out of order" (dropped, still 204).
#[test]
fn a_far_future_sample_is_refused_and_does_not_wipe_the_window() {
    let d = Daemon::start("");
    let t0 = now() - 30.0;
    let batch = |start: f64, n: usize| {
        json!({"gate": "w1", "start": start, "rate_hz": 100, "values": vec![1.0; n]}).to_string()
    };
    let r = d.post("/api/v1/samples", &[], batch(t0, 50).as_bytes());
    assert_eq!(r.status, 204);
    let r = d.post("/api/v1/samples", &[], batch(t0 + 1e6, 1).as_bytes());
    assert_eq!(r.status, 400);
    assert_eq!(
        (r.json()["field"].clone(), r.json()["index"].clone()),
        (json!("start"), json!(0))
    );
    assert!(r.json()["error"]
        .as_str()
        .unwrap()
        .contains("max_future_seconds"));
    let r = d.post("/api/v1/samples", &[], batch(t0 + 0.5, 50).as_bytes());
    assert_eq!(r.status, 204, "the good samples after it are all taken");
    let w = &d.get_json("/api/v1/gates/w1")["window"];
    assert_eq!(w["samples_total"], 100);
    assert_eq!(w["samples"], 100);
    assert!((w["last_sample_time"].as_f64().unwrap() - (t0 + 0.99)).abs() < 1e-6);
    assert_eq!(d.rejected("too_far_in_future"), 1.0);
    assert_eq!(d.rejected("out_of_order"), 0.0);

    // the same over the raw TCP listener: the line is counted and logged, the window is kept
    let mut s = TcpStream::connect(d.tcp).unwrap();
    let ns0 = ((t0 + 1.0) * 1e9) as i128;
    let mut text = String::new();
    for i in 0..50 {
        text.push_str(&format!("m,gate=w1 force=1 {}\n", ns0 + i * 10_000_000));
    }
    text.push_str(&format!(
        "m,gate=w1 force=1 {}\n",
        ns0 + 1_000_000_000_000_000
    ));
    for i in 50..100 {
        text.push_str(&format!("m,gate=w1 force=1 {}\n", ns0 + i * 10_000_000));
    }
    s.write_all(text.as_bytes()).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    let total = || d.get_json("/api/v1/gates/w1")["window"]["samples_total"].as_u64();
    while total() != Some(200) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(total(), Some(200));
    assert_eq!(d.rejected("too_far_in_future"), 2.0);
    assert_eq!(d.rejected("out_of_order"), 0.0);
    let deadline = Instant::now() + Duration::from_secs(20);
    while !d.stderr().contains("max_future_seconds") && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(d.stderr().contains("max_future_seconds"), "logged");
    assert!(!d.stderr().contains("panicked"));
}

/// Issue 12 point 5: samples dropped inside an accepted request are said so, never a bare 204.
#[test]
fn dropped_samples_are_reported_not_answered_204() {
    let d = Daemon::start("");
    let t0 = now() - 10.0;
    let batch = |start: f64| {
        json!({"gate": "d1", "start": start, "rate_hz": 100, "values": [1.0, 2.0, 3.0]}).to_string()
    };
    assert_eq!(
        d.post("/api/v1/samples", &[], batch(t0).as_bytes()).status,
        204
    );
    // the same three again: duplicates
    let r = d.post("/api/v1/samples", &[], batch(t0).as_bytes());
    assert_eq!(r.status, 200);
    assert_eq!(r.json()["accepted"], 0);
    assert_eq!(r.json()["dropped"]["duplicate"], 1);
    assert_eq!(r.json()["dropped"]["out_of_order"], 2);
    // the Influx routes keep 204 (Telegraf needs it) and say so in a header
    let ns = (t0 * 1e9) as i128;
    let r = d.post(
        "/api/v2/write",
        &[],
        format!("m,gate=d1 force=1 {ns}").as_bytes(),
    );
    assert_eq!(r.status, 204);
    assert_eq!(
        r.header("x-gatewatch-dropped"),
        Some("duplicate=0, out_of_order=1")
    );
}

// ---------------------------------------------------------------------------------------------
// configurations

/// Runs `gatewatch ARGS` with a deadline; (exit code, stderr). The daemon must exit by itself.
fn run(args: &[&str], file: &Path) -> (Option<i32>, String) {
    let mut child = Command::new(BIN)
        .args(args)
        .arg(file)
        .env_remove("RUST_LOG")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            child
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut err)
                .unwrap();
            return (status.code(), err);
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            return (None, "still running after 30 s".into());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Malformed configurations: the text, and what the message must contain (key, then the line
/// when the key is in the file).
fn bad_configs() -> Vec<(&'static str, String, &'static str, Option<usize>)> {
    let c = |name, text: &str, key, line| (name, text.to_string(), key, line);
    vec![
        c(
            "TOML syntax: unclosed table",
            "[server]\nmax_gates = 3\n[ingest\n",
            "line 3",
            None,
        ),
        c(
            "TOML syntax: missing value",
            "[server]\nmax_gates =\n",
            "line 2",
            None,
        ),
        c(
            // the error is at the end of the text, past its final newline: the last line is named
            "TOML syntax: unclosed multi-line string at the end",
            "[server]\nmax_gates = 3\n\"\"\"\n",
            "line 3",
            None,
        ),
        c(
            "TOML syntax: bare string",
            "[server]\nlisten = 127.0.0.1\n",
            "line 2",
            None,
        ),
        c(
            "TOML duplicate key",
            "[server]\nmax_gates = 3\nmax_gates = 4\n",
            "server.max_gates",
            Some(3),
        ),
        c(
            "TOML duplicate table",
            "[server]\n[log]\n[server]\n",
            "line 3",
            None,
        ),
        c(
            "wrong type under defaults",
            "[defaults]\nrate_hz = \"fast\"\n",
            "defaults.rate_hz",
            Some(2),
        ),
        c(
            "wrong type under defaults.alert",
            "[defaults.alert]\nfor_windows = \"two\"\n",
            "defaults.alert.for_windows",
            Some(2),
        ),
        c(
            "wrong type: defaults a number",
            "defaults = 5\n",
            "defaults",
            None,
        ),
        c(
            "bad tcp_precision",
            "[ingest]\ntcp_precision = \"xs\"\n",
            "ingest.tcp_precision",
            Some(2),
        ),
        c(
            "tcp_precision a number",
            "[ingest]\ntcp_precision = 9\n",
            "ingest.tcp_precision",
            Some(2),
        ),
        c(
            "unknown key in server",
            "[server]\nlisten_addr = \"x\"\n",
            "server.listen_addr",
            Some(2),
        ),
        c("unknown section", "[bogus]\n", "bogus", Some(1)),
        c(
            "unknown key in a gate",
            "[gates.g1]\nrte_hz = 1.0\n",
            "gates.g1.rte_hz",
            Some(2),
        ),
        c(
            "bad listen address",
            "[server]\nlisten = \"nope\"\n",
            "server.listen",
            Some(2),
        ),
        c(
            "bad tcp_listen address",
            "[server]\ntcp_listen = \"host\"\n",
            "server.tcp_listen",
            Some(2),
        ),
        c(
            "short token",
            "[server]\nauth_tokens = [\"short\"]\n",
            "server.auth_tokens",
            Some(2),
        ),
        c(
            "max_gates 0",
            "[server]\nmax_gates = 0\n",
            "server.max_gates",
            Some(2),
        ),
        c(
            "negative usize",
            "[server]\nmax_gates = -1\n",
            "server.max_gates",
            Some(2),
        ),
        c(
            "request_timeout_seconds 1e300",
            "[server]\nrequest_timeout_seconds = 1e300\n",
            "server.request_timeout_seconds",
            Some(2),
        ),
        c(
            "shutdown_grace_seconds 1e300",
            "[server]\nshutdown_grace_seconds = 1e300\n",
            "server.shutdown_grace_seconds",
            Some(2),
        ),
        c(
            "shutdown_grace_seconds nan",
            "[server]\nshutdown_grace_seconds = nan\n",
            "server.shutdown_grace_seconds",
            Some(2),
        ),
        c(
            "notify timeout 1e300",
            "[notify]\ntimeout_seconds = 1e300\n",
            "notify",
            None,
        ),
        c(
            "stale_after_seconds 1e300",
            "[defaults.alert]\nstale_after_seconds = 1e300\n",
            "defaults.alert.stale_after_seconds",
            Some(2),
        ),
        c(
            "model unbalanced",
            "[defaults]\nmodel = \"c1*ydd + ((c2*yd\"\n",
            "defaults.model",
            Some(2),
        ),
        c(
            "model ydd^2",
            "[defaults]\nmodel = \"ydd^2 + c1*y = 0\"\n",
            "defaults.model",
            Some(2),
        ),
        c(
            "model unknown symbol",
            "[defaults]\nmodel = \"c1*ydd + c2*yd + q*y = 0\"\n",
            "defaults.model",
            Some(2),
        ),
        c(
            "model without ydd",
            "[defaults]\nmodel = \"c1*yd + c2*y = 0\"\n",
            "defaults.model",
            Some(2),
        ),
        c(
            "model of one gate",
            "[gates.g1]\nmodel = \"c1*ydd + \"\n",
            "gates.g1.model",
            Some(2),
        ),
        c(
            "rate_hz 0",
            "[gates.g1]\nrate_hz = 0.0\n",
            "gates.g1.rate_hz",
            Some(2),
        ),
        c(
            "window too small",
            "[defaults]\nwindow_seconds = 0.01\n",
            "defaults.window_seconds",
            Some(2),
        ),
        c(
            "max_future_seconds negative",
            "[defaults]\nmax_future_seconds = -1.0\n",
            "defaults.max_future_seconds",
            Some(2),
        ),
        c(
            "bad gate id",
            "[gates.\"bad id!\"]\n",
            "gates.bad id!",
            None,
        ),
        c(
            "gate id `..`",
            "[gates.\"..\"]\n",
            "gates...: gate id must be",
            None,
        ),
        c(
            "gate id `.`",
            "[gates.\".\"]\nrate_hz = 100.0\n",
            "gates..: gate id must be",
            None,
        ),
        c(
            "fire_below above clear_above",
            "[defaults.alert]\nfire_below = 0.1\nclear_above = 0.0\n",
            "defaults.alert.clear_above",
            Some(3),
        ),
        c(
            "webhook URL not http",
            "[[notify.webhooks]]\nurl = \"ftp://x\"\n",
            "notify",
            None,
        ),
        c(
            "log format xml",
            "[log]\nformat = \"xml\"\n",
            "log.format",
            Some(2),
        ),
        c(
            "listen an integer",
            "[server]\nlisten = 5\n",
            "server.listen",
            Some(2),
        ),
        c(
            "pooling min_cycles negative",
            "[defaults.pooling]\nmin_cycles = -1.0\n",
            "defaults.pooling.min_cycles",
            Some(2),
        ),
        c(
            "polish_rtol 1",
            "[gates.g1]\npolish_rtol = 1.0\n",
            "gates.g1.polish_rtol",
            Some(2),
        ),
        c(
            "polish_solver unknown",
            "[defaults]\npolish_solver = \"euler\"\n",
            "defaults.polish_solver",
            Some(2),
        ),
        c(
            "pooling unknown key",
            "[defaults.pooling]\nmin_cycle = 100.0\n",
            "defaults.pooling.min_cycle",
            Some(2),
        ),
        // a param the model refuses is its own key's fault, at its line (it was `model`, at
        // the table's header or line 1)
        c(
            "reserved param name under [defaults]",
            "[server]\nmax_gates = 4\n\n[defaults]\nrate_hz = 200.0\nparams = { yd = 2.0 }\n",
            "defaults.params.yd: param name 'yd' is reserved",
            Some(6),
        ),
        c(
            "reserved param name in a gate",
            "[gates.g1]\nrate_hz = 100.0\nparams = { c1 = 2.0 }\n",
            "gates.g1.params.c1: param name 'c1' is reserved",
            Some(3),
        ),
        c(
            "param name that is no name",
            "[defaults]\nparams = { \"a b\" = 2.0 }\n",
            "defaults.params.a b: invalid param name",
            Some(2),
        ),
        // a value field no line can carry: every write was refused once the daemon ran
        c(
            "empty value field",
            "[ingest]\nvalue_fields = [\"force\", \"\"]\n",
            "ingest.value_fields[1]: must not be empty",
            Some(2),
        ),
        c(
            "value field ending with a backslash",
            "[ingest]\nvalue_fields = [\n  \"force\\\\\",\n]\n",
            "ingest.value_fields[0]: \"force\\\\\" ends with a backslash",
            Some(3),
        ),
    ]
}

#[test]
fn malformed_configs_fail_check_config_and_serve_alike_naming_key_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let configs = bad_configs();
    assert!(configs.len() >= 32, "{}", configs.len());
    let mut failures = Vec::new();
    for (i, (name, text, key, line)) in configs.iter().enumerate() {
        let file = dir.path().join(format!("bad{i}.toml"));
        // the daemon must not start: its listeners would be on these (free) ports otherwise
        let text = format!("{text}\n");
        std::fs::write(&file, &text).unwrap();
        let (code, check) = run(&["check-config"], &file);
        let (serve_code, serve) = run(&["serve", "--config"], &file);
        let mut why = Vec::new();
        if code != Some(2) {
            why.push(format!("check-config exit {code:?}"));
        }
        if serve_code != Some(2) {
            why.push(format!("serve exit {serve_code:?}"));
        }
        if !check.contains(key) {
            why.push(format!("check-config does not name `{key}`"));
        }
        if let Some(l) = line {
            if !check.contains(&format!("line {l}")) {
                why.push(format!("check-config does not name line {l}"));
            }
        }
        // the same message from both (after their prefixes: the file name, `gatewatch:`)
        let msg = |s: &str| {
            s.lines()
                .last()
                .and_then(|l| l.split_once(": "))
                .map(|(_, m)| m.to_string())
                .unwrap_or_default()
        };
        if msg(&check) != msg(&serve) {
            why.push(format!("messages differ: {check:?} vs {serve:?}"));
        }
        if check.contains("panicked") || serve.contains("panicked") {
            why.push("panicked".into());
        }
        if !why.is_empty() {
            failures.push(format!("{name}: {} ({})", why.join("; "), check.trim()));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn the_shipped_config_passes_check_config() {
    // the counterpart of the refusals above (tests/deploy.rs serves with it)
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/gatewatch.toml");
    let (code, err) = run(&["check-config"], &file);
    assert_eq!(code, Some(0), "{err}");
}

/// A configuration file that is not UTF-8 (a Latin-1 `°` typed in an editor) is named with the
/// line and column of the first bad byte: the message was "stream did not contain valid UTF-8".
#[test]
fn a_config_file_not_in_utf8_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("latin1.toml");
    std::fs::write(&file, b"[server]\nlisten = \"0.0.0.0:9464\xb0\"\n").unwrap();
    for args in [&["check-config"][..], &["serve", "--config"][..]] {
        let (code, err) = run(args, &file);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(
            err.contains("latin1.toml: line 2, column 23: not valid UTF-8 (byte 0xb0)"),
            "{args:?}: {err}"
        );
    }
}
