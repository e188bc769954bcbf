//! The 95 % interval of a model-based zeta0: the coefficients' covariance at the least-squares
//! optimum ([`identify::covariance`]) through the delta method on `zeta0 = C0 / (2 sqrt(K0 M0))`
//! (see `docs/damping.md`, "zeta0_interval"). Initial conditions estimated from the window
//! count as two more unknowns: held fixed, they made a growing window's interval four to eight
//! times too narrow (`bench warning`, the bursts' first windows: 0 of 14 covered).

use super::linearisation::Linearization;
use super::ModelInterval;
use crate::data::TimeSeries;
use crate::identify::{self, InitialValues, Output};
use crate::model::Model;

/// Step of the initial conditions' central differences, relative to the problem's displacement
/// and velocity scales (the coefficients' relative step in `identify::covariance`).
const DIFFERENCE_STEP_IC: f64 = 1e-4;

/// A fitted model as the interval needs it: the model, its coefficients, their DE scales (for
/// the difference steps), the initial conditions and the output that was fitted.
#[derive(Debug, Clone, Copy)]
pub struct FittedModel<'a> {
    /// The model.
    pub model: &'a Model,
    /// Its fitted coefficients `c1..cN`.
    pub coefficients: &'a [f64],
    /// The DE scales of the coefficients (empty: 1).
    pub scales: &'a [f64],
    /// The initial conditions of the fit.
    pub initial: InitialValues,
    /// What the fit compared with the data.
    pub output: Output,
    /// Whether the initial conditions were estimated from the window (a pre-run, a polish, the
    /// first samples, or the search): then they are unknowns of the covariance as much as the
    /// coefficients. `false` only for initial conditions the caller knows.
    pub initial_estimated: bool,
}

/// `zeta0 +- 1.96 sd` for the model linearised at `(t0, 0, 0)` with the difference steps of
/// [`Linearization::of`] set by `y_scale` and `v_scale`. `None` (never NaN) when the model has
/// no zeta0, an integration fails, or the covariance cannot say anything about zeta0 (a
/// singular Jacobian along a direction zeta0 depends on).
pub fn zeta0_interval(
    fit: &FittedModel<'_>,
    data: &TimeSeries,
    t0: f64,
    y_scale: f64,
    v_scale: f64,
    method: ModelInterval,
) -> Option<(f64, f64)> {
    let zeta0 = |c: &[f64]| Linearization::of(fit.model, c, t0, y_scale, v_scale).zeta0();
    let [interval] = intervals(fit, data, (y_scale, v_scale), method, [&zeta0]);
    interval
}

/// A figure computed from the coefficients (`None` where it is undefined), whose interval
/// [`intervals`] gives.
pub type CoefficientFunction<'a> = dyn Fn(&[f64]) -> Option<f64> + 'a;

