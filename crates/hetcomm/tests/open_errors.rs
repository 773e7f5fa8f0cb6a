//! Errors from opening a transport keep their cause: the link's error (and the operating
//! system's under it) is the `source()` of `OpenError::Transport`, not only its text.

use std::error::Error;

#[test]
fn an_endpoint_in_use_keeps_the_os_error_as_its_source() {
    let taken = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let text = format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.lan]
kind = "udp"
endpoints = {{ A = "127.0.0.1:{port}", B = "127.0.0.1:9" }}
[table]
columns = ["A", "B"]
A = ["X", "lan"]
B = ["lan", "X"]
"#
    );
    let mut fleet = hetcomm::config::parse_str(&text, "in-use.toml", None).unwrap();
    // Unsecured: the point is the socket's error, not the missing keys.
    fleet.transports[0].security = hetcomm::config::SecurityMode::None;
    let Err(err) = hetcomm::Comm::open_fleet(&fleet, "A") else {
        panic!("the port is taken: opening must fail");
    };
    assert!(
        matches!(&err, hetcomm::OpenError::Transport { transport, system, .. } if transport == "lan" && system == "A"),
        "{err}"
    );
    // Walk the chain down to the operating system's error.
    let mut cause: Option<&(dyn Error + 'static)> = err.source();
    let mut io = None;
    while let Some(c) = cause {
        if let Some(e) = c.downcast_ref::<std::io::Error>() {
            io = Some(e.kind());
        }
        cause = c.source();
    }
    assert_eq!(
        io,
        Some(std::io::ErrorKind::AddrInUse),
        "the chain reaches the OS error: {err:?}"
    );
}
