//! The bench's ratchet: every row has a recorded floor, the lowest median ratio it is
//! known to hold on the machines this project runs on, and `dncal bench --check` fails
//! where a row's median falls more than [`SLACK`] below it. `diagnose` became 5.7 times
//! slower in one week and no check saw it: the bench printed the figure with no target.
//!
//! A floor is a ratio against a reference run in the same process, so the machine's
//! speed cancels; the rows against a fixed reference (one camera's rate, a wall-time or
//! memory limit of a whole command) do not cancel it, and `--check` reports them without
//! failing. Floors are raised as the code gets faster (docs/benchmarks.md keeps each
//! row's history by commit), never lowered to let a slowdown through: a slowdown is
//! either mended or argued for in that history.
//!
//! Rows are matched by their name and baseline with the digits masked (`core, 2 bands, 2
//! threads` is the row of any thread count).

use serde::Serialize;

use super::{BenchReport, Ratio};

/// A row may fall this far below its floor before `--check` fails: the spread of one
/// row's medians between invocations on the 2-core machines (docs/benchmarks.md: 0.87 to
/// 1.00 for the core against the plain loop, 1.28 to 1.83 for two bands against one).
pub const SLACK: f64 = 0.75;

/// What a row's floor is.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Floor {
    /// A ratio against a reference in the same process: `--check` holds it.
    Ratio(f64),
    /// Reported only: against a fixed reference (the machine's speed does not cancel), or
    /// a measure of the host more than of the code (two threads' speed-up, which another
    /// tenant on the second core halves).
    Reported,
}

/// The recorded floors: (row name, baseline, floor, where it comes from). Measured with
/// the `checked` build CI runs (overflow checks on: the core's loops run at 0.73-0.89 of
/// the plain loop there, 0.87-1.00 in the release build) on the 2-core Intel Xeon and AMD
/// EPYC machines of docs/benchmarks.md.
const FLOORS: &[(&str, &str, Floor, &str)] = &[
    ("core, line by line", "plain LUT loop", Floor::Ratio(0.70), "medians 0.73-0.89 (checked, 3 invocations, 2026-12-04); 0.87-0.94 release"),
    ("core, frame as a block", "plain LUT loop", Floor::Ratio(0.72), "medians 0.75-0.87 (checked); 0.88-0.99 release"),
    ("core, frame as a block", "byte bound (no LUT)", Floor::Ratio(0.15), "medians 0.44-0.54 (checked, Xeon); 0.23-0.33 release on the AMD EPYC, where the checked build's core runs at about 0.76-0.99 of its release speed"),
    ("core, frame as a block", "gather loop (AVX*", Floor::Ratio(0.85), "medians 0.99, 1.05, 1.06 (checked, AVX-512 Xeon, the core on its AVX-512 kernel, 2026-12-04); 0.95 with the core held to its portable loop"),
    ("core, frame as a block", "numpy lut[adc, codes]", Floor::Ratio(4.0), "medians 4.97-8.77 release (AMD EPYC to Xeon); the checked build's core is up to a quarter slower; numpy alone (CI's python3 has it)"),
    ("core, # bands, # threads", "core, # band, # thread", Floor::Reported, "two threads' speed-up: medians 1.40-2.03 (checked), 1.28-2.16 release, single runs down to 0.98: the host's second core more than the code"),
    ("plain loop, # bands, # threads", "plain loop, # band, # thread", Floor::Reported, "the host's own ceiling: medians 1.06-1.21 (checked), 1.46-1.86 release"),
    ("stream, end to end", "one K-Cor camera (fixed)", Floor::Reported, "a fixed rate"),
    ("stream, end to end, # thread", "its draws alone, # thread", Floor::Ratio(0.3), "what the sampler's codes, the check's references and the core add to the draws: medians 0.49 and 0.44 (runs 0.42-0.51, two invocations, checked, AVX-512 Xeon, 2026-12-05); the draws are the vector unit's work, the rest partly scalar, so a CPU with narrower vectors measures higher"),
    ("stream --frames-from", "one K-Cor camera (fixed)", Floor::Reported, "a fixed rate"),
    ("camera draws, # streams (PTRS, Box-Muller)", "rand_distr Poisson::new + sample", Floor::Ratio(0.5), "a Poisson count and a Gaussian a pixel against the crate's Poisson count alone: median 1.26 (1.25-1.27, checked, AVX-512 Xeon, 2026-12-05); the AVX2 build draws at about 0.7 and the portable one about 0.55-0.6 of the AVX-512 build's speed (docs/benchmarks.md), so a CPU without AVX-512 measures lower: hence the floor"),
    ("linearity, # x # x #", "numpy/astropy, same steps", Floor::Ratio(12.0), "medians 14.5-26, release"),
    ("diagnose, # x # x # linearity set", "one quartic SVD fit per pixel", Floor::Ratio(0.032), "0.0407 (checked, 7d0b59b's fits on the stack, illumination solves and runs of pixels; single runs 0.039-0.050); 0.0227 at a0f0fa6; 0.013 at 02913d3, issue 59's figure after 5.7 times slower; raise it as that is mended"),
    ("firmware correction, QEMU count", "issue #: # instructions a pixel", Floor::Ratio(1.12), "a count: 6.249 instructions a pixel since 25cd9de"),
    ("linearity # x # x #, whole process", "numpy/astropy, same steps, # run", Floor::Ratio(10.0), "its target; 47x at 1024 x 1024 (25cd9de)"),
    ("linearity # x # x #, *", "issue #: *", Floor::Reported, "a limit of the whole command"),
    ("diagnose # x # x #, *", "issue #: *", Floor::Reported, "a limit of the whole command"),
    ("demo, defaults, wall", "issue #: # s", Floor::Reported, "a limit of the whole command"),
    ("Python *", "the core's Corrector, same frames", Floor::Ratio(1.0 / 1.2), "its target; no run recorded yet"),
    ("Python fit_linearity, *", "dncal linearity's analysis", Floor::Ratio(1.0 / 1.2), "its target; no run recorded yet"),
];

