//! Files on the host through ARM semihosting (`SYS_OPEN`, `SYS_READ`, `SYS_WRITE`,
//! `SYS_CLOSE`). Under QEMU paths are relative to QEMU's working directory.

use cortex_m_semihosting::{nr, syscall};

/// A host file that failed to open, read or write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub struct IoError {
    /// The file's name.
    pub file: &'static str,
    /// What failed.
    pub op: IoOp,
}

/// The operation that failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum IoOp {
    /// `SYS_OPEN`.
    Open,
    /// `SYS_READ`, or the file ended early.
    Read,
    /// `SYS_WRITE`.
    Write,
}

/// An open host file, closed on drop.
pub struct HostFile {
    fd: usize,
    name: &'static str,
}

impl HostFile {
    /// Opens `name` (without a trailing NUL; at most 63 bytes) for reading.
    pub fn open(name: &'static str) -> Result<Self, IoError> {
        Self::open_mode(name, nr::open::R_BINARY)
    }

    /// Creates or truncates `name` for writing.
    pub fn create(name: &'static str) -> Result<Self, IoError> {
        Self::open_mode(name, nr::open::W_TRUNC_BINARY)
    }

    fn open_mode(name: &'static str, mode: usize) -> Result<Self, IoError> {
        let mut path = [0u8; 64];
        let err = IoError { file: name, op: IoOp::Open };
        let bytes = name.as_bytes();
        if bytes.len() >= path.len() {
            return Err(err);
        }
        path[..bytes.len()].copy_from_slice(bytes);
        // SAFETY: SYS_OPEN reads `len` bytes of a NUL-terminated path that lives across the call.
        let fd = unsafe { syscall!(OPEN, path.as_ptr(), mode, bytes.len()) } as isize;
        if fd < 0 {
            return Err(err);
        }
        Ok(HostFile { fd: fd as usize, name })
    }

    /// Fills `buf` completely, or fails if the file ends first.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), IoError> {
        let mut filled = 0;
        while filled < buf.len() {
            let rest = &mut buf[filled..];
            // SAFETY: SYS_READ writes at most `rest.len()` bytes into `rest`.
            let not_read = unsafe { syscall!(READ, self.fd, rest.as_mut_ptr(), rest.len()) };
            let read = rest.len().checked_sub(not_read).ok_or(IoError { file: self.name, op: IoOp::Read })?;
            if read == 0 {
                return Err(IoError { file: self.name, op: IoOp::Read });
            }
            filled += read;
        }
        Ok(())
    }

    /// Reads up to `buf.len()` bytes; 0 at the end of the file.
    pub fn read(&mut self, buf: &mut [u8]) -> Result<usize, IoError> {
        // SAFETY: as in `read_exact`.
        let not_read = unsafe { syscall!(READ, self.fd, buf.as_mut_ptr(), buf.len()) };
        buf.len().checked_sub(not_read).ok_or(IoError { file: self.name, op: IoOp::Read })
    }

    /// Writes all of `bytes`.
    pub fn write_all(&mut self, bytes: &[u8]) -> Result<(), IoError> {
        // SAFETY: SYS_WRITE reads `bytes.len()` bytes from `bytes`.
        let not_written = unsafe { syscall!(WRITE, self.fd, bytes.as_ptr(), bytes.len()) };
        if not_written == 0 {
            Ok(())
        } else {
            Err(IoError { file: self.name, op: IoOp::Write })
        }
    }
}

impl Drop for HostFile {
    fn drop(&mut self) {
        // SAFETY: closes a descriptor this value owns.
        unsafe { syscall!(CLOSE, self.fd) };
    }
}
