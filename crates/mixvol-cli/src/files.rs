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
/// write leaves any previous file intact), naming the path on failure.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    create_parent(path)?;
    mixvol::output::write_file_atomically(path, text.as_bytes()).map_err(|e| Error::ImageWrite {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}
