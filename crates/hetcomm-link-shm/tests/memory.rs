//! Shared memory that is missing, not a directory, or too small for what a link maps is
//! refused before iceoryx2 maps anything, with what to do.

use std::path::Path;

use hetcomm_link_shm::memory::{check, free_bytes, SHM_DIR};

#[test]
fn missing_or_small_shared_memory_is_refused_with_what_to_do() {
    let missing = check(Path::new("/nonexistent/hetcomm-shm-test"), 1).unwrap_err();
    assert!(missing.contains("no shared memory"), "{missing}");
    assert!(missing.contains("--shm-size"), "{missing}");

    let file = std::env::temp_dir().join(format!("hetcomm-shm-not-a-dir-{}", std::process::id()));
    std::fs::write(&file, b"x").unwrap();
    let not_dir = check(&file, 1).unwrap_err();
    let _ = std::fs::remove_file(&file);
    assert!(not_dir.contains("is not a directory"), "{not_dir}");

    let shm = Path::new(SHM_DIR);
    let (free, size) = free_bytes(shm).unwrap();
    assert!(
        size >= free && size > 0,
        "statvfs of {SHM_DIR}: {free} free of {size}"
    );
    let small = check(shm, free + (1 << 40)).unwrap_err();
    assert!(small.contains("shared memory exhausted"), "{small}");
    assert!(small.contains("Docker gives containers 64 MB"), "{small}");
    assert!(check(shm, 1).is_ok());
}
