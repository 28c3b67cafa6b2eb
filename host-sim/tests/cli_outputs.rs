//! Commands that write several files write all of them or none (issue 18: never lose a
//! file). Each case makes one target impossible to write (a directory where a file goes)
//! or the run fail after some outputs are known, beside outputs of an earlier run with
//! known bytes: the command must fail with exit code 1 and one line naming the path, and
//! leave every earlier output byte-identical, no new file and no temporary.

mod support;

use std::path::Path;
use std::time::{Duration, Instant};

use support::{assert_failed_and_untouched, dncal, flat_histograms, small_linearity, snapshot, spawn, succeed};

/// Files with known bytes, as an earlier run left them.
fn earlier(dir: &Path, names: &[&str]) {
    for n in names {
        let p = dir.join(n);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, format!("earlier {n}")).unwrap();
    }
}

const DIRECTORY: &str = "is a directory; an output file cannot replace it";

/// Ramps small enough to simulate in a second or two, enough counts to flatten.
const SMALL_RAMPS: [&str; 8] = ["--first-ramp", "20", "--last-ramp", "21", "--pixels-per-adc", "20000", "--frames-per-level", "1"];

#[test]
fn lut_build_replaces_neither_file_when_the_image_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    earlier(d, &["cal.fits"]);
    std::fs::create_dir(d.join("cal.bin")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["lut", "build", "h.fits", "-o", "cal"], d);
    assert_failed_and_untouched(&out, &format!("cal.bin: {DIRECTORY}\n"), d, &before);
}

#[test]
fn lut_export_writes_no_table_when_one_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    succeed(&["lut", "build", "h.fits", "-o", "cal"], d);
    earlier(d, &["kc_adc0.bin", "kc_adc1.bin"]);
    std::fs::create_dir(d.join("kc_adc3.bin")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["lut", "export", "cal.fits", "--format", "kcor", "-o", "kc"], d);
    assert_failed_and_untouched(&out, &format!("kc_adc3.bin: {DIRECTORY}\n"), d, &before);
}

#[test]
fn lut_import_replaces_neither_file_when_the_image_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    succeed(&["lut", "build", "h.fits", "-o", "cal"], d);
    succeed(&["lut", "export", "cal.fits", "--format", "kcor", "-o", "kc"], d);
    earlier(d, &["imp.fits"]);
    std::fs::create_dir(d.join("imp.bin")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["lut", "import", "--kcor", "kc", "-o", "imp"], d);
    assert_failed_and_untouched(&out, &format!("imp.bin: {DIRECTORY}\n"), d, &before);
}

#[test]
fn diagnose_replaces_no_report_file_when_the_model_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_linearity(d, "lin.fits");
    earlier(d, &["d/report.html", "d/residuals.png"]);
    std::fs::create_dir(d.join("d/model.toml")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["diagnose", "lin.fits", "-o", "d"], d);
    assert_failed_and_untouched(&out, &format!("d/model.toml: {DIRECTORY}\n"), d, &before);
}

#[test]
fn diagnose_of_several_inputs_leaves_no_report_when_a_later_input_fails() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_linearity(d, "good.fits");
    std::fs::write(d.join("bad.fits"), "not a FITS file\n").unwrap();
    let before = snapshot(d);
    let out = dncal(&["diagnose", "good.fits", "bad.fits", "-o", "two"], d);
    assert_failed_and_untouched(&out, "bad.fits: not a readable FITS file", d, &before);
    // And beside the reports of an earlier run, those are kept as they were.
    earlier(d, &["two/0/report.html", "two/0/residuals.png", "two/0/model.toml"]);
    let before = snapshot(d);
    let out = dncal(&["diagnose", "good.fits", "bad.fits", "-o", "two"], d);
    assert_failed_and_untouched(&out, "bad.fits: not a readable FITS file", d, &before);
}

