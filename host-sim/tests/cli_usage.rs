//! The command line itself (issue 19): usage errors in the one-line format with exit code
//! 2 (bad data is 1), negative numbers taken as values, shell completions and manual pages.

mod support;

use std::path::Path;

use support::{dncal, succeed};

/// The command failed with exactly `line` on stderr, exit code 2, nothing on stdout.
fn assert_usage(args: &[&str], line: &str) {
    let out = dncal(args, Path::new("."));
    assert_eq!(String::from_utf8_lossy(&out.stderr), format!("{line}\n"), "dncal {args:?}");
    assert_eq!(out.status.code(), Some(2), "dncal {args:?}");
    assert!(out.stdout.is_empty());
}

#[test]
fn usage_errors_are_one_line_naming_the_help_to_read() {
    assert_usage(&["quantization", "--sigma", "abc"], "dncal: error: invalid value 'abc' for '--sigma <SIGMA>': invalid float literal (see dncal quantization --help)");
    assert_usage(&["bogus"], "dncal: error: unrecognized subcommand 'bogus' (see dncal --help)");
    // A near miss gets clap's suggestion, on the same line (issue 44).
    assert_usage(&["diagnoes", "x.fits"], "dncal: error: unrecognized subcommand 'diagnoes'; did you mean 'diagnose'? (see dncal --help)");
    assert_usage(&["lut", "inspekt", "x.fits"], "dncal: error: unrecognized subcommand 'inspekt'; did you mean 'inspect'? (see dncal lut --help)");
    assert_usage(&["diagnose", "--spil", "x.fits"], "dncal: error: unexpected argument '--spil' found; did you mean '--spill'? (see dncal diagnose --help)");
    assert_usage(&["lut", "build"], "dncal: error: the following required arguments were not provided: --out <OUT> <HIST> (see dncal lut build --help)");
    assert_usage(&["simulate", "histograms", "--bad"], "dncal: error: unexpected argument '--bad' found (see dncal simulate histograms --help)");
    assert_usage(&["completions", "tcsh"], "dncal: error: invalid value 'tcsh' for '<SHELL>' [possible values: bash, elvish, fish, powershell, zsh] (see dncal completions --help)");
    // A command without its subcommand gets its help (on stderr), exit 2.
    let out = dncal(&["lut"], Path::new("."));
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("Usage: dncal lut [OPTIONS] <COMMAND>"));
    // Help and version are not errors.
    let out = succeed(&["--version"], Path::new("."));
    assert_eq!(String::from_utf8_lossy(&out.stdout), format!("dncal {}\n", env!("CARGO_PKG_VERSION")));
}

#[test]
fn negative_numbers_are_values_and_get_the_domain_message() {
    // Before: `--sigma -1` was an unknown argument `-1` (exit 2); `--sigma=-1` got this.
    for args in [&["quantization", "--sigma", "-1"][..], &["quantization", "--sigma=-1"]] {
        let out = dncal(args, Path::new("."));
        assert_eq!(String::from_utf8_lossy(&out.stderr), "dncal: error: --sigma: noise rms -1 DN must be finite and >= 0\n", "{args:?}");
        assert_eq!(out.status.code(), Some(2), "a value out of its domain is a usage error");
    }
}

#[test]
fn completions_cover_every_subcommand() {
    let subcommands = ["simulate", "lut", "stream", "demo", "adc", "kcor-model", "linearity", "diagnose", "quantization", "emva", "fpga-size", "bench", "firmware-check", "completions", "man"];
    let bash = String::from_utf8(succeed(&["completions", "bash"], Path::new(".")).stdout).unwrap();
    assert!(bash.contains("_dncal()") && bash.contains("complete -F _dncal"), "not a bash completion script");
    for sub in subcommands {
        assert!(bash.contains(&format!("dncal,{sub})")), "bash completion lacks {sub}");
    }
    // bash itself reads the script without error.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("dncal.bash"), &bash).unwrap();
    let check = std::process::Command::new("bash").arg("-n").arg(dir.path().join("dncal.bash")).output().expect("bash runs");
    assert!(check.status.success(), "{}", String::from_utf8_lossy(&check.stderr));
    let zsh = String::from_utf8(succeed(&["completions", "zsh"], Path::new(".")).stdout).unwrap();
    assert!(zsh.starts_with("#compdef dncal"), "{}", &zsh[..zsh.len().min(80)]);
}

#[test]
fn manual_pages_are_roff_one_per_command() {
    let page = String::from_utf8(succeed(&["man"], Path::new(".")).stdout).unwrap();
    assert!(page.contains(&format!(".TH dncal 1  \"dncal {}\"", env!("CARGO_PKG_VERSION"))), "{}", &page[..page.len().min(200)]);
    assert!(page.contains("kcor\\-model") || page.contains("kcor-model"));
    let dir = tempfile::tempdir().unwrap();
    let out = succeed(&["man", "-o", "pages"], dir.path());
    assert_eq!(String::from_utf8_lossy(&out.stdout), "wrote 23 manual pages into pages\n");
    let mut names: Vec<String> = std::fs::read_dir(dir.path().join("pages")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    // The command, its 15 subcommands and the 7 of `simulate` (2) and `lut` (5).
    assert_eq!(names.len(), 23, "{names:?}");
    for name in ["dncal.1", "dncal-lut-build.1", "dncal-lut-convert.1", "dncal-simulate-linearity.1", "dncal-kcor-model.1"] {
        let text = std::fs::read_to_string(dir.path().join("pages").join(name)).unwrap();
        let stem = name.trim_end_matches(".1");
        assert!(text.contains(&format!(".TH {stem} 1 ")), "{name}: {}", &text[..text.len().min(200)]);
    }
}

/// One quantity, one name: `lut build` prints single-code widths and `lut inspect` entry
/// steps (the mean of two neighbouring widths), each said as such. A flat histogram set
/// has every width exactly 1 DN, so both ranges are 1..1.
#[test]
fn code_widths_and_entry_steps_are_named_apart() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    support::flat_histograms(&d.join("h.fits"));
    let build = String::from_utf8(succeed(&["lut", "build", "h.fits", "-o", "cal"], d).stdout).unwrap();
    assert!(build.contains("(code widths: each code's normalized width"), "{build}");
    assert!(build.contains("ADC 3: code widths 1.0000..1.0000 DN,"), "{build}");
    let inspect = String::from_utf8(succeed(&["lut", "inspect", "cal.fits"], d).stdout).unwrap();
    assert!(inspect.contains("(entry steps: entry k+1 - entry k, the mean width of codes k and k+1"), "{inspect}");
    assert!(inspect.contains("ADC 3: entry steps 1.0000..1.0000 DN,"), "{inspect}");
}

/// Without noise the Fourier series reads 0 at the sawtooth's jump while the others read
/// 0.5 DN; the output says why, and only there.
#[test]
fn the_zero_noise_fourier_value_is_explained() {
    let zero = String::from_utf8(succeed(&["quantization", "--sigma=0"], Path::new(".")).stdout).unwrap();
    assert!(zero.contains("a Fourier series converges to the middle of a jump, 0"), "{zero}");
    let small = String::from_utf8(succeed(&["quantization", "--sigma", "0.01"], Path::new(".")).stdout).unwrap();
    assert!(!small.contains("sawtooth"), "{small}");
}
