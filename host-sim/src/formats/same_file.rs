//! No output replaces an input (issue 43): `lut build h.fits -o h` would have written the
//! LUT FITS over its own histograms, and `simulate linearity --config c.toml -o c.toml`
//! its set over its config, both with exit 0.
//!
//! While a [`Watch`] is held (the `dncal` command holds one for its whole run), every
//! input opened through [`crate::formats::input::open_regular`] (the one door all readers
//! use) is noted by its file identity (device and inode), and so is every existing
//! output target an [`crate::formats::outputs::Outputs`] claims. Whichever comes second
//! is refused: a target that is an input, a hard or symbolic link to one, or a path that
//! resolves to one ([`HostError::OutputIsInput`]). Both happen before a command computes
//! anything (outputs are claimed and inputs opened first), so the refusal costs nothing.
//!
//! An identity is trusted only while its path still leads to it: a file deleted since
//! (its inode free for reuse) is no clash. Without a [`Watch`] (the library used from
//! Python, most tests) nothing is noted.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::HostError;

/// A file's identity: device and inode.
type Id = (u64, u64);

#[derive(Default)]
struct Seen {
    inputs: Vec<(Id, PathBuf)>,
    targets: Vec<(Id, PathBuf)>,
}

/// `None` while no [`Watch`] is held.
static SEEN: Mutex<Option<Seen>> = Mutex::new(None);

/// Inputs and outputs are compared while this is held ([`watch`]).
#[must_use = "the comparison stops when the watch is dropped"]
pub struct Watch(());

/// Starts comparing every input opened and output claimed in this process, until the
/// returned [`Watch`] is dropped.
pub fn watch() -> Watch {
    *lock() = Some(Seen::default());
    Watch(())
}

impl Drop for Watch {
    fn drop(&mut self) {
        *lock() = None;
    }
}

fn lock() -> std::sync::MutexGuard<'static, Option<Seen>> {
    // A panic elsewhere while it was held leaves the lists whole: use them.
    SEEN.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn id_of(meta: &std::fs::Metadata) -> Option<Id> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        Some((meta.dev(), meta.ino()))
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        None
    }
}

/// Whether `path` still leads to the file `id`.
fn still(path: &Path, id: Id) -> bool {
    std::fs::metadata(path).ok().and_then(|m| id_of(&m)) == Some(id)
}

/// Notes the input `path`, open as `file`; an error if it is an output already claimed.
pub(crate) fn note_input(path: &Path, file: &std::fs::File) -> Result<(), HostError> {
    let mut seen = lock();
    let Some(seen) = seen.as_mut() else { return Ok(()) };
    let Some(id) = file.metadata().ok().and_then(|m| id_of(&m)) else { return Ok(()) };
    if let Some((_, target)) = seen.targets.iter().find(|(t, p)| *t == id && still(p, id)) {
        return Err(HostError::OutputIsInput { path: target.clone(), input: path.into() });
    }
    if !seen.inputs.iter().any(|(i, p)| *i == id && p == path) {
        seen.inputs.push((id, path.into()));
    }
    Ok(())
}

/// Notes the output `target` (if it exists); an error if it is an input already opened.
pub(crate) fn note_target(target: &Path) -> Result<(), HostError> {
    let mut seen = lock();
    let Some(seen) = seen.as_mut() else { return Ok(()) };
    let Some(id) = std::fs::metadata(target).ok().and_then(|m| id_of(&m)) else { return Ok(()) };
    if let Some((_, input)) = seen.inputs.iter().find(|(i, p)| *i == id && still(p, id)) {
        return Err(HostError::OutputIsInput { path: target.into(), input: input.clone() });
    }
    seen.targets.push((id, target.into()));
    Ok(())
}

// Tested through the command (`host-sim/tests/cli_outputs.rs`): the watch is process-wide,
// and a unit test holding it would compare the files of every test running beside it.
