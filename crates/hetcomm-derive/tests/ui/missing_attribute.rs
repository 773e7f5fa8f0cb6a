use hetcomm_derive::Message;

#[derive(serde::Serialize, serde::Deserialize, Message)]
struct Wheels {
    left: f64,
}

fn main() {}
