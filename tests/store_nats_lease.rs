//! The NATS store's owner lease (one daemon per prefix) against a REAL `nats-server` on
//! loopback (skipped when it is not installed, failed under CI): a second store on a prefix is
//! refused naming the owner, another prefix is not; a released prefix is taken at once; an
//! abandoned lease (no release, as after `kill -9`) refuses until it expires, then is taken; of
//! two conditional writes with the same expected sequence exactly one is stored; a renewing
//! owner keeps its prefix, and one whose lease was taken writes nothing more; a server away
//! for longer than the TTL is no loss: writes wait, and resume once the lease is renewed, within
//! seconds of the server's return.

use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

use gatewatch::store::{
    nats_lease_renew_interval, nats_lease_retry_interval, LeaseRecord, NatsOptions, NatsStore,
    Store, StoreError, WriteBatch, NATS_RECONNECT_DELAY_MAX,
};

use crate::nats_common;
use nats_common::{nats_installed, NatsServer};

/// The call timeout of the tests' stores.
const TEST_TIMEOUT: Duration = Duration::from_secs(5);

fn options(url: &str, prefix: &str, lease: Option<Duration>) -> NatsOptions {
    NatsOptions {
        prefix: prefix.into(),
        timeout: TEST_TIMEOUT,
        owner_lease: lease,
        ..NatsOptions::new(url, Duration::from_secs(3600), 1_000_000)
    }
}

fn one_state() -> WriteBatch {
    WriteBatch {
        alert_states: vec![("g1".into(), "{}".into())],
        ..Default::default()
    }
}

fn refusal(r: Result<NatsStore, StoreError>) -> StoreError {
    match r {
        Ok(_) => panic!("a second owner was let in"),
        Err(e) => e,
    }
}

#[test]
fn a_second_store_on_a_prefix_is_refused_naming_the_owner_and_another_prefix_is_not() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let url = server.url();
    let lease = Some(Duration::from_secs(30));
    let first = NatsStore::open(&options(&url, "ONE", lease)).expect("first owner");
    let e = refusal(NatsStore::open(&options(&url, "ONE", lease)));
    let msg = e.to_string();
    assert!(e.is_owned(), "{msg}");
    let want = format!("another gatewatch owns prefix ONE on {url}: host ");
    assert!(msg.starts_with(&want), "{msg}");
    assert!(
        msg.contains(&format!(" pid {} since ", std::process::id())),
        "{msg}"
    );
    assert!(msg.contains("; its lease expires in "), "{msg}");
    // the refused one did not disturb the owner
    first.check().expect("still the owner");
    first.write(&one_state()).expect("the owner writes");
    // another prefix on the same server is another daemon's
    let other = NatsStore::open(&options(&url, "TWO", lease)).expect("another prefix");
    other.write(&one_state()).expect("the other owner writes");
}

#[test]
fn a_released_prefix_is_taken_at_once_and_the_releaser_writes_nothing_more() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let url = server.url();
    let lease = Some(Duration::from_secs(60));
    let first = NatsStore::open(&options(&url, "REL", lease)).expect("first owner");
    first.release().expect("release");
    assert!(first.write(&one_state()).is_err(), "a write after release");
    let started = Instant::now();
    let second = NatsStore::open(&options(&url, "REL", lease)).expect("taken after release");
    assert!(started.elapsed() < Duration::from_secs(5));
    second.write(&one_state()).expect("the new owner writes");
}

