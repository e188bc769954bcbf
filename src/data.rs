//! Time series and their CSV loading.
//!
//! Every error names the file and the place: line (1-based, the header is line 1), column name,
//! and what was wrong, so that an engineer can fix the file without guessing.

use std::path::{Path, PathBuf};

/// Largest magnitude of a value the analysis takes. Why: its correlations and sums of squares
/// multiply two values and add up to millions of them, so a value near 1.3e154 overflows to
/// infinity, and a singular-value decomposition then panicked on the NaN it made. No physical
/// force or displacement comes near 1e100 in any unit; such a value is a broken sensor or a
/// unit error, refused by name.
pub const MAX_ABS_VALUE: f64 = 1e100;

/// Largest input file read, bytes (1 GiB). Why: the file is read whole, then parsed into two
/// columns of `f64` (16 bytes a row against about 30 of text), so memory is about 1.5 times the
/// file; a day of a gate sampled at 200 Hz is about 17 million rows, 0.5 GB of text. Without a
/// bound `--input /dev/zero` (or a named pipe left open) read until the kernel killed the
/// process at 24 GB.
pub const MAX_INPUT_BYTES: u64 = 1 << 30;

/// How far, as a fraction of a step, a sample time may lie off the uniform grid (and a spacing
/// off the median step) for the series still to count as uniformly sampled.
///
/// Why 1 %: a uniformly sampled record exported with rounded times is not exactly uniform. A
/// 3000 Hz record printed with 6 decimals (as DAQ software and Excel print it) is off its grid by
/// up to 0.5 us, 0.15 % of its step, and its spacings differ by twice that; a logger's timestamp
/// jitter adds a few thousandths of a percent. The grid is the one that fits the times best
/// (least squares, [`TimeSeries::nonuniform_at`]). The analysis of a uniform record treats
/// sample `i` as taken at `t0 + i*h` (rate `1/h`, `h` from the first time to the last); that
/// grid lies within `e*h` of the fitted one wherever the times do, so a time within `e*h` of
/// the fitted grid is within `2*e*h` of the analysis's, which changes the sample by at most
/// `4*pi*e*f/fs` of the amplitude at frequency `f` and rate `fs`: 1.3 % at `e` = 1 % for a
/// gate sampled ten times faster than it vibrates, at the level of a load cell's noise. A
/// missing sample puts the times half a step or more off the grid, irregular sampling (a
/// clock that speeds up, samples taken when an event comes) more than 1 %: both are refused.
pub const GRID_TOLERANCE: f64 = 0.01;

/// How far, as a fraction of the median spacing, one spacing must be off it for
/// [`TimeSeries::grid_departure`] to name it as a gap (or as samples crowded together) rather
/// than as jitter: a missing sample doubles a spacing (100 %); a timestamp jittered by the
/// 1 % the grid allows moves two spacings by 1 % each.
pub const GAP_FRACTION: f64 = 0.25;

/// A sampled signal: strictly increasing times and finite values.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeSeries {
    /// Sample times, strictly increasing.
    pub t: Vec<f64>,
    /// Sample values.
    pub y: Vec<f64>,
}

/// Where sample times first leave a uniform grid ([`TimeSeries::grid_departure`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GridDeparture {
    /// Sample `index` comes `spacing` seconds after the previous one, where the median spacing
    /// is `step`: a gap (`spacing > step`) or samples closer together.
    Spacing {
        index: usize,
        spacing: f64,
        step: f64,
    },
    /// No spacing is far off the median's, yet sample `index` is `deviation` seconds off the
    /// least-squares grid of `step`, more than [`GRID_TOLERANCE`] of a step: timestamps that
    /// jitter, or a clock that drifts.
    OffGrid {
        index: usize,
        deviation: f64,
        step: f64,
    },
}

fn no_header(comment: bool) -> &'static str {
    if comment {
        "line 1 starts with '#', which marks a comment line (skipped), and the first line after the comments holds numbers; the header must not start with '#': name the columns on the first line, e.g. 't,y' (numpy.savetxt: pass comments='')"
    } else {
        "line 1 has no header (it holds numbers); the first line must name the columns, e.g. 't,y'"
    }
}

/// A problem with input data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DataError {
    /// The file cannot be read.
    #[error("{path}: cannot read the file: {reason}")]
    Io { path: PathBuf, reason: String },
    /// The file is larger than [`MAX_INPUT_BYTES`].
    #[error("{path}: the file holds more than {bound} bytes, the most gatewatch reads (1 GiB); split the record (a day of a gate at 200 Hz is about 0.5 GB)")]
    TooBig { path: PathBuf, bound: u64 },
    /// The file is empty.
    #[error("{path}: the file is empty")]
    Empty { path: PathBuf },
    /// The first line holds numbers, not column names (`comment`: the first line was skipped
    /// as a comment, `#` first, and the line the reader took for the header holds numbers).
    #[error("{path}: {}", no_header(*.comment))]
    NoHeader { path: PathBuf, comment: bool },
    /// A requested column is not in the header.
    #[error("{path}: no column named '{column}' (the header has: {available})")]
    UnknownColumn {
        path: PathBuf,
        column: String,
        available: String,
    },
    /// A malformed row (wrong number of fields, bad quoting, bad encoding).
    #[error("{path}: line {line}: {reason}")]
    Malformed {
        path: PathBuf,
        line: u64,
        reason: String,
    },
    /// A cell that is not a number.
    #[error("{path}: line {line}, column '{column}': '{cell}' is not a number")]
    NotANumber {
        path: PathBuf,
        line: u64,
        column: String,
        cell: String,
    },
    /// A NaN or infinite value.
    #[error("{path}: line {line}, column '{column}': value is not finite ({cell})")]
    NotFinite {
        path: PathBuf,
        line: u64,
        column: String,
        cell: String,
    },
    /// A value beyond [`MAX_ABS_VALUE`].
    #[error("{path}: line {line}, column '{column}': value {cell} is beyond +-1e100, where the analysis overflows (a broken sensor or a unit error?)")]
    TooLarge {
        path: PathBuf,
        line: u64,
        column: String,
        cell: String,
    },
    /// The header is one field holding semicolons or tabs: a CSV from a locale whose list
    /// separator is not the comma (European Excel), which the comma-separated reader sees as
    /// a single column.
    #[error("{path}: line 1: the file looks separated by {separator} (the header reads '{header}'); gatewatch reads comma-separated CSV with a decimal point: save it with commas as the separator and '.' as the decimal mark (where the comma is the decimal mark, change that first: in Excel, Options > Advanced > Decimal separator)")]
    NotCommaSeparated {
        path: PathBuf,
        separator: &'static str,
        header: String,
    },
    /// A requested column named twice in the header.
    #[error("{path}: line 1: column '{column}' appears {count} times in the header; name each column once")]
    DuplicateColumn {
        path: PathBuf,
        column: String,
        count: usize,
    },
    /// Time does not increase strictly.
    #[error(
        "{path}: line {line}, column '{column}': time {t} does not increase (previous {previous})"
    )]
    TimeNotIncreasing {
        path: PathBuf,
        line: u64,
        column: String,
        t: f64,
        previous: f64,
    },
    /// A header but no data rows.
    #[error("{path}: the file has a header but no data rows")]
    NoRows { path: PathBuf },
    /// Times and values of different lengths, or other inconsistent arrays.
    #[error("invalid series: {0}")]
    Invalid(String),
}

