//! The inbox's unit tests: stashes, intake, overflow policies, waiting.

use super::*;
use hetcomm_core::{Address, ModuleId, Priority, SystemId};

fn entry(prio: u8, tag: u8) -> Entry {
    let a = Address {
        system: SystemId(0),
        module: ModuleId(0),
    };
    let mut header = Header::data(a, a, MessageType(1));
    header.priority = Priority(prio);
    Entry {
        header,
        payload: PayloadBuf::copy_from_slice(&[tag]),
        received_at: hetcomm_core::Time::ZERO,
    }
}

fn inbox(capacity: usize, overflow: OverflowPolicy) -> Inbox {
    Inbox::new(InboxConfig { capacity, overflow })
}

fn drain(i: &Inbox) -> Vec<u8> {
    let mut out = vec![];
    while let Ok(Some(e)) = i.try_take(|_| true) {
        out.push(e.payload[0]);
    }
    out
}

#[test]
fn priority_then_arrival() {
    let i = inbox(10, OverflowPolicy::DropNewest);
    for (p, t) in [(1, 1), (5, 2), (1, 3), (9, 4), (5, 5)] {
        i.push(entry(p, t)).unwrap();
    }
    assert_eq!(drain(&i), vec![4, 2, 5, 1, 3]);
}

#[test]
fn drop_oldest_evicts_lowest_priority_oldest() {
    let i = inbox(3, OverflowPolicy::DropOldest);
    for (p, t) in [(5, 1), (1, 2), (1, 3)] {
        i.push(entry(p, t)).unwrap();
    }
    i.push(entry(1, 4)).unwrap(); // evicts 2
    assert_eq!(i.push(entry(0, 5)), Err(PushError::Full)); // everything outranks it
    let s = i.stats();
    assert_eq!((s.dropped_oldest, s.dropped_newest), (1, 1));
    assert_eq!(drain(&i), vec![1, 3, 4]);
}

#[test]
fn drop_newest_refuses() {
    let i = inbox(2, OverflowPolicy::DropNewest);
    for t in 0..5 {
        let _ = i.push(entry(1, t));
    }
    assert_eq!(i.stats().dropped_newest, 3);
    assert_eq!(drain(&i), vec![0, 1]);
}

#[test]
fn block_waits_for_room_then_gives_up() {
    let i = std::sync::Arc::new(inbox(
        1,
        OverflowPolicy::Block {
            timeout: Duration::from_millis(20),
        },
    ));
    i.push(entry(1, 0)).unwrap();
    assert_eq!(i.push(entry(1, 1)), Err(PushError::Full));
    assert_eq!(i.stats().dropped_after_wait, 1);
    // With a consumer making room, a blocked push succeeds.
    let patient = std::sync::Arc::new(inbox(
        1,
        OverflowPolicy::Block {
            timeout: Duration::from_secs(10),
        },
    ));
    patient.push(entry(1, 0)).unwrap();
    let p2 = patient.clone();
    let pusher = std::thread::spawn(move || p2.push(entry(1, 1)));
    let first = patient.take_timeout(|_| true, Some(Duration::from_secs(10)));
    assert_eq!(first.unwrap().unwrap().payload, vec![0]);
    assert_eq!(pusher.join().unwrap(), Ok(()));
    assert_eq!(drain(&patient), vec![1]);
    assert_eq!(patient.stats().dropped(), 0);
}

#[test]
fn refused_take_leaves_message() {
    let i = inbox(4, OverflowPolicy::DropNewest);
    i.push(entry(1, 7)).unwrap();
    assert!(i.try_take(|_| false).is_err());
    assert_eq!(i.len(), 1);
}

#[test]
fn a_higher_priority_overtakes_a_stashed_batch() {
    let i = inbox(10, OverflowPolicy::DropNewest);
    for t in 0..3 {
        i.push(entry(5, t)).unwrap();
    }
    // The first take moves all three into the stash.
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]);
    i.push(entry(9, 10)).unwrap();
    i.push(entry(5, 11)).unwrap(); // same priority as the stash: after it
    i.push(entry(1, 12)).unwrap();
    assert_eq!(i.next_type(), Some(MessageType(1)));
    assert_eq!(drain(&i), vec![10, 1, 2, 11, 12]);
    let s = i.stats();
    assert_eq!((s.accepted, s.taken, s.len), (6, 6, 0));
    assert!(i.is_empty());
}

#[test]
fn the_bound_counts_stashed_and_shared_messages() {
    let i = inbox(3, OverflowPolicy::DropNewest);
    for t in 0..3 {
        i.push(entry(1, t)).unwrap();
    }
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]); // stash: 1, 2
    i.push(entry(1, 3)).unwrap();
    assert_eq!(i.push(entry(9, 4)), Err(PushError::Full));
    assert_eq!(
        (i.len(), i.stats().len, i.stats().dropped_newest),
        (3, 3, 1)
    );
    assert!(!i.is_empty());
    assert_eq!(drain(&i), vec![1, 2, 3]);
    assert!(i.is_empty());
}