#[test]
fn linearity_replaces_no_file_when_the_corrected_cube_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    small_linearity(d, "lin.fits");
    earlier(d, &["L/coefficients.fits", "L/linearity_rms.png"]);
    std::fs::create_dir(d.join("L/corrected.fits")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["linearity", "lin.fits", "-o", "L"], d);
    assert_failed_and_untouched(&out, &format!("L/corrected.fits: {DIRECTORY}\n"), d, &before);
}

#[test]
fn adc_keeps_the_earlier_histograms_when_the_luts_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    earlier(d, &["a/histograms.fits", "a/lut.fits"]);
    std::fs::create_dir(d.join("a/lut.bin")).unwrap();
    let before = snapshot(d);
    let mut args = vec!["adc", "-o", "a"];
    args.extend(SMALL_RAMPS);
    let out = dncal(&args, d);
    assert_failed_and_untouched(&out, &format!("a/lut.bin: {DIRECTORY}\n"), d, &before);
}

#[test]
fn adc_leaves_no_simulated_histograms_when_their_flattening_fails() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let before = snapshot(d);
    // Too few counts per code to flatten: found after the histograms are simulated.
    let out = dncal(&["adc", "--first-ramp", "2", "--last-ramp", "3", "--pixels-per-adc", "1000", "--frames-per-level", "1", "-o", "a"], d);
    assert_failed_and_untouched(&out, "a/histograms.fits: ADC 0: ", d, &before);
}

/// Two sparse ramps (levels 200 codes apart): the shared recipe's spline through the
/// ADCs' mean histogram dips below zero; the refusal names the shared fit and the way
/// out, and nothing is written.
#[test]
fn a_ramp_too_sparse_for_the_shared_illumination_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let before = snapshot(d);
    let mut args = vec!["adc", "-o", "a"];
    args.extend(SMALL_RAMPS);
    let out = dncal(&args, d);
    assert_failed_and_untouched(&out, "a/histograms.fits: the illumination shared by the ADCs (fitted to their mean histogram): the spline is ", d, &before);
    assert!(String::from_utf8_lossy(&out.stderr).contains("--recipe paper"));
}

#[test]
fn demo_replaces_no_file_when_one_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    earlier(d, &["dm/histograms.fits", "dm/lut.fits"]);
    std::fs::create_dir(d.join("dm/lut.bin")).unwrap();
    let before = snapshot(d);
    let mut args = vec!["demo", "--frames", "1", "-o", "dm"];
    args.extend(SMALL_RAMPS);
    let out = dncal(&args, d);
    assert_failed_and_untouched(&out, &format!("dm/lut.bin: {DIRECTORY}\n"), d, &before);
}

#[test]
fn kcor_model_replaces_neither_figure_when_one_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    earlier(d, &["k/kcor_raw.png"]);
    std::fs::create_dir(d.join("k/kcor_lut.png")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["kcor-model", "--steps", "5", "-o", "k"], d);
    assert_failed_and_untouched(&out, &format!("k/kcor_lut.png: {DIRECTORY}\n"), d, &before);
}

#[test]
fn fpga_size_writes_no_readmemh_file_when_one_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    succeed(&["lut", "build", "h.fits", "-o", "cal"], d);
    earlier(d, &["hdl/lut_adc0.hex"]);
    std::fs::create_dir(d.join("hdl/lut_adc3.hex")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["fpga-size", "--size", "64", "--lut", "cal.fits", "-o", "hdl"], d);
    assert_failed_and_untouched(&out, &format!("hdl/lut_adc3.hex: {DIRECTORY}\n"), d, &before);
}

#[test]
fn emva_replaces_no_datasheet_file_when_one_cannot_be_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let descriptor = support::write_set(&d.join("set"), &support::photons(20, 20000.0), support::linear);
    // The set is characterizable: the same run without the obstacle writes the page, the
    // JSON and three figures (no spatial or dark-current series: no spectrograms, no
    // defect histograms).
    succeed(&["emva", descriptor.to_str().unwrap(), "-o", "ok"], d);
    let mut written: Vec<_> = std::fs::read_dir(d.join("ok")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    written.sort();
    assert_eq!(written, ["datasheet.html", "datasheet.json", "linearity.png", "photon_transfer.png", "snr.png"]);
    earlier(d, &["ds/datasheet.json", "ds/photon_transfer.png"]);
    std::fs::create_dir(d.join("ds/snr.png")).unwrap();
    let before = snapshot(d);
    let out = dncal(&["emva", descriptor.to_str().unwrap(), "-o", "ds"], d);
    assert_failed_and_untouched(&out, &format!("ds/snr.png: {DIRECTORY}\n"), d, &before);
}