impl TimeSeries {
    /// A series from arrays, checked: equal lengths, finite, strictly increasing times.
    pub fn new(t: Vec<f64>, y: Vec<f64>) -> Result<TimeSeries, DataError> {
        if t.len() != y.len() {
            return Err(DataError::Invalid(format!(
                "{} times but {} values",
                t.len(),
                y.len()
            )));
        }
        if let Some(i) = t.iter().chain(&y).position(|v| !v.is_finite()) {
            return Err(DataError::Invalid(format!(
                "non-finite {} at index {}",
                if i < t.len() { "time" } else { "value" },
                i % t.len().max(1)
            )));
        }
        if let Some(i) = y.iter().position(|v| v.abs() > MAX_ABS_VALUE) {
            return Err(DataError::Invalid(format!(
                "value {:e} at index {i} is beyond +-1e100, where the analysis overflows",
                y[i]
            )));
        }
        if let Some(i) = t.windows(2).position(|w| w[1] <= w[0]) {
            return Err(DataError::Invalid(format!(
                "time does not increase at index {}",
                i + 1
            )));
        }
        Ok(TimeSeries { t, y })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// The sample step when the times are uniform, `None` otherwise ([`Self::nonuniform_at`]).
    pub fn uniform_step(&self) -> Option<f64> {
        let n = self.t.len();
        if n < 2 || self.nonuniform_at().is_some() {
            return None;
        }
        Some((self.t[n - 1] - self.t[0]) / (n - 1) as f64)
    }

    /// The first sample off the uniform grid, as `(index, deviation in s, step in s)`; `None`
    /// when every time lies on it within [`GRID_TOLERANCE`] of a step plus the rounding of
    /// times of that size (eight ulps of the largest: about 3e-6 s at Unix epoch seconds). The
    /// grid is the least-squares line through the times (`t_i ~ a + i*h`). Why not the grid
    /// from the first time to the last: it is anchored on two samples, so their own jitter
    /// counted twice, and times jittered by 0.6 % of a step about an exact grid were refused
    /// while the rule said 1 %. Fewer than two samples have no grid and nothing off it (`None`;
    /// [`Self::uniform_step`] is `None` for them too).
    pub fn nonuniform_at(&self) -> Option<(usize, f64, f64)> {
        let (a, h) = self.fitted_grid()?;
        let t0 = self.t[0];
        let tn = self.t[self.t.len() - 1];
        let tol = GRID_TOLERANCE * h + 8.0 * f64::EPSILON * t0.abs().max(tn.abs());
        self.t.iter().enumerate().find_map(|(i, &ti)| {
            let d = (ti - t0) - (a + i as f64 * h);
            (d.abs() > tol).then_some((i, d, h))
        })
    }

    /// The least-squares grid of the times, `t_i - t_0 ~ a + i*h`, as `(a, h)` (`None` under
    /// two samples). Times are taken from the first one, so epoch seconds lose nothing.
    fn fitted_grid(&self) -> Option<(f64, f64)> {
        let n = self.t.len();
        if n < 2 {
            return None;
        }
        let t0 = self.t[0];
        let mean_i = (n - 1) as f64 / 2.0;
        let mean_t = self.t.iter().map(|&t| t - t0).sum::<f64>() / n as f64;
        let (mut sxy, mut sxx) = (0.0, 0.0);
        for (i, &t) in self.t.iter().enumerate() {
            let x = i as f64 - mean_i;
            sxy += x * (t - t0 - mean_t);
            sxx += x * x;
        }
        let h = sxy / sxx;
        Some((mean_t - h * mean_i, h))
    }

    /// Where the times first leave a uniform grid, told for a person: `None` exactly when
    /// [`Self::nonuniform_at`] is `None` (that check decides; this one only explains). A
    /// spacing more than [`GAP_FRACTION`] off the median spacing is named as such (a hole, or
    /// samples crowded together); the median, so that a hole does not skew the step. Otherwise
    /// the times jitter or drift off their grid by more than [`GRID_TOLERANCE`] of a step, and
    /// the first sample off it is named with its share of a step.
    pub fn grid_departure(&self) -> Option<GridDeparture> {
        let (index, deviation, step) = self.nonuniform_at()?;
        let mut spacings: Vec<f64> = self.t.windows(2).map(|w| w[1] - w[0]).collect();
        let mid = spacings.len() / 2;
        let median = *spacings.select_nth_unstable_by(mid, f64::total_cmp).1;
        let gap = self
            .t
            .windows(2)
            .position(|w| ((w[1] - w[0]) - median).abs() > GAP_FRACTION * median);
        Some(match gap {
            Some(j) => GridDeparture::Spacing {
                index: j + 1,
                spacing: self.t[j + 1] - self.t[j],
                step: median,
            },
            None => GridDeparture::OffGrid {
                index,
                deviation,
                step,
            },
        })
    }

    /// Loads two columns of a CSV file with a header row.
    pub fn from_csv(
        path: &Path,
        time_column: &str,
        value_column: &str,
    ) -> Result<TimeSeries, DataError> {
        Self::from_csv_with_lines(path, time_column, value_column).map(|(series, _)| series)
    }

    /// [`Self::from_csv`], with the file's line number (1-based, the header is line 1) of each
    /// sample, so that a later finding about sample `i` (a gap in the times) can name its line:
    /// comment and blank lines make it differ from `i + 2`.
    pub fn from_csv_with_lines(
        path: &Path,
        time_column: &str,
        value_column: &str,
    ) -> Result<(TimeSeries, Vec<u64>), DataError> {
        let p = || path.to_path_buf();
        let mut bytes = read_bounded(path, MAX_INPUT_BYTES)?;
        // Lines ending in a lone "\r" (old Mac files, some loggers): the reader splits rows at
        // it, but a comment runs to the next "\n", so a `#` line swallowed the rest of such a
        // file without a word, and every error was named line 1. Made "\n", one byte for one,
        // so lines and offsets stay the file's.
        for i in 0..bytes.len() {
            if bytes[i] == b'\r' && bytes.get(i + 1) != Some(&b'\n') {
                bytes[i] = b'\n';
            }
        }
        if bytes.iter().all(|b| b.is_ascii_whitespace()) {
            return Err(DataError::Empty { path: p() });
        }
        // UTF-16 (Excel's "Unicode text", Windows tools): a byte-order mark, or a zero byte
        // beside every ASCII character. Without the mark it is valid UTF-8 full of NULs, and
        // would be reported as a header with no column 't'.
        if bytes.starts_with(&[0xFF, 0xFE])
            || bytes.starts_with(&[0xFE, 0xFF])
            || bytes.iter().take(2).any(|&b| b == 0)
        {
            return Err(DataError::Malformed {
                path: p(),
                line: 1,
                reason: format!("the file is UTF-16 text, not UTF-8; {SAVE_AS_UTF8}"),
            });
        }
        // flexible: the fields are counted here, where a line of spaces can be told from a
        // row that lacks a field
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .flexible(true)
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .from_reader(bytes.as_slice());
        let headers = reader
            .headers()
            .map_err(|e| malformed(path, &bytes, &e))?
            .clone();
        // A stray quote in the header swallowed the file into one column name, which the
        // "no column named" error then printed whole (8.9 MB on stderr for a 200,000-line file).
        let header_line = headers
            .position()
            .map_or(1, |pos| LineCounter::new(&bytes).line_at(pos.byte()));
        if let Some(reason) = multi_line_cell(&headers, None, header_line) {
            return Err(DataError::Malformed {
                path: p(),
                line: header_line,
                reason: format!("the header: {reason}"),
            });
        }
        if headers.iter().all(|h| h.parse::<f64>().is_ok()) {
            let first = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
            return Err(DataError::NoHeader {
                path: p(),
                comment: first.trim_ascii_start().starts_with(b"#"),
            });
        }
        let find = |name: &str| {
            let count = headers.iter().filter(|h| *h == name).count();
            if count > 1 {
                return Err(DataError::DuplicateColumn {
                    path: p(),
                    column: name.to_string(),
                    count,
                });
            }
            headers
                .iter()
                .position(|h| h == name)
                .ok_or_else(|| DataError::UnknownColumn {
                    path: p(),
                    column: name.to_string(),
                    available: headers.iter().map(shown).collect::<Vec<_>>().join(", "),
                })
        };
        // Only when a column is missing: a file that names its columns and merely contains a
        // semicolon somewhere in a header cell loads as before (detect and explain, no change
        // of parsing).
        let lookup = find(time_column).and_then(|ti| find(value_column).map(|yi| (ti, yi)));
        let (ti, yi) = match lookup {
            Err(DataError::UnknownColumn { .. }) if headers.len() == 1 => {
                let header = headers.get(0).unwrap_or("");
                let separator = if header.contains(';') {
                    Some("';'")
                } else if header.contains('\t') {
                    Some("tabs")
                } else {
                    None
                };
                match separator {
                    Some(separator) => {
                        return Err(DataError::NotCommaSeparated {
                            path: p(),
                            separator,
                            header: header.replace('\t', "\\t"),
                        })
                    }
                    None => lookup?,
                }
            }
            other => other?,
        };
        let (mut t, mut y, mut lines) = (Vec::new(), Vec::new(), Vec::new());
        let mut line_counter = LineCounter::new(&bytes);
        let mut record = csv::StringRecord::new();
        loop {
            match reader.read_record(&mut record) {
                Ok(true) => {}
                Ok(false) => break,
                Err(e) => return Err(malformed(path, &bytes, &e)),
            }
            let line = record
                .position()
                .map_or(0, |pos| line_counter.line_at(pos.byte()));
            if record.len() == 1 && record.get(0) == Some("") {
                continue; // a line of spaces: blank, as the empty lines the reader skips
            }
            check_record(&record, &headers, line).map_err(|reason| DataError::Malformed {
                path: p(),
                line,
                reason,
            })?;
            let cell = |index: usize, column: &str| -> Result<f64, DataError> {
                let text = record.get(index).unwrap_or("");
                let v: f64 = text.parse().map_err(|_| DataError::NotANumber {
                    path: p(),
                    line,
                    column: column.to_string(),
                    cell: shown(text),
                })?;
                // `1e400` parses as infinity: a finite number too large, not "inf" or "NaN"
                let spelled = text.to_ascii_lowercase();
                if v.is_nan() || (v.is_infinite() && spelled.contains("inf")) {
                    return Err(DataError::NotFinite {
                        path: p(),
                        line,
                        column: column.to_string(),
                        cell: shown(text),
                    });
                }
                if v.abs() > MAX_ABS_VALUE {
                    return Err(DataError::TooLarge {
                        path: p(),
                        line,
                        column: column.to_string(),
                        cell: shown(text),
                    });
                }
                Ok(v)
            };
            let tv = cell(ti, time_column)?;
            let yv = cell(yi, value_column)?;
            if let Some(&previous) = t.last() {
                if tv <= previous {
                    return Err(DataError::TimeNotIncreasing {
                        path: p(),
                        line,
                        column: time_column.to_string(),
                        t: tv,
                        previous,
                    });
                }
            }
            t.push(tv);
            y.push(yv);
            lines.push(line);
        }
        if t.is_empty() {
            return Err(DataError::NoRows { path: p() });
        }
        Ok((TimeSeries { t, y }, lines))
    }

    /// Writes the series as CSV with the given column names.
    pub fn to_csv(
        &self,
        path: &Path,
        time_column: &str,
        value_column: &str,
    ) -> std::io::Result<()> {
        let mut w = csv::Writer::from_path(path)?;
        w.write_record([time_column, value_column])?;
        for (t, y) in self.t.iter().zip(&self.y) {
            w.write_record([format!("{t:.17e}"), format!("{y:.17e}")])?;
        }
        w.flush()
    }
}

/// Whether a record read from `line` is one row of the file with the header's fields: a cell
/// that holds a line break is refused, naming where its quote opened. Why: RFC 4180 lets a
/// quoted cell run over lines, so one stray `"` (a logger's comment `"valve open`) made every
/// line up to the next quote part of that cell, and those rows vanished without a word (or
/// surfaced as a "gap" in the times); a record of measurements has no cell that spans lines.
fn check_record(
    record: &csv::StringRecord,
    headers: &csv::StringRecord,
    line: u64,
) -> Result<(), String> {
    if let Some(reason) = multi_line_cell(record, Some(headers), line) {
        return Err(reason);
    }
    if record.len() != headers.len() {
        let fields = |n: usize| {
            if n == 1 {
                "1 field".to_string()
            } else {
                format!("{n} fields")
            }
        };
        return Err(format!(
            "{}, but the header has {}",
            fields(record.len()),
            headers.len()
        ));
    }
    Ok(())
}

/// Why `record`, which starts on `line`, is malformed when a cell of it runs over several
/// lines (a quote that opens a cell and is not closed on its line); the column is named by the
/// header's name when there is a header.
fn multi_line_cell(
    record: &csv::StringRecord,
    headers: Option<&csv::StringRecord>,
    line: u64,
) -> Option<String> {
    let (j, cell) = record
        .iter()
        .enumerate()
        .find(|(_, c)| c.contains(['\n', '\r']))?;
    let breaks = cell.matches('\n').count() as u64;
    let column = headers
        .and_then(|h| h.get(j))
        .map_or_else(|| format!("{}", j + 1), |h| format!("'{}'", shown(h)));
    Some(format!(
        "column {column}: a quote (\") opens a cell on this line that is not closed on it, so the cell runs over {} lines, to line {} (it reads '{}'); remove the stray quote or close it",
        breaks + 1,
        line + breaks,
        shown(cell)
    ))
}

/// Longest part of a cell an error quotes.
const SHOWN_CHARS: usize = 40;

/// A cell as an error quotes it: control characters escaped (a NUL byte printed raw made
/// `1.2\0` look like a number on a terminal) and cut after [`SHOWN_CHARS`] characters (a cell
/// that swallowed the rest of the file was printed whole: 1500 lines as "one line").
fn shown(cell: &str) -> String {
    let mut out = String::new();
    for (i, c) in cell.chars().enumerate() {
        if i == SHOWN_CHARS {
            out.push_str("...");
            break;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// The way out of an encoding error: Excel's "CSV" is the Windows code page (cp1252: a `µ` or
/// `°` in a header is one byte no UTF-8 reader takes), its "CSV UTF-8" is what is read here.
const SAVE_AS_UTF8: &str = "save it as \"CSV UTF-8\" (Excel: Save As, CSV UTF-8 (comma delimited))";

/// The line (1-based) of a record that starts at a byte offset into the file. Why not the csv
/// reader's own line: it does not count the comment and blank lines it skips, so every line
/// after a `# comment` was named too early; and its offset of a record is where those skipped
/// lines begin, so they are skipped here too. Offsets asked for only grow, so the file is
/// scanned once.
struct LineCounter<'a> {
    bytes: &'a [u8],
    /// Bytes counted so far, and the line at that offset.
    offset: usize,
    line: u64,
}

impl<'a> LineCounter<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        LineCounter {
            bytes,
            offset: 0,
            line: 1,
        }
    }

