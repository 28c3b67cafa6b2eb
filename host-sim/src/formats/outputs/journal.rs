//! A set of several files is published under a journal (issue 43: a kill between the
//! renames of `lut build` left the new `.fits` beside the old `.bin`, and the next run
//! deleted the backups instead of restoring them).
//!
//! Before the first rename, a journal listing every file of the set (its temporary, its
//! target, the backup of the target it replaces and whether there was one) is written,
//! whole or not at all (a temporary, synced, renamed), into every directory the set
//! writes into: `.dncal-journal.PID.XXXXXX`. Its first line says which way the set is
//! going: `commit` while the renames run, `rollback` once a failure has started putting
//! the old files back. It is removed after the last backup.
//!
//! A later run that names a file in one of those directories, and finds a journal whose
//! process is no longer running, finishes the set the way the journal says before it does
//! anything else ([`recover`]): forward (every temporary still there renamed over its
//! target; the backups removed) or back (every backup renamed over its target, every new
//! target removed, the temporaries removed). Both are idempotent, so a run killed while
//! recovering is recovered by the next. The set is then all new or all old, never mixed,
//! and no backup is deleted before its set is complete.

use std::path::{Path, PathBuf};

use crate::HostError;

/// Start of a journal's file name.
pub(super) const JOURNAL_PREFIX: &str = ".dncal-journal.";
/// Suffix of a journal being written.
const PART_SUFFIX: &str = ".part";

/// Which way an interrupted set is finished.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Direction {
    /// The renames were running: finish them.
    Commit,
    /// A failure was putting the old files back: finish that.
    Rollback,
}

/// One file of a journalled set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Entry {
    pub(super) tmp: PathBuf,
    pub(super) target: PathBuf,
    pub(super) backup: PathBuf,
    /// Whether the target existed before the set (and so has a backup to go back to).
    pub(super) had_old: bool,
}

/// A journal written for a set: its copies, one per directory.
#[derive(Debug)]
pub(super) struct Journal {
    copies: Vec<PathBuf>,
    entries: Vec<Entry>,
}

impl Journal {
    /// Writes the journal of `entries` (direction [`Direction::Commit`]) into each of
    /// `dirs`, named for process `pid`.
    pub(super) fn write(entries: Vec<Entry>, dirs: &[PathBuf], pid: u32) -> Result<Journal, HostError> {
        let random: String = {
            use rand::Rng;
            let mut rng = rand::rng();
            (0..6).map(|_| rng.sample(rand::distr::Alphanumeric) as char).collect()
        };
        let copies: Vec<PathBuf> = dirs.iter().map(|d| d.join(format!("{JOURNAL_PREFIX}{pid}.{random}"))).collect();
        let journal = Journal { copies, entries };
        journal.store(Direction::Commit)?;
        Ok(journal)
    }

    /// (Re)writes every copy with `direction`, each whole or not at all.
    pub(super) fn store(&self, direction: Direction) -> Result<(), HostError> {
        let text = encode(direction, &self.entries, &self.copies);
        for copy in &self.copies {
            let part = PathBuf::from(format!("{}{PART_SUFFIX}", copy.display()));
            let io = |e| HostError::io(copy, e);
            std::fs::write(&part, &text).map_err(io)?;
            std::fs::File::open(&part).and_then(|f| f.sync_all()).map_err(io)?;
            std::fs::rename(&part, copy).map_err(io)?;
            super::sync_dir(copy);
        }
        Ok(())
    }

    /// Removes every copy (the set is finished).
    pub(super) fn remove(self) {
        for copy in &self.copies {
            let _ = std::fs::remove_file(copy);
            super::sync_dir(copy);
        }
    }
}

