//! The host-memory limit volumes are checked against before any voxel is allocated or
//! computed: `MIXVOL_HOST_MEMORY_MB` when set (MiB), else the memory the kernel reports
//! available (`MemAvailable` in `/proc/meminfo`), else no limit.

use super::VolumeError;

/// The environment variable that sets the host-memory limit in MiB.
pub const HOST_MEMORY_ENV: &str = "MIXVOL_HOST_MEMORY_MB";

/// The host-memory limit in bytes (see the module docs); `u64::MAX` when nothing says. A
/// `MIXVOL_HOST_MEMORY_MB` that is not a whole number of MiB is an error
/// ([`VolumeError::Environment`]), not ignored.
pub fn host_memory_limit() -> Result<u64, VolumeError> {
    if let Ok(text) = std::env::var(HOST_MEMORY_ENV) {
        let mb = text
            .trim()
            .parse::<u64>()
            .map_err(|_| VolumeError::Environment {
                name: HOST_MEMORY_ENV.to_string(),
                value: text.clone(),
                expected: "expected a whole number of MiB".to_string(),
            })?;
        return Ok(mb.saturating_mul(1 << 20));
    }
    Ok(available_memory().unwrap_or(u64::MAX))
}

/// `MemAvailable` from `/proc/meminfo`, in bytes.
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// Checks that `bytes` of `what` fit the host-memory limit before the work that needs them.
pub fn check_host_bytes(what: &str, bytes: u64) -> Result<(), VolumeError> {
    let limit = host_memory_limit()?;
    if bytes > limit {
        return Err(VolumeError::TooLarge {
            what: what.to_string(),
            bytes,
            limit,
        });
    }
    Ok(())
}
