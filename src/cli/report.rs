//! The output of `gatewatch identify`: the `--json` object and the text report.

use super::opt;
use crate::analysis::{self, SeriesAnalysis, Signal};
use crate::identify::{Config, Initial};
use crate::model::Model;
use serde_json::json;
use std::io::Write;

fn coefficients_json(c: &[f64]) -> serde_json::Value {
    let map: serde_json::Map<String, serde_json::Value> = c
        .iter()
        .enumerate()
        .map(|(i, v)| (format!("c{}", i + 1), json!(v)))
        .collect();
    serde_json::Value::Object(map)
}

/// The `--json` object of `gatewatch identify` (field names are a stable interface).
pub fn identification_json(model: &Model, a: &SeriesAnalysis) -> serde_json::Value {
    let r = &a.identification;
    let best = r.best_run();
    // Reported coefficients are normalised when the structure is scale-free (the search's own
    // values, one arbitrary point of a line, stay in `raw_coefficients`).
    let coefficients = r.normalized(&best.coefficients);
    json!({
        "damping": a.damping,
        "linearization": a.linearization,
        "model": model.equation(),
        "equation": model.substitute(&coefficients),
        "coefficients": coefficients_json(&coefficients),
        "raw_coefficients": coefficients_json(&best.coefficients),
        "scale_groups": r.scale_groups.iter().map(|g| json!({
            "coefficients": g.members.iter().map(|j| format!("c{}", j + 1)).collect::<Vec<_>>(),
            "fixed": format!("c{}", g.fixed + 1),
            "kind": if g.sign_only { "sign" } else { "scale" },
            "fixed_value": if g.sign_only { coefficients[g.fixed] } else if g.sign_free { 1.0 } else { coefficients[g.fixed].signum() },
            "normalized": g.normalize(&best.coefficients).is_some(),
        })).collect::<Vec<_>>(),
        "initial": {"y0": best.initial.y0, "v0": best.initial.v0},
        "train_mae": best.train_mae,
        "test_nmae": best.test_nmae,
        "evaluations": best.evaluations,
        "seconds": best.seconds,
        "convergence": best.history,
        "coefficient_intervals": coefficient_intervals(r).map(|iv| {
            iv.iter()
                .enumerate()
                .map(|(i, (lo, hi))| (format!("c{}", i + 1), json!([lo, hi])))
                .collect::<serde_json::Map<String, serde_json::Value>>()
        }),
        "summary": {
            "mean_nmae": finite_or_null(r.summary.mean),
            "std_nmae": finite_or_null(r.summary.std),
            "min_nmae": finite_or_null(r.summary.min),
            "median_nmae": finite_or_null(r.summary.median),
        },
        "runs": r.runs.iter().map(|run| json!({
            "seed": run.seed,
            "coefficients": coefficients_json(&r.normalized(&run.coefficients)),
            "raw_coefficients": coefficients_json(&run.coefficients),
            "initial": {"y0": run.initial.y0, "v0": run.initial.v0},
            "train_mae": run.train_mae,
            "test_nmae": run.test_nmae,
            "evaluations": run.evaluations,
            "restarts": run.restarts,
            "seconds": run.seconds,
        })).collect::<Vec<_>>(),
    })
}

/// With several runs, each (normalised) coefficient's range over the runs (its spread: the
/// uncertainty of the identification itself).
fn coefficient_intervals(r: &crate::identify::Identification) -> Option<Vec<(f64, f64)>> {
    if r.runs.len() < 2 {
        return None;
    }
    let n = r.best_run().coefficients.len();
    Some(
        (0..n)
            .map(|j| {
                let v = r.runs.iter().map(|run| r.normalized(&run.coefficients)[j]);
                (
                    v.clone().fold(f64::INFINITY, f64::min),
                    v.fold(f64::NEG_INFINITY, f64::max),
                )
            })
            .collect(),
    )
}

fn finite_or_null(v: f64) -> serde_json::Value {
    if v.is_finite() {
        json!(v)
    } else {
        serde_json::Value::Null
    }
}