#[test]
fn an_abandoned_lease_refuses_until_it_expires_then_is_taken() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let url = server.url();
    let ttl = Duration::from_secs(3);
    // the lease is stamped inside this open: it expires no earlier than `ttl` from here
    let claimed = Instant::now();
    let first = NatsStore::open(&options(&url, "GONE", Some(ttl))).expect("first owner");
    // the owner vanishes without releasing: its runtime (and renewal) stops, as on kill -9
    drop(first);
    let gone = Instant::now();
    let e = refusal(NatsStore::open(&options(&url, "GONE", Some(ttl))));
    assert!(e.is_owned(), "{e}");
    // refused while the lease runs, then taken once it has expired. The bound only catches a
    // lease that never expires: the TTL plus 10 s for the polling and a loaded machine (it
    // was 3 s, little for a CI machine building beside it).
    let mut refusals = 1;
    let second = loop {
        match NatsStore::open(&options(&url, "GONE", Some(ttl))) {
            Ok(s) => break s,
            Err(e) => {
                assert!(e.is_owned(), "{e}");
                assert!(
                    gone.elapsed() < ttl + Duration::from_secs(10),
                    "still refused {:?} after the owner vanished: {e}",
                    gone.elapsed()
                );
                refusals += 1;
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    };
    assert!(refusals >= 2, "refused {refusals} times");
    // and not taken early: the record's expiry is the owner's wall clock (`unix_now`), this is
    // the monotonic one, so 100 ms are left for the two clocks' difference over 3 s
    let taken = claimed.elapsed();
    assert!(
        taken + Duration::from_millis(100) >= ttl,
        "taken {taken:?} after it was claimed, before its TTL of {ttl:?}"
    );
    second.write(&one_state()).expect("the new owner writes");
}

#[test]
fn of_two_claims_with_the_same_expected_sequence_exactly_one_wins() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut server = NatsServer::start(dir.path());
    let url = server.url();
    // the conditional write itself: two stores without a lease, both expecting "none"
    let stores: Vec<Arc<NatsStore>> = (0..2)
        .map(|_| Arc::new(NatsStore::open(&options(&url, "RACE", None)).expect("open")))
        .collect();
    assert!(stores[0].owner_lease().expect("read").is_none());
    let barrier = Arc::new(Barrier::new(stores.len()));
    let threads: Vec<_> = stores
        .iter()
        .map(|s| {
            let (s, barrier) = (s.clone(), barrier.clone());
            std::thread::spawn(move || {
                let record = LeaseRecord::this_process(Duration::from_secs(60));
                barrier.wait();
                s.claim_owner_lease(0, &record).expect("claim")
            })
        })
        .collect();
    let won: Vec<u64> = threads
        .into_iter()
        .filter_map(|t| t.join().expect("join"))
        .collect();
    assert_eq!(won.len(), 1, "winners: {won:?}");
    let (seq, _) = stores[1].owner_lease().expect("read").expect("a lease");
    assert_eq!(seq, won[0]);
    // a stale expected sequence is refused; the current one is stored
    let record = LeaseRecord::this_process(Duration::from_secs(60));
    assert_eq!(
        stores[1].claim_owner_lease(0, &record).expect("claim"),
        None
    );
    assert!(stores[1]
        .claim_owner_lease(seq, &record)
        .expect("claim")
        .is_some());

    // whole opens racing on a fresh prefix: exactly one owner. An open that fails for another
    // reason than the lease (a connection reset or a timeout of a loaded 2-core machine, seen
    // in a full run beside builds) is tried again, twice at most, still racing the others; the
    // reasons are kept for the message. Several rounds, each on a prefix of its own: the
    // streams are created by four clients at once every time, which is what killed Debian's
    // nats-server 2.9 while the open updated a stream before creating it (`ops::ensure`).
    //
    // Debian's nats-server 2.9.10 has a second bug this race can reach: a message get on a
    // stream another client is creating dereferences its store before it is set
    // (`jsMsgGetRequest`, a nil pointer, exit status 2): once in stop 69's CI rehearsal (the
    // integration binary, this test beside the others), not in 40 runs of it alone. No open
    // of ours can avoid
    // it, as the other client's creation is not ours to see. Such a round (the server's log
    // naming `jsMsgGetRequest` in its panic) is run again on a server started anew, twice
    // at most; any other death of the server, or a second owner, still fails.
    let mut server_bug = 0;
    let mut round = 0;
    while round < 4 {
        let prefix = format!("OPEN{round}_{server_bug}");
        let barrier = Arc::new(Barrier::new(4));
        let opens: Vec<_> = (0..4)
            .map(|_| {
                let (url, barrier, prefix) = (url.clone(), barrier.clone(), prefix.clone());
                std::thread::spawn(move || {
                    barrier.wait();
                    let mut transient = Vec::new();
                    loop {
                        let r =
                            NatsStore::open(&options(&url, &prefix, Some(Duration::from_secs(60))));
                        match r {
                            Err(e) if !e.is_owned() && transient.len() < 2 => {
                                transient.push(e.to_string())
                            }
                            r => return (r, transient),
                        }
                    }
                })
            })
            .collect();
        let (results, transient): (Vec<_>, Vec<_>) =
            opens.into_iter().map(|t| t.join().expect("join")).unzip();
        let owners = results.iter().filter(|r| r.is_ok()).count();
        let report = server.report();
        // a dead server makes the round unusable, whoever won it; two owners never are
        if owners <= 1
            && server_bug < 2
            && report.contains("exited")
            && report.contains("nil pointer dereference")
            && report.contains("jsMsgGetRequest")
        {
            server_bug += 1;
            eprintln!("round {round}: nats-server 2.9's message-get crash, the round again on a new server:\n{report}");
            drop(results);
            server.restart();
            continue;
        }
        assert_eq!(
            owners,
            1,
            "round {round}: {results:?}; retried after: {transient:?}; {}",
            server.report()
        );
        for e in results.iter().filter_map(|r| r.as_ref().err()) {
            assert!(e.is_owned(), "{e}");
        }
        round += 1;
    }
    let report = server.report();
    assert!(report.contains(" running;"), "{report}");
}

