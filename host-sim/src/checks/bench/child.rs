//! A command run as a child process and measured as a user would measure it: wall time
//! from spawn to exit, and its own peak resident memory (Linux).
//!
//! Peak memory: Linux carries a process's high-water mark across `exec`, so a child's
//! `ru_maxrss` (from `wait4`) is at least the high-water mark of the memory it was spawned
//! from: with `posix_spawn`, the parent's own (a 64 x 64 diagnosis spawned from the bench,
//! after the bench's in-process rows, read 197 MB; measured as below, 20 MB). Where
//! `ru_maxrss` exceeds the parent's high-water mark read after the spawn it is the child's
//! own, exact. Else the child stayed below its parent, and its own mark (`VmHWM` of its
//! `/proc/PID/status`, its memory since `exec`) read every 10 ms until it exits is taken:
//! a lower bound, short of growth in its last 10 ms. `waitid(WNOWAIT)` leaves the exited
//! child unreaped while that reading stops, so its pid cannot go to another process.

use std::ffi::OsString;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::HostError;

/// One finished process.
#[derive(Debug, Clone)]
pub struct Finished {
    /// From spawn to exit, seconds.
    pub wall_s: f64,
    /// Peak resident set size, bytes: the process's own (module documentation).
    pub peak_rss: u64,
    /// Whether `peak_rss` was sampled every 10 ms (a lower bound) rather than the
    /// kernel's exact mark.
    pub peak_sampled: bool,
    /// Its standard output.
    pub stdout: Vec<u8>,
}

/// How often the child's own high-water mark is read.
const POLL: Duration = Duration::from_millis(10);

/// Runs `exe args` to its end, its output and error output read as they come (a full
/// pipe would stall it). A failure (a nonzero exit, a signal) is an error naming the
/// command, with the last line of its error output; so is a peak memory that could not be
/// read.
pub fn run_measured(exe: &Path, args: &[OsString]) -> Result<Finished, HostError> {
    let program = std::iter::once(exe.display().to_string()).chain(args.iter().map(|a| a.to_string_lossy().into_owned())).collect::<Vec<_>>().join(" ");
    let tool = |message: String| HostError::Tool { program: program.clone(), message };
    let start = Instant::now();
    let mut child = Command::new(exe).args(args).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().map_err(|e| HostError::io(exe, e))?;
    // After `spawn` returns the child has exec'd; the parent's mark only grows.
    let parent_mark = high_water_mark(Path::new("/proc/self/status")).unwrap_or(u64::MAX);
    let out = drain(child.stdout.take());
    let err = drain(child.stderr.take());
    let pid = libc::pid_t::try_from(child.id()).map_err(|_| tool("process id out of range".into()))?;
    let exited = Arc::new(AtomicBool::new(false));
    let poller = {
        let (exited, status) = (exited.clone(), PathBuf::from(format!("/proc/{pid}/status")));
        std::thread::spawn(move || {
            let mut most = 0;
            while !exited.load(Ordering::Relaxed) {
                most = most.max(high_water_mark(&status).unwrap_or(0));
                std::thread::sleep(POLL);
            }
            most
        })
    };
    // The child stays a zombie (its pid ours) until the poller has stopped.
    let ended = wait_exited(pid);
    let wall_s = start.elapsed().as_secs_f64();
    exited.store(true, Ordering::Relaxed);
    let polled = poller.join().unwrap_or(0);
    let reaped = ended.and_then(|()| reap(pid));
    let (stdout, stderr) = (out.join().unwrap_or_default(), err.join().unwrap_or_default());
    let (status, max_rss) = reaped.map_err(|e| tool(format!("waiting for it: {e}")))?;
    if !(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0) {
        let how = if libc::WIFEXITED(status) { format!("exit status {}", libc::WEXITSTATUS(status)) } else { format!("signal {}", libc::WTERMSIG(status)) };
        let last = last_line(&stderr).unwrap_or_else(|| "no error output".into());
        return Err(tool(format!("failed ({how}): {last}")));
    }
    let (peak_rss, peak_sampled) = if max_rss > parent_mark { (max_rss, false) } else { (polled, true) };
    if peak_rss == 0 {
        return Err(tool("its peak memory could not be read (it ended before /proc/PID/status was read, or there is no /proc)".into()));
    }
    Ok(Finished { wall_s, peak_rss, peak_sampled, stdout })
}

/// The last non-blank line of a program's output, if any.
pub fn last_line(output: &[u8]) -> Option<String> {
    String::from_utf8_lossy(output).lines().rev().find(|l| !l.trim().is_empty()).map(|l| l.trim_end().to_string())
}

