use hetcomm_derive::Message;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = "seven", crate = "hetcomm_core")]
struct Wheels {
    left: f64,
}

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = 4294967296, crate = "hetcomm_core")]
struct TooBig;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = -1, crate = "hetcomm_core")]
struct Negative;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = 3u8, crate = "hetcomm_core")]
struct WrongSuffix;

fn main() {}
