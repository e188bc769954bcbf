//! The WAL reader on hand-built WALs (the format of sqlite.org/fileformat.html, 4.3) and on
//! WALs real SQLite wrote.

use super::*;

const PAGE: usize = 512;
const FRAME: usize = FRAME_HEADER + PAGE;
const SALTS: [u32; 2] = [0x0102_0304, 0xa0b0_c0d0];

/// A WAL header (big-endian checksums when `big`).
fn header(big: bool, salts: [u32; 2]) -> Vec<u8> {
    let mut h = Vec::with_capacity(HEADER);
    for v in [
        MAGIC | u32::from(big),
        VERSION,
        PAGE as u32,
        7,
        salts[0],
        salts[1],
    ] {
        h.extend_from_slice(&v.to_be_bytes());
    }
    let (a, b) = checksum(big, &h, (0, 0));
    h.extend_from_slice(&a.to_be_bytes());
    h.extend_from_slice(&b.to_be_bytes());
    h
}

/// Appends frames for pages `1..=n` to `wal` (its header first), the last one a commit, each
/// chained on the one before. Returns the checksums after the last.
fn frames(wal: &mut Vec<u8>, big: bool, salts: [u32; 2], n: u32) {
    let mut sums = (be(wal, 24), be(wal, 28));
    for pgno in 1..=n {
        let mut f = Vec::with_capacity(FRAME);
        let commit = if pgno == n { n } else { 0 };
        for v in [pgno, commit, salts[0], salts[1]] {
            f.extend_from_slice(&v.to_be_bytes());
        }
        let page: Vec<u8> = (0..PAGE).map(|i| (i as u32 * 31 + pgno) as u8).collect();
        sums = checksum(big, &f[..8], sums);
        sums = checksum(big, &page, sums);
        f.extend_from_slice(&sums.0.to_be_bytes());
        f.extend_from_slice(&sums.1.to_be_bytes());
        f.extend_from_slice(&page);
        wal.extend_from_slice(&f);
    }
}

fn valid(big: bool, n: u32) -> Vec<u8> {
    let mut w = header(big, SALTS);
    frames(&mut w, big, SALTS, n);
    w
}

fn run(bytes: &[u8]) -> Scan {
    scan(bytes).expect("reading a slice does not fail")
}

#[test]
fn a_valid_wal_has_no_damage_in_either_byte_order() {
    for big in [true, false] {
        let s = run(&valid(big, 3));
        assert_eq!(s.damage, None, "big-endian {big}");
        assert_eq!(s.valid_frames, 3);
        assert_eq!(s.valid_end, (HEADER + 3 * FRAME) as u64);
    }
}

#[test]
fn a_flipped_byte_in_frame_2_of_3_drops_frames_2_and_3() {
    let mut w = valid(true, 3);
    w[HEADER + FRAME + FRAME_HEADER + 100] ^= 0x01;
    let s = run(&w);
    assert_eq!(s.valid_frames, 1);
    assert_eq!(
        s.damage,
        Some(Damage {
            offset: (HEADER + FRAME) as u64,
            kind: DamageKind::Checksum,
            frames: 2,
            commits: 1,
        })
    );
}

#[test]
fn a_flipped_byte_in_the_last_frame_is_damage_too() {
    let mut w = valid(false, 3);
    let last = w.len() - 1;
    w[last] ^= 0x80;
    let d = run(&w).damage.expect("damage");
    assert_eq!((d.kind, d.frames, d.commits), (DamageKind::Checksum, 1, 1));
}

#[test]
fn a_truncated_last_frame_of_the_current_generation_is_damage() {
    let mut w = valid(true, 3);
    w.truncate(w.len() - 100);
    let s = run(&w);
    assert_eq!(s.valid_frames, 2);
    assert_eq!(
        s.damage,
        Some(Damage {
            offset: (HEADER + 2 * FRAME) as u64,
            kind: DamageKind::Truncated,
            frames: 1,
            commits: 1,
        })
    );
}

