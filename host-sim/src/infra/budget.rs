//! The memory budget (issue 18): before a command allocates for a size it read from a file
//! or a config, it asks here whether that fits. A refusal is a clean error naming the
//! file, what needed the memory and the limit, instead of an abort on allocation failure
//! (or the machine swapping) minutes later.
//!
//! The budget is per process, set once by `dncal --max-memory SIZE`; by default it is 3/4
//! of the memory the process can really have: the smallest of the machine's physical
//! memory (`MemTotal` of `/proc/meminfo`; 8 GiB where that cannot be read), the address
//! space and data limits (`RLIMIT_AS`, `RLIMIT_DATA`: `ulimit -v`, `prlimit`) less what
//! the process already maps, and its cgroup's `memory.max` (v2, every level up to the
//! root; v1's `memory.limit_in_bytes`) less what the cgroup already uses, all taken at the
//! first check (issue 43: under
//! `ulimit -v 4000000` the budget was 3/4 of 24 GiB, and a file declaring 9.6 GB aborted
//! on allocation). The checks are estimates of the largest allocations of a step (the
//! input's pixels as the command holds them, the per-pixel state of an analysis), not an
//! accounting of every byte: a command may use somewhat more than what it checked, never
//! an order of magnitude more.
//!
//! A command that reads a set checks its whole need at once, before its first large read
//! ([`Need`], issue 56): `linearity`, `emva`, `diagnose`, `lut build`, `adc --hist` and
//! `stream --hist` sum, from the file's header or the descriptor, everything they will
//! hold at the same time (the set as read, the analysis beside it, the file cfitsio holds
//! inflated), each part measured (`host-sim/tests/cli_budget.rs` runs each command under
//! a budget below its need, and just above it).

use std::sync::atomic::{AtomicU64, Ordering};

use crate::HostError;

/// 0: not set, use [`default_limit`].
static LIMIT: AtomicU64 = AtomicU64::new(0);

/// Used where the physical memory cannot be read.
const FALLBACK: u64 = 8 << 30;

/// 3/4 of the memory the process can have ([`room`]), taken once, at the first ask: a
/// budget that moved with the process's own use would answer two asks of one step
/// differently (the gzip count compares its limit with the budget to name which bound
/// refused), and every ask would read `/proc` and the cgroup's files again.
pub fn default_limit() -> u64 {
    static DEFAULT: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *DEFAULT.get_or_init(|| room() / 4 * 3)
}

/// The memory the process can still have, bytes: the smallest of the physical memory (or
/// 8 GiB where it cannot be read), each resource limit less what counts against it, and
/// the cgroup's limit less its use. At least 1.
pub fn room() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let mut room = physical_memory().unwrap_or(FALLBACK);
    // The address-space limit counts every mapping (VmSize), the data limit the
    // private writable ones (VmData).
    #[cfg(unix)]
    for (resource, used) in [(libc::RLIMIT_AS, "VmSize:"), (libc::RLIMIT_DATA, "VmData:")] {
        if let Some(limit) = rlimit(resource) {
            room = room.min(limit.saturating_sub(kib_field(&status, used).unwrap_or(0)));
        }
    }
    if let Some(left) = cgroup_room() {
        room = room.min(left);
    }
    room.max(1)
}

/// The soft limit of `resource`, bytes; `None` where it is unlimited or unknown.
#[cfg(unix)]
fn rlimit(resource: libc::__rlimit_resource_t) -> Option<u64> {
    let mut r = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: `r` is a valid rlimit for getrlimit to fill.
    let ok = unsafe { libc::getrlimit(resource, &mut r) } == 0;
    (ok && r.rlim_cur != libc::RLIM_INFINITY).then_some(r.rlim_cur)
}

/// What the process's cgroup may still use, bytes: for cgroup v2, the smallest of
/// `memory.max - memory.current` over its directory and every parent (a parent's limit
/// binds as well); for v1, `memory.limit_in_bytes - memory.usage_in_bytes`. `None`
/// without a limit or a cgroup file system.
fn cgroup_room() -> Option<u64> {
    let cgroups = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let root = std::path::Path::new("/sys/fs/cgroup");
    let read = |p: &std::path::Path| std::fs::read_to_string(p).ok().and_then(|t| t.trim().parse::<u64>().ok());
    let mut room: Option<u64> = None;
    for line in cgroups.lines() {
        let mut parts = line.splitn(3, ':');
        let (_, controllers, path) = (parts.next()?, parts.next()?, parts.next()?);
        let relative = path.trim_start_matches('/');
        let (base, max_file, used_file) = match controllers {
            "" => (root.to_path_buf(), "memory.max", "memory.current"),
            c if c.split(',').any(|c| c == "memory") => (root.join("memory"), "memory.limit_in_bytes", "memory.usage_in_bytes"),
            _ => continue,
        };
        let mut dir = base.join(relative);
        loop {
            // "max" (v2) does not parse: no limit at this level.
            if let Some(max) = read(&dir.join(max_file)) {
                let used = read(&dir.join(used_file)).unwrap_or(0);
                let left = max.saturating_sub(used);
                room = Some(room.map_or(left, |r| r.min(left)));
            }
            if dir == base || !dir.pop() || !dir.starts_with(&base) {
                break;
            }
        }
    }
    room
}

