//! The checked-in C header is what cbindgen makes from this crate now: a change to the C API
//! that was not followed by regenerating `include/hetcomm.h` fails here.
//!
//! Regenerate: `HETCOMM_BLESS=1 cargo test -p hetcomm-c --test header`.

use std::path::Path;

fn generate() -> String {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut out = Vec::new();
    cbindgen::Builder::new()
        .with_crate(dir)
        .with_config(config)
        .generate()
        .expect("cbindgen parses the crate")
        .write(&mut out);
    String::from_utf8(out).expect("the header is UTF-8")
}

#[test]
fn checked_in_header_is_current() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("include/hetcomm.h");
    let fresh = generate();
    if std::env::var_os("HETCOMM_BLESS").is_some() {
        std::fs::write(&path, &fresh).expect("writing include/hetcomm.h");
        return;
    }
    let checked_in = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        checked_in == fresh,
        "{} is stale: the C API changed. Regenerate it with \
         `HETCOMM_BLESS=1 cargo test -p hetcomm-c --test header` and commit it.",
        path.display()
    );
    // The header declares every function the library exports.
    for name in [
        "hetcomm_comm_open",
        "hetcomm_module_send",
        "hetcomm_module_recv",
        "hetcomm_ticket_wait_timeout",
        "hetcomm_module_on",
        "hetcomm_last_error",
    ] {
        assert!(fresh.contains(&format!("{name}(")), "{name} missing");
    }
}