#[test]
fn an_owner_renews_its_lease_and_one_whose_lease_is_taken_writes_nothing_more() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let url = server.url();
    // 2 s, renewed three times within it: a renewal held up for a few hundred milliseconds
    // by a loaded machine must not read as a lost lease here
    let ttl = Duration::from_secs(2);
    let owner = NatsStore::open(&options(&url, "KEEP", Some(ttl))).expect("owner");
    let (seq0, first) = owner.owner_lease().expect("read").expect("a lease");
    // three TTLs later the lease is still held: renewed, by the same instance
    std::thread::sleep(ttl * 3);
    owner.check().expect("still the owner");
    owner.write(&one_state()).expect("the owner writes");
    let (seq1, now) = owner.owner_lease().expect("read").expect("a lease");
    assert!(seq1 > seq0, "renewed: {seq0} -> {seq1}");
    assert_eq!(now.instance, first.instance);
    assert!(now.expires > first.expires);

    // another writer takes the lease (as a daemon would after a partition)
    let thief = NatsStore::open(&options(&url, "KEEP", None)).expect("open");
    let mut taken = LeaseRecord::this_process(Duration::from_secs(600));
    taken.host = "elsewhere".into();
    let stolen = loop {
        let (seq, _) = thief.owner_lease().expect("read").expect("a lease");
        if thief
            .claim_owner_lease(seq, &taken)
            .expect("claim")
            .is_some()
        {
            break seq;
        }
    };
    assert!(stolen > 0);
    // at its next renewal the owner finds it lost: it refuses writes and fails its check
    let deadline = Instant::now() + ttl * 3;
    let e = loop {
        match owner.check() {
            Err(e) => break e,
            Ok(()) => {
                assert!(Instant::now() < deadline, "the loss was not noticed");
                std::thread::sleep(Duration::from_millis(50));
            }
        }
    };
    let msg = e.to_string();
    assert!(e.is_owned(), "{msg}");
    assert!(
        msg.starts_with(&format!(
            "another gatewatch took prefix KEEP on {url}: host elsewhere pid "
        )),
        "{msg}"
    );
    let w = owner
        .write(&one_state())
        .expect_err("a write after the loss");
    assert!(w.is_owned(), "{w}");
    // the new owner's record is left alone, even by the loser's release
    owner.release().expect("release");
    let (_, kept) = thief.owner_lease().expect("read").expect("a lease");
    assert_eq!(kept.host, "elsewhere");
}

#[test]
fn an_unreachable_server_is_not_a_loss_and_the_lease_is_renewed_when_it_is_back() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut server = NatsServer::start(dir.path());
    let url = server.url();
    let ttl = Duration::from_secs(1);
    let owner = NatsStore::open(&options(&url, "AWAY", Some(ttl))).expect("owner");
    let (_, mine) = owner.owner_lease().expect("read").expect("a lease");
    // the server goes away for longer than the TTL: the renewals fail, the lease expires
    server.stop();
    std::thread::sleep(ttl * 2);
    owner.check().expect("an unreachable server is no loss");
    let e = owner
        .write(&one_state())
        .expect_err("a write on an expired lease");
    assert!(!e.is_owned(), "{e}");
    assert!(e.to_string().contains("expired without renewal"), "{e}");
    // back (same store directory, nobody took the prefix): renewed, writes resume
    server.restart();
    let deadline = Instant::now() + Duration::from_secs(20);
    while let Err(e) = owner.write(&one_state()) {
        assert!(Instant::now() < deadline, "writes did not resume: {e}");
        std::thread::sleep(Duration::from_millis(200));
    }
    owner.check().expect("still the owner");
    let (_, now) = owner.owner_lease().expect("read").expect("a lease");
    assert_eq!(now.instance, mine.instance);
    assert!(now.expires > mine.expires);
}

/// A server away for longer than the lease lets it expire, and every write is refused until a
/// renewal gets through. Once the server is back that takes a retry of the renewal (every fifth
/// of the renewal interval) after the client's reconnection (at most a second apart), not the
/// next whole interval after a reconnection up to 4 s apart (the client's default): before
/// session 56 that was 0 to 8 s with this TTL, and up to 14 s at the default 30 s.
#[test]
fn writes_resume_within_seconds_of_the_server_back_after_the_lease_expired() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut server = NatsServer::start(dir.path());
    let url = server.url();
    // renewed every 4 s, a failed renewal retried every 0.8 s
    let ttl = Duration::from_secs(12);
    assert_eq!(nats_lease_renew_interval(ttl), Duration::from_secs(4));
    assert_eq!(nats_lease_retry_interval(ttl), Duration::from_millis(800));
    let owner = NatsStore::open(&options(&url, "BACK", Some(ttl))).expect("owner");
    owner.write(&one_state()).expect("the owner writes");
    server.stop();
    // away until the lease expired: writes are refused as such
    let deadline = Instant::now() + ttl * 2;
    loop {
        match owner.write(&one_state()) {
            Err(e) if e.to_string().contains("expired without renewal") => break,
            other => {
                assert!(
                    Instant::now() < deadline,
                    "the lease did not expire: {other:?}"
                );
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    }
    server.restart();
    let back = Instant::now();
    // the bound: a reconnection and a retry, with a second of slack for a loaded machine
    let bound = NATS_RECONNECT_DELAY_MAX + nats_lease_retry_interval(ttl) + Duration::from_secs(1);
    while let Err(e) = owner.write(&one_state()) {
        assert!(
            back.elapsed() < bound,
            "writes did not resume within {bound:?} of the server's return: {e}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    owner.check().expect("still the owner");
}
