//! In-system topics (`hetcomm::node`): the thesis's Node API beside the module-to-module API,
//! in one object. Values reach subscribers as the very `Arc` published (no serialization),
//! notifications run per value, a topic keeps one type, full queues count what they push out.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{LocalFleet, Message, Node, TopicError};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 50)]
struct Pose {
    x: f64,
    y: f64,
}

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 51)]
struct Cmd {
    code: u8,
}

const FLEET: &str = r#"
[systems]
Alpha = 0
Charlie = 1
[modules]
Sense = 0
Plan = 1
Act = 2
[transports.net]
kind = "inproc"
[table]
columns = ["Alpha", "Charlie"]
Alpha = ["X", "net"]
Charlie = ["net", "X"]
"#;

fn fleet() -> LocalFleet {
    LocalFleet::open(hetcomm::parse_fleet(FLEET, "topics.toml", None).unwrap()).unwrap()
}

#[test]
fn a_published_value_reaches_subscribers_as_the_same_arc() {
    let f = fleet();
    let alpha = f.system("Alpha").unwrap();
    let sense: Node = alpha.node("Sense").unwrap();
    let plan: Node = alpha.node("Plan").unwrap();
    let act: Node = alpha.node("Act").unwrap();
    let poses = sense.advertise::<Pose>("pose").unwrap();
    let at_plan = plan.subscribe::<Pose>("pose").unwrap();
    let at_act = act.subscribe::<Pose>("pose").unwrap();
    let value = Arc::new(Pose { x: 1.0, y: 2.0 });
    poses.publish_arc(value.clone()).unwrap();
    let a = at_plan.try_recv().unwrap();
    let b = at_act.recv_timeout(Duration::from_secs(1)).unwrap();
    // Not a copy, not a decode: the publisher's allocation.
    assert!(Arc::ptr_eq(&a, &value) && Arc::ptr_eq(&b, &value));
    assert!(at_plan.try_recv().is_none());
    let info = alpha.topics();
    assert_eq!(info.len(), 1);
    assert_eq!((info[0].published, info[0].subscribers), (1, 2));
    // Another system's topic of the same name is another topic.
    let charlie_plan = f.system("Charlie").unwrap().node("Plan").unwrap();
    let elsewhere = charlie_plan.subscribe::<Pose>("pose").unwrap();
    poses.publish(Pose { x: 3.0, y: 4.0 }).unwrap();
    assert!(elsewhere.try_recv().is_none());
}

#[test]
fn the_same_node_also_sends_to_other_systems() {
    let f = fleet();
    let alpha_plan = f.system("Alpha").unwrap().node("Plan").unwrap();
    let charlie = f.system("Charlie").unwrap();
    let charlie_plan = charlie.node("Plan").unwrap();
    let charlie_act = charlie.node("Act").unwrap();
    // Charlie's Plan forwards what Alpha sends onto a topic of its own system.
    let to_act = charlie_plan.advertise::<Cmd>("cmd").unwrap();
    let got = Arc::new(Mutex::new(Vec::new()));
    let g = got.clone();
    let _n = charlie_act
        .notification::<Cmd>("cmd", move |c| g.lock().unwrap().push(c.code))
        .unwrap();
    alpha_plan
        .send("Charlie", "Plan", &Cmd { code: 9 })
        .unwrap()
        .wait();
    let m = charlie_plan
        .recv_timeout::<Cmd>(Duration::from_secs(1))
        .unwrap();
    to_act.publish(m.message).unwrap();
    assert_eq!(*got.lock().unwrap(), [9]);
}

#[test]
fn a_topic_keeps_one_type_and_full_queues_count_their_losses() {
    let f = fleet();
    let alpha = f.system("Alpha").unwrap();
    let plan = alpha.node("Plan").unwrap();
    plan.advertise::<Pose>("pose").unwrap();
    let err = plan.subscribe::<Cmd>("pose").unwrap_err();
    assert!(matches!(err, TopicError::TypeMismatch { .. }), "{err}");
    assert_eq!(
        plan.advertise::<Pose>("").unwrap_err(),
        TopicError::EmptyName
    );
    let sub = alpha
        .node("Act")
        .unwrap()
        .subscribe_with_capacity::<Pose>("pose", 2)
        .unwrap();
    for i in 0..5 {
        plan.publish(
            "pose",
            Pose {
                x: i as f64,
                y: 0.0,
            },
        )
        .unwrap();
    }
    assert_eq!((sub.pending(), sub.dropped(), sub.received()), (2, 3, 5));
    assert_eq!(sub.latest().unwrap().x, 4.0);
    assert_eq!(sub.pending(), 0);
    let err = sub.recv_timeout(Duration::from_millis(10)).unwrap_err();
    assert!(matches!(err, TopicError::Timeout { .. }));
    drop(sub);
    assert_eq!(alpha.topics()[0].subscribers, 0);
}

#[test]
fn notifications_run_in_order_under_the_simulator() {
    let fleet = hetcomm::parse_fleet(FLEET, "topics.toml", None).unwrap();
    let sim = SimFleet::open(fleet, SimOptions::default()).unwrap();
    let alpha = sim.system("Alpha").unwrap();
    let sense = alpha.node("Sense").unwrap();
    let sum = Arc::new(AtomicU64::new(0));
    let s = sum.clone();
    alpha
        .node("Plan")
        .unwrap()
        .on_topic::<Cmd>("cmd", move |c| {
            s.fetch_add(u64::from(c.code), Ordering::Relaxed);
        })
        .unwrap()
        .keep();
    for c in 1..=10 {
        sense.publish("cmd", Cmd { code: c }).unwrap();
    }
    assert_eq!(sum.load(Ordering::Relaxed), 55);
}
