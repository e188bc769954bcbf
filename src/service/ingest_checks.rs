//! Checks of an ingestion request beyond its syntax: sample times against the daemon's clock,
//! and query parameters given more than once.
//!
//! Why a time bound: a gate's window trusts its newest timestamp. One sample 1e6 s in the future
//! once made the window restart there (a "gap"), and every good sample after it was then "out of
//! order" and dropped, about 20 s of blindness at 200 Hz, while the requests were answered 204.
//! So a sample more than `max_future_seconds` ahead of the daemon's clock (Mimir refuses samples
//! more than 10 min ahead the same way) or more than `max_past_seconds` behind it refuses its
//! whole request with a 400 naming the sample, before anything is applied: the client learns
//! about its clock, and the window is untouched. The raw TCP listener goes through the same
//! check (the line is counted and logged, the window is untouched).
//!
//! Both bounds are per gate (`[defaults]` or `[gates.ID]`); 0 turns a bound off, for replaying
//! recorded data through a test daemon.

use super::config::{GateConfig, Precision};
use super::ingest::{BadRequest, Batch};
use super::metrics::RejectReason;
use crate::number::Num;

/// The location of the time of sample `i` of `batch`: line protocol names the `line` and the
/// `timestamp`; JSON `values` batches the `start` they count from (with the index), JSON
/// `samples` pairs the pair's index.
fn locate(batch: &Batch, i: usize, e: BadRequest) -> BadRequest {
    match &batch.lines {
        Some(lines) => {
            let mut e = e.field("timestamp");
            e.line = lines.get(i).copied();
            e
        }
        None => {
            let field = match batch.values_field.strip_suffix("values") {
                Some(prefix) => format!("{prefix}start"),
                None => batch.values_field.clone(),
            };
            e.field(field).index(i)
        }
    }
}

/// Refuses `batch` when a sample time is outside the bounds of its gate (`cfg`) around `now`
/// (Unix seconds, the daemon's clock). Non-finite times are left to the caller's own check.
/// When the time would be inside the bounds in another unit (a factor 1e3, 1e6 or 1e9 either
/// way), the message names that unit and how to send it (`unit_hint`).
pub fn check_times(
    batch: &Batch,
    cfg: &GateConfig,
    now: f64,
) -> Result<(), (RejectReason, BadRequest)> {
    let future = cfg.max_future_seconds;
    let past = cfg.max_past_seconds;
    for (i, &(t, _)) in batch.samples.iter().enumerate() {
        if !t.is_finite() {
            continue;
        }
        if future > 0.0 && t > now + future {
            let e = BadRequest::new(format!(
                "sample time {} is {} s ahead of the daemon's clock ({now:.3}); gate `{}` \
                 accepts at most max_future_seconds = {future}{}",
                Num(t),
                beyond(t - now, future),
                batch.gate,
                unit_hint(batch, t, cfg, now),
            ));
            return Err((RejectReason::TooFarInFuture, locate(batch, i, e)));
        }
        if past > 0.0 && t < now - past {
            let e = BadRequest::new(format!(
                "sample time {} is {} s behind the daemon's clock ({now:.3}); gate `{}` \
                 accepts at most max_past_seconds = {past}{}",
                Num(t),
                beyond(now - t, past),
                batch.gate,
                unit_hint(batch, t, cfg, now),
            ));
            return Err((RejectReason::TooOld, locate(batch, i, e)));
        }
    }
    Ok(())
}

/// `d` (> `bound`) printed with the fewest decimals (at least one) that still read above
/// `bound`. Why: rounded to whole seconds, a sample 600.4 s ahead read "600 s ahead ... accepts
/// at most 600", which contradicts itself. A `d` far beyond any bound (a time of 1e300) is
/// printed in scientific form ([`Num`]), not as 300 digits.
fn beyond(d: f64, bound: f64) -> String {
    if !Num(d).is_plain() {
        return Num(d).to_string();
    }
    (1..=9)
        .map(|digits| format!("{d:.digits$}"))
        .find(|s| s.parse::<f64>().is_ok_and(|x| x > bound))
        // the shortest representation that reads back as `d` itself, which is > bound
        .unwrap_or_else(|| d.to_string())
}

