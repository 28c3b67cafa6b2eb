//! All-or-nothing outputs (issue 18, "never lose a file"): a command that fails leaves
//! every file it would have written as it was, and adds none.
//!
//! [`Outputs`] is one command's set of files. Each is written to a temporary
//! `.NAME.PID.XXXXXX.dncal-tmp` beside its target (same directory, so that the final
//! rename is atomic and cannot cross file systems); [`Outputs::publish`] then renames them
//! over their targets, one by one. A rename over an existing file cannot be undone, so
//! every target about to be replaced is first kept as a hard link
//! `.NAME.PID.XXXXXX.dncal-old` (or, where hard links are not supported, renamed there).
//! If anything fails, before or while publishing, or the set is dropped unpublished (an
//! error returned with `?`), every temporary is removed, every replaced target is put
//! back from its backup, every target that is new is removed, and so is every directory
//! the set created: the targets are byte-identical to before.
//!
//! Most failures are found before anything is computed: a target is checked when first
//! named ([`Outputs::expect`]): it must not be a directory, device or FIFO, and its
//! temporary is created at once, so an unwritable directory fails there too. The `dncal`
//! command names every file its command line says it writes before the command reads or
//! computes anything (issue 56: [`Hold::reserve`]); the set that later writes one takes
//! over that claim. A kill
//! cannot clean up; its temporaries (and, killed while publishing, its backups) carry its
//! process id, and the next set that writes the same target removes those of processes
//! no longer running.
//!
//! Two runs never write one file together: each target is locked when named
//! ([`lock`]: a second run naming it fails at once). A set of several files is published
//! under a journal ([`journal`]), so a run killed between its renames is finished (or
//! undone) by the next run that names a file beside it: never a mixed set, never a
//! backup deleted before its set is whole.
//!
//! ```
//! use dncal_host::formats::outputs::Outputs;
//! let dir = tempfile::tempdir().unwrap();
//! let (a, b) = (dir.path().join("a.txt"), dir.path().join("b.txt"));
//! let mut out = Outputs::new();
//! out.expect([&a, &b])?;
//! out.write_bytes(&a, "first")?;
//! out.write_bytes(&b, "second")?;
//! assert!(!a.exists(), "nothing is visible before publishing");
//! out.publish()?;
//! assert_eq!(std::fs::read_to_string(&b).unwrap(), "second");
//! # Ok::<(), dncal_host::HostError>(())
//! ```

mod journal;
mod lock;

use std::path::{Path, PathBuf};

use crate::HostError;
use journal::{Direction, Journal};
use lock::TargetLock;

/// Why a path cannot take an output; `HostError::Output` wraps it with the path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum OutputFault {
    /// A directory the outputs go into is something else.
    #[error("is not a directory; outputs go into it")]
    NotADirectory,
    /// A target without a file name (`..`, `/`).
    #[error("not a file name to write to")]
    NotAFileName,
    /// A step's input that the step before it did not write (the demo's chain).
    #[error("not written by the step before")]
    NotStaged,
}

/// Suffix of a temporary output not yet published.
const TMP_SUFFIX: &str = ".dncal-tmp";
/// Suffix of the backup of a target being replaced.
const OLD_SUFFIX: &str = ".dncal-old";