/// Reads a pipe to its end on a thread of its own.
fn drain(pipe: Option<impl Read + Send + 'static>) -> std::thread::JoinHandle<Vec<u8>> {
    std::thread::spawn(move || {
        let mut bytes = Vec::new();
        if let Some(mut p) = pipe {
            let _ = p.read_to_end(&mut bytes);
        }
        bytes
    })
}

/// `VmHWM` of a `/proc/PID/status`, bytes; `None` where it cannot be read (a process gone
/// or a zombie, which has no memory left).
fn high_water_mark(status: &Path) -> Option<u64> {
    crate::infra::budget::kib_field(&std::fs::read_to_string(status).ok()?, "VmHWM:")
}

/// Waits until child `pid` has exited, leaving it unreaped (`WNOWAIT`).
fn wait_exited(pid: libc::pid_t) -> std::io::Result<()> {
    let id = libc::id_t::try_from(pid).map_err(|_| std::io::Error::other("process id out of range"))?;
    // SAFETY: `siginfo_t` is plain old data, all zeros a valid value.
    let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
    // SAFETY: `info` is valid for writes for the call's duration.
    restarting(|| unsafe { libc::waitid(libc::P_PID, id, &mut info, libc::WEXITED | libc::WNOWAIT) }).map(|_| ())
}

/// Reaps child `pid` (never waited for by `std`): its raw wait status and `ru_maxrss` in
/// bytes (the largest of the child and the descendants it waited for).
fn reap(pid: libc::pid_t) -> std::io::Result<(i32, u64)> {
    let mut status = 0;
    // SAFETY: `rusage` is plain old data, all zeros a valid value.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `status` and `usage` are valid for writes for the call's duration.
    restarting(|| unsafe { libc::wait4(pid, &mut status, 0, &mut usage) })?;
    // Linux gives `ru_maxrss` in KiB.
    Ok((status, u64::try_from(usage.ru_maxrss).unwrap_or(0).saturating_mul(1024)))
}

/// Calls a system call until it is not interrupted by a signal (`EINTR`): its result, or
/// its error.
fn restarting(mut call: impl FnMut() -> libc::c_int) -> std::io::Result<libc::c_int> {
    loop {
        let r = call();
        if r >= 0 {
            return Ok(r);
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn python(code: &str) -> Result<Finished, HostError> {
        run_measured(Path::new("python3"), &[OsString::from("-c"), OsString::from(code)])
    }

    /// Our own high-water mark, bytes.
    fn own_mark() -> u64 {
        high_water_mark(Path::new("/proc/self/status")).unwrap()
    }

    /// A child that stays below its parent: its own peak, sampled (a child holding nothing
    /// reads far less than the 400 MB this process has held, which `ru_maxrss` would
    /// report); one that holds 200 MB for 0.2 s reads at least that.
    #[test]
    fn a_child_below_its_parent_is_sampled() {
        drop(std::hint::black_box(vec![1u8; 400_000_000]));
        let small = python("import time; time.sleep(0.05)").unwrap();
        assert!(small.peak_sampled && small.peak_rss > 1_000_000 && small.peak_rss < 100_000_000, "{small:?}");
        let big = python("import time; b = bytearray(200 * 1000 * 1000); b[::4096] = b'x' * len(b[::4096]); time.sleep(0.2); print('ok')").unwrap();
        assert_eq!(String::from_utf8_lossy(&big.stdout).trim(), "ok");
        assert!(big.peak_rss >= 200_000_000 && big.wall_s >= 0.2, "{big:?}");
    }

    /// A child above its parent: the kernel's exact mark, even for memory held for no
    /// time at all before it exits (which sampling would miss).
    #[test]
    fn a_child_above_its_parent_reads_the_kernels_mark() {
        let size = own_mark() + 1_000_000_000;
        let f = python(&format!("b = bytearray({size}); b[::4096] = b'x' * len(b[::4096])")).unwrap();
        assert!(!f.peak_sampled && f.peak_rss >= size, "{f:?} against {size}");
    }

    /// A failing child is an error naming the command and what it said last; a signal is
    /// named as such; a missing program names its path.
    #[test]
    fn a_failing_child_is_an_error() {
        let e = python("import sys; sys.stderr.write('first\\nthe cause\\n\\n'); sys.exit(3)").unwrap_err().to_string();
        assert!(e.contains("python3 -c") && e.contains("exit status 3") && e.ends_with("the cause"), "{e}");
        let e = python("import os, signal; os.kill(os.getpid(), signal.SIGKILL)").unwrap_err().to_string();
        assert!(e.contains("signal 9") && e.ends_with("no error output"), "{e}");
        let e = run_measured(Path::new("/nonexistent/dncal"), &[]).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/dncal"), "{e}");
    }
}