/// The text report of `gatewatch identify` on a record of `signal`.
pub(super) fn write_identification(
    out: &mut impl Write,
    model: &Model,
    a: &SeriesAnalysis,
    config: &Config,
    max_fit_nmae: f64,
    signal: Signal,
) -> std::io::Result<()> {
    let r = &a.identification;
    let best = r.best_run();
    writeln!(out, "model:        {}", model.equation())?;
    let coefficients = r.normalized(&best.coefficients);
    writeln!(out, "identified:   {}", model.substitute(&coefficients))?;
    let mut fixed = Vec::new();
    for g in &r.scale_groups {
        let names: Vec<String> = g.members.iter().map(|j| format!("c{}", j + 1)).collect();
        let c = format!("c{}", g.fixed + 1);
        if g.sign_only {
            writeln!(
                out,
                "sign:         {} are determined only up to a common sign: normalised to {c} > 0",
                names.join(", ")
            )?;
        } else if g.normalize(&best.coefficients).is_some() {
            fixed.push(g.fixed);
            let one = if g.sign_free { "1" } else { "+-1" };
            writeln!(
                out,
                "scale:        {} are determined only up to a common factor: normalised to {c} = {one}",
                names.join(", ")
            )?;
        } else {
            writeln!(
                out,
                "scale:        {} are determined only up to a common factor ({c} = 0: not normalised)",
                names.join(", ")
            )?;
        }
    }
    let intervals = coefficient_intervals(r);
    for (i, c) in coefficients.iter().enumerate() {
        if fixed.contains(&i) {
            writeln!(
                out,
                "  c{:<3} = {c:.8e}   (fixed by the normalisation)",
                i + 1
            )?;
            continue;
        }
        match intervals.as_ref().map(|iv| iv[i]) {
            Some((lo, hi)) => writeln!(
                out,
                "  c{:<3} = {c:.8e}   (runs: {lo:.6e} .. {hi:.6e})",
                i + 1
            )?,
            None => writeln!(out, "  c{:<3} = {c:.8e}", i + 1)?,
        }
    }
    let how = match config.initial {
        Initial::Known { .. } => "given",
        Initial::FromData => "from the data",
        Initial::Fit => "identified",
    };
    writeln!(
        out,
        "initial:      y0 = {:.6e}, v0 = {:.6e} ({how})",
        best.initial.y0, best.initial.v0
    )?;
    writeln!(out, "train MAE:    {:.3e}", best.train_mae)?;
    match best.test_nmae {
        Some(v) => writeln!(out, "test NMAE:    {v:.3e}")?,
        None => writeln!(out, "test NMAE:    n/a (the test integration failed)")?,
    }
    writeln!(
        out,
        "evaluations:  {} (of which {} in the polish)",
        best.evaluations, best.refine_evaluations
    )?;
    writeln!(out, "time:         {:.3} s", best.seconds)?;
    if r.runs.len() > 1 {
        writeln!(
            out,
            "runs:         {} (best by training error: seed {})",
            r.runs.len(),
            best.seed
        )?;
        writeln!(
            out,
            "test NMAE:    mean {:.3e}, std {:.3e}, min {:.3e}, median {:.3e}",
            r.summary.mean, r.summary.std, r.summary.min, r.summary.median
        )?;
    }
    write_damping(out, &a.damping, max_fit_nmae, signal)
}

/// A damping ratio in percent: fixed point, or scientific beyond 1e5 % (a diverging estimate's
/// interval of +-3.9e101 % printed as a number of 100 digits).
fn percent(z: f64) -> String {
    let p = 100.0 * z;
    if p.abs() < 1e5 {
        format!("{p:.3} %")
    } else {
        format!("{p:.3e} %")
    }
}

/// The units of the damping block's amplitudes and energy (`docs/damping.md`): N and J for a
/// force signal; the data's own unit for a displacement, whose energy is in the unit of the
/// equation's terms times it (J for an equation in N and metres; J/kg for `ydd + ... = 0`).
struct Units {
    amplitude: &'static str,
    energy: &'static str,
}