fn physical_memory() -> Option<u64> {
    kib_field(&std::fs::read_to_string("/proc/meminfo").ok()?, "MemTotal:")
}

/// The value of a `KEY: N kB` line of a `/proc` file (`/proc/meminfo`,
/// `/proc/PID/status`), in bytes.
pub(crate) fn kib_field(text: &str, key: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(key))?;
    let kib: u64 = line[key.len()..].trim().trim_end_matches("kB").trim().parse().ok()?;
    kib.checked_mul(1024)
}

/// Sets the budget, bytes (at least 1).
pub fn set_limit(bytes: u64) {
    LIMIT.store(bytes.max(1), Ordering::Relaxed);
}

/// The budget in force, bytes.
pub fn limit() -> u64 {
    match LIMIT.load(Ordering::Relaxed) {
        0 => default_limit(),
        n => n,
    }
}

/// `Ok` if `bytes` fit the budget, else [`HostError::OverBudget`] naming `origin` (a file
/// or a `Subject`) and `what`.
pub fn check(origin: impl Into<crate::Origin>, what: &str, bytes: u64) -> Result<(), HostError> {
    let limit = limit();
    if bytes > limit {
        return Err(HostError::OverBudget { origin: origin.into(), what: what.into(), bytes, limit });
    }
    Ok(())
}

/// Whether `bytes` fit the budget.
pub fn fits(bytes: u64) -> bool {
    bytes <= limit()
}

/// What a command will hold at once, part by part, counted from its input's header (or
/// descriptor) before its first large read and checked as one total (issue 56: checked
/// step by step, `linearity` read both cubes of a 512 x 512 x 41 set, 180 MB, before its
/// analysis was refused by a budget of 100 MiB, and `emva` ran to its end at 67 MB under
/// 1.2 MiB, only each image's decoding checked). The per-step checks stay beside it, for
/// callers that hold their data already.
#[derive(Debug, Clone, Default)]
pub struct Need {
    /// What needs the memory and its bytes, in the order the message lists them.
    parts: Vec<(String, u64)>,
}

impl Need {
    /// Nothing yet.
    pub fn new() -> Self {
        Need::default()
    }

    /// `bytes` more, for `what` (a part of 0 bytes is left out of the message).
    pub fn with(mut self, what: impl Into<String>, bytes: u64) -> Self {
        if bytes > 0 {
            self.parts.push((what.into(), bytes));
        }
        self
    }

    /// Every part together, bytes (saturating: sizes read from a file may be absurd).
    pub fn total(&self) -> u64 {
        self.parts.iter().fold(0u64, |t, (_, b)| t.saturating_add(*b))
    }

    /// `Ok` where the total fits the budget, else [`HostError::OverBudget`] naming `origin`,
    /// `subject` and each part with its size: `l.fits: linearity of 512 x 512 pixels x 41
    /// levels (the two cubes as read 164.0 MiB + the fits 50.0 MiB) needs about 214.0 MiB,
    /// more than the memory budget of 100.0 MiB (--max-memory)`.
    pub fn check(&self, origin: impl Into<crate::Origin>, subject: &str) -> Result<(), HostError> {
        self.check_within(origin.into(), subject, limit())
    }

    /// [`Need::check`] against a budget of `limit` bytes.
    fn check_within(&self, origin: crate::Origin, subject: &str, limit: u64) -> Result<(), HostError> {
        let (bytes, parts): (u64, Vec<String>) = (self.total(), self.parts.iter().map(|(what, bytes)| format!("{what} {}", human(*bytes))).collect());
        if bytes > limit {
            return Err(HostError::OverBudget { origin, what: format!("{subject} ({})", parts.join(" + ")), bytes, limit });
        }
        Ok(())
    }
}

/// The threads a command's parallel steps run on (rayon's pool): what a step holds per
/// task in flight is held this many times at once.
pub fn threads() -> u64 {
    rayon::current_num_threads().max(1) as u64
}

/// `count` items of `size` bytes each, saturating (a size read from a file may be absurd).
pub fn bytes_of(count: u64, size: u64) -> u64 {
    count.saturating_mul(size)
}

