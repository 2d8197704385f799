//! Output files written so that a failed write never leaves a truncated file under the final
//! name nor destroys the file that was there: the bytes go to a temporary file in the same
//! folder, which is flushed, synced and then renamed over the target. Targets that exist but
//! are not regular files (devices such as `/dev/full`, FIFOs, folders) are refused rather than
//! replaced.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Numbers the temporary files of one process (two threads may write the same target).
static NEXT_PARTIAL: AtomicU64 = AtomicU64::new(0);

/// A temporary name for `path` to be written under before the rename:
/// `.NAME.partial-PID-N` beside it (`N` counts the calls of this process).
pub fn partial_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "output".into());
    let n = NEXT_PARTIAL.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}.partial-{}-{n}", std::process::id()))
}

/// Writes what `write` produces to `path` atomically (see the module docs). Errors: the target
/// exists and is not a regular file (`InvalidInput`), or any create, write, sync or rename
/// failure; the temporary file is removed then and an existing `path` is left as it was.
pub fn write_atomically_with(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> io::Result<()> {
    if let Ok(meta) = std::fs::metadata(path) {
        if !meta.is_file() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "the path exists and is not a regular file (a device, FIFO or folder); \
                 give a file path",
            ));
        }
    }
    let temp = partial_name(path);
    let result = (|| {
        let file = File::create_new(&temp)?;
        let mut writer = BufWriter::new(file);
        write(&mut writer)?;
        let file = writer.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&temp, path)
    })();
    if result.is_err() {
        // Best effort: nothing useful is left in the partial file.
        let _ = std::fs::remove_file(&temp);
    }
    result
}

/// Writes `bytes` to `path` atomically ([`write_atomically_with`]).
pub fn write_file_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomically_with(path, |w| w.write_all(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("mixvol-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_write_replaces_the_file_and_leaves_no_partial() {
        let d = dir("ok");
        let path = d.join("a.txt");
        write_file_atomically(&path, b"one").unwrap();
        write_file_atomically(&path, b"two").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        assert_eq!(
            std::fs::read_dir(&d).unwrap().count(),
            1,
            "no partial file left"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_failed_write_keeps_the_old_file_and_removes_the_partial() {
        let d = dir("fail");
        let path = d.join("a.txt");
        write_file_atomically(&path, b"old").unwrap();
        let e = write_atomically_with(&path, |w| {
            w.write_all(b"half")?;
            Err(io::Error::other("disk full"))
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "disk full");
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1, "partial removed");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn devices_and_folders_are_refused_not_replaced() {
        let d = dir("dev");
        let e = write_file_atomically(&d, b"x").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(d.is_dir());
        let e = write_file_atomically(Path::new("/dev/null"), b"x").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
