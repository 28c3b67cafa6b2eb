//! What a user sees while a command works, on stderr: a line as each stage starts
//! ([`stage`]) and a bar on every step longer than about a second ([`bar`], or
//! [`spinner`] where the step cannot count its work). Both show only when stderr is a
//! terminal and `--quiet` is not given, so `--json` output, pipes, CI logs and the
//! one-line error contract stay clean.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

static QUIET: AtomicBool = AtomicBool::new(false);

/// `--quiet`: no stage lines, no bars.
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

/// Whether progress is shown: stderr is a terminal and `--quiet` was not given.
pub fn shown() -> bool {
    !QUIET.load(Ordering::Relaxed) && std::io::stderr().is_terminal()
}

/// Announces a stage as it starts: `dncal: MESSAGE` on stderr (when [`shown`]).
pub fn stage(message: &str) {
    if shown() {
        eprintln!("dncal: {}", super::printable::printable(message));
    }
}

/// A bar of `len` steps labelled `message` (hidden unless [`shown`]).
pub fn bar(len: u64, message: &str) -> ProgressBar {
    if !shown() {
        return ProgressBar::hidden();
    }
    // Cleared when dropped too (a step that fails with `?` leaves no bar above the error).
    let pb = ProgressBar::new(len).with_finish(indicatif::ProgressFinish::AndClear);
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg:<28} [{bar:40}] {pos}/{len} ({elapsed}, eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(message.to_string());
    pb
}

/// A spinner with the time elapsed, for a step that cannot count its work (a fit over
/// every pixel at once, a solver): it ticks by itself until finished (hidden unless
/// [`shown`]).
pub fn spinner(message: &str) -> ProgressBar {
    if !shown() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner().with_finish(indicatif::ProgressFinish::AndClear);
    pb.set_style(ProgressStyle::with_template("{spinner} {msg} ({elapsed})").unwrap_or_else(|_| ProgressStyle::default_spinner()));
    pb.set_message(message.to_string());
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quiet_hides_everything() {
        // Under `cargo test` stderr may or may not be a terminal; quiet must hide either way.
        set_quiet(true);
        assert!(!shown());
        assert!(bar(10, "x").is_hidden());
        assert!(spinner("x").is_hidden());
        set_quiet(false);
        assert_eq!(shown(), std::io::stderr().is_terminal());
    }
}