#[test]
fn frames_of_an_older_generation_after_the_current_ones_are_not_damage() {
    // the WAL restarted after a checkpoint: 2 new frames over a longer old generation, whose
    // tail (3 frames and a part cut by journal_size_limit) is still in the file
    let old = [SALTS[0] - 1, 0x1234_5678];
    let mut w = header(true, old);
    frames(&mut w, true, old, 5);
    w.truncate(w.len() - 200);
    let mut new = header(true, SALTS);
    frames(&mut new, true, SALTS, 2);
    w[..new.len()].copy_from_slice(&new);
    let s = run(&w);
    assert_eq!(s.damage, None, "{s:?}");
    assert_eq!(s.valid_frames, 2);
    assert_eq!(s.valid_end, (HEADER + 2 * FRAME) as u64);
}

#[test]
fn a_damaged_salt_before_current_frames_is_damage() {
    let mut w = valid(true, 3);
    w[HEADER + FRAME + 9] ^= 0x04;
    let d = run(&w).damage.expect("damage");
    assert_eq!(
        (d.kind, d.frames, d.commits),
        (DamageKind::Salt, 1, 1),
        "{d:?}"
    );
}

#[test]
fn an_invalid_header_with_frames_after_it_is_damage() {
    let mut w = valid(true, 3);
    w[3] ^= 0x10; // magic
    let d = run(&w).damage.expect("damage");
    assert_eq!((d.kind, d.offset), (DamageKind::Header, 0));
    let mut w = valid(true, 3);
    w[20] ^= 0x10; // salt-2: the header's checksum fails
    let d = run(&w).damage.expect("damage");
    assert_eq!((d.kind, d.frames), (DamageKind::Header, 3));
    // a header alone loses nothing
    assert_eq!(run(&valid(true, 3)[..HEADER]).damage, None);
}

#[test]
fn no_input_panics_and_short_ones_lose_nothing() {
    let w = valid(true, 3);
    for len in 0..=w.len() {
        let s = run(&w[..len]);
        if len < HEADER + 16 {
            assert_eq!(s.damage, None, "prefix {len}");
        }
    }
    assert_eq!(run(&[]), Scan::default());
    // garbage of assorted lengths, a deterministic generator (no rand in the library tests)
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    for len in [1, 31, 32, 33, 100, 600, 5000] {
        let bytes: Vec<u8> = (0..len)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        let _ = run(&bytes);
        // a valid header followed by garbage: the first frame fails, nothing panics
        let mut h = header(false, SALTS);
        h.extend_from_slice(&bytes);
        let _ = run(&h);
    }
    // a header claiming 64 KiB pages over a few bytes
    let mut h = header(true, SALTS);
    h[8..12].copy_from_slice(&65536u32.to_be_bytes());
    h.extend_from_slice(&[0xff; 40]);
    let _ = run(&h);
}

/// A WAL real SQLite wrote (a connection still open, autocheckpoint off): the reader agrees
/// it is whole; a byte flipped in a middle frame's page is found, with frames after it.
#[test]
fn a_wal_sqlite_wrote_checks_out_and_a_flipped_byte_is_found() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("t.db");
    let c = rusqlite::Connection::open(&db).expect("open");
    c.execute_batch(
        "PRAGMA journal_mode = WAL; PRAGMA wal_autocheckpoint = 0; \
         CREATE TABLE t (x INTEGER, y TEXT);",
    )
    .expect("schema");
    for i in 0..20 {
        c.execute(
            "INSERT INTO t VALUES (?1, ?2)",
            rusqlite::params![i, "y".repeat(3000)],
        )
        .expect("insert");
    }
    let mut wal = std::fs::read(dir.path().join("t.db-wal")).expect("read the WAL");
    drop(c);
    let s = run(&wal);
    assert_eq!(s.damage, None, "{s:?}");
    assert!(s.valid_frames >= 20, "{s:?}");
    let page = be(&wal, 8) as usize;
    let frame = FRAME_HEADER + page;
    let middle = (s.valid_frames / 2) as usize;
    wal[HEADER + middle * frame + FRAME_HEADER + 10] ^= 0x01;
    let d = run(&wal).damage.expect("damage");
    assert_eq!(d.offset, (HEADER + middle * frame) as u64);
    assert_eq!(d.frames, s.valid_frames - middle as u64);
    assert!(d.commits >= 1, "{d:?}");
}
