//! Structure selection: which of several candidate equations a record supports.
//!
//! # Why
//! The chapter searches coefficients for a structure fixed in advance (section 8.7); its outlook
//! is the search for the structure itself, settled on an accuracy/complexity front ("predictive
//! ability versus parsimony", Schmidt and Lipson 2009, the chapter's Figure 8.16). An engineer
//! asks the first form of that question every time: does this gate's record need the cubic
//! damping term, or a displacement-dependent one (Van der Pol), or is it linear? This module
//! answers it for a list of candidates, each identified on the same record with the same
//! seeds, and is the seam a structure search (candidates generated from a term library) plugs
//! into: whatever proposes the structures, the ranking stays here.
//!
//! # How candidates are ranked
//! Each fitted candidate gives the residual sum of squares of its prediction over the `n`
//! samples and its number `p` of free coefficients (plus the initial conditions when they are
//! estimated). The Gaussian criteria would be `AIC = n ln(RSS/n) + 2p` and
//! `BIC = n ln(RSS/n) + p ln n`. They assume `n` independent residuals, and a gate's are not:
//! the turbulent forcing a free-vibration fit treats as error is narrow-band at the gate's own
//! frequency (docs/damping.md, "zeta0_interval"), which is where the coefficients take their
//! information from. Counted as white, the chapter's gate record (2000 samples) made a
//! superfluous `c4*y^2` damping term win by a BIC of 22, weight 1.000.
//!
//! So the log-likelihood is divided by the record's correlation factor
//! `lambda = S(f0) / mean(S)` ([`correlation_factor`]): the residuals' spectral density at the
//! gate's frequency against its mean over the band, by Welch's method. White residuals give
//! `lambda = 1` and the textbook criteria; residuals concentrated at `f0` hold `lambda` times
//! fewer independent samples where it matters (Whittle's likelihood weighs each frequency by
//! the noise density there, and the coefficients' Jacobian lives at `f0`). Then
//! `AIC = n ln(RSS/n) / lambda + 2p` and `BIC = n ln(RSS/n) / lambda + p ln(n / lambda)`, with
//! one `lambda` for every candidate, measured on the residuals of the best-fitting one (the
//! noise estimate least polluted by a missing term), so the candidates stay comparable.
//! Candidates are ranked by BIC; the weights `exp(-dBIC/2)`, normalised, say how decisive the
//! ranking is. A candidate is on the accuracy/complexity front when no candidate with fewer
//! coefficients fits as well and none with as many ranks above it ([`FRONT_TIE`]).
//!
//! Why the front measures accuracy by the RSS, as the ranking does: by the fit NMAE, two fits
//! of four coefficients on the chapter's record, equal to 2e-6 (a redundant `y^3` beside the
//! linear equation), came out in the opposite order to their BIC, and the front starred the
//! one ranked below while saying no other candidate fitted as well with as few coefficients.
//!
//! Why BIC first: it is the stricter of the two (a term enters only if it cuts the RSS by a
//! factor `(n/lambda)^(-lambda/n)`, 0.38 % for 2000 white samples, against AIC's 0.10 %), and a
//! gate's engineer wants the smallest equation the record supports. The front is shown beside
//! it because it needs no likelihood: where BIC and the front disagree, the record does not
//! decide, and the engineer's physics should.

/// One candidate identified on the record.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateFit {
    /// The equation as given.
    pub equation: String,
    /// Free parameters: the coefficients identified (and the initial conditions when fitted).
    pub parameters: usize,
    /// Samples the residuals are summed over.
    pub samples: usize,
    /// Residual sum of squares of the prediction over those samples (infinite when the model
    /// could not be simulated over the record).
    pub rss: f64,
    /// The prediction's NMAE over the record (infinite when it could not be simulated).
    pub fit_nmae: f64,
    /// Test NMAE of the chosen run.
    pub test_nmae: Option<f64>,
    /// The model's damping ratio at rest.
    pub zeta0: Option<f64>,
}

