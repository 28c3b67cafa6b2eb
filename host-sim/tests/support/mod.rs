//! What the host's CLI tests share: running `dncal` with a deadline, the one-line error
//! contract, listings and snapshots of a directory, small inputs. Each test file that
//! needs it says `mod support;`; not every file uses every helper.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use dncal_host::formats::fits::{write_histograms, AdcHistograms};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, Poisson};

/// How long a command may run before its test fails instead of hanging the suite
/// (generous: the demo runs here, and CI machines are shared).
pub const DEADLINE: Duration = Duration::from_secs(600);

/// How long a refusal may take ([`dncal_prompt`]): a bad input must be refused at once.
pub const PROMPT: Duration = Duration::from_secs(60);

/// The K-Coronagraph's shared tables' folder; `DNCAL_KCOR_LUTS` overrides it. `None`
/// (the test then says it skips) where it is absent.
#[allow(dead_code)]
pub fn kcor_luts_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("DNCAL_KCOR_LUTS")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/kcor-luts"));
    if dir.join("README.md").exists() {
        Some(dir)
    } else {
        eprintln!("skipping: {} is absent", dir.display());
        None
    }
}

/// `python` of the project's astropy venv (target/astropy-venv, made by
/// scripts/astropy-venv.sh when missing): astropy and numpy, never the system Python's.
pub fn python() -> Command {
    Command::new(python_path())
}

/// The path of the astropy venv's `python` (see [`python`]).
pub fn python_path() -> &'static Path {
    static PYTHON: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    PYTHON.get_or_init(|| {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/astropy-venv.sh");
        let out = Command::new(&script).output().expect("scripts/astropy-venv.sh runs");
        assert!(out.status.success(), "astropy-venv.sh failed:\n{}", String::from_utf8_lossy(&out.stderr));
        PathBuf::from(String::from_utf8_lossy(&out.stdout).lines().last().expect("the venv's python path").trim())
    })
}

/// `dncal args` in `dir`, stdin closed, stdout and stderr to be captured.
fn command(args: &[&str], dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_dncal"));
    c.args(args).current_dir(dir).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

/// `dncal args` started in `dir`, stdin closed, stdout and stderr captured.
pub fn spawn(args: &[&str], dir: &Path) -> Child {
    command(args, dir).spawn().expect("dncal runs")
}

/// Runs `dncal args` in `dir` as a user of the astropy venv would (its `bin` first on
/// `PATH`, so the `python3` dncal starts has numpy and astropy whatever the system's
/// Python holds), killed after [`DEADLINE`].
pub fn dncal_in_venv(args: &[&str], dir: &Path) -> Output {
    let bin = python_path().parent().expect("the venv's bin folder");
    let path = std::env::join_paths(std::iter::once(bin.to_path_buf()).chain(std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default()))).expect("a PATH");
    let mut c = command(args, dir);
    c.env("PATH", path);
    wait_within(c.spawn().expect("dncal runs"), args, DEADLINE)
}

/// Runs `dncal args` in `dir`, killed after [`DEADLINE`]. Its stdout and stderr are read
/// while it runs (a child writing more than a pipe holds would otherwise wait for ever).
pub fn dncal(args: &[&str], dir: &Path) -> Output {
    dncal_within(args, dir, DEADLINE)
}

/// Runs `dncal args` in `dir`, killed after [`PROMPT`]: for refusals.
pub fn dncal_prompt(args: &[&str], dir: &Path) -> Output {
    dncal_within(args, dir, PROMPT)
}

/// Runs `dncal args` in `dir`, killed after `limit`.
pub fn dncal_within(args: &[&str], dir: &Path, limit: Duration) -> Output {
    wait_within(spawn(args, dir), args, limit)
}

/// Waits for a started `dncal args`, killed after `limit`.
fn wait_within(mut child: Child, args: &[&str], limit: Duration) -> Output {
    use std::io::Read;
    let drain = |mut pipe: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            pipe.read_to_end(&mut bytes).expect("dncal's output");
            bytes
        })
    };
    let stdout = drain(Box::new(child.stdout.take().expect("piped stdout")));
    let stderr = drain(Box::new(child.stderr.take().expect("piped stderr")));
    let deadline = Instant::now() + limit;
    let status = loop {
        if let Some(status) = child.try_wait().expect("dncal can be waited for") {
            break status;
        }
        if Instant::now() > deadline {
            child.kill().ok();
            child.wait().ok();
            panic!("dncal {args:?} still running after {} s", limit.as_secs());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output { status, stdout: stdout.join().expect("stdout reader"), stderr: stderr.join().expect("stderr reader") }
}

/// Runs `dncal args` in the current directory.
pub fn dncal_here(args: &[&str]) -> Output {
    dncal(args, Path::new("."))
}

/// Runs `dncal args` in `dir` and fails the test unless it succeeded.
pub fn succeed(args: &[&str], dir: &Path) -> Output {
    let out = dncal(args, dir);
    assert!(out.status.success(), "dncal {args:?}: exit {:?}: {}", out.status, String::from_utf8_lossy(&out.stderr));
    out
}

/// The command succeeded and printed JSON on stdout.
pub fn stdout_json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "exit {:?}\nstderr: {}", out.status, String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)))
}

/// The command failed with exactly `dncal: error: {line}`, exit code 1, nothing on stdout.
pub fn assert_error(out: &Output, line: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr, format!("dncal: error: {line}\n"));
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
    assert!(out.stdout.is_empty(), "stdout: {}", String::from_utf8_lossy(&out.stdout));
}

