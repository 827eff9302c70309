//! The output folder of one run at a time: a lock file (`.impm.lock`, holding the process id)
//! so that a second run into the same folder fails with a clear message instead of
//! interleaving its files, and the removal of what an earlier run into the folder left that the
//! new run will not rewrite.
//!
//! A lock whose process no longer exists was left by a run that was killed; it is taken over
//! and reported ([`FolderLock::killed_run`]). Only files impm writes are removed: series files
//! `STEM_NNNN.vtu` of a series `STEM.pvd` in the folder, the `.pvd` files, `summary.json`,
//! `history.csv`, `checkpoint.json` and its `checkpoint_NNNN.bin`, and the temporary files of
//! interrupted atomic writes (`.NAME.PID.N.tmp`).

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// The lock on an output folder, released (removed) when dropped.
#[derive(Debug)]
pub struct FolderLock {
    path: PathBuf,
    killed: Option<u32>,
}

const LOCK_NAME: &str = ".impm.lock";

impl FolderLock {
    /// Locks `dir` (created if missing) for this process, or says which run holds it.
    pub fn acquire(dir: &Path) -> Result<Self, String> {
        fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create the output folder {}: {e}", dir.display()))?;
        let path = dir.join(LOCK_NAME);
        let mut killed = None;
        loop {
            match fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&path)
            {
                Ok(file) => {
                    use std::io::Write;
                    let mut file = file;
                    writeln!(file, "{}", std::process::id()).map_err(|e| {
                        format!("cannot write the lock file {}: {e}", path.display())
                    })?;
                    return Ok(Self { path, killed });
                }
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                    let holder = fs::read_to_string(&path)
                        .ok()
                        .and_then(|text| text.trim().parse::<u32>().ok());
                    match holder {
                        Some(pid) if pid != std::process::id() && process_exists(pid) => {
                            return Err(format!(
                                "another impm run (process {pid}) is writing into {}; wait for it to finish, or choose another folder with --out",
                                dir.display()
                            ));
                        }
                        _ => {
                            // stale: its process is gone (killed), or the file is unreadable
                            killed = holder.or(Some(0));
                            fs::remove_file(&path).map_err(|e| {
                                format!("cannot remove the stale lock {}: {e}", path.display())
                            })?;
                        }
                    }
                }
                Err(e) => {
                    return Err(format!(
                        "cannot lock the output folder {}: {e}",
                        dir.display()
                    ));
                }
            }
        }
    }

    /// The process id of an earlier run into the folder that was killed before it finished
    /// (its lock was left behind), if any; 0 if its lock file was unreadable.
    pub fn killed_run(&self) -> Option<u32> {
        self.killed
    }
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
    }
}

fn process_exists(pid: u32) -> bool {
    Path::new("/proc").join(pid.to_string()).exists()
}

/// Removes what an earlier run left in `dir` (see the module docs); returns how many files.
pub fn clear_earlier_run(dir: &Path) -> io::Result<usize> {
    remove_where(dir, is_impm_file)
}

/// Removes, for a run resumed after load step `step`, what the interrupted run wrote later: the
/// series files `STEM_NNNN.vtu` with `NNNN > step` of the series in `dir`, and the temporary
/// files of interrupted atomic writes. Returns how many files.
pub fn clear_after_step(dir: &Path, step: usize) -> io::Result<usize> {
    remove_where(dir, |name, series| {
        is_temporary(name) || series_step(name, series).is_some_and(|n| n > step)
    })
}