/// Hidden files in `dir`: temporaries and backups.
fn hidden(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir).map_or_else(|_| Vec::new(), |r| r.map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).filter(|n| n.starts_with('.')).collect())
}

#[cfg(unix)]
#[test]
fn temporaries_of_a_killed_run_are_removed_by_the_next_run_for_the_same_targets() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Two sparse ramps: their comb of levels 200 codes apart is more than the shared
    // recipe's 20-point spline follows (it refuses them, naming the shared fit); the
    // paper's per-ADC recipe flattens them, and the test is about the outputs.
    let mut args = vec!["adc", "-o", "a", "--recipe", "paper"];
    args.extend(SMALL_RAMPS);
    let mut child = spawn(&args, d);
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut left = Vec::new();
    while left.is_empty() && Instant::now() < deadline && child.try_wait().unwrap().is_none() {
        left = hidden(&d.join("a"));
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().ok();
    child.wait().unwrap();
    let left = hidden(&d.join("a"));
    assert!(!left.is_empty(), "the run was killed while writing and left its temporaries");
    succeed(&args, d);
    assert_eq!(hidden(&d.join("a")), Vec::<String>::new(), "left by the killed run: {left:?}");
}

/// Issue 43: an output that is the command's own input (by name, through a link, or one
/// file of a set written over one of the inputs) is refused before any work, exit 2, the
/// input byte for byte as it was and nothing written beside it. Each was exit 0 with the
/// input replaced.
#[test]
fn no_output_replaces_its_own_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    succeed(&["lut", "build", "h.fits", "-o", "cal"], d);
    succeed(&["lut", "export", "cal.fits", "--format", "kcor", "-o", "k"], d);
    std::fs::write(d.join("c.toml"), "gain_e_per_dn = 30.0\n").unwrap();
    std::os::unix::fs::symlink("h.fits", d.join("link.fits")).unwrap();
    let same = |output: &str, input: &str| format!("{output}: is the input {input} (or a link to it); writing it would replace that input: name another output\n");
    let cases: [(&[&str], String); 8] = [
        (&["lut", "build", "h.fits", "-o", "h"], same("h.fits", "h.fits")),
        (&["lut", "build", "h.fits", "-o", "h.fits"], same("h.fits", "h.fits")),
        (&["lut", "build", "link.fits", "-o", "h"], same("h.fits", "link.fits")),
        (&["lut", "import", "--kcor", "k_adc{adc}.bin", "-o", "k_adc0"], same("k_adc0.bin", "k_adc0.bin")),
        (&["simulate", "linearity", "--config", "c.toml", "--roi", "8x8+0+0", "--frames", "4", "-o", "c.toml"], same("c.toml", "c.toml")),
        (&["lut", "export", "k_adc0.bin", "--format", "kcor", "-o", "k"], same("k_adc0.bin", "k_adc0.bin")),
        (&["lut", "convert", "cal.fits", "--to", "fits", "-o", "cal.fits"], same("cal.fits", "cal.fits")),
        (&["lut", "convert", "cal.bin", "--to", "image", "-o", "cal"], same("cal.bin", "cal.bin")),
    ];
    for (args, message) in cases {
        let before = snapshot(d);
        let out = support::dncal_prompt(args, d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(stderr, format!("dncal: error: {message}"), "{args:?}");
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert_eq!(snapshot(d), before, "{args:?} changed the directory");
    }
}