impl Units {
    fn of(signal: Signal) -> Units {
        match signal {
            Signal::Force => Units {
                amplitude: " N",
                energy: " J",
            },
            Signal::Displacement => Units {
                amplitude: " (unit of the data)",
                energy: " (unit of the equation's terms x unit of the data: J for N and m)",
            },
        }
    }
}

/// The damping block. The lines that come from the identified equation alone (`zeta_eq`, the
/// energy, the limit cycle, the time to the limit) say so when the model is not trusted (its
/// fit above `--max-fit-nmae`, or at odds with the spectrum): on a noise-driven record a
/// free-vibration fit often finds a limit cycle at the record's own amplitude while the verdict,
/// from the ambient estimate, is `damped`, and an engineer must not read that limit cycle as
/// the gate's.
fn write_damping(
    out: &mut impl Write,
    d: &analysis::DampingReport,
    max_fit_nmae: f64,
    signal: Signal,
) -> std::io::Result<()> {
    let units = Units::of(signal);
    let model_trusted = d.fit_nmae <= max_fit_nmae && d.agrees != Some(false);
    let of_model = |v: String| {
        if model_trusted || v == "n/a" {
            v
        } else {
            format!("{v} (model, not trusted)")
        }
    };
    writeln!(out, "damping:")?;
    let interval = d.zeta0_interval.map_or(String::new(), |(lo, hi)| {
        format!(" [{}, {}]", percent(lo), percent(hi))
    });
    writeln!(
        out,
        "  zeta0 (at rest):        {}{interval} ({})",
        opt(d.zeta0, percent),
        d.zeta0_source.map_or("-", |s| s.as_str())
    )?;
    writeln!(
        out,
        "  zeta_eq (at amplitude): {}",
        of_model(opt(d.zeta_eq, percent))
    )?;
    writeln!(
        out,
        "  amplitude now:          {}",
        opt(d.amplitude, |v| format!("{v:.4e}{}", units.amplitude))
    )?;
    writeln!(
        out,
        "  energy fed per cycle:   {}",
        of_model(opt(d.energy_per_cycle, |v| format!(
            "{v:.4e}{}",
            units.energy
        )))
    )?;
    writeln!(
        out,
        "  limit-cycle amplitude:  {}",
        of_model(opt(d.limit_cycle_amplitude, |v| format!(
            "{v:.4e}{}",
            units.amplitude
        )))
    )?;
    writeln!(
        out,
        "  time to limit:          {}",
        of_model(opt(d.time_to_limit, |v| format!("{v:.1} s")))
    )?;
    writeln!(
        out,
        "  frequency:              {} (model {})",
        opt(d.frequency_hz, |v| format!("{v:.4} Hz")),
        opt(d.model_frequency_hz, |v| format!("{v:.4} Hz"))
    )?;
    writeln!(
        out,
        "  envelope growth:        {}",
        match (d.growth_rate, d.growth_rate_stderr) {
            (Some(g), Some(se)) => format!("{g:.4} 1/s (+- {se:.4})"),
            _ => "n/a".to_string(),
        }
    )?;
    if let Some((z, lo, hi)) = d.ambient_zeta.map(<(f64, f64, f64)>::from) {
        writeln!(
            out,
            "  ambient zeta (SSI-COV): {} [{}, {}]",
            percent(z),
            percent(lo),
            percent(hi)
        )?;
    }
    writeln!(
        out,
        "  fit NMAE:               {:.3e} (bound {max_fit_nmae:.3e}); agrees with the spectrum: {}; model trusted: {}",
        d.fit_nmae,
        match d.agrees {
            Some(true) => "yes",
            Some(false) => "no",
            None => "n/a (no spectrum to compare with)",
        },
        if model_trusted { "yes" } else { "no" }
    )?;
    writeln!(
        out,
        "  report trusted:         {} (zeta0 from {})",
        if d.trusted {
            "yes: in the daemon it would feed the alerts"
        } else {
            "no: in the daemon it would not feed the alerts"
        },
        d.zeta0_source.map_or("-", |s| s.as_str())
    )?;
    let verdict = match d.verdict {
        analysis::Verdict::Damped => "damped",
        analysis::Verdict::SelfExcited => "SELF-EXCITED (negative damping at rest)",
        analysis::Verdict::Unknown if d.trusted => {
            "unknown (zeta0's 95 % interval reaches zero: neither sign is certain)"
        }
        analysis::Verdict::Unknown => "unknown (no estimate here may be trusted)",
    };
    writeln!(out, "  verdict:                {verdict}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(d: &analysis::DampingReport, signal: Signal) -> String {
        let mut out = Vec::new();
        write_damping(&mut out, d, 0.2, signal).unwrap();
        String::from_utf8(out).unwrap()
    }

    fn line<'a>(text: &'a str, key: &str) -> &'a str {
        text.lines()
            .find(|l| l.trim_start().starts_with(key))
            .unwrap_or_else(|| panic!("no {key} line: {text}"))
    }

    /// Force records give N and J (docs/damping.md); displacement records the data's unit.
    #[test]
    fn amplitudes_and_energy_carry_their_units() {
        let d = analysis::DampingReport {
            zeta0: Some(-0.02),
            amplitude: Some(218.25),
            energy_per_cycle: Some(2.0598e-3),
            limit_cycle_amplitude: Some(232.05),
            fit_nmae: 0.01,
            agrees: Some(true),
            trusted: true,
            ..analysis::DampingReport::unknown()
        };
        let f = block(&d, Signal::Force);
        assert!(line(&f, "amplitude now").ends_with("2.1825e2 N"), "{f}");
        assert!(line(&f, "energy fed").ends_with("2.0598e-3 J"), "{f}");
        assert!(line(&f, "limit-cycle").ends_with("2.3205e2 N"), "{f}");
        assert!(
            line(&f, "report trusted").contains("yes: in the daemon it would feed the alerts"),
            "{f}"
        );
        let y = block(&d, Signal::Displacement);
        assert!(
            line(&y, "amplitude now").ends_with("(unit of the data)"),
            "{y}"
        );
        assert!(line(&y, "energy fed").contains("J for N and m"), "{y}");
        let untrusted = analysis::DampingReport {
            trusted: false,
            ..d
        };
        let u = block(&untrusted, Signal::Force);
        assert!(
            line(&u, "report trusted").contains("no: in the daemon it would not feed the alerts"),
            "{u}"
        );
    }

    /// Without the record's spectrum there is nothing to agree with: n/a, not "yes" (20 rows
    /// printed "frequency: n/a" and "agrees with the spectrum: yes"); the fit alone judges the
    /// model's trust there, and a disagreement still withdraws it.
    #[test]
    fn the_agreement_reads_n_a_without_a_spectrum() {
        let fits = analysis::DampingReport {
            fit_nmae: 0.01,
            ..analysis::DampingReport::unknown()
        };
        for (agrees, said, trusted) in [
            (None, "agrees with the spectrum: n/a", "model trusted: yes"),
            (
                Some(true),
                "agrees with the spectrum: yes",
                "model trusted: yes",
            ),
            (
                Some(false),
                "agrees with the spectrum: no",
                "model trusted: no",
            ),
        ] {
            let d = analysis::DampingReport {
                agrees,
                ..fits.clone()
            };
            let text = block(&d, Signal::Force);
            let l = line(&text, "fit NMAE");
            assert!(l.contains(said) && l.contains(trusted), "{agrees:?}: {l}");
        }
    }

    /// A diverging interval is printed in scientific notation, not as 100 digits.
    #[test]
    fn huge_percentages_are_scientific() {
        assert_eq!(percent(-0.0225), "-2.250 %");
        assert_eq!(percent(3.9e99), "3.900e101 %");
        let d = analysis::DampingReport {
            zeta0: Some(0.01),
            zeta0_interval: Some((-3.9e99, 3.9e99)),
            ..analysis::DampingReport::unknown()
        };
        let text = block(&d, Signal::Displacement);
        let z = line(&text, "zeta0");
        assert!(z.contains("[-3.900e101 %, 3.900e101 %]"), "{z}");
        assert!(z.len() < 100, "{z}");
    }
}