/// Finishes every set whose journal is in `dir` and whose process has died (see the
/// module docs); removes journals of dead processes that were never completed.
/// Best effort: what cannot be done stays for the next run.
pub(super) fn recover(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(JOURNAL_PREFIX)) else { continue };
        let (rest, part) = match rest.strip_suffix(PART_SUFFIX) {
            Some(r) => (r, true),
            None => (rest, false),
        };
        let Some(pid) = rest.split_once('.').and_then(|(p, _)| p.parse::<u32>().ok()) else { continue };
        if pid == std::process::id() || super::process_is_running(pid) {
            continue;
        }
        if part {
            // Killed while writing it: no rename had started.
            let _ = std::fs::remove_file(entry.path());
            continue;
        }
        let Ok(text) = std::fs::read(entry.path()) else { continue };
        let Some((direction, set, copies)) = decode(&text) else { continue };
        finish(direction, &set);
        for copy in copies {
            let _ = std::fs::remove_file(&copy);
        }
    }
}

/// Carries an interrupted set through in `direction`.
pub(super) fn finish(direction: Direction, set: &[Entry]) {
    for e in set {
        match direction {
            Direction::Commit => {
                if e.tmp.exists() {
                    let _ = std::fs::rename(&e.tmp, &e.target);
                }
            }
            Direction::Rollback => {
                if e.backup.exists() {
                    let _ = std::fs::rename(&e.backup, &e.target);
                } else if !e.had_old && !e.tmp.exists() {
                    // New, and published (its temporary is gone): not part of the old set.
                    let _ = std::fs::remove_file(&e.target);
                }
                let _ = std::fs::remove_file(&e.tmp);
            }
        }
        super::sync_dir(&e.target);
    }
    for e in set {
        let _ = std::fs::remove_file(&e.backup);
    }
}

/// The journal as text: `dncal-journal 1 commit|rollback`, then a line per file, `E`,
/// the four fields tab-separated (paths as hex of their bytes: any byte may be in a
/// name), then a line per copy, `J` and its path.
fn encode(direction: Direction, entries: &[Entry], copies: &[PathBuf]) -> Vec<u8> {
    let mut t = format!("dncal-journal 1 {}\n", if direction == Direction::Commit { "commit" } else { "rollback" });
    for e in entries {
        t += &format!("E\t{}\t{}\t{}\t{}\n", hex(&e.tmp), hex(&e.target), hex(&e.backup), u8::from(e.had_old));
    }
    for c in copies {
        t += &format!("J\t{}\n", hex(c));
    }
    t.into_bytes()
}

/// [`encode`]'s inverse; `None` for anything else.
fn decode(bytes: &[u8]) -> Option<(Direction, Vec<Entry>, Vec<PathBuf>)> {
    let text = std::str::from_utf8(bytes).ok()?;
    let mut lines = text.lines();
    let direction = match lines.next()? {
        "dncal-journal 1 commit" => Direction::Commit,
        "dncal-journal 1 rollback" => Direction::Rollback,
        _ => return None,
    };
    let (mut entries, mut copies) = (Vec::new(), Vec::new());
    for line in lines {
        let fields: Vec<&str> = line.split('\t').collect();
        match fields[..] {
            ["E", tmp, target, backup, had] => entries.push(Entry { tmp: unhex(tmp)?, target: unhex(target)?, backup: unhex(backup)?, had_old: had == "1" }),
            ["J", copy] => copies.push(unhex(copy)?),
            _ => return None,
        }
    }
    Some((direction, entries, copies))
}

fn hex(path: &Path) -> String {
    path.as_os_str().as_encoded_bytes().iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(text: &str) -> Option<PathBuf> {
    if !text.len().is_multiple_of(2) {
        return None;
    }
    let bytes: Option<Vec<u8>> = (0..text.len()).step_by(2).map(|i| u8::from_str_radix(text.get(i..i + 2)?, 16).ok()).collect();
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStringExt;
        Some(PathBuf::from(std::ffi::OsString::from_vec(bytes?)))
    }
    #[cfg(not(unix))]
    {
        Some(PathBuf::from(String::from_utf8(bytes?).ok()?))
    }
}