/// Removes the files of `dir` (a missing folder has none) for which `remove(name, series)`
/// holds, given the series (`.pvd` stems) in the folder; returns how many.
fn remove_where(dir: &Path, remove: impl Fn(&str, &[&str]) -> bool) -> io::Result<usize> {
    let names: Vec<String> = match fs::read_dir(dir) {
        Ok(entries) => entries
            .filter_map(|entry| entry.ok())
            .filter(|entry| entry.file_type().is_ok_and(|t| t.is_file()))
            .filter_map(|entry| entry.file_name().into_string().ok())
            .collect(),
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let series: Vec<&str> = names
        .iter()
        .filter_map(|name| name.strip_suffix(".pvd"))
        .collect();
    let mut removed = 0;
    for name in &names {
        if remove(name, &series) {
            fs::remove_file(dir.join(name))?;
            removed += 1;
        }
    }
    Ok(removed)
}

/// The step number of a series file `STEM_NNNN.vtu` of one of the `series`, or of a
/// distributed run's parallel file `STEM_NNNN.pvtu` and its pieces `STEM_NNNN_pK.vtu`.
fn series_step(name: &str, series: &[&str]) -> Option<usize> {
    let stem = match name.strip_suffix(".pvtu") {
        Some(stem) => stem,
        None => {
            let stem = name.strip_suffix(".vtu")?;
            match stem.rsplit_once("_p") {
                Some((step, piece))
                    if !piece.is_empty() && piece.bytes().all(|b| b.is_ascii_digit()) =>
                {
                    step
                }
                _ => stem,
            }
        }
    };
    let (series_name, number) = stem.rsplit_once('_')?;
    if number.is_empty() || !number.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    series
        .contains(&series_name)
        .then(|| number.parse().ok())
        .flatten()
}

/// Whether `name` is a file impm writes, given the series (`.pvd` stems) in its folder.
fn is_impm_file(name: &str, series: &[&str]) -> bool {
    if matches!(name, "summary.json" | "history.csv" | "checkpoint.json")
        || name.ends_with(".pvd")
        || is_checkpoint_data(name)
    {
        return true;
    }
    is_temporary(name) || series_step(name, series).is_some()
}

/// `checkpoint_NNNN.bin` (any number of digits), the binary file of a checkpoint, or
/// `checkpoint_NNNN_pK.bin`, a process's piece of one (`crate::restart`).
pub fn is_checkpoint_data(name: &str) -> bool {
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    name.strip_prefix("checkpoint_")
        .and_then(|rest| rest.strip_suffix(".bin"))
        .is_some_and(|stem| match stem.split_once("_p") {
            Some((step, piece)) => digits(step) && digits(piece),
            None => digits(stem),
        })
}

/// `.NAME.PID.N.tmp`, the temporary file of an atomic write.
fn is_temporary(name: &str) -> bool {
    let Some(inner) = name.strip_prefix('.').and_then(|n| n.strip_suffix(".tmp")) else {
        return false;
    };
    let mut parts = inner.rsplitn(3, '.');
    let counter = parts.next().unwrap_or_default();
    let pid = parts.next().unwrap_or_default();
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    digits(counter) && digits(pid) && parts.next().is_some_and(|n| !n.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_impm_files_are_recognised() {
        let series = ["particles", "grid"];
        for name in [
            "particles_0003.vtu",
            "particles_0003.pvtu",
            "particles_0003_p12.vtu",
            "grid_12345.vtu",
            "particles.pvd",
            "summary.json",
            "checkpoint_0012.bin",
            "checkpoint_0012_p3.bin",
            ".particles_0001.vtu.4242.0.tmp",
        ] {
            assert!(is_impm_file(name, &series), "{name}");
        }
        for name in [
            "mesh_0001.vtu",
            "particles_final.vtu",
            "particles_0003_p.vtu",
            "particles_final.pvtu",
            "notes.txt",
            "checkpoint_final.bin",
            "checkpoint_0012_p.bin",
            "checkpoint__p1.bin",
            ".hidden.tmp",
            "particles_0001.vtu.bak",
        ] {
            assert!(!is_impm_file(name, &series), "{name}");
        }
    }

    #[test]
    fn a_resumed_run_removes_only_the_later_steps() {
        let dir = std::env::temp_dir().join(format!("impm-after-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        let names = [
            "particles.pvd",
            "particles_0002.vtu",
            "particles_0003.vtu",
            "particles_0004.vtu",
            "mesh_0009.vtu",
            ".particles_0004.vtu.42.0.tmp",
        ];
        for name in names {
            fs::write(dir.join(name), "x").unwrap();
        }
        assert_eq!(clear_after_step(&dir, 3).unwrap(), 2);
        let mut left: Vec<String> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        assert_eq!(
            left,
            [
                "mesh_0009.vtu",
                "particles.pvd",
                "particles_0002.vtu",
                "particles_0003.vtu"
            ]
        );
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_second_lock_fails_and_a_stale_one_is_taken_over() {
        let dir = std::env::temp_dir().join(format!("impm-lock-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let lock = FolderLock::acquire(&dir).unwrap();
        assert_eq!(lock.killed_run(), None);
        drop(lock);
        // a lock of a live process that is not us (pid 1 exists on Linux)
        fs::write(dir.join(LOCK_NAME), "1\n").unwrap();
        let error = FolderLock::acquire(&dir).unwrap_err();
        assert!(error.contains("process 1"), "{error}");
        // a lock of a process that cannot exist (above the kernel's pid limit)
        fs::write(dir.join(LOCK_NAME), "2000000000\n").unwrap();
        let lock = FolderLock::acquire(&dir).unwrap();
        assert_eq!(lock.killed_run(), Some(2_000_000_000));
        drop(lock);
        assert!(!dir.join(LOCK_NAME).exists());
        let _ = fs::remove_dir_all(&dir);
    }
}
