//! gatewatch's hand-written line-protocol parser and the maintained `influxdb-line-protocol`
//! crate agree on the (gate, value, time) of generated lines, escapes and integer fields
//! included, so that `benches/line_protocol.rs` compares the same work.

use crate::lp_common;

use gatewatch::service::config::Precision;
use gatewatch::service::ingest::line_protocol::{
    parse, parse_line, to_batches, FieldValue, Mapping,
};
use lp_common::{crate_to_batches, crate_whole_body, numeric, telegraf_body};

/// A small deterministic generator (xorshift64*): the test needs no seedable crate.
struct Gen(u64);

impl Gen {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// One line whose gate tag value may hold `\ `, `\,` or `\=`, with extra escaped tags, and a
/// `force` field that is a float, an integer (`i`), an unsigned (`u`) or a bare integer, not
/// always first; returns the line and the (gate, value, time) it means.
fn generated_line(g: &mut Gen, i: usize) -> (String, (String, f64, i64)) {
    let (gate_raw, gate) = match g.below(5) {
        0 => (format!("g\\ {i}"), format!("g {i}")),
        1 => (format!("g\\,{i}"), format!("g,{i}")),
        2 => (format!("a\\=b{i}"), format!("a=b{i}")),
        3 => (format!("x\\ y\\,z\\={i}"), format!("x y,z={i}")),
        _ => (format!("g{:02}", i % 100), format!("g{:02}", i % 100)),
    };
    let magnitude = g.below(2_000_000) as i64 - 1_000_000;
    let (value_raw, value) = match g.below(4) {
        0 => (
            format!("{}.{:03}", magnitude / 1000, (magnitude % 1000).abs()),
            format!("{}.{:03}", magnitude / 1000, (magnitude % 1000).abs())
                .parse::<f64>()
                .unwrap(),
        ),
        1 => (format!("{magnitude}i"), magnitude as f64),
        2 => (
            format!("{}u", magnitude.unsigned_abs()),
            magnitude.unsigned_abs() as f64,
        ),
        _ => (format!("{magnitude}"), magnitude as f64),
    };
    let ts = lp_common::T0_NS + (i as i64) * 5_000_000 + g.below(1000) as i64;
    let extra_tags = if g.below(2) == 0 {
        ",site=north\\ bank,sensor=a\\=b\\,c"
    } else {
        ""
    };
    let line = if g.below(2) == 0 {
        format!("m\\ x,gate={gate_raw}{extra_tags} force={value_raw} {ts}")
    } else {
        format!("gate_force{extra_tags},gate={gate_raw} temp=21.5,n=3i,force={value_raw},ok=t,s=\"a b\" {ts}")
    };
    (line, (gate, value, ts))
}

fn gatewatch_triple(text: &str) -> (String, f64, i64) {
    let l = parse_line(text, 1).unwrap().unwrap();
    let gate = l.tags.iter().find(|(k, _)| k == "gate").unwrap().1.clone();
    let v = match &l.fields.iter().find(|(k, _)| k == "force").unwrap().1 {
        FieldValue::Float(x) => *x,
        FieldValue::Int(i) => *i as f64,
        FieldValue::UInt(u) => *u as f64,
        other => panic!("not numeric: {other:?}"),
    };
    (gate, v, l.timestamp.unwrap())
}

fn crate_triple(text: &str) -> (String, f64, i64) {
    let mut it = influxdb_line_protocol::parse_lines(text);
    let l = it.next().unwrap().unwrap();
    assert!(it.next().is_none());
    let gate = l.tag_value("gate").unwrap().as_str().to_string();
    let v = numeric(l.field_value("force").unwrap()).unwrap();
    (gate, v, l.timestamp.unwrap())
}

#[test]
fn both_parsers_agree_on_generated_lines() {
    let mut g = Gen(0x9E37_79B9_7F4A_7C15);
    for i in 0..400 {
        let (line, (gate, value, ts)) = generated_line(&mut g, i);
        let ours = gatewatch_triple(&line);
        let theirs = crate_triple(&line);
        // Both must read the decimal text to the same (correctly rounded) f64, so bits compare.
        assert_eq!(ours.0, gate, "gatewatch gate of {line:?}");
        assert_eq!(theirs.0, gate, "crate gate of {line:?}");
        assert_eq!(
            ours.1.to_bits(),
            value.to_bits(),
            "gatewatch value of {line:?}"
        );
        assert_eq!(
            theirs.1.to_bits(),
            value.to_bits(),
            "crate value of {line:?}"
        );
        assert_eq!((ours.2, theirs.2), (ts, ts), "time of {line:?}");
    }
}

fn mapping(fields: &[String]) -> Mapping<'_> {
    Mapping {
        gate_tag: "gate",
        value_fields: fields,
        precision: Precision::Ns,
        now: 0.0,
        max_gates: usize::MAX,
    }
}

#[test]
fn both_batchings_agree_on_the_bench_workload() {
    let fields = vec!["force".to_string()];
    let m = mapping(&fields);
    for extra in [false, true] {
        let body = telegraf_body(1000, 4, 200.0, 17, extra);
        let ours = to_batches(&parse(&body).unwrap(), &m).unwrap();
        let theirs = crate_to_batches(&body, &m).unwrap();
        assert_eq!(ours.len(), 4);
        assert_eq!(ours, theirs, "extra = {extra}");
        assert_eq!(ours[0].samples.len(), 250);
        assert_eq!(ours[1].lines.as_ref().unwrap()[..2], [2, 6]);
        let whole = crate_whole_body(&body, &m).unwrap();
        assert_eq!(whole.len(), 1000);
        let flat: Vec<(String, f64, f64)> = (0..1000)
            .map(|i| {
                let b = &ours[i % 4];
                let (t, v) = b.samples[i / 4];
                (b.gate.clone(), v, t)
            })
            .collect();
        assert_eq!(whole, flat, "extra = {extra}");
    }
}

#[test]
fn both_reject_the_same_bad_bodies() {
    let fields = vec!["force".to_string()];
    let m = mapping(&fields);
    for body in [
        "m,gate=g1 force=1 1\nm,gate=g1 force=abc 2\n",
        "m,gate=g1 force=\"text\" 1\n",
        "m,site=x force=1 1\n",
        "m,gate=g\\ 1 force=1 1\n",
        "m,gate=g1 temp=1 1\n",
        "m,gate=g1 force=1 notatime\n",
        "m,gate=g1\n",
        "\n# only a comment\n",
    ] {
        let ours = parse(body)
            .map_err(|e| e.to_string())
            .and_then(|l| to_batches(&l, &m).map_err(|e| e.error));
        let theirs = crate_to_batches(body, &m);
        assert!(ours.is_err(), "gatewatch accepted {body:?}");
        assert!(theirs.is_err(), "crate accepted {body:?}");
    }
}