/// A size as `--max-memory` takes it: bytes, or with a binary suffix `K`, `M`, `G`, `T`
/// (`KiB`, `MiB`, ... and `KB`, `MB`, ... read the same: powers of 1024), fractions allowed
/// (`1.5G`).
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let not_a_size = || format!("{text:?} is not a size (e.g. 4G, 512M, 1.5G)");
    if number.parse::<f64>().is_err() {
        return Err(not_a_size());
    }
    let shift = match unit.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 0,
        "K" | "KB" | "KIB" => 10,
        "M" | "MB" | "MIB" => 20,
        "G" | "GB" | "GIB" => 30,
        "T" | "TB" | "TIB" => 40,
        other => return Err(format!("unknown unit {other:?} in {text:?} (use K, M, G or T)")),
    };
    let value: f64 = number.parse().map_err(|_| not_a_size())?;
    let bytes = value * (1u64 << shift) as f64;
    if !(bytes >= 1.0 && bytes < 2f64.powi(63)) {
        return Err(format!("{text:?} is not a size between 1 byte and 8 EiB"));
    }
    Ok(bytes as u64)
}

/// Bytes in a short human form (binary units), for messages.
pub fn human(bytes: u64) -> String {
    const UNITS: [&str; 7] = ["bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit < UNITS.len() - 1 {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} bytes")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_in_binary_units() {
        assert_eq!(parse_size("4096"), Ok(4096));
        assert_eq!(parse_size("4K"), Ok(4096));
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("1.5G"), Ok(3 << 29));
        assert_eq!(parse_size("2 GiB"), Ok(2 << 30));
        assert_eq!(parse_size("1t"), Ok(1 << 40));
        for bad in ["", "G", "-1G", "0", "1.5X", "1e3", "NaN", "99999999999T"] {
            assert!(parse_size(bad).is_err(), "{bad:?} accepted");
        }
        // A number that is not one is named as such, not as a unit.
        assert_eq!(parse_size("-1G"), Err("\"-1G\" is not a size (e.g. 4G, 512M, 1.5G)".into()));
        assert_eq!(parse_size("1.5X"), Err("unknown unit \"X\" in \"1.5X\" (use K, M, G or T)".into()));
    }

    #[test]
    fn human_sizes_read_back() {
        assert_eq!(human(1000), "1000 bytes");
        assert_eq!(human(3 << 29), "1.5 GiB");
        // 2^64 - 1 bytes is a hair under 16 EiB.
        assert_eq!(human(u64::MAX), "16.0 EiB");
        assert_eq!(human(5 << 40), "5.0 TiB");
    }

    #[test]
    fn the_default_is_at_most_three_quarters_of_the_machine() {
        // Read independently of the parser above: the kB figure in /proc/meminfo. (A
        // limit of this process or its cgroup may make it smaller; the command's test
        // under `prlimit` checks that it does: `host-sim/tests/cli_inputs.rs`.)
        match std::fs::read_to_string("/proc/meminfo") {
            Ok(text) => {
                let kib: u64 = text.lines().find(|l| l.starts_with("MemTotal:")).unwrap().split_whitespace().nth(1).unwrap().parse().unwrap();
                assert!(default_limit() <= kib * 1024 / 4 * 3 && default_limit() > 0);
            }
            Err(_) => assert!(default_limit() <= FALLBACK),
        }
    }

    #[test]
    fn a_need_is_checked_as_its_total_and_names_its_parts() {
        let need = Need::new().with("the cubes", 3 << 20).with("nothing", 0).with("the fits", 1 << 20);
        assert_eq!(need.total(), 4 << 20);
        assert_eq!(Need::new().with("a", u64::MAX).with("b", 1).total(), u64::MAX);
        // Each part alone fits 3.5 MiB; together they do not.
        let x = || crate::Origin::from(std::path::Path::new("x.fits"));
        let e = need.check_within(x(), "linearity", 7 << 19).unwrap_err().to_string();
        assert_eq!(e, "x.fits: linearity (the cubes 3.0 MiB + the fits 1.0 MiB) needs about 4.0 MiB, more than the memory budget of 3.5 MiB (--max-memory)");
        assert!(need.check_within(x(), "linearity", 4 << 20).is_ok());
    }

    #[test]
    fn a_proc_field_is_read_in_bytes() {
        let status = "Name:\tdncal\nVmPeak:\t  900 kB\nVmHWM:\t   12345 kB\nVmRSS:\t 100 kB\n";
        assert_eq!(kib_field(status, "VmHWM:"), Some(12345 * 1024));
        assert_eq!(kib_field(status, "VmSwap:"), None);
        assert_eq!(kib_field("VmHWM: lots kB", "VmHWM:"), None);
        assert_eq!(kib_field(&format!("VmHWM: {} kB", u64::MAX / 1000), "VmHWM:"), None);
    }
}
