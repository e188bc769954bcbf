//! Error measures and summaries of the runs.

use super::Summary;

/// NMAE of `(prediction, target)` pairs: mean absolute error over the (population) standard
/// deviation of the targets. `None` when empty or the targets are constant.
pub fn nmae(pairs: impl Iterator<Item = (f64, f64)> + Clone) -> Option<f64> {
    let n = pairs.clone().count();
    if n == 0 {
        return None;
    }
    let mean = pairs.clone().map(|(_, t)| t).sum::<f64>() / n as f64;
    let var = pairs.clone().map(|(_, t)| (t - mean).powi(2)).sum::<f64>() / n as f64;
    let mae = pairs.map(|(p, t)| (p - t).abs()).sum::<f64>() / n as f64;
    (var > 0.0).then(|| mae / var.sqrt())
}

/// Population standard deviation (the RMS about the mean); 0 for an empty slice. The one
/// spread measure of the crate: the identification's noise and scale estimates and the
/// analysis' force RMS use it.
pub fn std_dev(y: &[f64]) -> f64 {
    let n = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / n;
    (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt()
}

/// Median of `v` (sorted in place, NaN last); `None` when empty. The crate's one median: the
/// run summaries, a gate's ambient level and the benches' tables use it.
pub fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

pub(super) fn magnitude(y: &[f64]) -> f64 {
    let m = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if m > 0.0 {
        m
    } else {
        1.0
    }
}

/// Mean, sample standard deviation, minimum and median of `values`.
pub fn summarize(values: impl Iterator<Item = f64>) -> Summary {
    let mut v: Vec<f64> = values.collect();
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let std = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    let median = median(&mut v).unwrap_or(f64::NAN);
    Summary {
        mean,
        std,
        min: v.first().copied().unwrap_or(f64::NAN),
        median,
    }
}

/// Mean absolute measurement noise of a finely sampled smooth signal, estimated from fourth
/// differences: for white noise of deviation `s`, `std(d4 y) = s sqrt(70)`, and a smooth signal
/// sampled at `h` contributes only about `(w h)^4` of its amplitude. Mean absolute value of
/// Gaussian noise: `s sqrt(2/pi)`.
pub(super) fn noise_mae(y: &[f64]) -> f64 {
    if y.len() < 5 {
        return 0.0;
    }
    let d4: Vec<f64> = y
        .windows(5)
        .map(|w| w[4] - 4.0 * w[3] + 6.0 * w[2] - 4.0 * w[1] + w[0])
        .collect();
    std_dev(&d4) / 70f64.sqrt() * (2.0 / std::f64::consts::PI).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_even_and_empty_sets_and_the_summary_uses_it() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0]), Some(3.0));
        assert_eq!(median(&mut [5.0, 1.0, 3.0]), Some(3.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        // NaN sorts last (total order), so one NaN of three leaves the middle finite
        assert_eq!(median(&mut [f64::NAN, 1.0, 2.0]), Some(2.0));
        let s = summarize([4.0, 1.0, 3.0, 2.0].into_iter());
        assert_eq!((s.min, s.median, s.mean), (1.0, 2.5, 2.5));
    }
}
