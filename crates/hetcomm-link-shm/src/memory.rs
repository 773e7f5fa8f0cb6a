//! What the operating system offers for shared memory, checked before iceoryx2 maps anything,
//! so that a missing, small or foreign `/dev/shm` is an error that says what to do.

use std::os::unix::fs::MetadataExt;
use std::path::Path;

/// Where POSIX shared memory lives on Linux (iceoryx2's segments are files there).
pub const SHM_DIR: &str = "/dev/shm";

/// Free bytes in the file system at `dir`, and its size.
pub fn free_bytes(dir: &Path) -> std::io::Result<(u64, u64)> {
    let c = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes())
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
    // SAFETY: `c` is a valid NUL-terminated path and `st` a properly sized out-parameter.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    let block = st.f_frsize as u64;
    Ok((st.f_bavail as u64 * block, st.f_blocks as u64 * block))
}

/// Checks that shared memory can hold `needed` bytes now, or says why not and what to do.
pub fn check(dir: &Path, needed: u64) -> Result<(), String> {
    let meta = std::fs::metadata(dir).map_err(|e| {
        format!(
            "no shared memory: {} is not there ({e}); mount a tmpfs there (`mount -t tmpfs \
             tmpfs {0}`), or in a container give it one (`docker run --shm-size=256m`, \
             `--ipc=host` to share the host's)",
            dir.display()
        )
    })?;
    if !meta.is_dir() {
        return Err(format!(
            "no shared memory: {} is not a directory",
            dir.display()
        ));
    }
    // SAFETY: access(2) on a valid NUL-terminated path has no memory-safety preconditions.
    let c =
        std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()).map_err(|e| e.to_string())?;
    if unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) } != 0 {
        return Err(format!(
            "shared memory {} is not writable by this user (uid {}; it belongs to uid {}, mode \
             {:o}): run as a user that may create files there",
            dir.display(),
            // SAFETY: getuid never fails.
            unsafe { libc::getuid() },
            meta.uid(),
            meta.mode() & 0o7777
        ));
    }
    let (free, size) = free_bytes(dir).map_err(|e| format!("statvfs {}: {e}", dir.display()))?;
    if free < needed {
        return Err(too_small(dir, free, size, needed));
    }
    Ok(())
}

/// The error for shared memory without room for `needed` bytes.
pub fn too_small(dir: &Path, free: u64, size: u64, needed: u64) -> String {
    format!(
        "shared memory exhausted: {} has {} free of {} and the shm transport needs {} more; \
         Docker gives containers 64 MB unless run with `--shm-size` (e.g. `--shm-size=256m`); \
         or lower the transport's `queue_depth`, `initial_frame` or `max_frame`",
        dir.display(),
        mib(free),
        mib(size),
        mib(needed)
    )
}

fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / (1024.0 * 1024.0))
}
