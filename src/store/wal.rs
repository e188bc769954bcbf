//! A check of the store's `-wal` file before SQLite opens it: where its valid prefix ends, and
//! whether frames of the current generation lie beyond that end.
//!
//! Why: SQLite's WAL recovery replays the frames up to the first one whose salts or checksum
//! do not match, drops that frame and every frame after it, and says nothing; `PRAGMA
//! quick_check` passes afterwards. A flipped byte in the middle of the WAL silently cost every
//! transaction committed after it. The format is read here by hand
//! (<https://www.sqlite.org/fileformat.html>, section 4.3 "WAL File Format"): no crate reads a
//! WAL without opening the database, and opening it is what drops the frames.
//!
//! What counts as damage: a frame whose salts are the header's (the current generation, one
//! checkpoint cycle) at or after the first frame SQLite will not replay: its checksum fails,
//! its page number is 0, or it is cut short at the end of the file. Frames whose salts differ
//! are leftovers of an older generation (SQLite restarts the WAL from its start after a
//! checkpoint and leaves the old frames behind it): normal, not damage. Valid frames after the
//! last commit frame (an unfinished transaction) are dropped by SQLite as well, and rightly:
//! not damage either. A header that is not a WAL header, or whose checksum fails, with bytes
//! after it is damage: SQLite then ignores the whole file.
//!
//! The reader never panics, on any input: every length is checked before it is used.

use std::io::Read;
use std::path::{Path, PathBuf};

use super::StoreError;

/// Bytes of the WAL header.
const HEADER: usize = 32;
/// Bytes of a frame header (before the page).
const FRAME_HEADER: usize = 24;
/// The WAL format version SQLite writes (3.7.0).
const VERSION: u32 = 3_007_000;
/// The magic number, its low bit cleared (the low bit says the checksum's byte order).
const MAGIC: u32 = 0x377f_0682;

/// Why the valid prefix of a WAL ends where it does, when frames of the current generation
/// follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DamageKind {
    /// The header is not a WAL header (magic, version, page size) or its checksum fails:
    /// SQLite ignores every frame.
    Header,
    /// A frame of the current generation whose checksum fails (or whose page number is 0).
    Checksum,
    /// The last frame of the current generation is cut short by the end of the file.
    Truncated,
    /// A frame's salts are not the header's, yet frames after it have them: its header is
    /// damaged (an older generation's frames never come before the current one's).
    Salt,
}

impl DamageKind {
    /// In words, for the log.
    pub fn as_str(self) -> &'static str {
        match self {
            DamageKind::Header => "the WAL header is invalid",
            DamageKind::Checksum => "a frame's checksum fails",
            DamageKind::Truncated => "the last frame is cut short",
            DamageKind::Salt => "a frame's salts do not match the header's",
        }
    }
}

/// Damage found in a WAL: what SQLite will drop without a word.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Damage {
    /// Byte offset where the valid prefix ends (the first frame SQLite will not replay).
    pub offset: u64,
    /// What is wrong there.
    pub kind: DamageKind,
    /// Frames of the current generation from `offset` on (the bad one included): dropped.
    pub frames: u64,
    /// How many of them end a transaction (commit frames): committed transactions lost.
    pub commits: u64,
}

/// What [`scan`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Scan {
    /// Valid frames of the current generation before the first invalid one.
    pub valid_frames: u64,
    /// Byte offset where they end.
    pub valid_end: u64,
    /// Set when frames of the current generation lie at or beyond `valid_end`.
    pub damage: Option<Damage>,
}

/// Big-endian `u32` at `at` (the caller checked the length).
fn be(b: &[u8], at: usize) -> u32 {
    b.get(at..at + 4)
        .and_then(|s| <[u8; 4]>::try_from(s).ok())
        .map_or(0, u32::from_be_bytes)
}