/// The command failed cleanly: exit 1, one error line naming `file` and containing
/// `words` (case-insensitive), no panic.
pub fn assert_clean_failure(out: &Output, file: &str, words: &str) {
    assert_one_line_error(out, 1, file, words);
}

/// A usage error (a value clap's types or the command refuse): exit code 2, one line
/// naming the option `flag` and saying `words`, no panic.
pub fn assert_usage_failure(out: &Output, flag: &str, words: &str) {
    assert_one_line_error(out, 2, flag, words);
}

fn assert_one_line_error(out: &Output, code: i32, names: &str, words: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "stderr: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert!(stderr.starts_with("dncal: error: ") && stderr.lines().count() == 1, "{stderr}");
    // The system's words, not Rust's (issue 44).
    assert!(!stderr.contains("(os error"), "{stderr}");
    assert!(stderr.contains(names), "{stderr:?} should name {names}");
    assert!(stderr.to_lowercase().contains(&words.to_lowercase()), "{stderr:?} should say {words:?}");
}

/// Files in `dir`, sorted, hidden ones included: to see that nothing was written.
pub fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

/// Every file and directory under `dir` (hidden ones included), with the bytes of files.
pub fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
    let mut all = BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            all.insert(path.clone(), None);
            all.extend(snapshot(&path));
        } else {
            all.insert(path.clone(), Some(std::fs::read(&path).unwrap()));
        }
    }
    all
}

/// The command failed with one line starting `dncal: error: {start}`, exit code 1, and
/// left `dir` exactly as `before`.
pub fn assert_failed_and_untouched(out: &Output, start: &str, dir: &Path, before: &BTreeMap<PathBuf, Option<Vec<u8>>>) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    let after = snapshot(dir);
    let changed: std::collections::BTreeSet<_> = after.keys().chain(before.keys()).filter(|k| after.get(*k) != before.get(*k)).collect();
    assert!(changed.is_empty(), "changed, added or removed: {changed:?}; stderr: {stderr}");
    assert!(stderr.starts_with(&format!("dncal: error: {start}")) && stderr.lines().count() == 1, "stderr: {stderr}");
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}");
}

/// The real CCD's EMVA 1288 descriptor in `../shared/data/emva1288-ccd-12bit/` (read in
/// place, never copied; `DNCAL_EMVA_DIR` names another folder), or `None` after one line
/// saying the test skips, where it is absent.
pub fn real_ccd_descriptor() -> Option<PathBuf> {
    let dir = std::env::var_os("DNCAL_EMVA_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/emva1288-ccd-12bit"));
    let descriptor = dir.join("EMVA1288_Data.txt");
    if descriptor.is_file() {
        Some(descriptor)
    } else {
        eprintln!("skipping: {} is absent", descriptor.display());
        None
    }
}

/// A histogram set `lut build` accepts: 4 ADCs of 12 bits, 1000 samples in every code.
pub fn flat_histograms(path: &Path) {
    write_histograms(path, &AdcHistograms { bit_depth: 12, counts: vec![vec![1000; 4096]; 4] }).unwrap();
}

/// A small linearity set (16 x 8 pixels, 12 levels) that `linearity` and `diagnose` accept.
pub fn small_linearity(dir: &Path, name: &str) {
    succeed(&["simulate", "linearity", "--levels", "12", "--frames", "4", "--roi", "16x8+0+0", "-o", name], dir);
}

// A small EMVA 1288 set (for the datasheet's tests).

/// A 16-bit grayscale PNG of `codes`.
pub fn write_png(path: &Path, side: u32, codes: &[u16]) {
    let file = std::fs::File::create(path).unwrap();
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), side, side);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let bytes: Vec<u8> = codes.iter().flat_map(|c| c.to_be_bytes()).collect();
    encoder.write_header().unwrap().write_image_data(&bytes).unwrap();
}

/// A 12-bit set of `levels` photon levels at one exposure, two frames each and a dark
/// pair, 32 x 32 pixels; `frame(level, photons, rng)` draws each frame's codes.
pub fn write_set(dir: &Path, photons: &[f64], mut frame: impl FnMut(usize, f64, &mut rand::rngs::StdRng) -> Vec<u16>) -> PathBuf {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(1288);
    let mut text = String::from("v 3.1\nn 12 32 32\n");
    let mut image = 0;
    for (level, &p) in std::iter::once(&0.0).chain(photons).enumerate() {
        text += &if p > 0.0 { format!("b 1000.0 {p}\n") } else { "d 1000.0\n".to_string() };
        for _ in 0..2 {
            let name = format!("img{image}.png");
            image += 1;
            write_png(&dir.join("images").join(&name), 32, &frame(level, p, &mut rng));
            text += &format!("i images\\{name}\n");
        }
    }
    let descriptor = dir.join("EMVA1288_Data.txt");
    std::fs::write(&descriptor, text).unwrap();
    descriptor
}

/// A linear camera: QE 0.5, K 0.25 DN/e-, offset 50 DN, 2 DN read noise; the top code
/// clips at 4095.
pub fn linear(_level: usize, photons: f64, rng: &mut rand::rngs::StdRng) -> Vec<u16> {
    let read = Normal::new(0.0, 2.0).unwrap();
    let light = Poisson::new(0.5 * photons).ok();
    (0..32 * 32)
        .map(|_| (50.0 + 0.25 * light.map_or(0.0, |l| l.sample(rng)) + read.sample(rng)).round().clamp(0.0, 4095.0) as u16)
        .collect()
}

pub fn photons(n: usize, top: f64) -> Vec<f64> {
    (1..=n).map(|i| top * i as f64 / n as f64).collect()
}
