//! Atomic file replacement: write a temporary file next to the target, then rename it over the
//! target.
//!
//! A rename within one folder (one file system) is atomic: a concurrent reader sees either the
//! old file or the complete new one, never a partial write, and a process killed mid-write
//! leaves at most a stray temporary file (named `.NAME.PID.N.tmp`) but never a truncated `NAME`.
//! The data are not `fsync`ed (that would make every output step wait for the disk), so this is
//! not a durability guarantee against a power failure.

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Distinguishes temporary files of concurrent writers within one process.
static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `contents` to `path` atomically (temporary file in the same folder, then rename).
///
/// The folder must exist. On error the temporary file is removed and `path` is left as it was.
pub fn write_atomic(path: &Path, contents: &[u8]) -> io::Result<()> {
    write_atomic_with(path, |w| w.write_all(contents))
}

/// Like [`write_atomic`], but the contents are streamed by `write` into a buffered writer on the
/// temporary file (no need to hold a large file in memory). If `write` fails, the temporary file
/// is removed and the error is returned; `path` is untouched.
pub(crate) fn write_atomic_with<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> io::Result<()>,
{
    let (temp_path, file) = create_temp_beside(path)?;
    let result = (|| {
        let mut writer = BufWriter::new(file);
        write(&mut writer)?;
        writer.flush()?;
        // Drop (close) the file before the rename.
        drop(writer.into_inner().map_err(|e| e.into_error())?);
        fs::rename(&temp_path, path)
    })();
    if result.is_err() {
        // Best effort: the original error is the one worth reporting.
        let _ = fs::remove_file(&temp_path);
    }
    result.map_err(|e| {
        let hint = match e.kind() {
            io::ErrorKind::StorageFull | io::ErrorKind::QuotaExceeded => {
                " (no space left on the device: free space, or write elsewhere with --out)"
            }
            io::ErrorKind::PermissionDenied | io::ErrorKind::ReadOnlyFilesystem => {
                " (the folder is not writable: choose another with --out)"
            }
            _ => "",
        };
        io::Error::new(e.kind(), format!("writing {}: {e}{hint}", path.display()))
    })
}

/// Creates a new, uniquely named temporary file in the folder of `path`.
fn create_temp_beside(path: &Path) -> io::Result<(PathBuf, File)> {
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("output path {} does not name a file", path.display()),
        )
    })?;
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    loop {
        let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        let mut temp_name = std::ffi::OsString::from(".");
        temp_name.push(name);
        temp_name.push(format!(".{}.{n}.tmp", std::process::id()));
        let temp_path = folder.join(temp_name);
        match OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp_path)
        {
            Ok(file) => return Ok((temp_path, file)),
            // A leftover from a killed process with the same pid: try the next number.
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(e) => {
                return Err(io::Error::new(
                    e.kind(),
                    format!("creating a temporary file in {}: {e}", folder.display()),
                ));
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod test_dir {
    //! Unique scratch folders for tests (under the system temp folder, removed on drop).

    use std::path::{Path, PathBuf};
    use std::sync::atomic::{AtomicU64, Ordering};

    static COUNTER: AtomicU64 = AtomicU64::new(0);

    /// A fresh, empty folder, removed with its contents when dropped.
    pub(crate) struct TestDir(PathBuf);

    impl TestDir {
        pub(crate) fn new(label: &str) -> Self {
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let path = std::env::temp_dir().join(format!(
                "impm-output-test-{label}-{}-{n}",
                std::process::id()
            ));
            let _ = std::fs::remove_dir_all(&path);
            std::fs::create_dir_all(&path).expect("create test folder");
            TestDir(path)
        }

        pub(crate) fn path(&self) -> &Path {
            &self.0
        }

        /// Sorted names of the files in the folder.
        pub(crate) fn file_names(&self) -> Vec<String> {
            let mut names: Vec<String> = std::fs::read_dir(&self.0)
                .expect("read test folder")
                .map(|e| {
                    e.expect("dir entry")
                        .file_name()
                        .to_string_lossy()
                        .into_owned()
                })
                .collect();
            names.sort();
            names
        }
    }

    impl Drop for TestDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_dir::TestDir;
    use super::*;

    #[test]
    fn writes_and_replaces_without_leaving_temp_files() {
        let dir = TestDir::new("atomic");
        let path = dir.path().join("summary.json");
        write_atomic(&path, b"{\"a\": 1}").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"{\"a\": 1}");
        write_atomic(&path, b"{\"a\": 2}").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"{\"a\": 2}");
        assert_eq!(dir.file_names(), vec!["summary.json".to_string()]);
    }

    #[test]
    fn failed_write_leaves_target_and_no_temp_file() {
        let dir = TestDir::new("atomic-fail");
        let path = dir.path().join("data.txt");
        write_atomic(&path, b"old").unwrap();
        let err = write_atomic_with(&path, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("simulated failure"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("simulated failure"), "{err}");
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(dir.file_names(), vec!["data.txt".to_string()]);
    }

    #[test]
    fn missing_folder_is_an_error_not_a_panic() {
        let dir = TestDir::new("atomic-missing");
        let path = dir.path().join("no-such-folder").join("x.txt");
        let err = write_atomic(&path, b"x").unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::NotFound);
        assert!(err.to_string().contains("no-such-folder"), "{err}");
    }

    #[test]
    fn path_without_file_name_is_invalid_input() {
        let err = write_atomic(Path::new("/"), b"x").unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
    }
}