/// One target and where it stands.
#[derive(Debug)]
struct Staged {
    target: PathBuf,
    tmp: PathBuf,
    state: State,
    /// Held until the set is published or dropped (`None` only in a test's simulated
    /// kill).
    _lock: Option<TargetLock>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum State {
    /// The temporary exists, empty (named by [`Outputs::expect`], not written yet).
    Claimed,
    /// The temporary holds the complete file.
    Written,
    /// Renamed over the target; the old target, if there was one, is at the backup.
    Published { backup: Option<Backup> },
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Backup {
    path: PathBuf,
    /// A hard link (the target still existed beside it) rather than the target renamed.
    linked: bool,
}

/// The files of one command, published together or not at all (see the module docs).
/// Dropping it unpublished discards everything it staged.
#[derive(Debug)]
pub struct Outputs {
    staged: Vec<Staged>,
    /// Directories this set created, parents first.
    created_dirs: Vec<PathBuf>,
    /// The journal of a set of several files while it is published.
    journal: Option<Journal>,
    /// The process id its temporaries and journal are named for (this process's; a
    /// test's simulated kill names a dead one).
    pid: u32,
}

impl Default for Outputs {
    fn default() -> Self {
        Outputs { staged: Vec::new(), created_dirs: Vec::new(), journal: None, pid: std::process::id() }
    }
}

impl Outputs {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Creates `dir` and its missing parents; those created are removed again if the set
    /// is not published. An existing non-directory on the way is refused.
    pub fn create_dir(&mut self, dir: &Path) -> Result<(), HostError> {
        let mut missing = Vec::new();
        let mut at = Some(dir);
        while let Some(d) = at.filter(|d| !d.as_os_str().is_empty()) {
            match std::fs::symlink_metadata(d) {
                Ok(_) if d.is_dir() => break,
                Ok(_) => return Err(HostError::Output { path: d.into(), fault: OutputFault::NotADirectory }),
                Err(_) => missing.push(d.to_path_buf()),
            }
            at = d.parent();
        }
        for d in missing.into_iter().rev() {
            std::fs::create_dir(&d).map_err(|e| HostError::io(&d, e))?;
            self.created_dirs.push(d);
        }
        Ok(())
    }

    /// Checks `targets` before anything is computed: each must be a file or not exist,
    /// in a directory where its temporary can be created (created now; see the module
    /// docs). A target named but never written is left as it was.
    pub fn expect<P: AsRef<Path>>(&mut self, targets: impl IntoIterator<Item = P>) -> Result<(), HostError> {
        targets.into_iter().try_for_each(|t| self.claim(t.as_ref()).map(drop))
    }

    /// Runs `write` on the temporary of `target` (empty when `write` is called); the
    /// result is published with the rest.
    pub fn write(&mut self, target: &Path, write: impl FnOnce(&Path) -> Result<(), HostError>) -> Result<(), HostError> {
        let i = self.claim(target)?;
        let tmp = self.staged[i].tmp.clone();
        write(&tmp)?;
        // A replaced file keeps its permissions.
        if let Ok(old) = std::fs::metadata(target) {
            std::fs::set_permissions(&tmp, old.permissions()).map_err(|e| HostError::io(target, e))?;
        }
        std::fs::File::open(&tmp).and_then(|f| f.sync_all()).map_err(|e| HostError::io(target, e))?;
        self.staged[i].state = State::Written;
        Ok(())
    }

    /// Stages `bytes` as `target`.
    pub fn write_bytes(&mut self, target: &Path, bytes: impl AsRef<[u8]>) -> Result<(), HostError> {
        self.write(target, |tmp| std::fs::write(tmp, bytes.as_ref()).map_err(|e| HostError::io(target, e)))
    }

    /// Where the written, unpublished contents of `target` can be read back (a later step
    /// of the same command reading an earlier one's output).
    pub fn staged(&self, target: &Path) -> Option<&Path> {
        self.staged.iter().find(|s| s.target == target && s.state == State::Written).map(|s| s.tmp.as_path())
    }

    /// Renames every written file over its target; on any failure puts everything back
    /// (see the module docs) and returns the error. Returns the targets published.
    ///
    /// While a [`Hold`] is held (the `dncal` command holds one until its report is on
    /// stdout), the files are renamed into place but their backups and journal are kept:
    /// [`Hold::commit`] finishes the set, dropping the hold puts the old files back.
    pub fn publish(mut self) -> Result<Vec<PathBuf>, HostError> {
        self.start_journal()?;
        for s in self.staged.iter_mut().filter(|s| s.state == State::Written) {
            let backup = publish_one(s)?;
            s.state = State::Published { backup };
        }
        let published = self.staged.iter().filter(|s| matches!(s.state, State::Published { .. })).map(|s| s.target.clone()).collect();
        match held().as_mut() {
            Some(sets) => sets.push(self),
            None => self.finish(),
        }
        Ok(published)
    }

    /// Ends a published set: backups and temporaries removed, the journal last.
    fn finish(mut self) {
        for s in std::mem::take(&mut self.staged) {
            match s.state {
                State::Published { backup } => {
                    if let Some(b) = backup {
                        // The new file is in place; a backup left behind is only litter.
                        let _ = std::fs::remove_file(&b.path);
                    }
                    sync_dir(&s.target);
                }
                _ => {
                    let _ = std::fs::remove_file(&s.tmp);
                }
            }
        }
        self.created_dirs.clear();
        // Last: with it gone, no later run will touch this set.
        if let Some(j) = self.journal.take() {
            j.remove();
        }
    }

    /// Writes the journal of a set of two or more written files ([`journal`]) into every
    /// directory they go to, before the first rename.
    fn start_journal(&mut self) -> Result<(), HostError> {
        let written: Vec<&Staged> = self.staged.iter().filter(|s| s.state == State::Written).collect();
        if written.len() < 2 {
            return Ok(());
        }
        let entries = written
            .iter()
            .map(|s| journal::Entry { tmp: absolute(&s.tmp), target: absolute(&s.target), backup: absolute(&backup_path(&s.tmp)), had_old: std::fs::symlink_metadata(&s.target).is_ok() })
            .collect();
        let mut dirs: Vec<PathBuf> = Vec::new();
        for s in &written {
            let dir = absolute(s.tmp.parent().unwrap_or(Path::new(".")));
            if !dirs.contains(&dir) {
                dirs.push(dir);
            }
        }
        self.journal = Some(Journal::write(entries, &dirs, self.pid)?);
        Ok(())
    }

    /// The index of `target`'s entry, made (checked, stale files removed, temporary
    /// created) if new.
    fn claim(&mut self, target: &Path) -> Result<usize, HostError> {
        if let Some(i) = self.staged.iter().position(|s| s.target == target) {
            return Ok(i);
        }
        // Claimed before the command started ([`Hold::reserve`]): checked, locked, its
        // temporary made; now this set's.
        if let Some(s) = take_reserved(target, self.pid) {
            self.staged.push(s);
            return Ok(self.staged.len() - 1);
        }
        check_target(target)?;
        crate::formats::same_file::note_target(target)?;
        let (dir, prefix) = temp_prefix(target)?;
        let lock = TargetLock::take(target, dir, &prefix)?;
        // A set a killed run left half published is finished first; what is left of it
        // after that is litter.
        journal::recover(dir);
        remove_stale(dir, &prefix);
        let mine = format!("{prefix}{}.", self.pid);
        let mut builder = tempfile::Builder::new();
        builder.prefix(&mine).suffix(TMP_SUFFIX).rand_bytes(6);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            // The process umask applies, as for any newly created file.
            builder.permissions(std::fs::Permissions::from_mode(0o666));
        }
        let tmp = builder.tempfile_in(dir).map_err(|e| HostError::io(target, e))?.into_temp_path().keep().map_err(|e| HostError::io(target, e.error))?;
        self.staged.push(Staged { target: target.into(), tmp, state: State::Claimed, _lock: Some(lock) });
        Ok(self.staged.len() - 1)
    }
}

impl Drop for Outputs {
    /// Puts everything back: published targets first (newest first), then temporaries,
    /// then the directories this set created.
    fn drop(&mut self) {
        // A run killed while it puts the old files back is finished that way by the next.
        if let Some(j) = &self.journal {
            let _ = j.store(Direction::Rollback);
        }
        for s in self.staged.iter().rev() {
            match &s.state {
                State::Published { backup: Some(b) } => {
                    let _ = std::fs::rename(&b.path, &s.target);
                }
                State::Published { backup: None } => {
                    let _ = std::fs::remove_file(&s.target);
                }
                State::Claimed | State::Written => {
                    let _ = std::fs::remove_file(&s.tmp);
                }
            }
        }
        if let Some(j) = self.journal.take() {
            j.remove();
        }
        // The locks go with the entries, after everything is back; their files first,
        // so that the directories the set created can go too.
        self.staged.clear();
        for d in self.created_dirs.iter().rev() {
            // Only if empty: anything else in it is not ours.
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// Sets published while a [`Hold`] is held, not yet finished; `None` without a hold.
static HELD: std::sync::Mutex<Option<Vec<Outputs>>> = std::sync::Mutex::new(None);

fn held() -> std::sync::MutexGuard<'static, Option<Vec<Outputs>>> {
    HELD.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Keeps every set published while it is held undoable (issue 43: `lut build ...
/// --json > /dev/full` failed on stdout after its files were in place). [`Hold::commit`] once
/// the report is written; dropped instead (an error), every set held is put back, the
/// last published first. A run killed in between leaves journals, which the next run
/// finishes forward.
#[must_use = "dropping the hold puts the outputs back"]
pub struct Hold(());

/// Starts holding published sets ([`Hold`]).
pub fn hold() -> Hold {
    *held() = Some(Vec::new());
    Hold(())
}

/// The targets claimed by [`Hold::reserve`] and not yet taken over by a set; `None` when
/// none were.
static RESERVED: std::sync::Mutex<Option<Outputs>> = std::sync::Mutex::new(None);

fn reserved() -> std::sync::MutexGuard<'static, Option<Outputs>> {
    RESERVED.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The claim of `target` made by [`Hold::reserve`], taken out of the reservation for a
/// set of process `pid` (a test's simulated dead process takes none).
fn take_reserved(target: &Path, pid: u32) -> Option<Staged> {
    let mut reserved = reserved();
    let set = reserved.as_mut().filter(|r| r.pid == pid)?;
    let i = set.staged.iter().position(|s| s.target == target)?;
    Some(set.staged.remove(i))
}

impl Hold {
    /// Claims, before the command reads or computes anything, the targets and directories
    /// `declare` names ([`Outputs::expect`], [`Outputs::create_dir`]: the same checks,
    /// locks and temporaries as any set's) and keeps them claimed while the hold is held:
    /// the set that later names one of them takes its claim over. An error leaves nothing
    /// (the claims of `declare` are undone). What no set took over is released when the
    /// hold ends: its temporaries removed, and the directories it created with them if the
    /// hold is dropped (if committed, they stay, as a published set's do).
    pub fn reserve(&self, declare: impl FnOnce(&mut Outputs) -> Result<(), HostError>) -> Result<(), HostError> {
        let mut set = Outputs::new();
        declare(&mut set)?;
        let mut reserved = reserved();
        match reserved.as_mut() {
            Some(r) => {
                r.staged.append(&mut set.staged);
                r.created_dirs.append(&mut set.created_dirs);
            }
            None => *reserved = Some(set),
        }
        Ok(())
    }

    /// Finishes every set held.
    pub fn commit(self) {
        let sets = held().take();
        std::mem::forget(self);
        sets.into_iter().flatten().for_each(Outputs::finish);
        let unused = reserved().take();
        unused.into_iter().for_each(Outputs::finish);
    }
}

impl Drop for Hold {
    fn drop(&mut self) {
        let sets = held().take();
        // Each set's own drop puts its files back.
        sets.into_iter().flatten().rev().for_each(drop);
        // Then the claims no set took over, and the directories made for them (empty now).
        let unused = reserved().take();
        drop(unused);
    }
}

/// A directory a command writes its report into, inside the set of outputs the report
/// belongs to: the caller publishes the set, with whatever else it writes.
#[derive(Debug)]
pub struct OutDir<'a> {
    /// The set the files are staged in.
    pub files: &'a mut Outputs,
    /// The directory, created by the command ([`Outputs::create_dir`]).
    pub dir: &'a Path,
}

impl<'a> OutDir<'a> {
    /// `dir` inside `files`.
    pub fn new(files: &'a mut Outputs, dir: &'a Path) -> Self {
        OutDir { files, dir }
    }

    /// The path of `name` in the directory.
    pub fn at(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
}

/// Runs `command` with its output directory `dir`, if any, in a fresh set of outputs, and
/// publishes them: all files of the command or, if it fails, none.
pub fn staged<T>(dir: Option<&Path>, command: impl FnOnce(Option<OutDir<'_>>) -> Result<T, HostError>) -> Result<T, HostError> {
    let mut files = Outputs::new();
    let result = command(dir.map(|d| OutDir::new(&mut files, d)))?;
    files.publish()?;
    Ok(result)
}

/// [`staged`] for a command that always has an output directory.
pub fn staged_in<T>(dir: &Path, command: impl FnOnce(OutDir<'_>) -> Result<T, HostError>) -> Result<T, HostError> {
    let mut files = Outputs::new();
    let result = command(OutDir::new(&mut files, dir))?;
    files.publish()?;
    Ok(result)
}

/// Runs `stage` on a fresh set and publishes it: for a command or writer of one file.
pub fn write_one(stage: impl FnOnce(&mut Outputs) -> Result<(), HostError>) -> Result<(), HostError> {
    let mut out = Outputs::new();
    stage(&mut out)?;
    out.publish().map(drop)
}

/// Writes one file atomically: readers see the old file or the complete new one, never a
/// half-written one; on failure `path` is left as it was and no temporary remains.
pub fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<(), HostError>) -> Result<(), HostError> {
    let mut out = Outputs::new();
    out.write(path, write)?;
    out.publish().map(drop)
}

/// Writes `bytes` to `path` atomically (see [`write_atomically`]).
pub fn write_file_atomically(path: &Path, bytes: impl AsRef<[u8]>) -> Result<(), HostError> {
    write_atomically(path, |tmp| std::fs::write(tmp, bytes.as_ref()).map_err(|e| HostError::io(path, e)))
}

/// Backs the target of `s` up (if it exists) and renames the temporary over it. On
/// failure the target is as before and the backup gone.
fn publish_one(s: &Staged) -> Result<Option<Backup>, HostError> {
    let err = |e| HostError::io(&s.target, e);
    // Again: a directory made since the check would otherwise be moved to the backup.
    check_target(&s.target)?;
    let backup = match std::fs::symlink_metadata(&s.target) {
        Ok(_) => {
            let path = backup_path(&s.tmp);
            let linked = match std::fs::hard_link(&s.target, &path) {
                Ok(()) => true,
                Err(_) => {
                    std::fs::rename(&s.target, &path).map_err(err)?;
                    false
                }
            };
            Some(Backup { path, linked })
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(err(e)),
    };
    if let Err(e) = std::fs::rename(&s.tmp, &s.target) {
        if let Some(b) = &backup {
            let _ = if b.linked { std::fs::remove_file(&b.path) } else { std::fs::rename(&b.path, &s.target) };
        }
        return Err(err(e));
    }
    Ok(backup)
}

/// Where the target of temporary `tmp` is kept while the set is published: the
/// temporary's name with `.dncal-old` for `.dncal-tmp` (plain ASCII, see `temp_prefix`).
fn backup_path(tmp: &Path) -> PathBuf {
    let tmp_name = tmp.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    tmp.with_file_name(format!("{}{OLD_SUFFIX}", tmp_name.strip_suffix(TMP_SUFFIX).unwrap_or(tmp_name)))
}

/// `path` made absolute (a journal is read by runs started elsewhere).
fn absolute(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// Refuses a target that exists as anything but a file (or a link to one): a rename over
/// a directory fails, over a device would replace it.
fn check_target(target: &Path) -> Result<(), HostError> {
    match std::fs::metadata(target) {
        Ok(m) if !m.is_file() => Err(HostError::OutputNotFile { path: target.into(), kind: crate::formats::input::kind_of(&m.file_type()) }),
        _ => Ok(()),
    }
}

/// The directory of `target` and the start of its temporaries' names, `.NAME.` with only
/// plain characters in NAME: the temporary may go to cfitsio, which parses brackets and
/// more.
fn temp_prefix(target: &Path) -> Result<(&Path, String), HostError> {
    let file_name = target.file_name().ok_or_else(|| HostError::Output { path: target.into(), fault: OutputFault::NotAFileName })?;
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let plain: String = file_name.to_string_lossy().chars().map(|c| if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') { c } else { '_' }).collect();
    Ok((dir, format!(".{plain}.")))
}

/// Removes the temporaries and backups `prefix` names in `dir` that were left by
/// processes no longer running (killed mid-write). Best effort: a file that cannot be
/// removed stays.
fn remove_stale(dir: &Path, prefix: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(|n| stale_pid(n, prefix)) else { continue };
        if pid != std::process::id() && !process_is_running(pid) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// The process id in `name` if it is one of our temporaries or backups for `prefix`:
/// `{prefix}{pid}.{6 characters}.dncal-tmp` (`.dncal-old` for a backup).
fn stale_pid(name: &str, prefix: &str) -> Option<u32> {
    let rest = name.strip_prefix(prefix)?;
    let rest = rest.strip_suffix(TMP_SUFFIX).or_else(|| rest.strip_suffix(OLD_SUFFIX))?;
    let (pid, random) = rest.split_once('.')?;
    (random.len() == 6 && random.chars().all(|c| c.is_ascii_alphanumeric())).then_some(())?;
    pid.parse().ok()
}

/// Whether process `pid` exists (on other systems than Unix: assumed to).
fn process_is_running(pid: u32) -> bool {
    #[cfg(unix)]
    {
        let Ok(pid) = libc::pid_t::try_from(pid) else { return true };
        // SAFETY: signal 0 only checks that the process exists and may be signalled.
        let r = unsafe { libc::kill(pid, 0) };
        r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

/// Makes a rename in `target`'s directory durable. Best effort.
fn sync_dir(target: &Path) {
    #[cfg(unix)]
    if let Some(d) = target.parent().map(|d| if d.as_os_str().is_empty() { Path::new(".") } else { d }) {
        let _ = std::fs::File::open(d).and_then(|f| f.sync_all());
    }
    #[cfg(not(unix))]
    let _ = target;
}

/// `s` escaped for HTML text and quoted attributes.
pub fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// How a report page names an input file: its absolute path, escaped. (A relative path
/// would be read relative to the page, not to where the command ran.)
pub fn html_path(path: &Path) -> String {
    html_escape(&std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()).display().to_string())
}

/// One figure of a report page: image `src` shown `width` pixels wide, `alt` the text for
/// a reader that does not show it, and `caption` under it when given (all escaped here).
pub fn html_figure(src: &str, width: u32, alt: &str, caption: Option<&str>) -> String {
    let caption = caption.map_or(String::new(), |c| format!("<figcaption>{}</figcaption>", html_escape(c)));
    format!("<figure><img src=\"{}\" width=\"{width}\" alt=\"{}\">{caption}</figure>", html_escape(src), html_escape(alt))
}

#[cfg(test)]
impl Outputs {
    /// A set whose files are named for process `pid` (a dead one: a simulated kill).
    fn for_pid(pid: u32) -> Outputs {
        let mut out = Outputs::new();
        out.pid = pid;
        out
    }

    /// What a run killed after `renames` of its renames leaves: its journal, those
    /// renames with their backups, the other temporaries; no lock held (the kernel drops
    /// a dead process's), nothing put back.
    fn killed_after(mut self, renames: usize) {
        self.start_journal().unwrap();
        for s in self.staged.iter_mut().filter(|s| s.state == State::Written).take(renames) {
            let backup = publish_one(s).unwrap();
            s.state = State::Published { backup };
        }
        for s in &mut self.staged {
            s._lock = None;
        }
        std::mem::forget(self);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dead process's id.
    fn dead_pid() -> u32 {
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        pid
    }

    /// Issue 43: a run killed between the renames of a set of files. The next run naming
    /// any of them (here a third file beside one of them) finishes the set: every file
    /// the new one, the backups gone only then, no journal, temporary or backup left.
    /// Killed before any rename, after one, after all: the same end.
    #[test]
    fn a_set_killed_between_its_renames_is_finished_by_the_next_run() {
        for renames in 0..=3 {
            let dir = tempfile::tempdir().unwrap();
            let d = dir.path();
            std::fs::create_dir(d.join("sub")).unwrap();
            let (a, b, c) = (d.join("a.fits"), d.join("a.bin"), d.join("sub/c.toml"));
            std::fs::write(&a, "old a").unwrap();
            std::fs::write(&b, "old b").unwrap();
            let mut out = Outputs::for_pid(dead_pid());
            for (t, text) in [(&a, "new a"), (&b, "new b"), (&c, "new c")] {
                out.write_bytes(t, text).unwrap();
            }
            out.killed_after(renames);
            let mixed = std::fs::read_to_string(&a).unwrap();
            assert_eq!(mixed, if renames >= 1 { "new a" } else { "old a" });
            // The next run, for another file in the subdirectory.
            write_file_atomically(&d.join("sub/other"), "x").unwrap();
            for (t, text) in [(&a, "new a"), (&b, "new b"), (&c, "new c")] {
                assert_eq!(std::fs::read_to_string(t).unwrap(), text, "killed after {renames} renames");
            }
            assert_eq!(names(d), ["a.bin", "a.fits", "sub"], "killed after {renames} renames");
            assert_eq!(names(&d.join("sub")), ["c.toml", "other"]);
        }
    }

    /// A run killed while it put the old files back (its journal says `rollback`) is
    /// undone the rest of the way: the old files, a new one removed.
    #[test]
    fn a_set_killed_while_rolling_back_is_rolled_back() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let (a, b) = (d.join("a"), d.join("b"));
        std::fs::write(&a, "old a").unwrap();
        let mut out = Outputs::for_pid(dead_pid());
        out.write_bytes(&a, "new a").unwrap();
        out.write_bytes(&b, "new b").unwrap();
        out.start_journal().unwrap();
        for s in out.staged.iter_mut() {
            let backup = publish_one(s).unwrap();
            s.state = State::Published { backup };
            s._lock = None;
        }
        out.journal.as_ref().unwrap().store(Direction::Rollback).unwrap();
        std::mem::forget(out);
        write_file_atomically(&d.join("c"), "x").unwrap();
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "old a");
        assert_eq!(names(d), ["a", "c"]);
    }

    /// Two sets naming one file: the second is refused at once, naming the file, and
    /// takes it once the first is done.
    #[test]
    fn a_file_another_set_is_writing_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a");
        let mut first = Outputs::new();
        first.write_bytes(&a, "first").unwrap();
        let e = Outputs::new().expect([&a]).unwrap_err();
        assert!(e.to_string().starts_with(&format!("{}: another dncal run (process {}) is writing this output now", a.display(), std::process::id())), "{e}");
        first.publish().unwrap();
        write_file_atomically(&a, "second").unwrap();
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "second");
        assert_eq!(names(dir.path()), ["a"]);
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[test]
    fn a_failure_while_publishing_restores_every_target_and_removes_the_new_ones() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let (a, b, c) = (d.join("a"), d.join("b"), d.join("sub/c"));
        std::fs::write(&a, "old a").unwrap();
        let mut out = Outputs::new();
        out.create_dir(&d.join("sub")).unwrap();
        out.write_bytes(&a, "new a").unwrap();
        out.write_bytes(&c, "new c").unwrap();
        out.write_bytes(&b, "new b").unwrap();
        // After the checks, b becomes a directory: its rename fails mid-publish, after a
        // and c are in place.
        std::fs::create_dir(&b).unwrap();
        let e = out.publish().unwrap_err();
        assert_eq!(e.to_string(), format!("{}: is a directory; an output file cannot replace it", b.display()));
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "old a");
        assert_eq!(names(d), ["a", "b"], "c and its new directory removed, no temporary or backup left");
        assert!(names(&b).is_empty());
    }

    #[test]
    fn dropping_unpublished_discards_and_publishing_replaces_keeping_permissions() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a");
        std::fs::write(&a, "old").unwrap();
        let mut out = Outputs::new();
        out.write_bytes(&a, "new").unwrap();
        assert_eq!(std::fs::read(out.staged(&a).unwrap()).unwrap(), b"new");
        drop(out);
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "old");
        assert_eq!(names(dir.path()), ["a"]);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&a, std::fs::Permissions::from_mode(0o640)).unwrap();
            write_file_atomically(&a, "new").unwrap();
            assert_eq!(std::fs::metadata(&a).unwrap().permissions().mode() & 0o777, 0o640);
        }
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "new");
        assert_eq!(names(dir.path()), ["a"]);
    }

