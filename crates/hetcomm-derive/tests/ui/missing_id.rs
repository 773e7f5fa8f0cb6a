use hetcomm_derive::Message;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(crate = "hetcomm_core")]
struct Wheels {
    left: f64,
}

fn main() {}