/// `s` with every run of digits (and a decimal point between them) as one `#`.
fn masked(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut in_number = false;
    for c in s.chars() {
        let digit = c.is_ascii_digit() || (in_number && c == '.');
        if !digit {
            out.push(c);
        } else if !in_number {
            out.push('#');
        }
        in_number = digit;
    }
    out
}

/// Whether `name` matches `pattern` (digits masked; a trailing `*` matches any rest).
fn matches(pattern: &str, name: &str) -> bool {
    let name = masked(name);
    match pattern.strip_suffix('*') {
        Some(prefix) => name.starts_with(prefix),
        None => name == pattern,
    }
}

/// The recorded floor of `row`, with where it comes from; `None` for a row without one
/// (itself a failure of `--check`: every row must have a floor).
pub fn floor_of(row: &Ratio) -> Option<(Floor, &'static str)> {
    FLOORS.iter().find(|(n, b, _, _)| matches(n, &row.name) && matches(b, &row.baseline)).map(|&(_, _, f, why)| (f, why))
}

/// What `--check` found.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Checked {
    /// Rows below [`SLACK`] times their floor, or without a floor: what fails.
    pub failures: Vec<String>,
    /// Rows reported without a check ([`Floor::Reported`]), with why.
    pub unchecked: Vec<String>,
}

impl Checked {
    /// Whether every row holds.
    pub fn holds(&self) -> bool {
        self.failures.is_empty()
    }
}