/// The hint appended to a time-bound refusal when the time `t` would be inside the gate's
/// bounds after a factor 1e3, 1e6 or 1e9 either way: the client's timestamps are most likely
/// in another unit (milliseconds in a JSON `start`, milliseconds sent as line protocol's default
/// nanoseconds). Empty when no factor makes the time plausible. A bound turned off (0) counts
/// as a year here, so that a hint still needs the time to come near the clock.
fn unit_hint(batch: &Batch, t: f64, cfg: &GateConfig, now: f64) -> String {
    const YEAR: f64 = 365.25 * 86_400.0;
    let bound = |b: f64| if b > 0.0 { b } else { YEAR };
    let (future, past) = (bound(cfg.max_future_seconds), bound(cfg.max_past_seconds));
    let Some(k) = [1e3, 1e6, 1e9, 1e-3, 1e-6, 1e-9]
        .into_iter()
        .find(|k| (now - past..=now + future).contains(&(t * k)))
    else {
        return String::new();
    };
    // the client's unit, in seconds: k times the unit its number was read in
    let read_in = batch.precision.map_or(1.0, Precision::seconds_per_unit);
    let unit = read_in * k;
    let name = [(1e-9, "ns"), (1e-6, "us"), (1e-3, "ms"), (1.0, "s")]
        .into_iter()
        .find(|(u, _)| ((unit - u) / u).abs() < 1e-6)
        .map(|(_, n)| n);
    let (factor, way) = if k > 1.0 {
        (k, "larger")
    } else {
        (1.0 / k, "smaller")
    };
    let plausible = format!("it would be plausible {factor:.0e} times {way}");
    match (batch.precision, name) {
        (Some(_), Some(n)) => format!(
            "; {plausible}: are the timestamps in {n}? send them with `?precision={n}` (raw \
             TCP: `ingest.tcp_precision = \"{n}\"`)"
        ),
        (None, Some(n)) => format!(
            "; {plausible}: is it in {n}? JSON times are Unix seconds (or RFC 3339 for `start`)"
        ),
        (_, None) => format!("; {plausible}: check the unit of the times"),
    }
}

/// The one value of query parameter `name` in the raw query string `query` (`None` when
/// absent); a parameter given twice is refused, since which one wins is a guess (InfluxDB
/// takes the first, most frameworks the last).
pub fn single_param(query: Option<&str>, name: &str) -> Result<Option<String>, BadRequest> {
    let Some(query) = query else {
        return Ok(None);
    };
    single_value(form_urlencoded::parse(query.as_bytes()), name)
}

