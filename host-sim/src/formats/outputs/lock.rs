//! One run at a time per output file (issue 43: two `lut build` runs with different
//! inputs and the same `-o` left `out.fits` from one and `out.bin` from the other in 4 of
//! 200 trials, both with exit 0).
//!
//! Each target is locked when it is first named: an exclusive `flock` on `.NAME.dncal-lock`
//! beside it, taken without waiting, held until the set is published or dropped. A second
//! run naming the same file fails at once, naming the file and the process that holds it
//! ([`HostError::Busy`]); as every run takes all of its locks before it computes anything,
//! two runs never publish into one set together and neither waits for the other (no
//! deadlock is possible: nobody waits).
//!
//! The lock file is removed by its holder while it still holds it: a run that opened the
//! file just before and locks it just after finds, by comparing the inode it locked with
//! the one the name now leads to, that it locked a removed file, and tries again. A run
//! killed with its lock leaves the file, unlocked (the kernel drops a dead process's
//! locks): the next run takes it over and removes it in turn.

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::HostError;

/// Suffix of a target's lock file.
pub(super) const LOCK_SUFFIX: &str = "dncal-lock";

/// A held lock on one target; released (its file removed) on drop.
#[derive(Debug)]
pub(super) struct TargetLock {
    path: PathBuf,
    // Kept open: closing it releases the lock.
    _file: File,
}

impl TargetLock {
    /// Locks `target`, whose lock file is `{prefix}dncal-lock` in `dir` (the prefix of its
    /// temporaries); [`HostError::Busy`] if another run holds it.
    pub(super) fn take(target: &Path, dir: &Path, prefix: &str) -> Result<Self, HostError> {
        let path = dir.join(format!("{prefix}{LOCK_SUFFIX}"));
        let io = |e| HostError::io(target, e);
        loop {
            let mut options = std::fs::OpenOptions::new();
            options.read(true).write(true).create(true);
            #[cfg(unix)]
            {
                use std::os::unix::fs::OpenOptionsExt;
                options.mode(0o666);
            }
            let file = options.open(&path).map_err(io)?;
            if !try_lock(&file).map_err(io)? {
                return Err(HostError::Busy { path: target.into(), pid: holder(&path) });
            }
            if same_file(&file, &path) {
                write_pid(&file);
                return Ok(TargetLock { path, _file: file });
            }
            // Locked a file its holder removed as we opened it: again, on the new one.
        }
    }
}

impl Drop for TargetLock {
    fn drop(&mut self) {
        // Removed while held (see the module docs), then released as the file closes.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// An exclusive lock on `file` without waiting: `Ok(false)` if another holds one.
fn try_lock(file: &File) -> std::io::Result<bool> {
    #[cfg(unix)]
    {
        use std::os::unix::io::AsRawFd;
        // SAFETY: flock on a descriptor this process holds open.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::EWOULDBLOCK) { Ok(false) } else { Err(e) }
    }
    #[cfg(not(unix))]
    {
        let _ = file;
        Ok(true)
    }
}

/// Whether the open `file` is the one `path` now names.
fn same_file(file: &File, path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), std::fs::metadata(path)) {
            (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (file, path);
        true
    }
}

/// Records this process as the holder (for the message of a run that finds it busy).
fn write_pid(mut file: &File) {
    use std::io::Write;
    let _ = file.set_len(0).and_then(|()| file.write_all(std::process::id().to_string().as_bytes()));
}

/// The process a busy lock file names, where it names one.
fn holder(path: &Path) -> Option<u32> {
    std::fs::read_to_string(path).ok()?.trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_and_the_file_goes_with_the_first() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.fits");
        let first = TargetLock::take(&target, dir.path(), ".out.fits.").unwrap();
        let lock_file = dir.path().join(".out.fits.dncal-lock");
        assert_eq!(std::fs::read_to_string(&lock_file).unwrap(), std::process::id().to_string());
        let e = TargetLock::take(&target, dir.path(), ".out.fits.").unwrap_err();
        assert_eq!(e.to_string(), format!("{}: another dncal run (process {}) is writing this output now; run again when it has finished, or name another output", target.display(), std::process::id()));
        drop(first);
        assert!(!lock_file.exists());
        // Taken again, and a lock file left by a killed run (unlocked) is taken over.
        drop(TargetLock::take(&target, dir.path(), ".out.fits.").unwrap());
        std::fs::write(&lock_file, "99999999").unwrap();
        drop(TargetLock::take(&target, dir.path(), ".out.fits.").unwrap());
        assert!(!lock_file.exists());
    }
}