/// A candidate with its criteria, as [`rank`] orders them.
#[derive(Debug, Clone, PartialEq)]
pub struct RankedCandidate {
    /// The fit.
    pub fit: CandidateFit,
    /// Akaike's information criterion (infinite without a finite RSS).
    pub aic: f64,
    /// The Bayesian (Schwarz) information criterion.
    pub bic: f64,
    /// BIC minus the smallest BIC of the list.
    pub delta_bic: f64,
    /// `exp(-delta_bic / 2)` normalised over the list: the share of support.
    pub weight: f64,
    /// On the accuracy/complexity front.
    pub on_front: bool,
}

/// `(AIC, BIC)` of a Gaussian fit with residual sum of squares `rss` over `n` samples, `p`
/// free parameters and the record's correlation factor `lambda` (>= 1; 1 for white residuals,
/// see the module documentation); infinite when `rss` is not finite or `n` is 0. A perfect fit
/// (`rss = 0`) is floored at the smallest positive double so its criteria stay finite and
/// ordered by `p`.
pub fn information_criteria(rss: f64, n: usize, p: usize, lambda: f64) -> (f64, f64) {
    if !rss.is_finite() || rss < 0.0 || n == 0 {
        return (f64::INFINITY, f64::INFINITY);
    }
    let lambda = if lambda.is_finite() {
        lambda.max(1.0)
    } else {
        1.0
    };
    let nf = n as f64;
    let fit = nf * (rss.max(f64::MIN_POSITIVE) / nf).ln() / lambda;
    let n_eff = (nf / lambda).max(1.0);
    (fit + 2.0 * p as f64, fit + p as f64 * n_eff.ln())
}

/// Relative difference of two residual sums of squares within which the front counts the fits
/// as equally good. Value: twenty times the spread between seeds of one structure on the
/// chapter's record (3e-7 to 5e-7), so that the optimiser's noise does not buy a coefficient a
/// place on the front; and below the gain BIC asks of a term (`ln(n_eff) / n_eff`, 0.44 % at
/// 1696 effective samples) up to about a million effective samples, so the two rarely part.
pub const FRONT_TIE: f64 = 1e-5;

/// The candidates ranked by BIC (smallest first; a candidate without a finite fit last, in the
/// order given), each with its criteria, its weight and whether it is on the front. `lambda`:
/// the record's [`correlation_factor`], the same for every candidate.
pub fn rank(fits: Vec<CandidateFit>, lambda: f64) -> Vec<RankedCandidate> {
    let mut ranked: Vec<RankedCandidate> = fits
        .into_iter()
        .map(|fit| {
            let (aic, bic) = information_criteria(fit.rss, fit.samples, fit.parameters, lambda);
            RankedCandidate {
                fit,
                aic,
                bic,
                delta_bic: f64::INFINITY,
                weight: 0.0,
                on_front: false,
            }
        })
        .collect();
    // Stable: equal criteria (and every failed fit) keep the order given.
    ranked.sort_by(|a, b| a.bic.total_cmp(&b.bic));
    let front: Vec<bool> = (0..ranked.len()).map(|i| on_front(&ranked, i)).collect();
    for (r, on) in ranked.iter_mut().zip(front) {
        r.on_front = on;
    }
    let best = ranked.first().map_or(f64::INFINITY, |r| r.bic);
    if best.is_finite() {
        for r in &mut ranked {
            r.delta_bic = r.bic - best;
        }
        let total: f64 = ranked.iter().map(|r| (-r.delta_bic / 2.0).exp()).sum();
        for r in &mut ranked {
            r.weight = (-r.delta_bic / 2.0).exp() / total;
        }
    }
    ranked
}

