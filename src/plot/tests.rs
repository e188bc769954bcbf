//! Unit tests of the pictures.

use super::*;
use crate::stability::{StabilityMap, Trial};

fn sine(n: usize) -> (Vec<f64>, Vec<f64>) {
    let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
    let y = t.iter().map(|t| (-0.05 * t).exp() * t.sin()).collect();
    (t, y)
}

#[test]
fn format_follows_the_extension() {
    assert_eq!(
        Format::from_path(Path::new("a/fit.svg")).unwrap(),
        Format::Svg
    );
    assert_eq!(
        Format::from_path(Path::new("fit.PNG")).unwrap(),
        Format::Png
    );
    let e = Format::from_path(Path::new("fit.pdf"))
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("fit.pdf:") && e.contains(".svg or .png"),
        "{e}"
    );
    assert!(Format::from_path(Path::new("fit")).is_err());
}

#[test]
fn svg_and_png_files_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let (t, y) = sine(200);
    let train: Vec<usize> = (0..200).step_by(2).collect();
    let test: Vec<usize> = (1..200).step_by(2).collect();
    let units = Units {
        time: Some("s".into()),
        signal: Some("mm".into()),
        force: Some("kN".into()),
        data: None,
    };
    for ext in ["svg", "png"] {
        let p = dir.path().join(format!("fit.{ext}"));
        fit(&p, &t, &y, &train, &test, &t, &y, &units).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        if ext == "svg" {
            let text = String::from_utf8(bytes).unwrap();
            assert!(text.starts_with("<svg"), "{}", &text[..50]);
            assert!(text.contains("time t [s]"));
            assert!(text.contains("displacement y [mm]"));
            assert!(text.contains("test samples (100)"));
        } else {
            assert_eq!(&bytes[1..4], b"PNG");
        }
    }
    let p = dir.path().join("phase.svg");
    phase(&p, Some((&y, &t, "data")), &y, &t, &units).unwrap();
    assert!(std::fs::read_to_string(&p)
        .unwrap()
        .contains("velocity yd [mm/s]"));
    let p = dir.path().join("loop.svg");
    hysteresis(&p, (&y, &t), (&y, &t), (&y, &t), (&y, &t), &units).unwrap();
    assert!(std::fs::read_to_string(&p)
        .unwrap()
        .contains("support force F [kN]"));
}

#[test]
fn convergence_with_zero_costs_draws_them_on_a_floor() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.svg");
    convergence(&p, &[1e3, 10.0, 0.5, 0.0, 0.0], None, Some("N")).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains("log scale") && text.contains("drawn at the floor"));
    // The cost has the data's unit.
    assert!(text.contains("best training cost (MAE) [N], log scale"));
    convergence(&p, &[0.0, 0.0], None, None).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(!text.contains("log scale"));
    assert!(text.contains("best training cost (MAE, unit of the data)"));
    assert!(convergence(&p, &[], None, None).is_err());
}

#[test]
fn stability_map_counts_both_classes() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("map.svg");
    let map = StabilityMap {
        x_name: "c1".into(),
        y_name: "c2".into(),
        trials: vec![
            Trial {
                x: 1.0,
                y: 1.0,
                stable: true,
            },
            Trial {
                x: -1.0,
                y: 1.0,
                stable: false,
            },
        ],
        t_end: 1.0,
        undecided: 0,
    };
    stability_map(&p, &map, "ydd + c1*yd + c2*y = 0").unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(text.contains("stable (1)") && text.contains("unstable (1)"));
}

#[test]
fn unwritable_or_unknown_paths_are_errors_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let (t, y) = sine(10);
    let p = dir.path().join("missing").join("fit.svg");
    let e = fit(&p, &t, &y, &[0], &[1], &[], &[], &Units::default()).unwrap_err();
    assert!(matches!(e, PlotError::Write { .. }));
    assert!(e.to_string().contains("missing"), "{e}");
    let p = dir.path().join("fit.jpg");
    let e = fit(&p, &t, &y, &[0], &[1], &[], &[], &Units::default()).unwrap_err();
    assert!(matches!(e, PlotError::Format { .. }));
    let e = fit(
        &dir.path().join("f.svg"),
        &t,
        &y,
        &[99],
        &[],
        &[],
        &[],
        &Units::default(),
    )
    .unwrap_err();
    assert!(matches!(e, PlotError::NoData { .. }));
}

/// Verdict changes a few pixels apart get their labels on separate rows, or none, never one
/// over another ("unknowdampedunknown" in the audit's picture).
#[test]
fn verdict_labels_close_together_do_not_overlap() {
    let dir = tempfile::tempdir().unwrap();
    let verdicts = ["damped", "unknown", "self_excited", "unknown", "damped"];
    let points: Vec<DampingPoint> = (0..720)
        .map(|i| DampingPoint {
            time: 1.7e9 + 5.0 * i as f64,
            zeta0: Some(0.01),
            interval: Some((0.005, 0.015)),
            // four changes within 20 s of an hour's plot, one far from them
            verdict: match i {
                300..=303 => verdicts[i - 299],
                600.. => "self_excited",
                _ => "damped",
            }
            .to_string(),
            trusted: true,
        })
        .collect();
    let p = dir.path().join("h.svg");
    damping_history(&p, "g1", &points, None).unwrap();
    let svg = std::fs::read_to_string(&p).unwrap();
    // (x, y, text) of every verdict label
    let labels: Vec<(f64, f64, String)> = svg
        .split("<text")
        .skip(1)
        .filter_map(|el| {
            let attr = |name: &str| -> Option<f64> {
                let at = el.find(&format!(" {name}=\""))? + name.len() + 3;
                el[at..].split('"').next()?.parse().ok()
            };
            let text = el.split('>').nth(1)?.split('<').next()?.trim().to_string();
            if !verdicts.contains(&text.as_str()) {
                return None;
            }
            Some((attr("x")?, attr("y")?, text))
        })
        .collect();
    assert!(labels.len() >= 4, "{labels:?}");
    // some rows differ (the close ones were stacked), and no two on one row overlap
    assert!(
        labels.iter().any(|a| labels.iter().any(|b| a.1 != b.1)),
        "{labels:?}"
    );
    for (i, a) in labels.iter().enumerate() {
        for b in &labels[i + 1..] {
            if a.1 == b.1 {
                let width = 0.5 * (a.2.len().max(b.2.len()) as f64) * 8.0;
                assert!((a.0 - b.0).abs() > width, "{a:?} over {b:?}");
            }
        }
    }
}
