//! The one door every input file comes in by: regular files only, of a bounded size.
//!
//! A path on the command line can name anything. `/dev/zero` or `/dev/urandom` given as a
//! LUT or a camera config never ends, and a whole-file read of it grows until memory runs
//! out; a FIFO with no writer blocks `open` itself, so the command hangs before it could
//! look at the file (issue 18). So every reader opens through [`open_regular`]: the open
//! is non-blocking (`O_NONBLOCK`, which a FIFO honours and a regular file ignores), and
//! the handle is refused unless `fstat` says it is a regular file ([`HostError::NotRegular`]).
//! The check is on the opened handle, not on the path, so the path cannot be swapped
//! between check and read. Paths handed to cfitsio are checked here first; cfitsio then
//! opens the path again, which a rename in between could still change.
//!
//! Whole-file reads ([`read_regular`], [`read_text`], [`read_toml`]) also refuse a file
//! larger than any file of its kind can be ([`SizeLimit`], [`HostError::TooLarge`]),
//! before allocating for it; a file that grows while it is read is cut at the limit and
//! refused as well. TOML errors are one line: file, line, column and the message.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use serde::de::DeserializeOwned;

use crate::HostError;

/// The most bytes a kind of input file may have, and the kind's name for messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SizeLimit {
    /// What the file is, as in "camera config" (messages say "camera config files").
    pub what: &'static str,
    /// Largest accepted size, bytes.
    pub bytes: u64,
}

/// Opens `path` for reading if it is a regular file (after following symbolic links);
/// anything else is [`HostError::NotRegular`], a missing or unreadable file
/// [`HostError::Io`]. Never blocks on a FIFO.
pub fn open_regular(path: &Path) -> Result<File, HostError> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // Only the open needs it; reads of a regular file never block in the first place.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(|e| HostError::io(path, e))?;
    let file_type = file.metadata().map_err(|e| HostError::io(path, e))?.file_type();
    if file_type.is_file() {
        crate::formats::same_file::note_input(path, &file)?;
        Ok(file)
    } else {
        Err(HostError::NotRegular { path: path.into(), kind: kind_of(&file_type) })
    }
}

/// Whether the regular file `path` starts with `magic` (a shorter file does not).
pub fn starts_with(path: &Path, magic: &[u8]) -> Result<bool, HostError> {
    let mut start = Vec::with_capacity(magic.len());
    open_regular(path)?.take(magic.len() as u64).read_to_end(&mut start).map_err(|e| HostError::io(path, e))?;
    Ok(start == magic)
}

/// How messages name a file type other than a regular file.
pub(crate) fn kind_of(file_type: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if file_type.is_char_device() {
            return "character device";
        }
        if file_type.is_block_device() {
            return "block device";
        }
        if file_type.is_fifo() {
            return "FIFO";
        }
        if file_type.is_socket() {
            return "socket";
        }
    }
    if file_type.is_dir() {
        "directory"
    } else {
        "special file"
    }
}

/// The whole of the regular file `path`, at most `limit.bytes` of it.
pub fn read_regular(path: &Path, limit: SizeLimit) -> Result<Vec<u8>, HostError> {
    let file = open_regular(path)?;
    let len = file.metadata().map_err(|e| HostError::io(path, e))?.len();
    let too_large = |len| HostError::TooLarge { path: path.into(), len, what: limit.what, limit: limit.bytes };
    if len > limit.bytes {
        return Err(too_large(len));
    }
    // One byte past the limit is enough to see that the file grew beyond it.
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(limit.bytes + 1).read_to_end(&mut bytes).map_err(|e| HostError::io(path, e))?;
    if bytes.len() as u64 > limit.bytes {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// [`read_regular`] as UTF-8 text; other bytes are a [`HostError::NotUtf8`] giving the
/// offset of the first.
pub fn read_text(path: &Path, limit: SizeLimit) -> Result<String, HostError> {
    String::from_utf8(read_regular(path, limit)?).map_err(|e| HostError::NotUtf8 { path: path.into(), valid_up_to: e.utf8_error().valid_up_to() })
}

/// Reads and parses a TOML file; a syntax or type error is one line naming the line and
/// column ([`toml_error`]).
pub fn read_toml<T: DeserializeOwned>(path: &Path, limit: SizeLimit) -> Result<T, HostError> {
    let text = read_text(path, limit)?;
    toml::from_str(&text).map_err(|e| toml_error(path, &text, &e))
}

/// A TOML error as one line, `line L, column C: message`: toml's own display spans five
/// lines with a caret drawing, which breaks the one-line error contract.
pub fn toml_error(path: &Path, text: &str, e: &toml::de::Error) -> HostError {
    let message = e.message().lines().map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join("; ");
    let message = match e.span() {
        Some(span) => {
            let (line, column) = line_and_column(text, span.start);
            format!("line {line}, column {column}: {message}")
        }
        None => message,
    };
    HostError::Format { path: path.into(), message }
}

/// The 1-based line and column (in characters) of byte `offset` of `text`.
fn line_and_column(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (before.matches('\n').count() + 1, before[line_start..].chars().count() + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: SizeLimit = SizeLimit { what: "test", bytes: 8 };

    #[test]
    fn regular_files_are_read_whole_up_to_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f");
        std::fs::write(&p, b"12345678").unwrap();
        assert_eq!(read_regular(&p, TINY).unwrap(), b"12345678");
        std::fs::write(&p, b"123456789").unwrap();
        let e = read_regular(&p, TINY).unwrap_err();
        assert_eq!(e.to_string(), format!("{}: 9 bytes; test files are at most 8 bytes", p.display()));
    }

    #[test]
    fn directories_and_devices_are_refused_by_kind() {
        let dir = tempfile::tempdir().unwrap();
        let e = open_regular(dir.path()).unwrap_err();
        assert_eq!(e.to_string(), format!("{}: is a directory, not a regular file", dir.path().display()));
        #[cfg(unix)]
        {
            let e = read_regular(Path::new("/dev/zero"), TINY).unwrap_err();
            assert_eq!(e.to_string(), "/dev/zero: is a character device, not a regular file");
        }
        assert!(matches!(open_regular(&dir.path().join("none")), Err(HostError::Io { .. })));
    }

    #[test]
    fn text_that_is_not_utf8_names_the_byte() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t");
        std::fs::write(&p, b"ab\xffc").unwrap();
        let e = read_text(&p, TINY).unwrap_err();
        assert_eq!(e.to_string(), format!("{}: not UTF-8 text (byte 2 is invalid)", p.display()));
    }

    #[test]
    fn toml_errors_are_one_line_with_line_and_column() {
        #[derive(Debug, serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct T {
            a: u32,
        }
        let p = Path::new("t.toml");
        for (text, want) in [
            ("# c\na = \n", "t.toml: line 2, column 5: invalid string; expected `\"`, `'`"),
            ("a = 1\n\"bé\" = 2\n", "t.toml: line 2, column 1: unknown field `bé`, expected `a`"),
            ("a = \"x\"\n", "t.toml: line 1, column 5: invalid type: string \"x\", expected u32"),
        ] {
            let e = toml::from_str::<T>(text).unwrap_err();
            assert_eq!(toml_error(p, text, &e).to_string(), want, "{text:?}");
        }
        // Columns count characters, not bytes.
        assert_eq!(line_and_column("é = x", 4), (1, 4));
    }
}
