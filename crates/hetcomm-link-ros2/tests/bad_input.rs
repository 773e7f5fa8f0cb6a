//! Samples on a system's topic that are not frames (another struct under the same DDS type
//! name, an empty `data`) are counted as dropped and never delivered; frames after them still
//! arrive. On rustdds, and with the `cyclone` feature on Cyclone DDS (the foreign writers
//! are rustdds's, so the samples cross between the two implementations).

use std::time::Duration;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::Link;
use hetcomm_link_ros2::msg::{FrameMessage, FRAME_TYPE};
use hetcomm_link_ros2::{link, names, Backend, Ros2Link, Ros2Settings};
use rustdds::TopicKind;
use serde::Serialize;

/// Claims to be a `std_msgs/msg/UInt8MultiArray`; one byte long.
#[derive(Serialize, Debug)]
struct Garbage {
    junk: u8,
}

/// A link of either backend, with what the test reads of it.
enum Either {
    RustDds(Box<Ros2Link>),
    #[cfg(feature = "cyclone")]
    Cyclone(hetcomm_link_ros2::cyclone::CycloneLink),
}

impl Either {
    fn open(
        dds: Backend,
        id: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: std::sync::Arc<CollectSink>,
    ) -> Either {
        match dds {
            Backend::RustDds => Either::RustDds(Box::new(
                Ros2Link::open(id, names, settings, sink).expect("open"),
            )),
            #[cfg(feature = "cyclone")]
            Backend::Cyclone => Either::Cyclone(
                hetcomm_link_ros2::cyclone::CycloneLink::open(id, names, settings, sink)
                    .expect("open"),
            ),
            #[cfg(not(feature = "cyclone"))]
            Backend::Cyclone => unreachable!("no cyclone feature"),
        }
    }

    fn link(&self) -> &dyn Link {
        match self {
            Either::RustDds(l) => &**l,
            #[cfg(feature = "cyclone")]
            Either::Cyclone(l) => l,
        }
    }

    fn topic(&self) -> &str {
        match self {
            Either::RustDds(l) => l.topic(),
            #[cfg(feature = "cyclone")]
            Either::Cyclone(l) => l.topic(),
        }
    }

    fn malformed(&self) -> u64 {
        match self {
            Either::RustDds(l) => l.malformed(),
            #[cfg(feature = "cyclone")]
            Either::Cyclone(l) => l.malformed(),
        }
    }
}

#[test]
fn garbage_on_a_system_topic_is_counted_and_the_link_keeps_delivering() {
    garbage_is_counted(Backend::RustDds, 66);
}

#[cfg(feature = "cyclone")]
#[test]
fn garbage_on_a_cyclone_system_topic_is_counted_and_the_link_keeps_delivering() {
    garbage_is_counted(Backend::Cyclone, 80);
}

fn garbage_is_counted(dds: Backend, domain_id: u16) {
    let settings = Ros2Settings {
        domain_id,
        namespace: format!("/bad_{}", std::process::id()),
        dds,
        ..Ros2Settings::default()
    };
    let names = vec![
        (SystemId(1), "A".to_string()),
        (SystemId(2), "B".to_string()),
    ];
    let sink = CollectSink::new();
    let b = Either::open(dds, SystemId(2), &names, &settings, sink.clone());
    let a = Either::open(dds, SystemId(1), &names, &settings, CollectSink::new());
    let (a, b_link) = (a.link(), b.link());

    // A foreign writer on B's topic.
    let dp = link::participant(&settings).expect("participant");
    let qos = link::qos(&settings);
    let topic = dp
        .create_topic(
            names::dds_topic(b.topic()),
            names::dds_type(FRAME_TYPE),
            &qos,
            TopicKind::NoKey,
        )
        .unwrap();
    let publisher = dp.create_publisher(&qos).unwrap();
    let garbage = publisher
        .create_datawriter_no_key_cdr::<Garbage>(&topic, Some(qos.clone()))
        .unwrap();
    let empty = publisher
        .create_datawriter_no_key_cdr::<FrameMessage>(&topic, Some(qos.clone()))
        .unwrap();

    a.send(SystemId(2), b"first frame").expect("send");
    assert_eq!(sink.wait_for(1, Duration::from_secs(10)), 1);
    // Written until counted: the foreign writers' readers match asynchronously.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while b_link.stats().frames_dropped < 10 {
        assert!(
            std::time::Instant::now() < deadline,
            "dropped {} of 10",
            b_link.stats().frames_dropped
        );
        garbage.write(Garbage { junk: 9 }, None).unwrap();
        empty.write(FrameMessage::default(), None).unwrap();
        std::thread::sleep(Duration::from_millis(20));
    }
    a.send(SystemId(2), b"second frame").expect("send");
    assert_eq!(sink.wait_for(2, Duration::from_secs(10)), 2);
    let frames: Vec<Vec<u8>> = sink.frames().into_iter().map(|r| r.bytes).collect();
    assert_eq!(frames, [b"first frame".to_vec(), b"second frame".to_vec()]);
    assert_eq!(b.malformed(), b_link.stats().frames_dropped);
}
