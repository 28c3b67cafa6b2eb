//! File names handed to cfitsio in a form it takes literally (`h.fits[1]` is a file of
//! that name, not HDU 1 of `h.fits`).

use super::*;

/// A name under which cfitsio opens a file as that file and nothing else.
///
/// cfitsio parses file names: `h.fits[1]` or `h.fits+1` is HDU 1 of `h.fits`, `a(b)`
/// copies `a` to `b`, `-` is standard input, `!x` clobbers `x`, `mem://` is memory; and
/// fitsio panics on a name that is not UTF-8. Absolute UTF-8 paths free of that syntax
/// are used as they are. Any other path is reached through a symbolic link with a plain
/// name in a fresh temporary directory (Unix only; elsewhere such paths are an error).
pub(super) struct CfitsioName {
    pub(super) name: String,
    /// Holds the link; removing it removes only the link.
    _alias: Option<tempfile::TempDir>,
}

impl CfitsioName {
    /// For the existing file `path`.
    pub(super) fn for_reading(path: &Path) -> Result<Self, HostError> {
        let absolute = std::path::absolute(path).map_err(|e| HostError::io(path, e))?;
        match plain_for_cfitsio(&absolute) {
            Some(name) => Ok(CfitsioName { name, _alias: None }),
            None => Self::alias(&absolute, "file.fits", path),
        }
    }

    /// For `tmp`, a temporary [`Outputs::write`] made (its own name is plain), reporting
    /// errors as about `shown`. A directory with cfitsio syntax in its path is linked, so
    /// the file is still created in that directory and can be renamed into place.
    pub(super) fn for_writing(tmp: &Path, shown: &Path) -> Result<Self, HostError> {
        let absolute = std::path::absolute(tmp).map_err(|e| HostError::io(shown, e))?;
        if let Some(name) = plain_for_cfitsio(&absolute) {
            return Ok(CfitsioName { name, _alias: None });
        }
        let (Some(dir), Some(file)) = (absolute.parent(), absolute.file_name()) else {
            return Err(format_error(shown, "no directory to write in"));
        };
        let mut alias = Self::alias(dir, "dir", shown)?;
        alias.name = format!("{}/{}", alias.name, file.to_string_lossy());
        Ok(alias)
    }

    /// A link named `link` to `target`, in a new temporary directory.
    fn alias(target: &Path, link: &str, shown: &Path) -> Result<Self, HostError> {
        #[cfg(unix)]
        {
            let dir = tempfile::Builder::new().prefix("dncal-fits").tempdir().map_err(|e| HostError::io(shown, e))?;
            let alias = dir.path().join(link);
            std::os::unix::fs::symlink(target, &alias).map_err(|e| HostError::io(shown, e))?;
            match plain_for_cfitsio(&alias) {
                Some(name) => Ok(CfitsioName { name, _alias: Some(dir) }),
                None => Err(format_error(shown, "the temporary directory's path is not usable by cfitsio")),
            }
        }
        #[cfg(not(unix))]
        {
            let _ = (target, link);
            Err(format_error(shown, "cfitsio would read this path's brackets, parentheses or other syntax; rename it"))
        }
    }
}

/// `path` as a string cfitsio takes literally: absolute, UTF-8, no extended syntax.
pub(super) fn plain_for_cfitsio(path: &Path) -> Option<String> {
    let name = path.to_str()?;
    let ends_with_hdu_number =
        name.rsplit_once('+').is_some_and(|(_, n)| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
    let plain =
        path.is_absolute() && !name.contains(['[', ']', '(', ')']) && !name.contains("://") && !ends_with_hdu_number;
    plain.then(|| name.to_owned())
}