#[test]
fn drop_oldest_evicts_from_the_stash_first_on_a_tie() {
    let i = inbox(3, OverflowPolicy::DropOldest);
    for t in 0..3 {
        i.push(entry(1, t)).unwrap();
    }
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]); // stash: 1, 2
    i.push(entry(1, 3)).unwrap(); // room: 3 queued
    i.push(entry(1, 4)).unwrap(); // full: evicts 1 (stashed, oldest)
    i.push(entry(0, 5)).unwrap_err(); // everything outranks it
    i.push(entry(7, 6)).unwrap(); // evicts 2 (stashed)
    assert_eq!(drain(&i), vec![6, 3, 4]);
    let s = i.stats();
    assert_eq!((s.dropped_oldest, s.dropped_newest, s.len), (2, 1, 0));
    assert_eq!(s.accepted, s.taken + s.dropped_oldest);
}

#[test]
fn a_blocked_push_is_woken_by_a_take_from_the_stash() {
    let i = std::sync::Arc::new(inbox(
        2,
        OverflowPolicy::Block {
            timeout: Duration::from_secs(10),
        },
    ));
    i.push(entry(1, 0)).unwrap();
    i.push(entry(1, 1)).unwrap();
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]); // stash: 1
    i.push(entry(1, 2)).unwrap(); // full again
    let i2 = i.clone();
    let started = Instant::now();
    let pusher = std::thread::spawn(move || i2.push(entry(1, 3)));
    std::thread::sleep(Duration::from_millis(20));
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [1u8]);
    assert_eq!(pusher.join().unwrap(), Ok(()));
    assert!(started.elapsed() < Duration::from_secs(5));
    assert_eq!(drain(&i), vec![2, 3]);
}

#[test]
fn places_freed_in_a_batch_not_yet_given_back_still_count_as_room() {
    // 64 places: a consumer gives freed places back 8 at a time.
    let i = inbox(64, OverflowPolicy::DropNewest);
    for t in 0..64 {
        i.push(entry(1, t)).unwrap();
    }
    assert_eq!(i.push(entry(1, 99)), Err(PushError::Full));
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]);
    // One place is free although the consumer has not given it back yet.
    i.push(entry(1, 64)).unwrap();
    assert_eq!(i.push(entry(1, 99)), Err(PushError::Full));
    let s = i.stats();
    assert_eq!(
        (s.len, s.accepted, s.taken, s.dropped_newest),
        (64, 65, 1, 2)
    );
    assert_eq!(drain(&i), (1..=64).collect::<Vec<u8>>());
}

#[test]
fn a_sleeping_consumer_is_woken_by_a_push_and_by_close() {
    let i = std::sync::Arc::new(inbox(8, OverflowPolicy::DropNewest));
    let i2 = i.clone();
    let started = Instant::now();
    let consumer = std::thread::spawn(move || {
        let first = i2.take_timeout(|_| true, None).unwrap().unwrap();
        let after_close = i2.take_timeout(|_| true, None);
        (first.payload[0], after_close.map(|e| e.is_none()))
    });
    std::thread::sleep(Duration::from_millis(30)); // long enough to be asleep
    i.push(entry(1, 42)).unwrap();
    std::thread::sleep(Duration::from_millis(30));
    i.close();
    let (first, after_close) = consumer.join().unwrap();
    assert_eq!((first, after_close), (42, Ok(true)));
    assert!(started.elapsed() < Duration::from_secs(5));
    assert_eq!(i.push(entry(1, 1)), Err(PushError::Closed));
}