    #[test]
    fn a_failing_writer_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.fits");
        std::fs::write(&p, "old").unwrap();
        let mut seen = None;
        let result = write_atomically(&p, |tmp| {
            seen = Some(tmp.to_path_buf());
            std::fs::write(tmp, b"half").unwrap();
            Err(HostError::Format { path: tmp.into(), message: "stopped halfway".into() })
        });
        assert!(result.unwrap_err().to_string().ends_with("stopped halfway"));
        assert_eq!(seen.unwrap().parent(), Some(dir.path()));
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(names(dir.path()), ["h.fits"]);
        let e = write_atomically(Path::new(""), |_| Ok(())).unwrap_err();
        assert!(e.to_string().ends_with("not a file name to write to"), "{e}");
    }

    #[test]
    fn targets_that_are_not_files_are_refused_when_named() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("d");
        std::fs::create_dir(&d).unwrap();
        let mut out = Outputs::new();
        let e = out.expect([&dir.path().join("x"), &d]).unwrap_err();
        assert_eq!(e.to_string(), format!("{}: is a directory; an output file cannot replace it", d.display()));
        drop(out);
        assert_eq!(names(dir.path()), ["d"]);
    }

    #[test]
    fn only_stale_files_of_dead_processes_for_the_same_target_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let me = std::process::id();
        let keep = [format!(".a.fits.{me}.abc123.dncal-tmp"), format!(".b.fits.{dead}.abc123.dncal-tmp"), format!(".a.fits.{dead}.abc123.tmp"), ".a.fits.x.abc123.dncal-tmp".into()];
        let stale = [format!(".a.fits.{dead}.abc123.dncal-tmp"), format!(".a.fits.{dead}.Xyz789.dncal-old")];
        for n in keep.iter().chain(&stale) {
            std::fs::write(d.join(n), "").unwrap();
        }
        write_file_atomically(&d.join("a.fits"), "new").unwrap();
        let mut want: Vec<String> = keep.to_vec();
        want.push("a.fits".into());
        want.sort();
        assert_eq!(names(d), want);
    }
}
