//! The schema and its migrations.
//!
//! Migrations are versioned in code with SQLite's own `PRAGMA user_version` (a header field of
//! the file made for this): [`MIGRATIONS`] is a list of steps, the file's version is the number
//! applied, and each step runs in the same transaction as the version bump (a crash during a
//! migration leaves the file at the old version, whole). That is what `rusqlite_migration`
//! does too; doing it in a few lines avoids a crate that pins our rusqlite version. A file from
//! a newer gatewatch (version above ours) is refused rather than written in a schema we do not
//! know.
//!
//! Version 2 (why in `docs/design.md`, "The history table"): the history is a `WITHOUT ROWID`
//! table keyed by `(gate, window_end, seq)`, so one gate's rows sit together in the file and a
//! day of one gate is a few thousand consecutive pages instead of 17 280 pages each shared
//! with 15 other gates; the summary an engineer filters and plots on is in real columns, so
//! the CSV and the plot need no JSON parsing.

use rusqlite::{params, Connection, Transaction};

use super::row::{compact_damping, unparsed, Summary};

/// One migration step.
enum Step {
    /// A SQL script.
    Sql(&'static str),
    /// Code (rows to transform).
    Code(fn(&Transaction<'_>) -> rusqlite::Result<()>),
}

/// The steps, in order; the file's `user_version` counts those applied.
const MIGRATIONS: &[Step] = &[
    // 1: history, alert state, outbox.
    Step::Sql(
        "CREATE TABLE identifications (
        id INTEGER PRIMARY KEY,
        gate TEXT NOT NULL,
        time REAL NOT NULL,
        window_start REAL NOT NULL,
        window_end REAL NOT NULL,
        equation TEXT NOT NULL,
        coefficients TEXT NOT NULL,
        damping TEXT NOT NULL,
        verdict TEXT NOT NULL,
        fit_nmae REAL NOT NULL,
        path TEXT NOT NULL
    );
    CREATE INDEX identifications_gate_end ON identifications (gate, window_end);
    CREATE INDEX identifications_end ON identifications (window_end);
    CREATE TABLE alert_state (
        gate TEXT PRIMARY KEY,
        state TEXT NOT NULL
    );
    -- AUTOINCREMENT: ids never reused, so the id order is the order of the transitions even
    -- after deletions.
    CREATE TABLE outbox (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        target TEXT NOT NULL,
        fingerprint TEXT NOT NULL,
        status TEXT NOT NULL,
        created REAL NOT NULL,
        batch INTEGER NOT NULL,
        payload TEXT NOT NULL
    );
    CREATE INDEX outbox_target_fingerprint ON outbox (target, fingerprint);",
    ),
    // 2: the history clustered by gate, its summary in columns, the curve thinned.
    Step::Code(to_clustered_history),
];

/// The schema version this build writes (the number of migration steps).
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// The history table of version 2. `seq` orders rows of the same gate and window end in the
/// order they were written (it is the old row id for migrated rows).
const HISTORY_TABLE: &str = "CREATE TABLE history (
        gate TEXT NOT NULL,
        window_end REAL NOT NULL,
        seq INTEGER NOT NULL,
        time REAL NOT NULL,
        window_start REAL NOT NULL,
        zeta0 REAL,
        zeta0_low REAL,
        zeta0_high REAL,
        zeta0_source TEXT,
        frequency_hz REAL,
        trusted INTEGER NOT NULL,
        verdict TEXT NOT NULL,
        regime TEXT,
        fit_nmae REAL NOT NULL,
        path TEXT NOT NULL,
        equation TEXT NOT NULL,
        coefficients TEXT NOT NULL,
        damping TEXT NOT NULL,
        PRIMARY KEY (gate, window_end, seq)
    ) WITHOUT ROWID;
    -- the retention and the size bound delete the oldest across gates
    CREATE INDEX history_end ON history (window_end);";

/// One row of the history table, ready to insert.
pub(crate) struct NewRow<'a> {
    pub gate: &'a str,
    pub window_end: f64,
    pub time: f64,
    pub window_start: f64,
    pub summary: Summary,
    pub verdict: &'a str,
    pub fit_nmae: f64,
    pub path: &'a str,
    pub equation: &'a str,
    pub coefficients: &'a str,
    pub damping: &'a str,
}

