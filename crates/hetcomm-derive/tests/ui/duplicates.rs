use hetcomm_derive::Message;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = 1, id = 2, crate = "hetcomm_core")]
struct TwoIds;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = 1, crate = "hetcomm_core")]
#[message(id = 2)]
struct TwoAttributes;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = 1, crate = "not a path")]
struct BadPath;

fn main() {}
