//! Inputs that are not what a command expects, as a user gives them (issue 18: never
//! panic, never hang, never lose a file): devices, FIFOs and oversized files where a file
//! is read, TOML mistakes, FITS headers that declare more than the file holds, and `-o`
//! naming a directory where a file prefix is expected. Each must be one line
//! `dncal: error: FILE: problem`, exit code 1, promptly, with nothing written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use dncal_host::fits::{write_histograms, AdcHistograms};

/// Runs `dncal args` in `dir`, killed after 60 s: a command that hangs fails its test
/// instead of hanging the suite.
fn dncal(args: &[&str], dir: &Path) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_dncal"))
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("dncal runs");
    let deadline = Instant::now() + Duration::from_secs(60);
    while child.try_wait().expect("dncal can be waited for").is_none() {
        if Instant::now() > deadline {
            child.kill().ok();
            child.wait().ok();
            panic!("dncal {args:?} still running after 60 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().expect("dncal's output")
}

/// The command failed with exactly `dncal: error: {line}` and exit code 1.
fn assert_error(out: &Output, line: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr, format!("dncal: error: {line}\n"));
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
    assert!(out.stdout.is_empty(), "stdout: {}", String::from_utf8_lossy(&out.stdout));
}

/// Files in `dir`, sorted, hidden ones included: to see that nothing was written.
fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

/// A histogram set `lut build` accepts: 4 ADCs of 12 bits, 1000 samples in every code.
fn flat_histograms(path: &Path) {
    write_histograms(path, &AdcHistograms { bit_depth: 12, counts: vec![vec![1000; 4096]; 4] }).unwrap();
}

#[cfg(unix)]
#[test]
fn devices_and_fifos_given_as_inputs_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A FIFO nobody writes to: opening it for reading blocks unless the open is
    // non-blocking.
    let made = Command::new("mkfifo").arg(d.join("in.fifo")).status().expect("mkfifo runs");
    assert!(made.success());
    std::fs::create_dir(d.join("folder")).unwrap();
    let kinds = [("/dev/zero", "character device"), ("/dev/urandom", "character device"), ("in.fifo", "FIFO"), ("folder", "directory")];
    for (input, kind) in kinds {
        let before = listing(d);
        let cases: [&[&str]; 10] = [
            &["lut", "inspect", input],
            &["simulate", "histograms", "--config", input, "-o", "h.fits"],
            &["emva", input],
            &["lut", "build", input, "-o", "cal"],
            &["linearity", input],
            &["diagnose", input],
            &["stream", "--frames-from", input],
            &["kcor-model", "--lut", input],
            &["lut", "import", "--kcor", input, input, input, input, "-o", "cal"],
            &["fpga-size", "--lut", input, "-o", "mem"],
        ];
        for args in cases {
            let out = dncal(args, d);
            assert_error(&out, &format!("{input}: is a {kind}, not a regular file"));
            assert_eq!(listing(d), before, "{args:?} wrote something");
        }
    }
}

#[test]
fn inputs_larger_than_their_kind_are_refused_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Sparse: 17 MiB of zeros that cost nothing to make.
    for (name, len) in [("big.toml", 17u64 << 20), ("big.txt", 5 << 20)] {
        std::fs::File::create(d.join(name)).unwrap().set_len(len).unwrap();
    }
    let out = dncal(&["simulate", "histograms", "--config", "big.toml", "-o", "h.fits"], d);
    assert_error(&out, "big.toml: 17825792 bytes; camera config files are at most 16777216 bytes");
    let out = dncal(&["emva", "big.txt"], d);
    assert_error(&out, "big.txt: 5242880 bytes; EMVA 1288 descriptor files are at most 4194304 bytes");
    assert!(!d.join("h.fits").exists());
}

#[test]
fn toml_errors_are_one_line_with_the_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases = [
        ("syntax.toml", "name = \"cam\"\nread_noise_e = \n", "syntax.toml: line 2, column 16: invalid string; expected `\"`, `'`"),
        ("type.toml", "# a comment\n\nbits = \"twelve\"\n", "type.toml: line 3, column 8: invalid type: string \"twelve\", expected u32"),
        ("table.toml", "[adc]\nstage_bits = [3, 3, 3, 3]\nseed = -1\n", "table.toml: line 3, column 8: invalid value: integer `-1`, expected u64"),
    ];
    for (name, text, line) in cases {
        std::fs::write(d.join(name), text).unwrap();
        assert_error(&dncal(&["simulate", "histograms", "--config", name, "-o", "h.fits"], d), line);
    }
    // An unknown field lists the known ones, still on one line.
    std::fs::write(d.join("typo.toml"), "read_nois_e = 3.0\n").unwrap();
    let out = dncal(&["simulate", "histograms", "--config", "typo.toml", "-o", "h.fits"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.starts_with("dncal: error: typo.toml: line 1, column 1: unknown field `read_nois_e`, expected one of `name`, "), "{stderr}");
    assert_eq!((stderr.lines().count(), out.status.code()), (1, Some(1)), "{stderr}");
    assert!(!d.join("h.fits").exists());
}