/// SQLite's WAL checksum (`walChecksumBytes`): over 32-bit words in the byte order the magic
/// names, two running sums seeded with `seed`. `data.len()` is a multiple of 8 (8-byte frame
/// header prefix, 24-byte header prefix, a page); a tail shorter than 8 bytes is ignored.
pub fn checksum(big_endian: bool, data: &[u8], seed: (u32, u32)) -> (u32, u32) {
    let (mut s1, mut s2) = seed;
    for pair in data.chunks_exact(8) {
        let word = |i: usize| {
            let w = [pair[i], pair[i + 1], pair[i + 2], pair[i + 3]];
            if big_endian {
                u32::from_be_bytes(w)
            } else {
                u32::from_le_bytes(w)
            }
        };
        s1 = s1.wrapping_add(word(0)).wrapping_add(s2);
        s2 = s2.wrapping_add(word(4)).wrapping_add(s1);
    }
    (s1, s2)
}

/// Reads into `buf` until it is full or the input ends: the bytes read.
fn fill(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Walks the WAL read from `r` (the whole file, from its first byte) as SQLite's recovery
/// does, and reports where its valid prefix ends and what of the current generation lies
/// beyond. An empty input, or one shorter than a header, holds no frame: nothing to lose.
/// Only a read error is an error; any bytes are a [`Scan`].
pub fn scan(mut r: impl Read) -> std::io::Result<Scan> {
    let mut header = [0u8; HEADER];
    let n = fill(&mut r, &mut header)?;
    if n < HEADER {
        return Ok(Scan::default());
    }
    let magic = be(&header, 0);
    let page_size = be(&header, 8);
    let page_ok = page_size.is_power_of_two() && (512..=65536).contains(&page_size);
    let big_endian = magic & 1 == 1;
    let seed = checksum(big_endian, &header[..24], (0, 0));
    let header_ok = magic & !1 == MAGIC
        && be(&header, 4) == VERSION
        && page_ok
        && seed == (be(&header, 24), be(&header, 28));
    let salts = [be(&header, 16), be(&header, 20)];
    if !header_ok {
        // whatever follows, SQLite replays none of it; the frames are counted when the page
        // size can be believed
        let frame = if page_ok {
            FRAME_HEADER + page_size as usize
        } else {
            0
        };
        let mut rest = 0u64;
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            let k = fill(&mut r, &mut buf)?;
            rest += k as u64;
            if k < buf.len() {
                break;
            }
        }
        if rest == 0 {
            return Ok(Scan::default());
        }
        let frames = if frame > 0 {
            rest.div_ceil(frame as u64)
        } else {
            0
        };
        return Ok(Scan {
            valid_frames: 0,
            valid_end: 0,
            damage: Some(Damage {
                offset: 0,
                kind: DamageKind::Header,
                frames,
                commits: 0,
            }),
        });
    }
    let frame_len = FRAME_HEADER + page_size as usize;
    let mut frame = vec![0u8; frame_len];
    let mut sums = seed;
    let mut offset = HEADER as u64;
    let mut out = Scan {
        valid_end: offset,
        ..Scan::default()
    };
    // once the valid prefix ended: what is wrong there, and the current frames from it on
    let mut broken: Option<Damage> = None;
    loop {
        let k = fill(&mut r, &mut frame)?;
        if k == 0 {
            break;
        }
        // the salts are bytes 8..16 of the frame header: a shorter tail cannot be placed
        let current = k >= 16 && [be(&frame, 8), be(&frame, 12)] == salts;
        let commit = k >= 8 && be(&frame, 4) != 0;
        if k < frame_len {
            if current {
                let d = broken.get_or_insert(Damage {
                    offset,
                    kind: DamageKind::Truncated,
                    frames: 0,
                    commits: 0,
                });
                d.frames += 1;
                d.commits += u64::from(commit);
            }
            break;
        }
        match broken.as_mut() {
            Some(d) => {
                if current {
                    d.frames += 1;
                    d.commits += u64::from(commit);
                }
            }
            None => {
                let next = checksum(big_endian, &frame[..8], sums);
                let next = checksum(big_endian, &frame[FRAME_HEADER..], next);
                let valid =
                    current && be(&frame, 0) != 0 && next == (be(&frame, 16), be(&frame, 20));
                if valid {
                    sums = next;
                    out.valid_frames += 1;
                    out.valid_end = offset + frame_len as u64;
                } else {
                    broken = Some(Damage {
                        offset,
                        kind: if current {
                            DamageKind::Checksum
                        } else {
                            DamageKind::Salt
                        },
                        frames: u64::from(current),
                        commits: u64::from(current && commit),
                    });
                }
            }
        }
        offset += frame_len as u64;
    }
    out.damage = broken.filter(|d| d.frames > 0);
    Ok(out)
}

