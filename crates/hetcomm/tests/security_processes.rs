//! A secured fleet across two operating-system processes, over UDP and over TCP: this test
//! runs system B and starts this same test binary again as system A (the `child_a_sends`
//! test, which does nothing unless `HC_SECURE_CHILD` names its directory). The child knows
//! the systems' public keys and only its own private key, given the way a deployment would:
//! the `HETCOMM_PRIVATE_KEY` environment variable naming the `.key` file.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::attack::{security, Kind, Setup, TABLE};
use hetcomm::security::PublicKey;
use hetcomm::{Comm, MessageType, Outcome, SendOptions};

const MESSAGES: u8 = 10;
const WAIT: Duration = Duration::from_secs(30);

/// The child: system A, from the fleet text, public keys and private key in `dir`.
#[test]
fn child_a_sends() {
    let Some(dir) = std::env::var_os("HC_SECURE_CHILD").map(PathBuf::from) else {
        return; // run by the parent below only
    };
    let text = std::fs::read_to_string(dir.join("fleet.toml")).expect("fleet text");
    let mut fleet = hetcomm::parse_fleet(&text, "fleet.toml", None).expect("fleet");
    for s in &mut fleet.systems {
        let public = PublicKey::load(&dir.join(format!("{}.pub", s.name))).expect("public key");
        s.public_key = Some(public.0);
    }
    assert!(
        !dir.join("B.key").exists(),
        "the child holds only A's private key"
    );
    // The private key comes from HETCOMM_PRIVATE_KEY (set by the parent).
    let a = Comm::open_fleet(&fleet, "A").expect("opening A in the child");
    let plan = a.module("Plan").unwrap();
    for i in 0..MESSAGES {
        let outcome = plan
            .send_raw("B", "Act", MessageType(1), &[i], SendOptions::default())
            .expect("send")
            .wait_timeout(WAIT)
            .expect("an outcome");
        assert!(
            matches!(outcome, Outcome::Delivered { .. }),
            "message {i}: {outcome:?}"
        );
    }
    let s = security(&a);
    assert_eq!((s.handshakes, s.rejected()), (1, 0), "{s:?}");
    println!("A: {MESSAGES} delivered");
}

/// Writes what the child may know into `dir`: the fleet, every public key, A's private key.
fn child_dir(setup: &Setup, dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("fleet.toml"), setup.text(&[], TABLE)).unwrap();
    for (name, pair) in &setup.keys.pairs {
        let (private, _) = pair.write(dir, name).unwrap();
        if name != "A" {
            std::fs::remove_file(private).unwrap();
        }
    }
}

fn across_processes(kind: Kind) {
    let setup = Setup::new(kind.clone());
    let dir = setup.keys.dir.join("child");
    child_dir(&setup, &dir);
    let b = setup.open("B", &[]);
    let act = b.module("Act").unwrap();
    let child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "child_a_sends",
            "--nocapture",
            "--test-threads=1",
        ])
        .env("HC_SECURE_CHILD", &dir)
        .env("HETCOMM_PRIVATE_KEY", dir.join("A.key"))
        .output()
        .expect("starting the child");
    let out = String::from_utf8_lossy(&child.stdout);
    let err = String::from_utf8_lossy(&child.stderr);
    assert!(
        child.status.success() && out.contains("A: 10 delivered"),
        "{kind:?}: the child (system A) failed:\n{out}\n{err}"
    );
    let mut got: Vec<u8> = (0..MESSAGES)
        .map(|_| {
            let m = act.recv_raw_timeout(Some(WAIT)).expect("a message from A");
            assert_eq!(m.envelope.source_system, "A");
            m.payload[0]
        })
        .collect();
    got.sort();
    assert_eq!(got, (0..MESSAGES).collect::<Vec<_>>());
    assert!(act.try_recv_raw().is_none());
    let s = security(&b);
    assert!(s.enabled, "{s:?}");
    assert_eq!((s.handshakes, s.rejected()), (1, 0), "{kind:?}: {s:?}");
}

#[test]
fn a_secured_udp_fleet_runs_across_two_processes() {
    across_processes(Kind::Udp);
}

#[test]
fn a_secured_tcp_fleet_runs_across_two_processes() {
    across_processes(Kind::Tcp);
}