/// The offset of the first 80-byte header card `key` from `from` on, and its integer
/// value (0 for a card without one, such as END).
fn card(bytes: &[u8], from: usize, key: &str) -> (usize, i64) {
    let at = (from..bytes.len()).step_by(80).find(|&i| bytes[i..i + 8] == *format!("{key:<8}").as_bytes()).unwrap_or_else(|| panic!("no {key} card"));
    let value = std::str::from_utf8(&bytes[at + 10..at + 30]).unwrap().trim().parse().unwrap_or(0);
    (at, value)
}

#[test]
fn a_heap_larger_than_the_file_is_refused_naming_the_hdu() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(dncal(&["simulate", "linearity", "--levels", "12", "--frames", "4", "--roi", "16x16+0+0", "-o", "lin.fits"], d).status.success());
    // The file as written is read: what fails below is the patched PCOUNT.
    assert!(dncal(&["linearity", "lin.fits"], d).status.success());
    assert!(dncal(&["diagnose", "lin.fits"], d).status.success());
    let mut bytes = std::fs::read(d.join("lin.fits")).unwrap();
    // The REFERENCE table, the file's last HDU: PCOUNT (its heap) set to 2e9 bytes.
    let table = (0..bytes.len()).step_by(2880).find(|&i| bytes[i..].starts_with(b"XTENSION= 'BINTABLE'")).unwrap();
    let hdu = (0..table).step_by(2880).filter(|&i| bytes[i..].starts_with(b"XTENSION=")).count() + 1;
    let (pcount, zero) = card(&bytes, table, "PCOUNT");
    assert_eq!(zero, 0);
    bytes[pcount + 10..pcount + 30].copy_from_slice(format!("{:>20}", 2_000_000_000).as_bytes());
    std::fs::write(d.join("heap.fits"), &bytes).unwrap();
    // Where the table's heap would end, from the standard: header blocks, then rows x
    // row bytes + PCOUNT in whole blocks.
    let (end_card, _) = card(&bytes, table, "END");
    let data_start = (end_card / 2880 + 1) * 2880;
    let (_, row_bytes) = card(&bytes, table, "NAXIS1");
    let (_, rows) = card(&bytes, table, "NAXIS2");
    let end = data_start as u64 + ((row_bytes * rows) as u64 + 2_000_000_000).div_ceil(2880) * 2880;
    let line = format!(
        "heap.fits: the HDU {hdu} (REFERENCE) declares its header, data and heap (PCOUNT) to end at byte {end}; the file has {} bytes (truncated?)",
        bytes.len()
    );
    for args in [&["linearity", "heap.fits"][..], &["diagnose", "heap.fits", "-o", "report"]] {
        assert_error(&dncal(args, d), &line);
    }
    assert!(!d.join("report").exists());
}

#[test]
fn an_output_prefix_naming_a_directory_is_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    std::fs::create_dir(d.join("out")).unwrap();
    assert!(dncal(&["lut", "build", "h.fits", "-o", "cal"], d).status.success());
    let before = listing(d);
    let builds = [
        ("out/", "out/: names a directory; -o takes a file prefix OUT and writes OUT.fits and OUT.bin (e.g. -o out/cal)"),
        ("out", "out: names a directory; -o takes a file prefix OUT and writes OUT.fits and OUT.bin (e.g. -o out/cal)"),
        ("new/", "new/: names a directory; -o takes a file prefix OUT and writes OUT.fits and OUT.bin (e.g. -o new/cal)"),
    ];
    for (out, line) in builds {
        assert_error(&dncal(&["lut", "build", "h.fits", "-o", out], d), line);
    }
    let line = "out/: names a directory; -o takes a file prefix OUT and writes OUT_adc0.bin .. OUT_adc3.bin (e.g. -o out/cal)";
    assert_error(&dncal(&["lut", "export", "--format", "kcor", "cal.fits", "-o", "out/"], d), line);
    assert_eq!(listing(d), before);
    assert!(listing(&d.join("out")).is_empty());
    // A prefix inside the directory is what was meant, and works.
    assert!(dncal(&["lut", "build", "h.fits", "-o", "out/cal"], d).status.success());
    assert_eq!(listing(&d.join("out")), [d.join("out/cal.bin"), d.join("out/cal.fits")]);
}