/// `<db>-wal`, where SQLite keeps the WAL of the database at `db`.
pub fn wal_path(db: &Path) -> PathBuf {
    let mut s = db.as_os_str().to_owned();
    s.push("-wal");
    PathBuf::from(s)
}

/// Before SQLite opens the store at `db` (named `name` in messages): when a non-empty `-wal`
/// file is beside it and [`scan`] finds frames of the current generation SQLite would drop,
/// the whole `-wal` is copied to `<db>-wal.damaged-<unix seconds>` (synced), and a warning
/// names the WAL, the byte offset, the frames dropped and the copy. Returns the frames SQLite
/// will drop (0 when none), for `gatewatch_store_restore_skipped_total{what="wal_frame"}`.
///
/// A WAL that cannot be read, or a copy that fails (a full disk), stops the start with an
/// error naming both: opening the store would drop the frames with no evidence left.
pub fn keep_damaged(db: &Path, name: &str) -> Result<u64, StoreError> {
    let wal = wal_path(db);
    if !std::fs::metadata(&wal).is_ok_and(|m| m.is_file() && m.len() > 0) {
        return Ok(0);
    }
    let err = |message: String| StoreError::Open {
        path: name.to_string(),
        message,
    };
    let scanned = std::fs::File::open(&wal)
        .and_then(|f| scan(std::io::BufReader::with_capacity(1 << 16, f)))
        .map_err(|e| err(format!("cannot read its WAL {}: {e}", wal.display())))?;
    let Some(d) = scanned.damage else {
        return Ok(0);
    };
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |t| t.as_secs());
    let copy = (0..100)
        .map(|n| {
            let mut s = wal.as_os_str().to_owned();
            s.push(format!(".damaged-{secs}"));
            if n > 0 {
                s.push(format!("-{n}"));
            }
            PathBuf::from(s)
        })
        .find(|p| std::fs::symlink_metadata(p).is_err())
        .unwrap_or_else(|| PathBuf::from(format!("{}.damaged-{secs}", wal.display())));
    let what = format!(
        "its WAL {} is damaged at byte {} ({}): SQLite drops the {} frames of the last writes \
         from there on ({} of them end a committed transaction) when it opens the store",
        wal.display(),
        d.offset,
        d.kind.as_str(),
        d.frames,
        d.commits
    );
    std::fs::copy(&wal, &copy)
        .and_then(|_| std::fs::File::open(&copy)?.sync_all())
        .map_err(|e| {
            err(format!(
                "{what}, and copying it to {} first failed ({e}): copy the WAL aside by hand \
                 (or free space) before starting again",
                copy.display()
            ))
        })?;
    tracing::warn!(
        store = %name,
        wal = %wal.display(),
        offset = d.offset,
        frames = d.frames,
        copy = %copy.display(),
        "store {name}: {what}; the whole WAL was kept as {} (the frames are lost to the store, \
         not to the copy)",
        copy.display()
    );
    Ok(d.frames)
}

#[cfg(test)]
#[path = "wal_tests.rs"]
mod tests;
