use hetcomm_derive::Message;

#[derive(serde::Serialize, serde::Deserialize, Message)]
#[message(id = 1, name = "Wheels", crate = "hetcomm_core")]
struct Wheels {
    left: f64,
}

fn main() {}