/// Two histogram sets in `dir` whose LUTs differ: `h1.fits` (flat), `h2.fits` (sloped).
fn two_histogram_sets(dir: &Path) {
    use dncal_host::formats::fits::{write_histograms, AdcHistograms};
    flat_histograms(&dir.join("h1.fits"));
    let sloped: Vec<Vec<u64>> = (0..4).map(|a| (0..4096u64).map(|k| 800 + (k * 7 + a * 13) % 400).collect()).collect();
    write_histograms(&dir.join("h2.fits"), &AdcHistograms { bit_depth: 12, counts: sloped }).unwrap();
}

/// The LUT tables in `path`, any format.
fn tables(path: &Path) -> Vec<Vec<u32>> {
    dncal_host::formats::lut::read(path).unwrap().1.tables
}

/// Issue 43: two `lut build` runs with different inputs into one `-o`, 200 times. Before,
/// 4 of 200 left `out.fits` from one run and `out.bin` from the other, both exit 0. Now
/// each run publishes its whole set or is refused at once (exit 1, the file and the
/// other run named); the two files always hold one LUT, one of the two runs', and no
/// temporary, backup, journal or lock is left.
#[test]
fn two_runs_into_one_output_set_never_mix_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    two_histogram_sets(d);
    succeed(&["lut", "build", "h1.fits", "-o", "one"], d);
    succeed(&["lut", "build", "h2.fits", "-o", "two"], d);
    let (one, two) = (tables(&d.join("one.fits")), tables(&d.join("two.fits")));
    assert_ne!(one, two);
    let (mut both, mut refused) = (0, 0);
    for trial in 0..200 {
        let runs = [spawn(&["lut", "build", "h1.fits", "-o", "out", "-q"], d), spawn(&["lut", "build", "h2.fits", "-o", "out", "-q"], d)];
        let outs: Vec<std::process::Output> = runs.into_iter().map(|c| c.wait_with_output().unwrap()).collect();
        let ok = outs.iter().filter(|o| o.status.success()).count();
        for o in outs.iter().filter(|o| !o.status.success()) {
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert!(stderr.starts_with("dncal: error: out.") && stderr.contains("another dncal run") && stderr.contains("is writing this output now") && o.status.code() == Some(1), "trial {trial}: {stderr}");
            refused += 1;
        }
        assert!(ok >= 1, "trial {trial}: neither run published");
        both += usize::from(ok == 2);
        let (fits, image) = (tables(&d.join("out.fits")), tables(&d.join("out.bin")));
        assert_eq!(fits, image, "trial {trial}: out.fits and out.bin hold different LUTs");
        assert!(fits == one || fits == two, "trial {trial}: a LUT neither run built");
        let litter: Vec<String> = support::listing(d).iter().filter_map(|p| p.file_name()?.to_str().filter(|n| n.starts_with('.')).map(String::from)).collect();
        assert!(litter.is_empty(), "trial {trial}: left {litter:?}");
    }
    eprintln!("two runs into one set, 200 trials: both published one after the other {both} times, one refused {refused} times");
}

/// Issue 43: a run killed while it publishes (here at random moments of many runs) leaves
/// at worst a journal; the next run that names a file of the set, even one that then
/// fails (a missing input), finishes it first: `out.fits` and `out.bin` hold one LUT.
#[cfg(unix)]
#[test]
fn a_killed_run_never_leaves_a_mixed_set_for_the_next() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    two_histogram_sets(d);
    succeed(&["lut", "build", "h1.fits", "-o", "out"], d);
    let (mut killed, mut journals) = (0, 0);
    for trial in 0..60u64 {
        let input = if trial % 2 == 0 { "h2.fits" } else { "h1.fits" };
        let mut child = spawn(&["lut", "build", input, "-o", "out", "-q"], d);
        // Somewhere in its run (it takes some tens of milliseconds).
        std::thread::sleep(Duration::from_micros(500 * (trial * 37 % 97)));
        killed += usize::from(child.try_wait().unwrap().is_none());
        child.kill().ok();
        child.wait().unwrap();
        journals += support::listing(d).iter().filter(|p| p.file_name().unwrap().to_string_lossy().starts_with(".dncal-journal.")).count();
        let out = dncal(&["lut", "build", "missing.fits", "-o", "out"], d);
        assert_eq!(out.status.code(), Some(1));
        assert_eq!(tables(&d.join("out.fits")), tables(&d.join("out.bin")), "trial {trial}: a mixed set");
        let litter: Vec<String> = support::listing(d).iter().filter_map(|p| p.file_name()?.to_str().filter(|n| n.starts_with(".dncal-journal") || n.ends_with(".dncal-old")).map(String::from)).collect();
        assert!(litter.is_empty(), "trial {trial}: left {litter:?}");
    }
    eprintln!("killed {killed} of 60 runs mid-way; {journals} left a journal the next run finished");
}