/// The residuals' correlation factor at `frequency_hz`: their spectral density there (the mean
/// of the three nearest bins) over its mean across the band, by Welch's method (Hann segments
/// of the largest power of two up to a quarter of the record, at least 32 samples, half
/// overlapping), at least 1. 1 when the record is too short for two segments, the frequency is
/// outside the band, or the residuals are all zero.
pub fn correlation_factor(residuals: &[f64], rate_hz: f64, frequency_hz: f64) -> f64 {
    let n = residuals.len();
    let mut len = 32usize;
    while len * 2 <= n / 4 {
        len *= 2;
    }
    if n < 2 * len || !(rate_hz > 0.0 && frequency_hz > 0.0 && frequency_hz < rate_hz / 2.0) {
        return 1.0;
    }
    let window = crate::spectral::hann(len);
    let fft = rustfft::FftPlanner::<f64>::new().plan_fft_forward(len);
    let mut buf = vec![rustfft::num_complex::Complex::new(0.0, 0.0); len];
    let mut density = vec![0.0; len / 2 + 1];
    let mean = residuals.iter().sum::<f64>() / n as f64;
    let mut start = 0;
    while start + len <= n {
        for ((b, &r), &w) in buf
            .iter_mut()
            .zip(&residuals[start..start + len])
            .zip(&window)
        {
            *b = rustfft::num_complex::Complex::new((r - mean) * w, 0.0);
        }
        fft.process(&mut buf);
        for (d, b) in density.iter_mut().zip(&buf) {
            *d += b.norm_sqr();
        }
        start += len / 2;
    }
    // The band without the DC bin (the mean removed) and Nyquist.
    let band = &density[1..len / 2];
    let average = band.iter().sum::<f64>() / band.len() as f64;
    let k0 = (frequency_hz * len as f64 / rate_hz).round() as usize;
    let (lo, hi) = (k0.saturating_sub(1).max(1), (k0 + 1).min(len / 2 - 1));
    let at = density[lo..=hi].iter().sum::<f64>() / (hi - lo + 1) as f64;
    if average > 0.0 && at.is_finite() {
        (at / average).max(1.0)
    } else {
        1.0
    }
}

