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

use super::config::GateConfig;
use super::ingest::{BadRequest, Batch};
use super::metrics::RejectReason;

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
                "sample time {t} is {:.0} s ahead of the daemon's clock ({now:.0}); gate `{}` \
                 accepts at most max_future_seconds = {future}",
                t - now,
                batch.gate
            ));
            return Err((RejectReason::TooFarInFuture, locate(batch, i, e)));
        }
        if past > 0.0 && t < now - past {
            let e = BadRequest::new(format!(
                "sample time {t} is {:.0} s behind the daemon's clock ({now:.0}); gate `{}` \
                 accepts at most max_past_seconds = {past}",
                now - t,
                batch.gate
            ));
            return Err((RejectReason::TooOld, locate(batch, i, e)));
        }
    }
    Ok(())
}

/// The one value of query parameter `name` in the raw query string `query` (`None` when
/// absent); a parameter given twice is refused, since which one wins is a guess (InfluxDB
/// takes the first, most frameworks the last).
pub fn single_param(query: Option<&str>, name: &str) -> Result<Option<String>, BadRequest> {
    let mut found: Option<String> = None;
    let Some(query) = query else {
        return Ok(None);
    };
    for (k, v) in form_urlencoded::parse(query.as_bytes()) {
        if k == name {
            if let Some(first) = &found {
                return Err(BadRequest::new(format!(
                    "parameter `{name}` given more than once (`{first}` and `{v}`)"
                ))
                .field(name));
            }
            found = Some(v.into_owned());
        }
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
