//! Every ROS 1 type shipped with hetcomm has the MD5 sum `rosmsg md5` prints for it (ROS 1's
//! own computation from the installed definitions), and the committed table the pure-Rust
//! tests check (crates/hetcomm-rosmsg/msg/ros1-md5sums.txt) says the same. ROS 1
//! checks this sum at every connection: a wrong one and nothing is received.

mod common;

use std::process::Command;

use hetcomm_rosmsg::schema::Flavour;

#[test]
fn every_shipped_type_has_the_md5_sum_rosmsg_prints() {
    common::require_ros();
    let registry = Flavour::Ros1.shipped();
    let names = registry.names();
    let table = include_str!("../../hetcomm-rosmsg/msg/ros1-md5sums.txt");
    // rosmsg takes about half a second a call: two at a time (the machine has two cores).
    let theirs: Vec<(String, String)> = std::thread::scope(|s| {
        let halves: Vec<_> = names
            .chunks(names.len().div_ceil(2))
            .map(|chunk| {
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|name| {
                            let out = Command::new("rosmsg")
                                .args(["md5", name])
                                .output()
                                .expect("running rosmsg");
                            let md5 = String::from_utf8_lossy(&out.stdout).trim().to_string();
                            (name.clone(), md5)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        halves
            .into_iter()
            .flat_map(|h| h.join().expect("a rosmsg thread"))
            .collect()
    });
    assert_eq!(theirs.len(), names.len());
    for (name, md5) in &theirs {
        let ours = registry.resolve(name).expect("a shipped type resolves");
        assert_eq!(ours.md5, md5, "{name}: rosmsg md5 says {md5}");
        assert!(
            table.lines().any(|l| l == format!("{name} {md5}")),
            "{name} {md5} is not in ros1-md5sums.txt"
        );
    }
}

#[test]
fn the_full_definitions_give_roslibrust_the_same_md5_sums() {
    // A publisher advertises with the full definition; roslibrust computes the sum it sends
    // in the connection header from it.
    let registry = Flavour::Ros1.shipped();
    for name in registry.names() {
        let t = registry.resolve(&name).expect("a shipped type resolves");
        let theirs = roslibrust::md5sum::from_message_definition(&name, t.definition);
        // roslibrust 0.26 refuses an empty definition ("empty cleaned root definition", e.g.
        // nav_msgs/GetMapFeedback) and does not know the `char` primitive (std_msgs/Char):
        // advertising those fails at open, saying so (docs/ros-bridges.md).
        let empty = t.fields.is_empty() && t.constants.is_empty();
        if empty || t.definition.lines().any(|l| l.starts_with("char ")) {
            assert!(
                theirs.is_err(),
                "{name}: roslibrust now reads it: {theirs:?}"
            );
            continue;
        }
        assert_eq!(theirs.ok().as_deref(), Some(t.md5), "{name}");
    }
}