/// Whether candidate `i` of the ranking is on the accuracy/complexity front: it has a finite
/// fit, no candidate with fewer parameters fits as well (its RSS at most [`FRONT_TIE`] above),
/// and none with as many ranks above it. Accuracy is the RSS the ranking is made of, so that
/// of equal parameters the front keeps the better-ranked fit and the printed "no other
/// candidate fits as well with as few coefficients" holds; fits equal within the tie go to the
/// fewer coefficients, or, of as many, to the better rank (the order given when equal).
fn on_front(ranked: &[RankedCandidate], i: usize) -> bool {
    let c = &ranked[i].fit;
    if !c.rss.is_finite() {
        return false;
    }
    !ranked.iter().enumerate().any(|(j, o)| {
        let o = &o.fit;
        j != i
            && o.rss.is_finite()
            && ((o.parameters < c.parameters && o.rss <= c.rss * (1.0 + FRONT_TIE))
                || (o.parameters == c.parameters && j < i))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit(equation: &str, parameters: usize, rss: f64, nmae: f64) -> CandidateFit {
        CandidateFit {
            equation: equation.to_string(),
            parameters,
            samples: 1000,
            rss,
            fit_nmae: nmae,
            test_nmae: None,
            zeta0: None,
        }
    }

    #[test]
    fn the_criteria_are_the_gaussian_ones() {
        let (aic, bic) = information_criteria(2.0, 100, 3, 1.0);
        let base = 100.0 * (0.02f64).ln();
        assert!((aic - (base + 6.0)).abs() < 1e-12);
        assert!((bic - (base + 3.0 * 100f64.ln())).abs() < 1e-12);
        assert_eq!(
            information_criteria(f64::INFINITY, 100, 3, 1.0).1,
            f64::INFINITY
        );
        assert_eq!(information_criteria(f64::NAN, 100, 3, 1.0).0, f64::INFINITY);
        assert_eq!(information_criteria(1.0, 0, 3, 1.0).0, f64::INFINITY);
        // A perfect fit stays finite, and the smaller model wins it.
        let (a0, _) = information_criteria(0.0, 100, 2, 1.0);
        let (a1, _) = information_criteria(0.0, 100, 3, 1.0);
        assert!(a0.is_finite() && a0 < a1);
    }

    #[test]
    fn a_superfluous_term_that_buys_nothing_ranks_below_the_true_structure() {
        // The same RSS with one term more: BIC prefers the smaller model by ln(1000) = 6.9.
        let r = rank(
            vec![
                fit("big", 4, 10.0, 0.050),
                fit("true", 3, 10.0, 0.050),
                fit("linear", 2, 400.0, 0.400),
            ],
            1.0,
        );
        let order: Vec<&str> = r.iter().map(|c| c.fit.equation.as_str()).collect();
        assert_eq!(order, ["true", "big", "linear"]);
        assert_eq!(r[0].delta_bic, 0.0);
        assert!((r[1].delta_bic - 1000f64.ln()).abs() < 1e-9);
        let total: f64 = r.iter().map(|c| c.weight).sum();
        assert!((total - 1.0).abs() < 1e-12);
        assert!(r[0].weight > 0.95);
        // The front: "true" dominates "big" (same NMAE, fewer terms); "linear" is the simplest.
        let front: Vec<bool> = r.iter().map(|c| c.on_front).collect();
        assert_eq!(front, [true, false, true]);
    }

    #[test]
    fn the_front_measures_accuracy_as_the_ranking_does() {
        // The chapter's record: the linear equation and a redundant `y^3` beside it, four
        // coefficients each, whose NMAE and RSS order disagree by 2e-6. The front keeps the one
        // the ranking puts first, and only it.
        let r = rank(
            vec![
                fit("cubic damping", 5, 4536.65, 0.0106),
                fit("linear", 4, 208_374.18, 0.083_804_75),
                fit("linear + y^3", 4, 208_374.67, 0.083_804_48),
            ],
            1.18,
        );
        let order: Vec<&str> = r.iter().map(|c| c.fit.equation.as_str()).collect();
        assert_eq!(order, ["cubic damping", "linear", "linear + y^3"]);
        let front: Vec<bool> = r.iter().map(|c| c.on_front).collect();
        assert_eq!(front, [true, true, false]);
        // The same fit twice: the first given is on the front.
        let r = rank(vec![fit("a", 3, 10.0, 0.05), fit("b", 3, 10.0, 0.05)], 1.0);
        assert_eq!(r[0].fit.equation, "a");
        assert_eq!([r[0].on_front, r[1].on_front], [true, false]);
    }

    #[test]
    fn a_gain_within_the_tie_buys_no_place_on_the_front() {
        // One term more for a tenth of the tie: the smaller fits as well.
        let gain = 1.0 - FRONT_TIE / 10.0;
        let r = rank(
            vec![
                fit("small", 3, 10.0, 0.05),
                fit("big", 4, 10.0 * gain, 0.05),
            ],
            1.0,
        );
        assert_eq!(r[0].fit.equation, "small");
        assert_eq!([r[0].on_front, r[1].on_front], [true, false]);
        // Ten times the tie is a trade-off the front shows, whatever BIC makes of it.
        let gain = 1.0 - FRONT_TIE * 10.0;
        let r = rank(
            vec![
                fit("small", 3, 10.0, 0.05),
                fit("big", 4, 10.0 * gain, 0.05),
            ],
            1.0,
        );
        assert!(r.iter().all(|c| c.on_front));
    }

    #[test]
    fn a_term_that_halves_the_residuals_is_worth_its_price() {
        let r = rank(
            vec![fit("small", 3, 10.0, 0.05), fit("big", 4, 5.0, 0.03)],
            1.0,
        );
        assert_eq!(r[0].fit.equation, "big");
        assert!(r.iter().all(|c| c.on_front));
    }

    #[test]
    fn a_candidate_that_could_not_be_simulated_ranks_last_and_off_the_front() {
        let r = rank(
            vec![
                fit("broken", 2, f64::INFINITY, f64::INFINITY),
                fit("ok", 3, 10.0, 0.05),
            ],
            1.0,
        );
        assert_eq!(r[0].fit.equation, "ok");
        assert_eq!(r[1].fit.equation, "broken");
        assert!(!r[1].on_front && r[1].weight == 0.0 && r[1].delta_bic == f64::INFINITY);
        assert_eq!(r[0].weight, 1.0);
        // Nothing finite: no weights, nothing on the front, the order given.
        let r = rank(
            vec![
                fit("a", 2, f64::INFINITY, f64::INFINITY),
                fit("b", 3, f64::NAN, f64::INFINITY),
            ],
            1.0,
        );
        assert_eq!(r[0].fit.equation, "a");
        assert!(r.iter().all(|c| c.weight == 0.0 && !c.on_front));
    }

    #[test]
    fn correlated_residuals_count_for_fewer_samples_and_a_small_gain_no_longer_buys_a_term() {
        // Halving the RSS buys a term at lambda = 1; at lambda = 50 (n ln 2 / 50 = 13.9 against
        // ln(1000 / 50) = 3.0 per term) it still does, and a 2 % gain (0.4) does not.
        let r = rank(
            vec![fit("small", 3, 10.0, 0.05), fit("big", 4, 9.8, 0.049)],
            1.0,
        );
        assert_eq!(r[0].fit.equation, "big");
        let r = rank(
            vec![fit("small", 3, 10.0, 0.05), fit("big", 4, 9.8, 0.049)],
            50.0,
        );
        assert_eq!(r[0].fit.equation, "small");
        let r = rank(
            vec![fit("small", 3, 10.0, 0.05), fit("big", 4, 5.0, 0.03)],
            50.0,
        );
        assert_eq!(r[0].fit.equation, "big");
        // lambda below 1 or not finite is 1.
        assert_eq!(
            information_criteria(2.0, 100, 3, 0.5),
            information_criteria(2.0, 100, 3, 1.0)
        );
        assert_eq!(
            information_criteria(2.0, 100, 3, f64::NAN),
            information_criteria(2.0, 100, 3, 1.0)
        );
    }

    #[test]
    fn white_residuals_have_no_correlation_and_a_narrow_band_at_the_frequency_has_much() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let white: Vec<f64> = (0..4000).map(|_| StandardNormal.sample(&mut rng)).collect();
        let lambda = correlation_factor(&white, 200.0, 10.0);
        assert!((1.0..1.6).contains(&lambda), "white: {lambda}");
        // The same noise through a lightly damped resonator at 10 Hz (200 Hz sampling): the
        // response of a gate to turbulence, what a free-vibration fit leaves as residuals.
        let (w, zeta, dt) = (2.0 * std::f64::consts::PI * 10.0, 0.02, 1.0 / 200.0);
        let (mut y, mut v) = (0.0f64, 0.0f64);
        let narrow: Vec<f64> = white
            .iter()
            .map(|&f| {
                v += dt * (f * 100.0 - 2.0 * zeta * w * v - w * w * y);
                y += dt * v;
                y
            })
            .collect();
        let at = correlation_factor(&narrow, 200.0, 10.0);
        assert!(at > 10.0, "narrow band at its frequency: {at}");
        // Away from the band the density is below the mean: the factor is floored at 1.
        assert_eq!(correlation_factor(&narrow, 200.0, 60.0), 1.0);
        // Too short, or a frequency outside the band: 1.
        assert_eq!(correlation_factor(&narrow[..40], 200.0, 10.0), 1.0);
        assert_eq!(correlation_factor(&narrow, 200.0, 150.0), 1.0);
        assert_eq!(correlation_factor(&vec![0.0; 4000], 200.0, 10.0), 1.0);
    }
}
