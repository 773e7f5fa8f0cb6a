//! Username/password and TLS against the group's mosquitto (scripts/mqtt-test.sh starts it
//! with a password listener and a TLS listener that wants client certificates, signed by a
//! test CA it makes): accepted with the right credentials, refused with the wrong ones,
//! saying why and naming the broker.

mod common;

use std::time::{Duration, Instant};

use common::fleet::{fleet_text, keys, open_pair, send};
use common::unique_fleet;
use hetcomm::Outcome;

/// A variable scripts/mqtt-test.sh sets.
fn script_env(name: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| {
        panic!("{name} is not set: run these tests with `bash scripts/mqtt-test.sh`, which starts the broker they need")
    })
}

fn open_error(keys: &str) -> (String, Duration) {
    let fleet = hetcomm::parse_fleet(&fleet_text(keys), "m.toml", None).expect("valid");
    let started = Instant::now();
    match hetcomm::Comm::open_fleet(&fleet, "A") {
        Ok(_) => panic!("opening must fail"),
        Err(e) => (e.to_string(), started.elapsed()),
    }
}

fn delivers(keys: &str) {
    let (a, b) = open_pair(keys);
    let to = b.module("M").unwrap();
    for i in 0..5 {
        let outcome = send(&a.module("M").unwrap(), i);
        assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");
        assert!(to.recv_raw_timeout(Some(Duration::from_secs(5))).is_ok());
    }
}

/// mosquitto answers a wrong password with the reason code "not authorized" (0x87).
#[test]
fn username_and_password_are_accepted_and_wrong_ones_refused_at_once() {
    let broker = script_env("HETCOMM_MQTT_AUTH_BROKER");
    let fleet = unique_fleet();
    delivers(&keys(
        &broker,
        &fleet,
        "username = \"robot\"\npassword = \"s3cret\"",
    ));
    let (e, took) = open_error(&keys(
        &broker,
        &fleet,
        "username = \"robot\"\npassword = \"wrong\"",
    ));
    assert!(
        e.contains(&format!(
            "the MQTT broker mqtt://{broker} refused the connection: not authorized"
        )),
        "{e}"
    );
    assert!(took < Duration::from_secs(2), "{took:?}");
    let (e, _) = open_error(&keys(&broker, &fleet, ""));
    assert!(e.contains("refused the connection"), "{e}");
}

#[test]
fn tls_with_the_test_ca_and_a_client_certificate_delivers() {
    let broker = script_env("HETCOMM_MQTT_TLS_BROKER");
    let dir = script_env("HETCOMM_MQTT_TLS_DIR");
    let tls = format!(
        "ca_file = \"{dir}/ca.crt\"\nclient_cert_file = \"{dir}/client.crt\"\nclient_key_file = \"{dir}/client.key\""
    );
    delivers(&keys(&broker, &unique_fleet(), &tls));
}

#[test]
fn tls_refuses_a_broker_another_ca_signed_and_the_broker_refuses_no_client_certificate() {
    let broker = script_env("HETCOMM_MQTT_TLS_BROKER");
    let dir = script_env("HETCOMM_MQTT_TLS_DIR");
    let fleet = unique_fleet();
    let (e, took) = open_error(&keys(
        &broker,
        &fleet,
        &format!("ca_file = \"{dir}/other-ca.crt\"\nclient_cert_file = \"{dir}/client.crt\"\nclient_key_file = \"{dir}/client.key\"\nopen_timeout_ms = 1500"),
    ));
    assert!(e.contains(&broker) && e.contains("UnknownIssuer"), "{e}");
    assert!(took < Duration::from_secs(4), "{took:?}");
    let (e, _) = open_error(&keys(
        &broker,
        &fleet,
        &format!("ca_file = \"{dir}/ca.crt\"\nopen_timeout_ms = 1500"),
    ));
    assert!(e.contains(&broker) && e.contains("within 1500 ms"), "{e}");
    let (e, _) = open_error(&keys(&broker, &fleet, "ca_file = \"/nonexistent/ca.crt\""));
    assert!(
        e.contains("cannot read `ca_file` `/nonexistent/ca.crt`"),
        "{e}"
    );
}