/// Issue 43: the demo checks every step's files, at any depth, before its first step: a
/// directory where `diagnose/model.toml` goes, or a file where the `linearity` folder
/// goes, was refused after 42 s of work. Now at once (with the default ramps and frames,
/// whose first step alone takes longer than the 20 s allowed here), the directory as it
/// was.
#[test]
fn the_demo_refuses_a_clash_deep_in_its_outputs_before_any_work() {
    for (clash, is_dir, message) in [("dm/diagnose/model.toml", true, "dm/diagnose/model.toml: is a directory; an output file cannot replace it\n"), ("dm/linearity", false, "dm/linearity: is not a directory; outputs go into it\n")] {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let p = d.join(clash);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        if is_dir {
            std::fs::create_dir(&p).unwrap();
        } else {
            std::fs::write(&p, "a file").unwrap();
        }
        let before = snapshot(d);
        let start = Instant::now();
        let out = support::dncal_prompt(&["demo", "-o", "dm"], d);
        assert_failed_and_untouched(&out, message, d, &before);
        assert!(start.elapsed() < Duration::from_secs(20), "refused after {:?}", start.elapsed());
    }
}

/// Issue 43: `--json` into a stdout that cannot take it (`/dev/full`) fails before the
/// outputs are committed: the earlier files stay, none is added.
#[cfg(target_os = "linux")]
#[test]
fn a_report_that_cannot_be_written_leaves_no_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    flat_histograms(&d.join("h.fits"));
    earlier(d, &["cal.fits"]);
    let before = snapshot(d);
    for json in [true, false] {
        let mut args = vec!["lut", "build", "h.fits", "-o", "cal"];
        if json {
            args.push("--json");
        }
        let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_dncal")).args(&args).current_dir(d).stdout(full).stderr(std::process::Stdio::piped()).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.starts_with("dncal: error: stdout: ") && stderr.lines().count() == 1, "{stderr}");
        assert_eq!(out.status.code(), Some(1));
        assert_eq!(snapshot(d), before, "--json {json}: outputs left");
    }
}

/// The subcommands `dncal --help` lists, at every depth, that take no subcommand of their
/// own (`simulate histograms`, `adc`, ...).
fn leaf_commands(path: &mut Vec<String>, leaves: &mut Vec<String>) {
    let mut args: Vec<&str> = path.iter().map(String::as_str).collect();
    args.push("--help");
    let help = String::from_utf8(succeed(&args, Path::new(".")).stdout).unwrap();
    // Each command a line of its own: its name indented by two spaces, then what it does.
    let subs: Vec<String> = help
        .split("\nCommands:\n")
        .nth(1)
        .map(|rest| rest.lines().take_while(|l| !l.trim().is_empty()).filter(|l| l.starts_with("  ") && !l.starts_with("   ")).filter_map(|l| l.split_whitespace().next()).filter(|n| *n != "help").map(String::from).collect())
        .unwrap_or_default();
    if subs.is_empty() {
        leaves.push(path.join(" "));
    }
    for s in subs {
        path.push(s);
        leaf_commands(path, leaves);
        path.pop();
    }
}

