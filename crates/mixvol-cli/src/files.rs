//! Writing output files: folders created first, failures naming the path.

use mixvol::{Error, Result};
use std::path::Path;

/// Creates the folder `path` will be written into.
pub fn create_parent(path: &Path) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::ImageWrite {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    }
    Ok(())
}

/// Writes `text` to `path` (creating its folder) atomically ([`mixvol::output`]: a failed
/// write leaves any previous file intact), naming `what` it is and the path on failure.
pub fn write_text(what: &str, path: &Path, text: &str) -> Result<()> {
    let fail = |e: &dyn std::fmt::Display| Error::FileWrite {
        what: what.to_string(),
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| fail(&e))?;
    }
    mixvol::output::write_file_atomically(path, text.as_bytes()).map_err(|e| fail(&e))
}

/// Writes `value` (`what` it is, for messages) as one line of JSON to `path`, or to standard
/// output for `-`.
pub fn write_json(what: &str, path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let text = serde_json::to_string(value)
        .map_err(|e| Error::InvalidInput(format!("results as JSON: {e}")))?
        + "\n";
    if path.as_os_str() == "-" {
        print!("{text}");
        Ok(())
    } else {
        write_text(what, path, &text)
    }
}

/// Says that timings from a CPU implementation (lavapipe) are CPU times.
pub fn note_cpu_device(info: &mixvol::gpu::DeviceInfo) {
    if info.device_type == ash::vk::PhysicalDeviceType::CPU {
        println!(
            "note: {} is a CPU implementation; compare ratios, not absolute times",
            info.name
        );
    }
}
