//! Helpers the facade's integration tests share.
#![allow(dead_code)] // each test binary uses its own subset

/// A UDP port on 127.0.0.1 that was free a moment ago.
pub fn free_udp_port() -> u16 {
    not_given_before(|| {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .map(|a| a.port())
            .expect("a free port")
    })
}

/// Calls `pick` until it returns a port this process has not handed out yet: the kernel can
/// return a just-closed port again, and two systems of one fleet would share an endpoint.
pub fn not_given_before(pick: impl Fn() -> u16) -> u16 {
    static GIVEN: parking_lot::Mutex<std::collections::BTreeSet<u16>> =
        parking_lot::Mutex::new(std::collections::BTreeSet::new());
    loop {
        let port = pick();
        if GIVEN.lock().insert(port) {
            return port;
        }
    }
}

/// A fleet of systems A and B, module line `modules` (e.g. `M = 0`), joined by one UDP
/// transport `u` on free loopback ports; `keys` are more lines for that transport (e.g.
/// `delivery = "unacknowledged"`) and `head` goes before everything (e.g. an `[inbox]` table).
pub fn udp_pair_text(head: &str, modules: &str, keys: &str) -> String {
    let (pa, pb) = (free_udp_port(), free_udp_port());
    format!(
        r#"{head}
[systems]
A = 0
B = 1
[modules]
{modules}
[transports.u]
kind = "udp"
{keys}
endpoints = {{ A = "127.0.0.1:{pa}", B = "127.0.0.1:{pb}" }}
[table]
columns = ["A", "B"]
A = ["X", "u"]
B = ["u", "X"]
"#
    )
}

pub mod attack;
