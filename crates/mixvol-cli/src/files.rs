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

/// Writes `text` to `path` (creating its folder), naming the path on failure.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    create_parent(path)?;
    std::fs::write(path, text).map_err(|e| Error::ImageWrite {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}
