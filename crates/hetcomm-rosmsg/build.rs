//! Lists the shipped `.msg` files (`msg/ros1/PKG/msg/*.msg`, `msg/ros2/PKG/msg/*.msg`) as
//! `include_str!`s in `$OUT_DIR/shipped.rs`, so that adding a file is all it takes to ship it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn list(root: &Path) -> Vec<(String, String, PathBuf)> {
    let mut out = Vec::new();
    let mut packages: Vec<_> = std::fs::read_dir(root)
        .unwrap_or_else(|e| panic!("reading {}: {e}", root.display()))
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.join("msg").is_dir())
        .collect();
    packages.sort();
    for pkg in packages {
        let name = pkg.file_name().unwrap().to_string_lossy().to_string();
        let mut files: Vec<_> = std::fs::read_dir(pkg.join("msg"))
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "msg"))
            .collect();
        files.sort();
        for f in files {
            let ty = f.file_stem().unwrap().to_string_lossy().to_string();
            out.push((name.clone(), ty, f));
        }
    }
    out
}

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let mut src = String::new();
    for (flavour, dir) in [("ROS1", "ros1"), ("ROS2", "ros2")] {
        let root = manifest.join("msg").join(dir);
        writeln!(
            src,
            "pub(crate) static {flavour}: &[(&str, &str, &str)] = &["
        )
        .unwrap();
        for (pkg, ty, path) in list(&root) {
            writeln!(
                src,
                "    ({pkg:?}, {ty:?}, include_str!({:?})),",
                path.display()
            )
            .unwrap();
        }
        writeln!(src, "];").unwrap();
    }
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    std::fs::write(out.join("shipped.rs"), src).expect("writing shipped.rs");
    println!("cargo:rerun-if-changed=msg");
}