/// A 12-bit EMVA 1288 set of `side` x `side` pixels of a linear camera (QE 0.5, K 0.25
/// DN/e-, offset 50 DN, 2 DN read noise, shot noise as a normal law): a temporal pair
/// dark and at each of `levels` photon levels up to 16000 photons, and a spatial series of
/// `spatial` frames dark and at 8000 photons (the datasheet's nonuniformities,
/// spectrograms and defect histograms).
fn emva_set(dir: &Path, side: u32, levels: usize, spatial: usize) {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(56);
    let mut text = format!("v 3.1\nn 12 {side} {side}\n");
    let temporal = std::iter::once(0.0).chain(support::photons(levels, 16000.0)).map(|p| (p, 2));
    let mut image = 0;
    for (p, frames) in temporal.chain([(0.0, spatial), (8000.0, spatial)]) {
        text += &if p > 0.0 { format!("b 1000.0 {p}\n") } else { "d 1000.0\n".to_string() };
        let electrons: f64 = 0.5 * p;
        let noise = Normal::new(0.0, (4.0 + 0.0625 * electrons).sqrt()).unwrap();
        for _ in 0..frames {
            let codes: Vec<u16> = (0..side * side).map(|_| (50.0 + 0.25 * electrons + noise.sample(&mut rng)).round().clamp(0.0, 4095.0) as u16).collect();
            let name = format!("img{image}.png");
            image += 1;
            support::write_png(&dir.join("images").join(&name), side, &codes);
            text += &format!("i images\\{name}\n");
        }
    }
    std::fs::write(dir.join("EMVA1288_Data.txt"), text).unwrap();
}

/// Every file under `dir`, relative to it, sorted.
fn files_under(dir: &Path) -> Vec<String> {
    let mut all: Vec<String> = support::snapshot(dir).into_iter().filter(|(_, bytes)| bytes.is_some()).map(|(p, _)| p.strip_prefix(dir).unwrap().to_string_lossy().into_owned()).collect();
    all.sort();
    all
}