/// `g(c) +- 1.96 sd` for each function `g` of the coefficients, from one covariance at the
/// optimum through the delta method (each gradient by central differences with the
/// covariance's own steps). An entry is `None` (never NaN) where its function fails at or near
/// the optimum or the covariance says nothing about it; every entry is `None` when the
/// covariance cannot be computed. Used for zeta0 ([`zeta0_interval`]) and, on a window that
/// grew into its cycle, for the damping law it carries (`series`, `growth_law_zeta`): one
/// covariance (a Jacobian's integrations) for both.
pub fn intervals<const N: usize>(
    fit: &FittedModel<'_>,
    data: &TimeSeries,
    (y_scale, v_scale): (f64, f64),
    method: ModelInterval,
    functions: [&CoefficientFunction<'_>; N],
) -> [Option<(f64, f64)>; N] {
    let steps = identify::difference_steps(fit.coefficients, fit.scales);
    // Gradients first: they cost no integration, and functions undefined nearby need none.
    let mut c = fit.coefficients.to_vec();
    let mut gradient = |g: &CoefficientFunction<'_>| -> Option<(f64, Vec<f64>)> {
        let value = g(fit.coefficients)?;
        let mut gradient = Vec::with_capacity(c.len());
        for (j, h) in steps.iter().enumerate() {
            c[j] = fit.coefficients[j] + h;
            let plus = g(&c);
            c[j] = fit.coefficients[j] - h;
            let minus = g(&c);
            c[j] = fit.coefficients[j];
            gradient.push((plus? - minus?) / (2.0 * h));
        }
        Some((value, gradient))
    };
    let gradients = functions.map(|g| gradient(g));
    if gradients.iter().all(Option::is_none) {
        return [None; N];
    }
    let covariance = match method {
        ModelInterval::NeweyWest => identify::covariance,
        ModelInterval::Forcing => identify::covariance_under_forcing,
    };
    let Some(cov) = covariance(&identify::Optimum {
        model: fit.model,
        series: data,
        coefficients: fit.coefficients,
        init: fit.initial,
        output: fit.output,
        steps: &steps,
        initial_steps: fit
            .initial_estimated
            .then_some((DIFFERENCE_STEP_IC * y_scale, DIFFERENCE_STEP_IC * v_scale)),
    }) else {
        return [None; N];
    };
    gradients.map(|g| {
        let (value, mut gradient) = g?;
        if cov.matrix.nrows() > gradient.len() {
            gradient.resize(cov.matrix.nrows(), 0.0);
        }
        let sd = cov.std_dev_of(&gradient)?;
        // Newey-West: the fixed-b value, not 1.96 (the residuals of a forced window stay
        // coherent over much of it, and the sum is then too small and too random for a normal
        // quantile); under the forcing model, 1.96.
        let half = cov.critical_value_95() * sd;
        let (lo, hi) = (value - half, value + half);
        (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{Config, Initial};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    const ZETA: f64 = 0.02;
    const OMEGA: f64 = 2.0 * std::f64::consts::PI * 2.0;

    /// A free decay from (1, 0) plus white noise of `sigma`,
    /// 10 s at 50 Hz (20 cycles).
    fn decay(seed: u64, sigma: f64) -> TimeSeries {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let wd = OMEGA * (1.0 - ZETA * ZETA).sqrt();
        let t: Vec<f64> = (0..500).map(|i| i as f64 / 50.0).collect();
        let y = t
            .iter()
            .map(|&t| {
                let e: f64 = StandardNormal.sample(&mut rng);
                // y(0) = 1, yd(0) = 0.
                let decay = (wd * t).cos() + ZETA * OMEGA / wd * (wd * t).sin();
                (-ZETA * OMEGA * t).exp() * decay + sigma * e
            })
            .collect();
        TimeSeries::new(t, y).unwrap()
    }

    /// The least-squares fit from the truth (the polish alone), then the interval.
    fn fitted_interval(model: &Model, series: &TimeSeries, truth: &[f64]) -> Option<(f64, f64)> {
        fitted_interval_with(model, series, truth, false)
    }

    /// [`fitted_interval`], the initial conditions counted as unknowns or not.
    fn fitted_interval_with(
        model: &Model,
        series: &TimeSeries,
        truth: &[f64],
        initial_estimated: bool,
    ) -> Option<(f64, f64)> {
        let config = Config::default();
        let problem = config
            .problem(model, series)
            .unwrap()
            .with_initial(Initial::Known { y0: 1.0, v0: 0.0 })
            .unwrap();
        let id = crate::identify::refine(&problem, &config.search, &config.protocol, truth, 400)
            .unwrap();
        let run = id.best_run();
        let fit = FittedModel {
            model,
            coefficients: &run.coefficients,
            scales: &[],
            initial: run.initial,
            output: Output::Displacement,
            initial_estimated,
        };
        zeta0_interval(&fit, series, 0.0, 1.0, OMEGA, ModelInterval::NeweyWest)
    }

    #[test]
    fn the_interval_covers_the_true_zeta0_at_its_nominal_rate() {
        let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
        let truth = [2.0 * ZETA * OMEGA, OMEGA * OMEGA];
        let seeds = 40;
        let (mut covered, mut widths) = (0, Vec::new());
        for seed in 0..seeds {
            let (lo, hi) = fitted_interval(&model, &decay(seed, 0.05), &truth)
                .unwrap_or_else(|| panic!("seed {seed}: no interval"));
            assert!(lo < hi, "seed {seed}: ({lo}, {hi})");
            covered += usize::from(lo <= ZETA && ZETA <= hi);
            widths.push(hi - lo);
        }
        let mean = widths.iter().sum::<f64>() / widths.len() as f64;
        eprintln!("coverage {covered}/{seeds}, mean width {mean}");
        assert!(
            covered >= 36,
            "covered {covered} of {seeds}, widths {widths:?}"
        );
        // Honest but not useless: a 20-cycle decay at 5 % noise pins zeta0 to a few tenths of a
        // point.
        assert!(mean > 1e-4 && mean < 0.01, "mean width {mean}");
    }

    #[test]
    fn estimated_initial_conditions_widen_the_interval_and_it_still_covers() {
        // The same decays, with the initial conditions counted as unknowns: every interval at
        // least as wide as with them held fixed (with white residuals the coefficients' block
        // of the larger covariance is a Schur complement: it only adds variance; the
        // Newey-West sandwich of coloured residuals can come out narrower, docs/damping.md),
        // and still covering at the nominal rate.
        let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
        let truth = [2.0 * ZETA * OMEGA, OMEGA * OMEGA];
        let seeds = 40;
        let (mut covered, mut wider) = (0, 0);
        for seed in 0..seeds {
            let series = decay(seed, 0.05);
            let fixed = fitted_interval(&model, &series, &truth).unwrap();
            let (lo, hi) = fitted_interval_with(&model, &series, &truth, true).unwrap();
            assert!(
                hi - lo >= (fixed.1 - fixed.0) * (1.0 - 1e-9),
                "seed {seed}: ({lo}, {hi}) narrower than {fixed:?}"
            );
            wider += usize::from(hi - lo > (fixed.1 - fixed.0) * 1.01);
            covered += usize::from(lo <= ZETA && ZETA <= hi);
        }
        assert!(covered >= 36, "covered {covered} of {seeds}");
        // A free decay from a known start pins its amplitude: counting y0 and v0 must still
        // cost something on most seeds, or the columns were not counted.
        assert!(
            2 * wider >= seeds as usize,
            "wider on {wider} of {seeds} seeds"
        );
    }

    #[test]
    fn a_scale_group_still_gets_an_interval() {
        // c1*ydd + c2*yd + c3*y = 0 is determined only up to a common factor: J^T J is
        // singular along c itself, which zeta0 does not depend on.
        let model = Model::parse("c1*ydd + c2*yd + c3*y = 0", &[]).unwrap();
        let truth = [1.0, 2.0 * ZETA * OMEGA, OMEGA * OMEGA];
        let (lo, hi) = fitted_interval(&model, &decay(7, 0.05), &truth).unwrap();
        assert!(lo <= ZETA && ZETA <= hi && hi - lo < 0.01, "({lo}, {hi})");
    }

    #[test]
    fn a_signal_that_determines_nothing_gives_no_interval() {
        // At rest with zero initial conditions every model predicts zero: the Jacobian is
        // zero, and the interval is None, not NaN and not a panic.
        let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
        let t: Vec<f64> = (0..200).map(|i| i as f64 / 50.0).collect();
        let series = TimeSeries::new(t, vec![0.0; 200]).unwrap();
        let fit = FittedModel {
            model: &model,
            coefficients: &[0.5, 100.0],
            scales: &[],
            initial: InitialValues { y0: 0.0, v0: 0.0 },
            output: Output::Displacement,
            initial_estimated: false,
        };
        for method in [ModelInterval::NeweyWest, ModelInterval::Forcing] {
            assert_eq!(zeta0_interval(&fit, &series, 0.0, 1.0, 10.0, method), None);
        }
        // A model without a zeta0 (no restoring force) has no interval either.
        let fit = FittedModel {
            coefficients: &[0.5, -100.0],
            initial: InitialValues { y0: 1.0, v0: 0.0 },
            ..fit
        };
        for method in [ModelInterval::NeweyWest, ModelInterval::Forcing] {
            assert_eq!(zeta0_interval(&fit, &series, 0.0, 1.0, 10.0, method), None);
        }
    }
}