/// Inserts a row; `seq`: `None` for the next of its `(gate, window_end)` (0 for the first).
pub(crate) fn insert_row(
    tx: &Transaction<'_>,
    r: &NewRow<'_>,
    seq: Option<i64>,
) -> rusqlite::Result<()> {
    let s = &r.summary;
    tx.prepare_cached(
        "INSERT INTO history (gate, window_end, seq, time, window_start, zeta0, zeta0_low,
            zeta0_high, zeta0_source, frequency_hz, trusted, verdict, regime, fit_nmae, path,
            equation, coefficients, damping)
         VALUES (?1, ?2, coalesce(?3, (SELECT coalesce(max(seq) + 1, 0) FROM history
                                       WHERE gate = ?1 AND window_end = ?2)),
            ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18)",
    )?
    .execute(params![
        r.gate,
        r.window_end,
        seq,
        r.time,
        r.window_start,
        s.zeta0,
        s.zeta0_low,
        s.zeta0_high,
        s.zeta0_source,
        s.frequency_hz,
        s.trusted,
        r.verdict,
        s.regime,
        r.fit_nmae,
        r.path,
        r.equation,
        r.coefficients,
        r.damping,
    ])?;
    Ok(())
}

/// Version 1 to 2: every row copied into the clustered table (in key order, so the new table
/// is written front to back), its curve thinned and its summary extracted; then the old table
/// dropped (its pages are reused by the new rows; the file does not shrink without `VACUUM`).
fn to_clustered_history(tx: &Transaction<'_>) -> rusqlite::Result<()> {
    tx.execute_batch(HISTORY_TABLE)?;
    let mut read = tx.prepare(
        "SELECT id, gate, time, window_start, window_end, equation, coefficients, damping,
            verdict, fit_nmae, path
         FROM identifications ORDER BY gate, window_end, id",
    )?;
    let mut rows = read.query([])?;
    while let Some(row) = rows.next()? {
        let id: i64 = row.get(0)?;
        let gate: String = row.get(1)?;
        let damping_text: String = row.get(7)?;
        let damping = serde_json::from_str(&damping_text)
            .map(|v| compact_damping(&v))
            .unwrap_or_else(|_| unparsed(&damping_text));
        let coefficients: String = row.get(6)?;
        let coefficients = match serde_json::from_str::<serde_json::Value>(&coefficients) {
            Ok(_) => coefficients,
            Err(_) => unparsed(&coefficients).to_string(),
        };
        let verdict: String = row.get(8)?;
        let path: String = row.get(10)?;
        let equation: String = row.get(5)?;
        insert_row(
            tx,
            &NewRow {
                gate: &gate,
                window_end: row.get(4)?,
                time: row.get(2)?,
                window_start: row.get(3)?,
                summary: Summary::of(&damping),
                verdict: &verdict,
                fit_nmae: row.get(9)?,
                path: &path,
                equation: &equation,
                coefficients: &coefficients,
                damping: &damping.to_string(),
            },
            Some(id),
        )?;
    }
    drop(rows);
    drop(read);
    tx.execute_batch("DROP TABLE identifications;")
}

/// Brings the schema to [`SCHEMA_VERSION`]; the message says why it cannot.
pub(crate) fn migrate(c: &mut Connection) -> Result<(), String> {
    let version: i64 = c
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .map_err(|e| e.to_string())?;
    if version > SCHEMA_VERSION {
        return Err(format!(
            "schema version {version} is newer than this gatewatch's ({SCHEMA_VERSION}): \
             written by a newer release"
        ));
    }
    for (i, step) in MIGRATIONS.iter().enumerate().skip(version.max(0) as usize) {
        let to = i + 1;
        let tx = c.transaction().map_err(|e| e.to_string())?;
        match step {
            Step::Sql(script) => tx.execute_batch(script),
            Step::Code(f) => f(&tx),
        }
        .and_then(|()| tx.execute_batch(&format!("PRAGMA user_version = {to}")))
        .and_then(|()| tx.commit())
        .map_err(|e| format!("migration to schema version {to}: {e}"))?;
    }
    Ok(())
}

/// Applies the steps up to `version` only: a file in an old schema, for the migration tests.
#[cfg(test)]
pub(crate) fn migrate_to(c: &mut Connection, version: usize) -> rusqlite::Result<()> {
    for (i, step) in MIGRATIONS.iter().enumerate().take(version) {
        let tx = c.transaction()?;
        match step {
            Step::Sql(script) => tx.execute_batch(script)?,
            Step::Code(f) => f(&tx)?,
        }
        tx.execute_batch(&format!("PRAGMA user_version = {}", i + 1))?;
        tx.commit()?;
    }
    Ok(())
}
