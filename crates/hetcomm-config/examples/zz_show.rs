fn main() {
    for a in std::env::args().skip(1) {
        match hetcomm_config::load(std::path::Path::new(&a)) {
            Ok(f) => println!("== {a}: OK {}", f.summary()),
            Err(e) => println!("== {a}:\n{e}"),
        }
    }
}
