//! The shared conformance suite on `mqtt` links through a real mosquitto: QoS 0 and QoS 1,
//! each bare and wrapped in emulation, and QoS 1 under the security layer.

mod common;

use common::MqttHarness;
use hetcomm_link::conformance::{self, Layered};
use hetcomm_link_mqtt::Qos;

#[test]
fn mqtt_qos1_passes_conformance() {
    conformance::run_all(&mut MqttHarness::new(Qos::AtLeastOnce));
}

#[test]
fn mqtt_qos0_passes_conformance() {
    conformance::run_all(&mut MqttHarness::new(Qos::AtMostOnce));
}

#[test]
fn mqtt_qos1_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(MqttHarness::new(Qos::AtLeastOnce)));
}

#[test]
fn mqtt_qos0_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(MqttHarness::new(Qos::AtMostOnce)));
}

/// Each link under the security layer (a Noise handshake per pair over publishes, every frame
/// sealed), as a secured `mqtt` transport opens it.
#[test]
fn mqtt_qos1_passes_conformance_secured() {
    conformance::run_all(&mut hetcomm_security::conformance::secured(
        MqttHarness::new(Qos::AtLeastOnce),
        [hetcomm::SystemId(1), hetcomm::SystemId(2)],
    ));
}