/// One command that writes files, as [`every_command_refuses_an_output_it_cannot_write_before_any_work`] runs it.
struct Case {
    /// The subcommand, as `dncal --help` names it.
    command: &'static str,
    /// Its arguments (run in a directory of its own; the inputs are in `../in`).
    args: Vec<&'static str>,
    /// What `-o` names, and how: a file, a file prefix (`lut`) or a directory.
    out: (&'static str, Out),
    /// It computes for seconds: a refusal must take under a fifth of its run. (Otherwise,
    /// a format's conversion or the manual pages, under a second.)
    computes: bool,
    /// Whether to run one of its files named only once found (a diagnosis's finding's
    /// figure, `finding-K-EFFECT.png`): refused then, after the work. (Not the demo's: each
    /// would be a whole demo.)
    run_a_late_one: bool,
}

#[derive(Clone, Copy, PartialEq)]
enum Out {
    File,
    Prefix,
    Dir,
}

/// A file named only once the analysis finds it: a diagnosis's finding's figure.
fn named_when_found(file: &str) -> bool {
    Path::new(file).file_name().unwrap().to_string_lossy().starts_with("finding-")
}

/// Issue 56: `simulate histograms -o DIR/x.fits` with `x.fits` a directory was refused
/// after 5-12 s of simulation. Every command that writes files (the list is `dncal
/// --help`'s, and a command it adds fails this test until it has a case here or is
/// listed as writing none) is run once as it is (timed, its files listed), then once with
/// a directory at each file it wrote (and a file where its `-o` directory goes, a
/// directory at a `lut` command's prefix): each is refused with exit 1 and one line
/// naming the path, nothing left, in under a fifth of the command's own run (its inputs
/// chosen so that it computes for seconds; a command with nothing to compute, a format's
/// conversion or the manual pages, in under a second). The one exception, a file named
/// only once the analysis finds it, is still refused cleanly, after the work. Before,
/// `simulate histograms`, `emva -o`, `quantization --figure` and `adc`'s per-ADC figures
/// were refused after their work.
#[test]
fn every_command_refuses_an_output_it_cannot_write_before_any_work() {
    // Reports on stdout only.
    let writes_none = ["lut inspect", "stream", "bench", "firmware-check", "completions"];
    let root = tempfile::tempdir().unwrap();
    let inputs = root.path().join("in");
    std::fs::create_dir(&inputs).unwrap();
    // (768 x 768 ran 0.5-0.7 s on an idle 2-core machine, under the case's 1 s floor.)
    emva_set(&inputs.join("emva"), 1024, 50, 32);
    // A small linearity set for `diagnose` (the linearity case's 384 x 384 would take it
    // seconds more; 64 x 64 with the histograms took 0.8 s once its fits were on the stack,
    // under the 1 s floor).
    succeed(&["simulate", "linearity", "--roi", "192x192+416+416", "--frames", "32", "-o", "small.fits"], &inputs);
    // In the order of their inputs: each case's outputs become the inputs of those after it.
    let cases = [
        Case { command: "simulate histograms", args: vec!["simulate", "histograms", "-o", "h.fits"], out: ("h.fits", Out::File), computes: true, run_a_late_one: false },
        Case { command: "simulate linearity", args: vec!["simulate", "linearity", "--roi", "384x384+320+320", "--frames", "32", "-o", "lin.fits"], out: ("lin.fits", Out::File), computes: true, run_a_late_one: false },
        Case { command: "lut build", args: vec!["lut", "build", "../in/h.fits", "-o", "cal"], out: ("cal", Out::Prefix), computes: false, run_a_late_one: false },
        Case { command: "lut export", args: vec!["lut", "export", "../in/cal.fits", "--format", "kcor", "-o", "kc"], out: ("kc", Out::Prefix), computes: false, run_a_late_one: false },
        Case { command: "lut import", args: vec!["lut", "import", "--kcor", "../in/kc", "-o", "imp"], out: ("imp", Out::Prefix), computes: false, run_a_late_one: false },
        Case { command: "lut convert", args: vec!["lut", "convert", "../in/cal.fits", "--to", "image", "-o", "conv"], out: ("conv", Out::Prefix), computes: false, run_a_late_one: false },
        Case { command: "adc", args: vec!["adc", "-o", "a"], out: ("a", Out::Dir), computes: true, run_a_late_one: false },
        Case { command: "adc", args: vec!["adc", "--hist", "../in/h.fits", "-o", "a"], out: ("a", Out::Dir), computes: false, run_a_late_one: false },
        Case { command: "adc", args: vec!["adc", "--from-luts", "../in/kc", "-o", "a"], out: ("a", Out::Dir), computes: true, run_a_late_one: false },
        Case { command: "kcor-model", args: vec!["kcor-model", "--steps", "80", "-o", "k"], out: ("k", Out::Dir), computes: true, run_a_late_one: false },
        Case { command: "linearity", args: vec!["linearity", "../in/lin.fits", "--held-out", "2,3,4,5,6", "-o", "L"], out: ("L", Out::Dir), computes: true, run_a_late_one: false },
        Case { command: "diagnose", args: vec!["diagnose", "../in/h.fits", "../in/small.fits", "-o", "d"], out: ("d", Out::Dir), computes: true, run_a_late_one: true },
        Case { command: "emva", args: vec!["emva", "../in/emva/EMVA1288_Data.txt", "-o", "ds"], out: ("ds", Out::Dir), computes: true, run_a_late_one: false },
        Case { command: "fpga-size", args: vec!["fpga-size", "--size", "3072", "--lut", "../in/cal.fits", "-o", "hdl"], out: ("hdl", Out::Dir), computes: true, run_a_late_one: false },
        Case { command: "quantization", args: vec!["quantization", "--sigma", "0.3", "--samples", "200000000", "--figure", "q.png"], out: ("q.png", Out::File), computes: true, run_a_late_one: false },
        Case { command: "man", args: vec!["man", "-o", "pages"], out: ("pages", Out::Dir), computes: false, run_a_late_one: false },
        Case { command: "demo", args: vec!["demo", "--frames", "1", "-o", "dm"], out: ("dm", Out::Dir), computes: true, run_a_late_one: false },
    ];
    let mut leaves = Vec::new();
    leaf_commands(&mut Vec::new(), &mut leaves);
    let mut covered: Vec<&str> = cases.iter().map(|c| c.command).chain(writes_none).collect();
    covered.sort();
    covered.dedup();
    leaves.sort();
    assert_eq!(leaves, covered, "every subcommand needs a case here (or, writing no file, a place in writes_none)");
    for c in writes_none {
        let mut args: Vec<&str> = c.split(' ').collect();
        args.push("--help");
        let help = String::from_utf8(succeed(&args, Path::new(".")).stdout).unwrap();
        assert!(!help.contains("--out") && !help.contains("--figure"), "{c} has an output option: it needs a case");
    }
    let mut table = Vec::new();
    for (n, case) in cases.iter().enumerate() {
        let d = root.path().join(format!("case{n}"));
        std::fs::create_dir(&d).unwrap();
        let start = Instant::now();
        succeed(&case.args, &d);
        let normal = start.elapsed();
        let written = files_under(&d);
        assert!(!written.is_empty(), "{:?} wrote nothing", case.args);
        // Kept as the inputs of later cases; the directory emptied for the refusals.
        for f in &written {
            let to = inputs.join(f);
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            std::fs::rename(d.join(f), to).unwrap();
        }
        std::fs::remove_dir_all(&d).unwrap();
        std::fs::create_dir(&d).unwrap();
        if case.computes {
            assert!(normal > Duration::from_secs(1), "{:?} took {normal:?}: too little work to tell a refusal before it from one after", case.args);
        }
        let limit = if case.computes { normal / 5 } else { Duration::from_secs(1) };
        // Each obstacle: the path made a directory (or, `-o`'s directory, a file), and the
        // start of the error line.
        let (out, kind) = case.out;
        let mut obstacles: Vec<(String, bool, String)> = written.iter().filter(|f| !named_when_found(f)).map(|f| (f.clone(), true, format!("{f}: {DIRECTORY}\n"))).collect();
        match kind {
            Out::Dir => obstacles.push((out.into(), false, format!("{out}: is not a directory; outputs go into it\n"))),
            Out::Prefix => obstacles.push((out.into(), true, format!("{out}: names a directory; -o takes a file prefix OUT"))),
            Out::File => assert_eq!(written, [out], "{:?}", case.args),
        }
        let mut slowest = Duration::ZERO;
        for (path, as_dir, message) in &obstacles {
            let p = d.join(path);
            std::fs::create_dir_all(if *as_dir { &p } else { p.parent().unwrap() }).unwrap();
            if !*as_dir {
                std::fs::write(&p, "a file").unwrap();
            }
            let before = snapshot(&d);
            let start = Instant::now();
            let refused = support::dncal_prompt(&case.args, &d);
            let took = start.elapsed();
            assert_failed_and_untouched(&refused, message, &d, &before);
            assert!(took < limit, "{:?} with {path} in the way: refused after {took:?}, its run takes {normal:?}", case.args);
            slowest = slowest.max(took);
            std::fs::remove_dir_all(&d).unwrap();
            std::fs::create_dir(&d).unwrap();
        }
        let late: Vec<&String> = written.iter().filter(|f| named_when_found(f)).collect();
        if let (true, Some(f)) = (case.run_a_late_one, late.first()) {
            std::fs::create_dir_all(d.join(f)).unwrap();
            let before = snapshot(&d);
            let refused = dncal(&case.args, &d);
            assert_failed_and_untouched(&refused, &format!("{f}: {DIRECTORY}\n"), &d, &before);
            std::fs::remove_dir_all(&d).unwrap();
            std::fs::create_dir(&d).unwrap();
        }
        table.push(format!("| `{}` | {:.2} s | {} | {:.3} s | {} |", case.args.join(" "), normal.as_secs_f64(), obstacles.len(), slowest.as_secs_f64(), late.len()));
    }
    eprintln!("| command | normal run | refusals | slowest refusal | files named when found |\n|---|---|---|---|---|\n{}", table.join("\n"));
}