    fn line_at(&mut self, byte: u64) -> u64 {
        let mut end = usize::try_from(byte)
            .unwrap_or(usize::MAX)
            .min(self.bytes.len());
        // past the comment lines (`#` first) and blank lines the reader skipped
        while let Some(&b) = self.bytes.get(end) {
            match b {
                b'\n' | b'\r' => end += 1,
                b'#' => {
                    end = self.bytes[end..]
                        .iter()
                        .position(|&c| c == b'\n')
                        .map_or(self.bytes.len(), |p| end + p + 1)
                }
                _ => break,
            }
        }
        if end < self.offset {
            // not the growing offsets this is for: count from the start
            *self = LineCounter::new(self.bytes);
        }
        self.line += self.bytes[self.offset..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count() as u64;
        self.offset = end;
        self.line
    }
}

/// The whole file, refused past `limit` bytes ([`MAX_INPUT_BYTES`]; read through the bound,
/// not by its metadata: a pipe or a device has no size to ask).
fn read_bounded(path: &Path, limit: u64) -> Result<Vec<u8>, DataError> {
    use std::io::Read;
    let io = |e: std::io::Error| DataError::Io {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .map_err(io)?
        .take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(DataError::TooBig {
            path: path.to_path_buf(),
            bound: limit,
        });
    }
    Ok(bytes)
}

fn malformed(path: &Path, bytes: &[u8], e: &csv::Error) -> DataError {
    let line = e
        .position()
        .map_or(0, |p| LineCounter::new(bytes).line_at(p.byte()));
    let reason = match e.kind() {
        csv::ErrorKind::Utf8 { .. } => format!("not valid UTF-8; {SAVE_AS_UTF8}"),
        _ => e.to_string(),
    };
    DataError::Malformed {
        path: path.to_path_buf(),
        line,
        reason,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn file(text: &str) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().unwrap();
        f.write_all(text.as_bytes()).unwrap();
        f
    }

    fn load(text: &str) -> Result<TimeSeries, DataError> {
        let f = file(text);
        TimeSeries::from_csv(f.path(), "t", "y")
    }

    #[test]
    fn loads_columns_by_name_in_any_order() {
        let s = load("y, t ,z\n1.5,0,9\n2.5, 0.1 ,9\n# a comment\n-3e-1,0.2,9\n").unwrap();
        assert_eq!(s.t, vec![0.0, 0.1, 0.2]);
        assert_eq!(s.y, vec![1.5, 2.5, -0.3]);
    }

    #[test]
    fn errors_name_the_place() {
        let f = file("t,y\n0,1\n0.1,abc\n");
        let e = TimeSeries::from_csv(f.path(), "t", "y").unwrap_err();
        assert!(
            matches!(e, DataError::NotANumber { line: 3, ref column, ref cell, .. } if column == "y" && cell == "abc"),
            "{e}"
        );
        assert!(
            e.to_string()
                .contains("line 3, column 'y': 'abc' is not a number"),
            "{e}"
        );

        let e = load("t,y\n0,1\n0.1,NaN\n").unwrap_err();
        assert!(matches!(e, DataError::NotFinite { line: 3, .. }), "{e}");
        let e = load("t,y\n0,1\n0.1,inf\n").unwrap_err();
        assert!(matches!(e, DataError::NotFinite { line: 3, .. }), "{e}");
        // a finite number past f64's range is too large, not "not finite"
        for big in ["1e400", "-1e400"] {
            let e = load(&format!("t,y\n0,1\n0.1,{big}\n")).unwrap_err();
            assert!(matches!(e, DataError::TooLarge { line: 3, .. }), "{e}");
        }
        let e = load("t,y\n0,1\n0.1,2\n0.1,3\n").unwrap_err();
        assert!(
            matches!(e, DataError::TimeNotIncreasing { line: 4, .. }),
            "{e}"
        );
        let e = load("t,y\n0,1\n0.1,2,5\n").unwrap_err();
        assert!(matches!(e, DataError::Malformed { line: 3, .. }), "{e}");
        assert!(
            e.to_string().contains("3 fields, but the header has 2"),
            "{e}"
        );
        let e = load("t,y\n0,1\n0.1,2e154\n").unwrap_err();
        assert!(
            matches!(e, DataError::TooLarge { line: 3, ref cell, .. } if cell == "2e154"),
            "{e}"
        );
        assert!(e.to_string().contains("beyond +-1e100"), "{e}");
        // at the bound it loads (Unix nanoseconds reach 1.7e18); past it, times are refused
        // too (1e300 s gave a rate printed with 300 digits)
        assert!(load("t,y\n0,1e100\n1e100,-1e100\n").is_ok());
        assert!(matches!(
            load("t,y\n0,1\n1e101,-1\n"),
            Err(DataError::TooLarge { line: 3, .. })
        ));
        assert!(TimeSeries::new(vec![0.0, 1.0], vec![1.0, -1e101]).is_err());
    }

    /// A stray quote makes the reader run one cell over the following lines; those rows must
    /// not vanish (they did, exit 0), and the error names the line and column where the quote
    /// opened, quoting a short, escaped part of the cell, not the rest of the file.
    #[test]
    fn a_stray_quote_is_named_not_swallowed() {
        let mut text = String::from("t,y,comment\n");
        for i in 0..20 {
            let note = match i {
                5 => "\"valve",
                15 => "open\"",
                _ => "ok",
            };
            text.push_str(&format!("{},{},{note}\n", i as f64 * 0.1, i));
        }
        let e = load(&text).unwrap_err();
        assert!(matches!(e, DataError::Malformed { line: 7, .. }), "{e}");
        let message = e.to_string();
        assert!(message.contains("column 'comment'"), "{message}");
        assert!(
            message.contains("runs over 11 lines, to line 17"),
            "{message}"
        );
        assert!(message.contains("(it reads 'valve\\n0.6"), "{message}");
        // an unclosed quote in the value column, to the end of a long file: one short line
        let mut text = String::from("t,y\n");
        for i in 0..2000 {
            let q = if i == 3 { "\"" } else { "" };
            text.push_str(&format!("{},{q}{}\n", i as f64 * 0.1, i));
        }
        let message = load(&text).unwrap_err().to_string();
        assert!(message.contains("line 5: column 'y'"), "{message}");
        assert!(message.contains("1997 lines, to line 2001"), "{message}");
        assert!(message.len() < 400 && !message.contains('\n'), "{message}");
    }

    /// A stray quote in the header made the whole file one column name, and the "no column
    /// named" error printed it whole (8.9 MB on stderr); a header name with a control character
    /// was listed as if it were the name asked for (`the header has: t, y` for `y\0`).
    #[test]
    fn a_stray_quote_in_the_header_is_named_where_it_opens() {
        let mut text = String::from("# logger export\n\"t,y\n");
        for i in 0..2000 {
            text.push_str(&format!("{},{}\n", i as f64 * 0.1, i));
        }
        let e = load(&text).unwrap_err();
        assert!(matches!(e, DataError::Malformed { line: 2, .. }), "{e}");
        let message = e.to_string();
        assert!(
            message.contains("line 2: the header: column 1: a quote (\") opens a cell"),
            "{message}"
        );
        assert!(message.contains("2001 lines, to line 2002"), "{message}");
        assert!(message.len() < 400 && !message.contains('\n'), "{message}");
        let e = load("t,y\u{0}\n0,1\n").unwrap_err().to_string();
        assert!(
            e.contains("no column named 'y' (the header has: t, y\\u{0})"),
            "{e}"
        );
    }

    /// A line of spaces is blank, like an empty line; a short row says "1 field"; a control
    /// character in a cell is escaped in the message.
    #[test]
    fn blank_lines_short_rows_and_control_characters() {
        let s = load("t,y\n0,1\n   \n0.1,2\n").unwrap();
        assert_eq!(s.len(), 2);
        let e = load("t,y\n0,1\n0.1\n").unwrap_err();
        assert!(
            e.to_string()
                .contains("line 3: 1 field, but the header has 2"),
            "{e}"
        );
        let e = load("t,y\n0,1\n0.1,1.2\u{0}5\n").unwrap_err();
        assert!(
            e.to_string().contains("'1.2\\u{0}5' is not a number"),
            "{e}"
        );
    }

    #[test]
    fn header_problems() {
        assert!(matches!(load(""), Err(DataError::Empty { .. })));
        assert!(matches!(load(" \n\n"), Err(DataError::Empty { .. })));
        assert!(matches!(
            load("0,1\n1,2\n"),
            Err(DataError::NoHeader { .. })
        ));
        assert!(matches!(load("t,y\n"), Err(DataError::NoRows { .. })));
        let e = load("time,y\n0,1\n").unwrap_err();
        assert!(matches!(e, DataError::UnknownColumn { ref column, .. } if column == "t"));
        assert!(e.to_string().contains("the header has: time, y"), "{e}");
        let e = load("t,y,y\n0,1,2\n").unwrap_err();
        assert!(
            matches!(e, DataError::DuplicateColumn { ref column, count: 2, .. } if column == "y"),
            "{e}"
        );
        // a repeated column nobody asked for is no ambiguity
        assert!(load("t,y,note,note\n0,1,a,b\n").is_ok());
    }

    /// A semicolon- or tab-separated file is named as such (not as a missing column 't'); an
    /// encoding other than UTF-8 gets the way to save it as UTF-8.
    #[test]
    fn other_separators_and_encodings_are_explained() {
        for (text, sep) in [("t;y\n0;1\n", "';'"), ("t\ty\n0\t1\n", "tabs")] {
            let e = load(text).unwrap_err();
            assert!(
                matches!(e, DataError::NotCommaSeparated { separator, .. } if separator == sep),
                "{e}"
            );
            let msg = e.to_string();
            assert!(
                msg.contains(": line 1: the file looks separated by"),
                "{msg}"
            );
            assert!(msg.contains("comma-separated"), "{msg}");
        }
        // A semicolon inside a header that names its columns changes nothing.
        assert!(load("t,y,note;x\n0,1,a\n").is_ok());
        // A missing column in a one-column file without separators is still that.
        assert!(matches!(
            load("time\n0\n"),
            Err(DataError::UnknownColumn { .. })
        ));
        // cp1252 `µ` (0xB5) in the header.
        let mut f = tempfile::NamedTempFile::new().unwrap();
        f.write_all(b"t,y \xb5m\n0,1\n").unwrap();
        let e = TimeSeries::from_csv(f.path(), "t", "y").unwrap_err();
        assert!(matches!(e, DataError::Malformed { line: 1, .. }), "{e}");
        assert!(
            e.to_string()
                .contains("not valid UTF-8; save it as \"CSV UTF-8\""),
            "{e}"
        );
        // UTF-16 with and without its byte-order mark.
        let utf16: Vec<u8> = "t,y\n0,1\n"
            .encode_utf16()
            .flat_map(u16::to_le_bytes)
            .collect();
        for bytes in [[&[0xFF, 0xFE][..], &utf16].concat(), utf16.clone()] {
            let mut f = tempfile::NamedTempFile::new().unwrap();
            f.write_all(&bytes).unwrap();
            let e = TimeSeries::from_csv(f.path(), "t", "y").unwrap_err();
            assert!(e.to_string().contains("line 1: the file is UTF-16"), "{e}");
            assert!(e.to_string().contains("CSV UTF-8"), "{e}");
        }
    }

    /// Times at Unix-epoch magnitude are uniform although no f64 holds them exactly; a sample
    /// 5 % of a step off is not, and is named.
    #[test]
    fn uniform_times_at_epoch_magnitude() {
        let h = 0.005;
        let t: Vec<f64> = (0..2000).map(|i| 1.7e9 + i as f64 * h).collect();
        let s = TimeSeries::new(t.clone(), vec![0.0; 2000]).unwrap();
        let step = s.uniform_step().expect("uniform at epoch magnitude");
        assert!((step - h).abs() < 1e-9, "{step}");
        let mut off = t;
        off[700] += 0.05 * h;
        let s = TimeSeries::new(off, vec![0.0; 2000]).unwrap();
        assert_eq!(s.uniform_step(), None);
        let (i, d, _) = s.nonuniform_at().unwrap();
        assert_eq!(i, 700);
        assert!((d - 0.05 * h).abs() < 1e-6, "{d}");
        // one sample: no grid, so no step and no sample off it
        let one = TimeSeries::new(vec![1.7e9], vec![0.0]).unwrap();
        assert_eq!((one.uniform_step(), one.nonuniform_at()), (None, None));
    }

    /// A 2 s hole in a 200 Hz record is named where it is (sample 800, its time, its
    /// length), with the step from the median spacing, not as the second sample off a grid
    /// whose step the hole stretched.
    #[test]
    fn a_hole_is_named_where_it_is() {
        let h = 0.005;
        let t: Vec<f64> = (0..1600)
            .map(|i| if i < 800 { i } else { i + 400 } as f64 * h)
            .collect();
        let s = TimeSeries::new(t, vec![0.0; 1600]).unwrap();
        match s.grid_departure() {
            Some(GridDeparture::Spacing {
                index,
                spacing,
                step,
            }) => {
                assert_eq!(index, 800);
                assert!((spacing - 401.0 * h).abs() < 1e-9, "{spacing}");
                assert!((step - h).abs() < 1e-12, "{step}");
            }
            other => panic!("{other:?}"),
        }
        // Uniform: nothing to explain, as nonuniform_at says.
        let u = TimeSeries::new((0..100).map(|i| i as f64 * h).collect(), vec![0.0; 100]).unwrap();
        assert_eq!((u.nonuniform_at(), u.grid_departure()), (None, None));
        // A slow drift (the spacing grows by 2e-7 of a step a sample): every spacing is the
        // median's within 1 % of a step, the times still leave the grid by 0.1 step.
        let drift: Vec<f64> = (0..2000)
            .map(|i| {
                let i = i as f64;
                h * (i + 1e-7 * i * i)
            })
            .collect();
        let d = TimeSeries::new(drift, vec![0.0; 2000]).unwrap();
        assert!(d.nonuniform_at().is_some());
        assert!(
            matches!(d.grid_departure(), Some(GridDeparture::OffGrid { .. })),
            "{:?}",
            d.grid_departure()
        );
    }

    /// Uniformly sampled records as exported, with their times rounded to 6 decimals (300,
    /// 1024 and 3000 Hz: a step of 3.333333 ms prints as 3.333 or 3.334 ms) or jittered by a
    /// few thousandths of a percent, are uniform at the mean rate; a missing sample, or
    /// one sample 5 % of a step late, is not.
    #[test]
    fn rounded_and_jittered_times_are_uniform_gaps_are_not() {
        let rounded = |fs: f64, n: usize| -> Vec<f64> {
            (0..n)
                .map(|i| format!("{:.6}", i as f64 / fs).parse().unwrap())
                .collect()
        };
        for fs in [300.0, 1024.0, 3000.0] {
            let n = 60_000;
            let s = TimeSeries::new(rounded(fs, n), vec![0.0; n]).unwrap();
            assert_eq!(s.grid_departure(), None, "{fs} Hz");
            let step = s.uniform_step().expect("uniform");
            assert!((step * fs - 1.0).abs() < 1e-6, "{fs} Hz: step {step}");
        }
        // 0.002 % timestamp jitter (a deterministic pseudo-random sequence in [-1, 1))
        let h = 1.0 / 3000.0;
        let jitter = |i: usize| ((i * 7919 % 1000) as f64 / 500.0 - 1.0) * 2e-5 * h;
        let t: Vec<f64> = (0..30_000).map(|i| i as f64 * h + jitter(i)).collect();
        let s = TimeSeries::new(t, vec![0.0; 30_000]).unwrap();
        assert_eq!(s.grid_departure(), None);
        // one sample missing at index 1000 of the rounded 3000 Hz record
        let mut gap = rounded(3000.0, 3001);
        gap.remove(1000);
        let s = TimeSeries::new(gap, vec![0.0; 3000]).unwrap();
        assert_eq!(s.uniform_step(), None);
        match s.grid_departure() {
            Some(GridDeparture::Spacing {
                index,
                spacing,
                step,
            }) => {
                assert_eq!(index, 1000);
                assert!((spacing / step - 2.0).abs() < 0.01, "{spacing} {step}");
            }
            other => panic!("{other:?}"),
        }
        // one sample 5 % of a step late: off the grid, not a gap
        let mut late = rounded(3000.0, 3000);
        late[2000] += 0.05 * h;
        let (index, deviation, step) = off_grid(&TimeSeries::new(late, vec![0.0; 3000]).unwrap());
        assert_eq!(index, 2000);
        assert!(
            (deviation / step - 0.05).abs() < 0.001,
            "{deviation} {step}"
        );
    }

    /// The sample a series' [`GridDeparture::OffGrid`] names, with its deviation and step
    /// (panics on any other explanation).
    fn off_grid(s: &TimeSeries) -> (usize, f64, f64) {
        match s.grid_departure() {
            Some(GridDeparture::OffGrid {
                index,
                deviation,
                step,
            }) => (index, deviation, step),
            other => panic!("{other:?}"),
        }
    }

    /// "Every time within 1 % of a step of the uniform grid" holds about the grid that fits
    /// the times best: timestamps alternating 0.6 % of a step either side of an exact 200 Hz
    /// grid, or jittered at random by up to 0.8 %, are uniform (the grid from the first time to
    /// the last refused both: its two anchors' jitter counted twice); at 1.5 % they are not, and
    /// the explanation names the first sample off the grid with the true step, not a gap.
    #[test]
    fn jitter_within_the_tolerance_is_uniform_about_the_fitted_grid() {
        let h = 0.005;
        let alternating = |e: f64| -> Vec<f64> {
            (0..2000)
                .map(|i| (i as f64 + if i % 2 == 0 { -e } else { e }) * h)
                .collect()
        };
        let s = TimeSeries::new(alternating(0.006), vec![0.0; 2000]).unwrap();
        assert_eq!(s.nonuniform_at(), None);
        assert!((s.uniform_step().unwrap() - h).abs() < 1e-4 * h);
        let mut rng = 12345u64;
        let mut uniform = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let jittered: Vec<f64> = (0..5000)
            .map(|i| (i as f64 + 0.008 * uniform()) * h)
            .collect();
        let s = TimeSeries::new(jittered, vec![0.0; 5000]).unwrap();
        assert_eq!(s.nonuniform_at(), None);
        let (index, deviation, step) =
            off_grid(&TimeSeries::new(alternating(0.015), vec![0.0; 2000]).unwrap());
        assert_eq!(index, 0);
        assert!((step - h).abs() < 1e-4 * h, "{step}");
        assert!(
            (deviation.abs() / step - 0.015).abs() < 0.001,
            "{deviation}"
        );
    }

    /// The line of each sample, and of each error, is the file's, past comment and blank
    /// lines (the csv reader's own count skipped them: an error on line 6 was named line 3).
    #[test]
    fn lines_of_the_samples() {
        let f = file("t,y\n0,1\n# note\n\n0.1,2\n0.2,3\n");
        let (s, lines) = TimeSeries::from_csv_with_lines(f.path(), "t", "y").unwrap();
        assert_eq!(s.len(), 3);
        assert_eq!(lines, vec![2, 5, 6]);
        let e = load("t,y\n0,1\n# note\n# more\n\n0.1,abc\n").unwrap_err();
        assert!(matches!(e, DataError::NotANumber { line: 6, .. }), "{e}");
        let e = load("t,y\r\n0,1\r\n# note\r\n0.1,2,3\r\n").unwrap_err();
        assert!(matches!(e, DataError::Malformed { line: 4, .. }), "{e}");
        let e = load("# exported\nt,y\n0,1\n0,2\n").unwrap_err();
        assert!(
            matches!(e, DataError::TimeNotIncreasing { line: 4, .. }),
            "{e}"
        );
        // lone "\r" line ends (old Mac files), which the reader splits lines at: every line
        // was named line 1
        let f = file("t,y\r0,1\r# note\r\r0.1,2\r0.2,3\r");
        let (_, lines) = TimeSeries::from_csv_with_lines(f.path(), "t", "y").unwrap();
        assert_eq!(lines, vec![2, 5, 6]);
        let e = load("t,y\r0,1\r0.05,2\r0.1,abc\r").unwrap_err();
        assert!(matches!(e, DataError::NotANumber { line: 4, .. }), "{e}");
    }

    /// numpy.savetxt(..., header='t,y') writes the header as a comment ("# t,y"), which the
    /// reader skips: the error says so instead of calling line 1 numbers.
    #[test]
    fn a_header_written_as_a_comment_is_named() {
        let e = load("# t,y\n0,1\n0.05,2\n").unwrap_err();
        assert!(
            matches!(e, DataError::NoHeader { comment: true, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("line 1 starts with '#'"), "{e}");
        let e = load("0,1\n0.05,2\n").unwrap_err();
        assert!(
            matches!(e, DataError::NoHeader { comment: false, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("line 1 has no header"), "{e}");
    }

    /// Times past +-1e100 are refused as values are (`1e300` gave a sample rate printed with
    /// 300 digits when no trial integrated).
    #[test]
    fn times_beyond_the_bound_are_refused_by_line_and_column() {
        let e = load("t,y\n0,1\n1e300,2\n").unwrap_err();
        assert!(
            matches!(e, DataError::TooLarge { line: 3, ref column, .. } if column == "t"),
            "{e}"
        );
    }

    /// A file is read through a bound: past it, refused by name, however the source goes on
    /// (`/dev/zero` was read until the process was killed at 24 GB).
    #[test]
    fn input_past_the_size_bound_is_refused() {
        let f = file("t,y\n0,1\n0.05,2\n");
        let e = read_bounded(f.path(), 8).unwrap_err();
        assert!(matches!(e, DataError::TooBig { bound: 8, .. }), "{e}");
        assert!(e.to_string().contains("more than 8 bytes"), "{e}");
        assert_eq!(read_bounded(f.path(), 15).unwrap().len(), 15);
        let e = read_bounded(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(matches!(e, DataError::TooBig { .. }), "{e}");
    }

    #[test]
    fn missing_file() {
        let e = TimeSeries::from_csv(Path::new("/nonexistent/x.csv"), "t", "y").unwrap_err();
        assert!(matches!(e, DataError::Io { .. }));
        assert!(e
            .to_string()
            .starts_with("/nonexistent/x.csv: cannot read the file"));
    }

    #[test]
    fn round_trip_and_uniform_step() {
        let s = TimeSeries::new(vec![0.0, 0.5, 1.0], vec![1.0, -2.0, 3.25]).unwrap();
        assert_eq!(s.uniform_step(), Some(0.5));
        let f = tempfile::NamedTempFile::new().unwrap();
        s.to_csv(f.path(), "t", "y").unwrap();
        assert_eq!(TimeSeries::from_csv(f.path(), "t", "y").unwrap(), s);
        let s = TimeSeries::new(vec![0.0, 0.5, 1.1], vec![1.0, 2.0, 3.0]).unwrap();
        assert_eq!(s.uniform_step(), None);
        assert!(TimeSeries::new(vec![0.0, 0.0], vec![1.0, 2.0]).is_err());
        assert!(TimeSeries::new(vec![0.0], vec![1.0, 2.0]).is_err());
        assert!(TimeSeries::new(vec![0.0, 1.0], vec![1.0, f64::NAN]).is_err());
    }
}
