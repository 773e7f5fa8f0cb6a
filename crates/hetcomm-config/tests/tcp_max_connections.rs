//! The `tcp` transport's `max_connections` key (issue 20): parsed into the model, checked
//! for range, and refused on `udp`, where it means nothing.

use hetcomm_link_ip::IpSettings;

mod common;
use common::parse_str;

fn fleet(kind: &str, extra: &str) -> String {
    format!(
        "\
[systems]
Alpha = 0
Bravo = 1

[transports.lan]
kind = \"{kind}\"
endpoints = {{ Alpha = \"127.0.0.1:7400\", Bravo = \"127.0.0.1:7401\" }}
{extra}
"
    )
}

fn ip_settings(text: &str) -> IpSettings {
    let f = parse_str(text, "tcp.toml", None).expect("valid fleet");
    match f.transports[0].settings.registered::<IpSettings>() {
        Some(ip) => ip.clone(),
        None => panic!("not ip settings: {:?}", f.transports[0].settings),
    }
}

fn errors(text: &str) -> Vec<String> {
    let e = parse_str(text, "tcp.toml", None).unwrap_err();
    e.0.iter()
        .map(|e| format!("{}:{}: {}", e.line, e.column, e.message))
        .collect()
}

#[test]
fn max_connections_reaches_the_model_and_defaults_to_none() {
    assert_eq!(ip_settings(&fleet("tcp", "")).max_connections, None);
    let ip = ip_settings(&fleet("tcp", "max_connections = 1000"));
    assert_eq!(ip.max_connections, Some(1000));
}

#[test]
fn max_connections_is_range_checked_and_tcp_only() {
    assert_eq!(
        errors(&fleet("tcp", "max_connections = 0")),
        ["8:19: `transports.lan.max_connections` must be from 1 to 1048576, found 0"]
    );
    assert_eq!(
        errors(&fleet("tcp", "max_connections = \"many\"")),
        ["8:19: `transports.lan.max_connections` must be an integer, found string `\"many\"`"]
    );
    assert_eq!(
        errors(&fleet("udp", "max_connections = 10")),
        ["8:1: unknown key `max_connections` in `transports.lan`"]
    );
}
