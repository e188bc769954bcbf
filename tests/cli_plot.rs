//! `gatewatch identify --plot` and `gatewatch stability-map` through the binary.

use std::path::Path;
use std::process::Output;

use crate::cli_common;
use cli_common::{gw, text};

fn stderr(o: &Output) -> String {
    text(&o.stderr)
}

/// A decaying oscillation `ydd + 0.2*yd + y = 0`, `y(0) = 1`, `yd(0) = -0.1`, as CSV.
fn write_series(path: &Path) {
    let mut text = String::from("t,y\n");
    let w = (1.0f64 - 0.01).sqrt();
    for i in 0..200 {
        let t = i as f64 * 0.1;
        text.push_str(&format!("{t},{}\n", (-0.1 * t).exp() * (w * t).cos()));
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn identify_writes_the_pictures_into_the_plot_dir() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d.csv");
    write_series(&data);
    let out_dir = dir.path().join("pictures/new");
    let identify = |extra: &[&str]| {
        let model = "ydd + c1*yd + c2*y = 0";
        let (data, out_dir) = (data.to_str().unwrap(), out_dir.to_str().unwrap());
        let args = [
            "identify",
            "--input",
            data,
            "--model",
            model,
            "--generations",
            "30",
        ];
        let o = gw(&[&args[..], &["--plot", out_dir], extra].concat());
        assert!(o.status.success(), "{}", stderr(&o));
    };
    identify(&["--plot-format", "png"]);
    for name in ["fit.png", "phase.png", "convergence.png"] {
        let bytes = std::fs::read(out_dir.join(name)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{name}");
    }
    identify(&[]);
    let svg = std::fs::read_to_string(out_dir.join("fit.svg")).unwrap();
    assert!(svg.contains("identified model"));
}

#[test]
fn stability_map_writes_csv_and_picture() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("map.csv");
    let svg = dir.path().join("map.svg");
    let args = [
        "stability-map",
        "--model",
        "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0",
        "--range",
        "c1=-3:3",
        "--range",
        "c2=-3:3",
        "--fix",
        "c3=1",
        "--samples",
        "300",
        "--seed",
        "5",
        "--output",
        csv.to_str().unwrap(),
        "--plot",
        svg.to_str().unwrap(),
    ];
    let o = gw(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("c1,c2,stable"));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 300);
    // y0 = 0.1: the linear damping c1 decides away from c1 = 0.
    for row in &rows {
        let f: Vec<&str> = row.split(',').collect();
        let c1: f64 = f[0].parse().unwrap();
        if c1.abs() > 0.2 {
            assert_eq!(f[2] == "1", c1 > 0.0, "{row}");
        }
    }
    assert!(std::fs::read_to_string(&svg).unwrap().contains("stable ("));
    // Same seed, same map; to stdout without --output.
    let o = gw(&args[..args.len() - 4]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(String::from_utf8(o.stdout).unwrap(), text);
}

#[test]
fn stability_map_bad_inputs_exit_2_naming_the_option() {
    let base = [
        "stability-map",
        "--model",
        "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0",
    ];
    let cases: &[(&[&str], &str)] = &[
        (
            &["--range", "c1=-3..3", "--range", "c2=-3:3", "--fix", "c3=1"],
            "--range",
        ),
        (
            &["--range", "c1=3:-3", "--range", "c2=-3:3", "--fix", "c3=1"],
            "minimum",
        ),
        (
            &["--range", "c1=-3:3", "--range", "c5=-3:3", "--fix", "c3=1"],
            "c5",
        ),
        (&["--range", "c1=-3:3", "--range", "c2=-3:3"], "--fix: c3"),
        (
            &["--range", "c1=-3:3", "--range", "c2=-3:3", "--fix", "c9=1"],
            "--fix",
        ),
        (&["--range", "c1=-3:3"], "exactly two"),
        (
            &[
                "--range",
                "c1=-3:3",
                "--range",
                "c2=-3:3",
                "--fix",
                "c3=1",
                "--samples",
                "0",
            ],
            "--samples",
        ),
        (
            &[
                "--range", "c1=-3:3", "--range", "c2=-3:3", "--fix", "c3=1", "--plot", "m.gif",
            ],
            "--plot",
        ),
    ];
    for (extra, needle) in cases {
        let mut args: Vec<&str> = base.to_vec();
        args.extend_from_slice(extra);
        let o = gw(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{extra:?}: {e}");
        assert!(e.contains(needle), "{extra:?}: {e}");
    }
    let o = gw(&["stability-map", "--model", "ydd + = 0", "--range", "c1=0:1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--model"));
}

// ------------------------------------------------------------------------------------------------
// What the pictures of `identify --plot` show, read back from the SVG.

/// `(y, text)` of every `<text>` element (plotters writes the content on its own line).
fn texts(svg: &str) -> Vec<(f64, String)> {
    svg.split("<text ")
        .skip(1)
        .filter_map(|el| {
            let y = attr(el, "y")?;
            let body = el.split_once('>')?.1.split("</text>").next()?;
            Some((y, body.trim().to_string()))
        })
        .collect()
}

fn attr(el: &str, name: &str) -> Option<f64> {
    let el = format!(" {el}");
    let start = el.find(&format!(" {name}=\""))? + name.len() + 3;
    el[start..].split('"').next()?.parse().ok()
}

/// `(cx, cy, r)` of the circles filled with `fill`.
fn circles(svg: &str, fill: &str) -> Vec<(f64, f64, f64)> {
    svg.split("<circle ")
        .skip(1)
        .filter(|el| el.contains(&format!("fill=\"{fill}\"")))
        .filter_map(|el| Some((attr(el, "cx")?, attr(el, "cy")?, attr(el, "r")?)))
        .collect()
}

/// The points of the polylines stroked with `stroke` at `width`.
fn polylines(svg: &str, stroke: &str, width: u32) -> Vec<Vec<(f64, f64)>> {
    svg.split("<polyline ")
        .skip(1)
        .filter(|el| el.contains(&format!("stroke=\"{stroke}\" stroke-width=\"{width}\"")))
        .filter_map(|el| {
            let start = el.find("points=\"")? + 8;
            let pts = el[start..].split('"').next()?;
            Some(
                pts.split_whitespace()
                    .filter_map(|p| {
                        let (x, y) = p.split_once(',')?;
                        Some((x.parse().ok()?, y.parse().ok()?))
                    })
                    .collect(),
            )
        })
        .collect()
}

const BLUE: &str = "#0072B2";
const GREEN: &str = "#009E73";
const GREY: &str = "#5A5A5A";

fn train_mae(stdout: &[u8]) -> f64 {
    let v: serde_json::Value = serde_json::from_slice(stdout).expect("one JSON object");
    v["train_mae"].as_f64().expect("train_mae")
}

/// The value at screen height `y` on the log axis whose tick labels (`1e-3`, `2e0`, ...) are
/// in `svg`.
fn log_axis_value(svg: &str, y: f64) -> f64 {
    let ticks: Vec<(f64, f64)> = texts(svg)
        .into_iter()
        .filter_map(|(py, t)| {
            let (m, e) = t.split_once('e')?;
            let (m, e): (f64, i32) = (m.parse().ok()?, e.parse().ok()?);
            Some((py, (m * 10f64.powi(e)).log10()))
        })
        .collect();
    let (a, b) = (
        ticks
            .iter()
            .cloned()
            .fold((0.0, f64::INFINITY), |m, t| if t.1 < m.1 { t } else { m }),
        ticks.iter().cloned().fold(
            (0.0, f64::NEG_INFINITY),
            |m, t| if t.1 > m.1 { t } else { m },
        ),
    );
    assert!(b.1 > a.1, "too few tick labels: {ticks:?}");
    10f64.powf(a.1 + (y - a.0) / (b.0 - a.0) * (b.1 - a.1))
}

fn identify_with_plots(extra: &[&str], out_dir: &Path) -> Output {
    let mut args = vec!["identify"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--json", "--plot", out_dir.to_str().unwrap()]);
    let o = gw(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    o
}

#[test]
fn the_convergence_curve_ends_at_the_reported_training_error() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d.csv");
    write_series(&data);
    let out_dir = dir.path().join("p");
    let o = identify_with_plots(
        &[
            "--input",
            data.to_str().unwrap(),
            "--model",
            "ydd + c1*yd + c2*y = 0",
            "--generations",
            "30",
        ],
        &out_dir,
    );
    let mae = train_mae(&o.stdout);
    let svg = std::fs::read_to_string(out_dir.join("convergence.svg")).unwrap();
    // The legend prints the final value, the very number the run reports...
    let label = format!("after the polish: {mae:.3e}");
    assert!(
        texts(&svg).iter().any(|(_, t)| t.starts_with(&label)),
        "{label}"
    );
    // ...and the curve's last point is drawn at it, after the last generation. (It need not be
    // below the DE's best: the polish reports its cost at a tighter solver tolerance.)
    // (The legend's sample is the circle of radius 5.)
    let marker: Vec<_> = circles(&svg, GREEN)
        .into_iter()
        .filter(|c| c.2 > 5.5)
        .collect();
    assert_eq!(marker.len(), 1, "{marker:?}");
    let drawn = log_axis_value(&svg, marker[0].1);
    assert!(
        (drawn.log10() - mae.log10()).abs() < 0.05,
        "marker at {drawn:e}, training error {mae:e}"
    );
    let de = polylines(&svg, BLUE, 2);
    let de_last = de.last().and_then(|l| l.last()).expect("the DE curve");
    assert!(
        marker[0].1 >= de_last.1,
        "the polish did not lower the cost?"
    );
    assert!(
        marker[0].0 > de_last.0,
        "the polished point comes after the last generation"
    );

    // The phase plane shows the data (one dot per sample) beside the model's trajectory.
    let phase = std::fs::read_to_string(out_dir.join("phase.svg")).unwrap();
    let labels: Vec<String> = texts(&phase).into_iter().map(|t| t.1).collect();
    assert!(labels.iter().any(|t| t.starts_with("data:")), "{labels:?}");
    assert!(labels.iter().any(|t| t == "identified model"), "{labels:?}");
    // 200 samples, one legend dot.
    assert_eq!(circles(&phase, GREY).len(), 201);
    let model: usize = polylines(&phase, BLUE, 2).iter().map(Vec::len).sum();
    assert!(model > 200, "the model curve has {model} points");
}

#[test]
fn force_pictures_show_the_whole_force_a_zoom_with_its_residual_and_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("gate.csv");
    let o = gw(&[
        "bench",
        "generate",
        "--case",
        "gate_example",
        "--output",
        data.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let samples = std::fs::read_to_string(&data).unwrap().lines().count() - 1;
    let out_dir = dir.path().join("p");
    identify_with_plots(
        &[
            "--input",
            data.to_str().unwrap(),
            "--signal",
            "force",
            "--stiffness",
            "81360",
            "--model",
            "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0",
            "--population",
            "20",
            "--generations",
            "40",
        ],
        &out_dir,
    );
    let read = |name: &str| std::fs::read_to_string(out_dir.join(name)).unwrap();

    // The damping-amplitude curve (issue 8): zeta_eq in percent against the force amplitude,
    // a line of the report's points.
    let svg = read("damping.svg");
    let labels: Vec<String> = texts(&svg).into_iter().map(|t| t.1).collect();
    assert!(
        labels.iter().any(|t| t == "amplitude A [N]")
            && labels
                .iter()
                .any(|t| t == "equivalent damping ratio zeta_eq [%]"),
        "{labels:?}"
    );
    assert!(
        polylines(&svg, BLUE, 2).iter().any(|l| l.len() > 2),
        "the curve is drawn"
    );

    // Hysteresis: the axis says support force, and the panel under it spans the whole force
    // (hundreds of newtons, as the samples), measured and model; the velocity-dependent part
    // has its own panel. The model loops are smooth (hundreds of points, not a 19-point polygon).
    let svg = read("hysteresis.svg");
    let labels: Vec<String> = texts(&svg).into_iter().map(|t| t.1).collect();
    assert!(
        labels.iter().any(|t| t == "support force F [N]"),
        "{labels:?}"
    );
    assert!(
        labels
            .iter()
            .any(|t| t.starts_with("F minus restoring force")),
        "{labels:?}"
    );
    assert_eq!(labels.iter().filter(|t| *t == "measured").count(), 2);
    assert_eq!(
        labels.iter().filter(|t| *t == "identified model").count(),
        2
    );
    let force_ticks: Vec<f64> = texts(&svg)
        .into_iter()
        .filter_map(|(_, t)| t.parse::<f64>().ok())
        .collect();
    assert!(
        force_ticks.iter().any(|v| *v >= 200.0) && force_ticks.iter().any(|v| *v <= -200.0),
        "the whole force is drawn: {force_ticks:?}"
    );
    // (Legend samples are two-point lines.)
    let loops: Vec<usize> = polylines(&svg, BLUE, 2)
        .iter()
        .map(Vec::len)
        .filter(|n| *n > 2)
        .collect();
    assert!(
        loops.len() == 2 && loops.iter().all(|n| *n > 100),
        "{loops:?}"
    );
    assert!(
        circles(&svg, GREY).len() > 2 * 20,
        "measured dots in both panels"
    );

    // Fit: a zoom of a few periods (a few dozen samples, not the whole record) above the
    // residual over the whole record.
    let svg = read("fit.svg");
    let labels: Vec<String> = texts(&svg).into_iter().map(|t| t.1).collect();
    assert!(labels.iter().any(|t| t.ends_with("(zoom)")), "{labels:?}");
    // The zoom ends before the last half second, where the centred moving average (1 s by
    // default) is truncated and the data carry its lag: it ended at the last sample, where
    // the residual jumped from ~0 to +6 N. Its title says the unit of its times.
    let t_last: f64 = std::fs::read_to_string(&data)
        .unwrap()
        .lines()
        .last()
        .and_then(|l| l.split(',').next()?.parse().ok())
        .unwrap();
    let title = labels.iter().find(|t| t.ends_with("(zoom)")).unwrap();
    let end: f64 = title
        .split(" to ")
        .nth(1)
        .and_then(|r| r.strip_suffix(" s (zoom)"))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{title}"));
    assert!(end <= t_last - 0.45, "the zoom ends at {end} of {t_last}");
    assert!(labels.iter().any(|t| t == "residual [N]"), "{labels:?}");
    assert!(
        labels
            .iter()
            .any(|t| t.starts_with("edges: moving average truncated")),
        "{labels:?}"
    );
    assert!(
        read("convergence.svg").contains("best training cost (MAE) [N], log scale"),
        "the cost's unit"
    );
    assert!(
        labels
            .iter()
            .any(|t| t.starts_with("residual: measured - model")),
        "{labels:?}"
    );
    let shown = circles(&svg, BLUE).len() - 1;
    assert!(
        shown > 20 && shown < samples / 10,
        "{shown} of {samples} samples in the zoom"
    );
    let residual = polylines(&svg, "#D55E00", 1);
    assert!(
        residual.iter().map(Vec::len).sum::<usize>() > 100,
        "the residual is drawn"
    );

    // Phase: the data beside the model.
    let svg = read("phase.svg");
    let labels: Vec<String> = texts(&svg).into_iter().map(|t| t.1).collect();
    assert!(
        labels.iter().any(|t| t.starts_with("data: F/k")),
        "{labels:?}"
    );
    assert!(circles(&svg, GREY).len() > 20);
}