/// Each row of `report` against its floor.
pub fn check(report: &BenchReport) -> Checked {
    let mut c = Checked::default();
    for r in &report.ratios {
        let row = format!("{} vs {}", r.name, r.baseline);
        match floor_of(r) {
            None => c.failures.push(format!("{row}: no floor recorded (checks/bench/ratchet.rs)")),
            Some((Floor::Reported, why)) => c.unchecked.push(format!("{row}: {:.4}x, reported, not checked ({why})", r.ratio_median)),
            Some((Floor::Ratio(f), why)) => {
                // (A NaN median, a row that did not measure, fails too.)
                if r.ratio_median.is_nan() || r.ratio_median < SLACK * f {
                    c.failures.push(format!("{row}: {:.4}x, below {SLACK} of its floor {f} ({why})", r.ratio_median));
                }
            }
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checks::bench::{compared, Better};

    #[test]
    fn digits_are_masked_and_rows_matched_whatever_their_counts() {
        assert_eq!(masked("core, 2 bands, 16 threads"), "core, # bands, # threads");
        assert_eq!(masked("diagnose, 128 x 128 x 41 linearity set"), "diagnose, # x # x # linearity set");
        assert_eq!(masked("issue 17: 7 instructions a pixel"), "issue #: # instructions a pixel");
        assert_eq!(masked("a 1.5 b"), "a # b");
        assert!(matches("Python *", "Python Corrector.add, 1024 x 1024"));
        assert!(!matches("core, frame as a block", "core, frame as a block, more"));
    }

    /// Every row the bench makes has a floor (the in-process rows, the firmware's count,
    /// the whole commands' and the Python package's names as they build them).
    #[test]
    fn every_row_name_the_bench_makes_has_a_floor() {
        let row = |name: &str, baseline: &str| compared(name, &[1.0], baseline, &[1.0], "x", Better::Higher, None);
        for (name, baseline) in [
            ("core, line by line", "plain LUT loop"),
            ("core, frame as a block", "plain LUT loop"),
            ("core, frame as a block", "byte bound (no LUT)"),
            ("core, frame as a block", "numpy lut[adc, codes]"),
            ("core, 2 bands, 2 threads", "core, 1 band, 1 thread"),
            ("plain loop, 8 bands, 8 threads", "plain loop, 1 band, 1 thread"),
            ("stream, end to end", "one K-Cor camera (fixed)"),
            ("stream, end to end, 1 thread", "its draws alone, 1 thread"),
            ("stream --frames-from", "one K-Cor camera (fixed)"),
            ("camera draws, 8 streams (PTRS, Box-Muller)", "rand_distr Poisson::new + sample"),
            ("linearity, 256 x 256 x 41", "numpy/astropy, same steps"),
            ("diagnose, 128 x 128 x 41 linearity set", "one quartic SVD fit per pixel"),
            ("firmware correction, QEMU count", "issue 17: 7 instructions a pixel"),
            ("Python Corrector.add, 1024 x 1024 x 16", "the core's Corrector, same frames"),
            ("Python fit_linearity, 256 x 256 x 41", "dncal linearity's analysis"),
            ("linearity 1024 x 1024 x 41, wall", "issue 17: 2 s"),
            ("linearity 1024 x 1024 x 41, beyond input", "issue 17: 1 KB a pixel"),
            ("linearity 1024 x 1024 x 41, whole process", "numpy/astropy, same steps, 1 run"),
            ("diagnose 2048 x 2048 x 41, wall", "issue 17: 5 min"),
            ("diagnose 2048 x 2048 x 41, peak RSS", "issue 17: 4 GB"),
            ("diagnose 2048 x 2048 x 41, RSS a pixel", "issue 17: 1 KB a pixel"),
            ("demo, defaults, wall", "issue 17: 60 s"),
        ] {
            assert!(floor_of(&row(name, baseline)).is_some(), "{name} vs {baseline}");
        }
    }

    /// A row at its floor holds, at 0.76 of it holds, at 0.74 fails; a reported one never
    /// fails; one without a floor fails.
    #[test]
    fn check_fails_a_row_below_three_quarters_of_its_floor() {
        let report = |ratio: f64, name: &str, baseline: &str| BenchReport {
            machine: String::new(),
            runs: 1,
            ratios: vec![compared(name, &[ratio], baseline, &[1.0], "x", Better::Higher, None)],
            notes: vec![],
            check: None,
        };
        let diagnose = ("diagnose, 128 x 128 x 41 linearity set", "one quartic SVD fit per pixel");
        assert!(check(&report(0.032, diagnose.0, diagnose.1)).holds());
        assert!(check(&report(0.76 * 0.032, diagnose.0, diagnose.1)).holds());
        let slow = check(&report(0.74 * 0.032, diagnose.0, diagnose.1));
        assert!(!slow.holds() && slow.failures[0].contains("below 0.75 of its floor 0.032"), "{slow:?}");
        let fixed = check(&report(0.01, "stream, end to end", "one K-Cor camera (fixed)"));
        assert!(fixed.holds() && fixed.unchecked.len() == 1);
        assert!(!check(&report(5.0, "something new", "anything")).holds());
        // (NaN, a row that did not measure, fails.)
        assert!(!check(&report(f64::NAN, diagnose.0, diagnose.1)).holds());
    }
}
