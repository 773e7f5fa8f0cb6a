//! `#[derive(Message)]` on a struct, an enum and a generic struct, checked through
//! `hetcomm_core` (the facade crate is not a dependency inside the workspace).

use hetcomm_core::{payload, Message, MessageType, TypeRegistry};
use hetcomm_derive::Message;
use serde::{de::DeserializeOwned, Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, PartialEq, Clone)]
#[message(id = 1, crate = "hetcomm_core")]
struct Wheels {
    left: f64,
    right: f64,
}

#[derive(Serialize, Deserialize, Message, Debug, PartialEq, Clone)]
#[message(crate = "hetcomm_core", id = 4_294_967_295)]
enum Command {
    Stop,
    Drive { speed: f64 },
    Turn(i16),
}

#[derive(Serialize, Deserialize, Message, Debug, PartialEq, Clone)]
#[message(id = 0x20, crate = "::hetcomm_core")]
#[serde(bound(deserialize = ""))]
struct Tagged<T>
where
    T: Serialize + DeserializeOwned + Send + 'static,
{
    tag: String,
    value: T,
}

#[derive(Serialize, Deserialize, Message, Debug, PartialEq, Clone)]
#[message(id = 7u32, crate = "hetcomm_core")]
struct Ping;

/// A path that renames the crate, as a user re-exporting hetcomm would.
mod reexport {
    pub use hetcomm_core as hc;
}

#[derive(Serialize, Deserialize, Message, Debug, PartialEq)]
#[message(id = 9, crate = "crate::reexport::hc")]
struct ThroughReexport(u8, u8);

fn round_trip<M: Message + PartialEq + std::fmt::Debug>(value: &M) {
    let bytes = payload::encode(value).unwrap();
    let back: M = payload::decode(&bytes).unwrap();
    assert_eq!(&back, value, "{} round trip", M::NAME);
}

#[test]
fn struct_type_name_and_payload() {
    assert_eq!(Wheels::TYPE, MessageType(1));
    assert_eq!(Wheels::NAME, "Wheels");
    let w = Wheels {
        left: -10.0,
        right: 10.0,
    };
    round_trip(&w);
    let json = payload::to_json(&payload::encode(&w).unwrap()).unwrap();
    assert_eq!(json, serde_json::json!({"left": -10.0, "right": 10.0}));
}

#[test]
fn enum_type_name_and_payload() {
    assert_eq!(Command::TYPE, MessageType(u32::MAX));
    assert_eq!(Command::NAME, "Command");
    round_trip(&Command::Stop);
    round_trip(&Command::Drive { speed: 0.5 });
    round_trip(&Command::Turn(-90));
}

#[test]
fn generic_struct_type_name_and_payload() {
    assert_eq!(<Tagged<u64>>::TYPE, MessageType(0x20));
    assert_eq!(<Tagged<u64>>::NAME, "Tagged");
    assert_eq!(<Tagged<Vec<String>>>::TYPE, MessageType(32));
    round_trip(&Tagged {
        tag: "odometry".into(),
        value: 42u64,
    });
    round_trip(&Tagged {
        tag: "names".into(),
        value: vec!["a".to_string(), "b".to_string()],
    });
}

#[test]
fn unit_struct_and_suffixed_id() {
    assert_eq!(Ping::TYPE, MessageType(7));
    assert_eq!(Ping::NAME, "Ping");
    round_trip(&Ping);
}

#[test]
fn crate_path_through_a_reexport() {
    assert_eq!(ThroughReexport::TYPE, MessageType(9));
    assert_eq!(ThroughReexport::NAME, "ThroughReexport");
    round_trip(&ThroughReexport(1, 2));
}

#[test]
fn derived_types_register() {
    let mut registry = TypeRegistry::new();
    registry.register::<Wheels>().unwrap();
    registry.register::<Command>().unwrap();
    registry.register::<Tagged<u8>>().unwrap();
    registry.register::<Ping>().unwrap();
    assert_eq!(registry.get(MessageType(1)).unwrap().name, "Wheels");
    assert_eq!(
        registry.by_name("Command").unwrap().id,
        MessageType(u32::MAX)
    );
    assert_eq!(registry.iter().count(), 4);
}

#[test]
fn compile_errors() {
    let t = trybuild::TestCases::new();
    t.compile_fail("tests/ui/*.rs");
}