/// Producers overflowing a small `drop-oldest` inbox while a consumer takes: every
/// accepted message is taken or counted as evicted, none twice.
#[test]
fn concurrent_drop_oldest_accounts_for_every_message() {
    const PRODUCERS: u8 = 3;
    const EACH: u32 = 20_000;
    let i = std::sync::Arc::new(inbox(16, OverflowPolicy::DropOldest));
    let producers: Vec<_> = (0..PRODUCERS)
        .map(|p| {
            let i = i.clone();
            std::thread::spawn(move || {
                let mut refused = 0u64;
                for n in 0..EACH {
                    let mut e = entry((n % 2) as u8, p);
                    e.payload = PayloadBuf::copy_from_slice(&[&[p][..], &n.to_le_bytes()].concat());
                    if i.push(e).is_err() {
                        refused += 1;
                    }
                }
                refused
            })
        })
        .collect();
    let mut seen = std::collections::HashSet::new();
    let mut producers_left = producers;
    let mut refused = 0;
    loop {
        while let Ok(Some(e)) = i.try_take(|_| true) {
            assert!(seen.insert(e.payload.to_vec()), "taken twice");
        }
        if producers_left.iter().all(|p| p.is_finished()) {
            refused += producers_left
                .drain(..)
                .map(|p| p.join().unwrap())
                .sum::<u64>();
            while let Ok(Some(e)) = i.try_take(|_| true) {
                assert!(seen.insert(e.payload.to_vec()), "taken twice");
            }
            break;
        }
        std::thread::yield_now();
    }
    let s = i.stats();
    let total = u64::from(PRODUCERS) * u64::from(EACH);
    assert_eq!(s.taken, seen.len() as u64);
    assert_eq!(s.accepted, s.taken + s.dropped_oldest);
    assert_eq!(s.accepted + s.dropped_newest, total);
    assert_eq!(s.dropped_newest, refused);
    assert_eq!(s.len, 0);
}

/// Producers racing into a `drop-newest` inbox nobody reads: exactly `capacity` get in,
/// whether they pushed through the intake or, once it looked full, through the stash.
#[test]
fn concurrent_producers_never_exceed_the_bound() {
    const PRODUCERS: u8 = 4;
    const EACH: u8 = 200;
    let i = std::sync::Arc::new(inbox(101, OverflowPolicy::DropNewest));
    let producers: Vec<_> = (0..PRODUCERS)
        .map(|p| {
            let i = i.clone();
            std::thread::spawn(move || {
                (0..EACH)
                    .filter(|&n| i.push(entry(n % 3, p)).is_ok())
                    .count()
            })
        })
        .collect();
    let accepted: usize = producers.into_iter().map(|p| p.join().unwrap()).sum();
    let s = i.stats();
    assert_eq!((accepted, s.len, s.accepted), (101, 101, 101));
    assert_eq!(
        s.dropped_newest,
        u64::from(PRODUCERS) * u64::from(EACH) - 101
    );
    assert_eq!(drain(&i).len(), 101);
    assert!(i.is_empty());
}

/// A stream of one priority moves into the stash by swapping buffers; a message of
/// another priority arriving in the next batch still sorts in correctly, and an
/// emptied inbox takes the next stream the same way.
#[test]
fn swapped_batches_keep_priority_order() {
    let i = inbox(64, OverflowPolicy::DropNewest);
    for t in 0..4 {
        i.push(entry(2, t)).unwrap();
    }
    assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]);
    i.push(entry(2, 4)).unwrap();
    i.push(entry(3, 5)).unwrap();
    i.push(entry(1, 6)).unwrap();
    assert_eq!(drain(&i), vec![5, 1, 2, 3, 4, 6]);
    for t in 10..13 {
        i.push(entry(0, t)).unwrap();
    }
    assert_eq!(drain(&i), vec![10, 11, 12]);
    let s = i.stats();
    assert_eq!((s.accepted, s.taken, s.len), (10, 10, 0));
}

/// Producers on several threads, one consumer: nothing lost or duplicated, and each
/// producer's messages of one priority come out in the order sent.
#[test]
fn concurrent_producers_keep_per_priority_order() {
    const PRODUCERS: u8 = 3;
    const EACH: u32 = 20_000;
    let i = std::sync::Arc::new(inbox(
        64,
        OverflowPolicy::Block {
            timeout: Duration::from_secs(30),
        },
    ));
    let producers: Vec<_> = (0..PRODUCERS)
        .map(|p| {
            let i = i.clone();
            std::thread::spawn(move || {
                for n in 0..EACH {
                    let mut e = entry(((n * 7 + u32::from(p)) % 3) as u8, p);
                    e.payload = PayloadBuf::copy_from_slice(&[&[p][..], &n.to_le_bytes()].concat());
                    i.push(e).unwrap();
                }
            })
        })
        .collect();
    let mut last = std::collections::HashMap::new();
    let mut got = 0u32;
    while got < u32::from(PRODUCERS) * EACH {
        let e = i
            .take_timeout(|_| true, Some(Duration::from_secs(30)))
            .unwrap()
            .expect("a message within 30 s");
        let (p, n) = (
            e.payload[0],
            u32::from_le_bytes(e.payload[1..5].try_into().unwrap()),
        );
        let key = (p, e.header.priority.0);
        if let Some(prev) = last.insert(key, n) {
            assert!(
                n > prev,
                "producer {p} priority {}: {n} after {prev}",
                key.1
            );
        }
        got += 1;
    }
    for p in producers {
        p.join().unwrap();
    }
    let s = i.stats();
    assert_eq!(
        (s.accepted, s.taken, s.dropped(), s.len),
        (60_000, 60_000, 0, 0)
    );
}
