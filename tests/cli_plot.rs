//! `gatewatch identify --plot` and `gatewatch stability-map` through the binary.

use std::path::Path;
use std::process::{Command, Output};

fn gatewatch(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(args)
        .output()
        .expect("run gatewatch")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
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
    let o = gatewatch(&[
        "identify",
        "--input",
        data.to_str().unwrap(),
        "--model",
        "ydd + c1*yd + c2*y = 0",
        "--generations",
        "30",
        "--plot",
        out_dir.to_str().unwrap(),
        "--plot-format",
        "png",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for name in ["fit.png", "phase.png", "convergence.png"] {
        let bytes = std::fs::read(out_dir.join(name)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{name}");
    }
    let o = gatewatch(&[
        "identify",
        "--input",
        data.to_str().unwrap(),
        "--model",
        "ydd + c1*yd + c2*y = 0",
        "--generations",
        "30",
        "--plot",
        out_dir.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let svg = std::fs::read_to_string(out_dir.join("fit.svg")).unwrap();
    assert!(svg.contains("identified model"));
}

#[test]
fn identify_with_an_unwritable_plot_dir_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d.csv");
    write_series(&data);
    // A regular file where the directory should be: cannot be created, even as root.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, "x").unwrap();
    let target = blocker.join("plots");
    let o = gatewatch(&[
        "identify",
        "--input",
        data.to_str().unwrap(),
        "--model",
        "ydd + c1*yd + c2*y = 0",
        "--generations",
        "10",
        "--plot",
        target.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert_eq!(e.trim_end().lines().count(), 1, "{e}");
    assert!(e.contains("--plot") && e.contains("plots"), "{e}");
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
    let o = gatewatch(&args);
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
    let o = gatewatch(&args[..args.len() - 4]);
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
        let o = gatewatch(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{extra:?}: {e}");
        assert!(e.contains(needle), "{extra:?}: {e}");
    }
    let o = gatewatch(&["stability-map", "--model", "ydd + = 0", "--range", "c1=0:1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--model"));
}