/// The one value of `name` among urlencoded `pairs` (a query string's or a form body's), as
/// [`single_param`]: `None` when absent, refused when given twice.
pub fn single_value<K: AsRef<str>, V: AsRef<str>>(
    pairs: impl IntoIterator<Item = (K, V)>,
    name: &str,
) -> Result<Option<String>, BadRequest> {
    let mut found: Option<String> = None;
    for (k, v) in pairs {
        if k.as_ref() != name {
            continue;
        }
        if let Some(first) = &found {
            return Err(BadRequest::new(format!(
                "parameter `{name}` given more than once (`{first}` and `{}`)",
                v.as_ref()
            ))
            .field(name));
        }
        found = Some(v.as_ref().to_string());
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gate() -> GateConfig {
        GateConfig {
            max_future_seconds: 600.0,
            max_past_seconds: 3600.0,
            ..GateConfig::default()
        }
    }

    fn json_batch(samples: Vec<(f64, f64)>, field: &str) -> Batch {
        Batch {
            gate: "g1".into(),
            samples,
            rate: None,
            values_field: field.into(),
            lines: None,
            precision: None,
        }
    }

    const NOW: f64 = 1_800_000_000.0;

    #[test]
    fn times_inside_the_bounds_pass() {
        let b = json_batch(vec![(NOW - 3599.0, 1.0), (NOW + 599.0, 1.0)], "values");
        assert!(check_times(&b, &gate(), NOW).is_ok());
    }

    #[test]
    fn future_sample_names_start_and_index() {
        let b = json_batch(vec![(NOW, 1.0), (NOW + 1e6, 1.0)], "[1].values");
        let (reason, e) = check_times(&b, &gate(), NOW).unwrap_err();
        assert_eq!(reason, RejectReason::TooFarInFuture);
        assert_eq!(e.field.as_deref(), Some("[1].start"));
        assert_eq!(e.index, Some(1));
        assert!(e.error.contains("max_future_seconds"), "{}", e.error);
    }

    #[test]
    fn old_sample_names_the_pair_or_the_line() {
        // year 1971
        let b = json_batch(vec![(40_000_000.0, 1.0)], "samples");
        let (reason, e) = check_times(&b, &gate(), NOW).unwrap_err();
        assert_eq!(reason, RejectReason::TooOld);
        assert_eq!((e.field.as_deref(), e.index), (Some("samples"), Some(0)));
        let mut lp = json_batch(vec![(NOW, 1.0), (NOW - 7200.0, 1.0)], "force");
        lp.lines = Some(vec![3, 5]);
        let (_, e) = check_times(&lp, &gate(), NOW).unwrap_err();
        assert_eq!((e.field.as_deref(), e.line), (Some("timestamp"), Some(5)));
    }

    /// The numbers of a refusal agree with its bound: "600 s ahead ... at most 600" was a
    /// sample 600.4 s ahead, rounded.
    #[test]
    fn the_distance_is_printed_beyond_the_bound() {
        assert_eq!(beyond(600.4, 600.0), "600.4");
        assert_eq!(beyond(600.04, 600.0), "600.04");
        assert_eq!(beyond(1e6, 600.0), "1000000.0");
        let b = json_batch(vec![(NOW + 600.4, 1.0)], "values");
        let (_, e) = check_times(&b, &gate(), NOW).unwrap_err();
        assert!(e.error.contains("is 600.4 s ahead"), "{}", e.error);
        // no unit makes it plausible: no hint
        assert!(!e.error.contains("plausible"), "{}", e.error);
    }

    /// A time of 1e300 (or -1e300) is quoted as such, not as 301 digits, in the time and in
    /// the distance.
    #[test]
    fn a_huge_time_is_quoted_in_scientific_form() {
        let b = json_batch(vec![(1e300, 1.0)], "values");
        let (_, e) = check_times(&b, &gate(), NOW).unwrap_err();
        assert!(
            e.error.starts_with("sample time 1e300 is 1e300 s ahead"),
            "{}",
            e.error
        );
        let b = json_batch(vec![(-1e300, 1.0)], "values");
        let (_, e) = check_times(&b, &gate(), NOW).unwrap_err();
        assert!(
            e.error.starts_with("sample time -1e300 is 1e300 s behind"),
            "{}",
            e.error
        );
        assert_eq!(beyond(2.5e17, 600.0), "2.5e17");
    }

    #[test]
    fn a_time_plausible_in_another_unit_names_it() {
        let hint = |t: f64, precision: Option<Precision>| {
            let mut b = json_batch(vec![(t, 1.0)], "values");
            if precision.is_some() {
                b.lines = Some(vec![1]);
                b.precision = precision;
            }
            check_times(&b, &gate(), NOW).unwrap_err().1.error
        };
        // JSON `start` in ms, us, ns; and in ks (1e3 times too small)
        for (t, unit) in [(NOW * 1e3, "ms"), (NOW * 1e6, "us"), (NOW * 1e9, "ns")] {
            let e = hint(t, None);
            assert!(e.contains(&format!("is it in {unit}?")), "{e}");
            assert!(e.contains("Unix seconds"), "{e}");
        }
        let e = hint(NOW / 1e3, None);
        assert!(
            e.contains("1e3 times larger") && e.contains("check the unit"),
            "{e}"
        );
        // line protocol: ms read as ns, us read as ns, s read as ms, ns read as s
        for (t, p, unit) in [
            (NOW * 1e-6, Precision::Ns, "ms"),
            (NOW * 1e-3, Precision::Ns, "us"),
            (NOW * 1e-3, Precision::Ms, "s"),
            (NOW * 1e9, Precision::S, "ns"),
        ] {
            let e = hint(t, Some(p));
            assert!(e.contains(&format!("`?precision={unit}`")), "{p:?}: {e}");
        }
        // 1e3 hours is no unit: the factor only
        let e = hint(NOW * 1e-3, Some(Precision::H));
        assert!(e.contains("check the unit"), "{e}");
    }

    #[test]
    fn zero_turns_a_bound_off() {
        let cfg = GateConfig {
            max_future_seconds: 0.0,
            max_past_seconds: 0.0,
            ..GateConfig::default()
        };
        // year 33658 and 1970
        let b = json_batch(vec![(1e12, 1.0), (0.0, 1.0)], "values");
        assert!(check_times(&b, &cfg, NOW).is_ok());
    }

    #[test]
    fn repeated_parameters_are_refused() {
        assert_eq!(single_param(None, "precision"), Ok(None));
        assert_eq!(
            single_param(Some("db=x&precision=s"), "precision"),
            Ok(Some("s".into()))
        );
        let e = single_param(Some("precision=s&precision=ns"), "precision").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("precision"));
        assert!(e.error.contains("more than once"), "{}", e.error);
        // percent-encoded names count too
        assert!(single_param(Some("precision=s&%70recision=ms"), "precision").is_err());
    }
}
