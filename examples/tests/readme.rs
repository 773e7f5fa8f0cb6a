//! The README's Rust program is `examples/readme.rs`, byte for byte, so the code a new user
//! copies is the code the test suite compiles (and `scripts/test.sh` runs).

#[test]
fn the_readme_program_is_the_readme_example() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let example = std::fs::read_to_string(root.join("examples/readme.rs")).unwrap();
    let block = format!("```rust\n{example}```\n");
    assert!(
        readme.contains(&block),
        "README.md's Rust block differs from examples/readme.rs; copy the file into the README"
    );
    assert!(example.contains("fn main()") && example.contains("got.message"));
}
