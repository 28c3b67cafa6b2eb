//! The IEEE 1241 histogram test of `dncal adc --density ramp|sine` against two oracles we
//! did not write in Rust, on sets they wrote:
//! - `scripts/ieee1241_oracle.py`: a numpy implementation of the standard's definitions
//!   and an independent SAR simulator (unit capacitors with mismatch, planted weight
//!   errors, Poisson counts), written apart from the Rust code;
//! - `adctoolbox` (PyPI 0.9.1, MIT): a third party's SAR capacitor-mismatch model and its
//!   own ramp histogram analysis (`compute_inl_from_ramp`).
//!
//! The venv (`scripts/adctoolbox-venv.sh`) is made when missing. Without Python these
//! tests fail; they do not skip.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn venv_python() -> PathBuf {
    let out = Command::new(root().join("scripts/adctoolbox-venv.sh")).output().expect("scripts/adctoolbox-venv.sh runs");
    assert!(out.status.success(), "adctoolbox-venv.sh failed:\n{}", String::from_utf8_lossy(&out.stderr));
    PathBuf::from(String::from_utf8_lossy(&out.stdout).lines().last().expect("the venv's python path").trim())
}

fn oracle(py: &Path, args: &[&str]) {
    let out = Command::new(py).arg(root().join("scripts/ieee1241_oracle.py")).args(args).output().unwrap();
    assert!(out.status.success(), "ieee1241_oracle.py {args:?}:\n{}", String::from_utf8_lossy(&out.stderr));
}

fn read_json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// `dncal adc --hist HIST --density DENSITY --json`: its per-ADC `linearity`.
fn dncal_linearity(hist: &Path, density: &str, dir: &Path) -> Vec<Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_dncal"))
        .args(["adc", "--hist"])
        .arg(hist)
        .args(["--density", density, "--json", "-o"])
        .arg(dir.join(format!("adc-{density}")))
        .output()
        .unwrap();
    assert!(out.status.success(), "dncal adc: {}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    v["linearity"].as_array().unwrap().clone()
}

fn codes(v: &Value) -> Vec<u64> {
    v.as_array().unwrap().iter().map(|c| if c.is_u64() { c.as_u64().unwrap() } else { c["code"].as_u64().unwrap() }).collect()
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// The `n` largest `|DNL|` values, largest first.
fn top_abs(dnl: &[f64], n: usize) -> Vec<f64> {
    let mut v: Vec<f64> = dnl.iter().map(|d| d.abs()).collect();
    v.sort_by(|a, b| b.total_cmp(a));
    v.truncate(n);
    v
}

/// Ours against the oracle's analysis of one ADC: the same analysed range, DNL and INL
/// code by code, missing codes, and the widest codes (by value: equal counts tie).
fn agree(ours: &Value, theirs: &Value, tolerance: f64, what: &str) {
    assert_eq!((ours["first_code"].as_u64(), ours["last_code"].as_u64()), (theirs["first_code"].as_u64(), theirs["last_code"].as_u64()), "{what}: analysed range");
    let (a, b) = (floats(&ours["dnl_lsb"]), floats(&theirs["dnl"]));
    assert_eq!(a.len(), b.len(), "{what}");
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    assert!(worst < tolerance, "{what}: DNL differs by up to {worst}");
    let (a, b) = (floats(&ours["inl_endpoint_lsb"]), floats(&theirs["inl_endpoint"]));
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    assert!(worst < 100.0 * tolerance, "{what}: end-point INL differs by up to {worst}");
    if theirs["inl_bestfit"].is_array() {
        let (a, b) = (floats(&ours["inl_bestfit_lsb"]), floats(&theirs["inl_bestfit"]));
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(a.len() == b.len() && worst < 100.0 * tolerance, "{what}: best-fit INL differs by up to {worst}");
    }
    assert_eq!(codes(&ours["missing"]), codes(&theirs["missing_codes"]), "{what}: missing codes");
    let widest: Vec<f64> = theirs["widest_codes"].as_array().unwrap().iter().map(|p| p[1].as_f64().unwrap()).collect();
    let our_widest: Vec<f64> = {
        let mut v = floats(&ours["dnl_lsb"]);
        v.sort_by(|x, y| y.total_cmp(x));
        v.truncate(widest.len());
        v
    };
    assert!(widest.iter().zip(&our_widest).all(|(x, y)| (x - y).abs() < tolerance), "{what}: widest {widest:?} vs ours {our_widest:?}");
    // Our worst list is the codes of largest |DNL|, with the oracle's values.
    let theirs_dnl = floats(&theirs["dnl"]);
    let first = ours["first_code"].as_u64().unwrap();
    for c in ours["worst"].as_array().unwrap() {
        let k = c["code"].as_u64().unwrap();
        assert!((c["dnl_lsb"].as_f64().unwrap() - theirs_dnl[(k - first) as usize]).abs() < tolerance, "{what}: worst code {k}");
    }
    let listed: Vec<f64> = ours["worst"].as_array().unwrap().iter().map(|c| c["dnl_lsb"].as_f64().unwrap().abs()).collect();
    assert!(listed.iter().zip(top_abs(&theirs_dnl, listed.len())).all(|(x, y)| (x - y).abs() < tolerance), "{what}: worst codes are not the largest |DNL|");
}

#[test]
fn ramp_and_sine_agree_with_the_numpy_oracle_and_the_planted_truth() {
    let py = venv_python();
    let dir = tempfile::tempdir().unwrap();
    for input in ["ramp", "sine"] {
        for seed in [1u64, 2] {
            // 12 bits, 400 counts a code, four ADCs: 0 with bit 10 1.6 LSB short (codes
            // 1023 and 3071 missing), 1 with bit 9 1.5 LSB long, 2 with random unit-capacitor
            // mismatch, 3 ideal.
            let hist = dir.path().join(format!("{input}{seed}.fits"));
            let truth = dir.path().join(format!("{input}{seed}-truth.json"));
            let s = seed.to_string();
            oracle(&py, &["simulate-sar", "--bits", "12", "--adcs", "4", "--counts-per-code", "400", "--input", input, "--seed", &s, "--mismatch", "0.004",
                "--plant-weight", "0:10:-1.6", "--plant-weight", "1:9:1.5", "--ideal-adc", "3", "--out", hist.to_str().unwrap(), "--truth", truth.to_str().unwrap()]);
            let result = dir.path().join(format!("{input}{seed}-oracle.json"));
            oracle(&py, &["analyse", hist.to_str().unwrap(), "--input", input, "--out", result.to_str().unwrap()]);
            let (truth, theirs) = (read_json(&truth), read_json(&result));
            let ours = dncal_linearity(&hist, input, dir.path());
            for adc in 0..4 {
                let what = format!("{input} seed {seed} ADC {adc}");
                agree(&ours[adc], &theirs["adcs"][adc], 1e-9, &what);
                // The truth's missing codes are found, and nothing else is missing.
                assert_eq!(codes(&ours[adc]["missing"]), codes(&truth["adcs"][adc]["missing_codes"]), "{what}");
            }
            assert_eq!(codes(&ours[0]["missing"]), vec![1023, 3071], "{input} seed {seed}");
            // Bit 9 long by 1.5 LSB: the four codes below its carry are named wide, and
            // the SAR fit attributes the error to bit 9.
            let wide: Vec<u64> = ours[1]["named"].as_array().unwrap().iter().filter(|c| c["kind"] == "wide").map(|c| c["code"].as_u64().unwrap()).collect();
            assert_eq!(wide, vec![511, 1535, 2559, 3583], "{input} seed {seed}");
            let sar = &ours[1]["structure"]["sar"];
            let bit9 = sar["carries"].as_array().unwrap().iter().find(|c| c["bit"] == 9).unwrap();
            // (The unit capacitors' mismatch, 0.4% each, moves bit 9 against the bits below
            // it by 0.13 LSB rms: 0.4 LSB is 3 sigma of that. Codes 1023 and 3071 are
            // missing on this ADC too, censoring bit 10.)
            let (e, sigma) = (bit9["weight_error_lsb"].as_f64().unwrap(), bit9["weight_sigma_lsb"].as_f64().unwrap());
            assert!(sar["explains"].as_bool().unwrap() && (e - 1.5).abs() < 4.0 * sigma + 0.4, "{input} seed {seed}: {sar}");
            let named: Vec<u64> = sar["carries"].as_array().unwrap().iter().filter(|c| c["weight_error_lsb"].as_f64().unwrap() != 0.0).map(|c| c["bit"].as_u64().unwrap()).collect();
            assert_eq!(named, vec![9], "{input} seed {seed}: {sar}");
            assert!(ours[3]["named"].as_array().unwrap().is_empty(), "{input} seed {seed}: the ideal ADC: {}", ours[3]["named"]);
        }
    }
}

#[test]
fn a_set_written_by_adctoolbox_is_read_as_adctoolbox_reads_it() {
    let py = venv_python();
    let dir = tempfile::tempdir().unwrap();
    let hist = dir.path().join("atb.fits");
    let truth = dir.path().join("atb-truth.json");
    // adctoolbox's own SAR converter (sar_convert with sar_apply_cap_mismatch) on a ramp,
    // 400 samples a code; ADC 0 with bit 10 short by 1.2 LSB, ADC 3 ideal.
    oracle(&py, &["simulate-sar", "--engine", "adctoolbox", "--bits", "12", "--adcs", "4", "--counts-per-code", "400", "--input", "ramp", "--seed", "5", "--mismatch", "0.02",
        "--plant-weight", "0:10:-1.2", "--ideal-adc", "3", "--out", hist.to_str().unwrap(), "--truth", truth.to_str().unwrap()]);
    let result = dir.path().join("atb-result.json");
    oracle(&py, &["analyse", hist.to_str().unwrap(), "--input", "ramp", "--engine", "adctoolbox", "--out", result.to_str().unwrap()]);
    let (truth, theirs) = (read_json(&truth), read_json(&result));
    let ours = dncal_linearity(&hist, "ramp", dir.path());
    for adc in 0..4 {
        let what = format!("adctoolbox ADC {adc}");
        // adctoolbox clips DNL at -1 and its end-point INL is the running DNL: the same
        // definitions as ours on a ramp.
        agree(&ours[adc], &theirs["adcs"][adc], 1e-9, &what);
        assert_eq!(codes(&ours[adc]["missing"]), codes(&truth["adcs"][adc]["missing_codes"]), "{what}");
    }
    assert!(!codes(&ours[0]["missing"]).is_empty(), "the planted bit-10 error leaves missing codes");
    // `diagnose` of the same set: every ADC with missing codes is named `adc-dnl`, its
    // missing codes listed by number in the detail; the ideal ADC is not named.
    let rep = dir.path().join("rep");
    let out = Command::new(env!("CARGO_BIN_EXE_dncal")).arg("diagnose").arg(&hist).arg("--json").arg("-o").arg(&rep).output().unwrap();
    assert!(out.status.success(), "dncal diagnose: {}", String::from_utf8_lossy(&out.stderr));
    let d: Value = serde_json::from_slice(&out.stdout).unwrap();
    let findings = d["findings"].as_array().unwrap();
    for adc in 0..4u64 {
        let missing = codes(&truth["adcs"][adc as usize]["missing_codes"]);
        let named: Vec<&Value> = findings.iter().filter(|f| f["effect"] == "adc-dnl" && f["adc"] == adc).collect();
        if adc == 3 {
            assert!(named.is_empty(), "the ideal ADC: {named:?}");
        }
        if !missing.is_empty() {
            assert_eq!(named.len(), 1, "ADC {adc}, missing {missing:?}: {findings:?}");
            let detail = named[0]["detail"].as_str().unwrap();
            for k in missing.iter().take(8) {
                assert!(detail.contains(&format!("{k} (")), "ADC {adc}: code {k} not in {detail}");
            }
        }
    }
    // The architecture: every named ADC is kept as a binary-weighted SAR and written so
    // into model.toml, whose code widths are adctoolbox's converter's (its weights,
    // through the conversion's regions), relative to the mean width: 0.02 rms over the
    // codes, 0.3 at any code (Poisson counts of 200 a code and a half would leave 0.07
    // LSB at the depths of one to four codes; this set's evenly spaced samples are
    // sub-Poisson, and measured 0.0001-0.0024 rms, 0.002-0.033 at worst). The weights
    // themselves are not compared: a high bit's is the sum of its depth and all below,
    // uncertain by the INL's noise (about 1.6 LSB at bit 11 with Poisson counts).
    let arch = d["adc_architecture"].as_array().unwrap();
    let model = dncal_host::model::camera::CameraConfig::from_toml_file(&rep.join("model.toml")).unwrap();
    assert_eq!(model.adc.architecture.len(), 4, "model.toml has no architectures: {arch:?}");
    for adc in 0..4usize {
        let named = findings.iter().any(|f| f["effect"] == "adc-dnl" && f["adc"] == adc as u64);
        if !named {
            assert_eq!(model.adc.architecture[adc], dncal_host::model::camera::Architecture::Ideal {});
            continue;
        }
        assert_eq!(arch[adc]["name"], "binary-weighted SAR", "ADC {adc}: {}", arch[adc]);
        assert_eq!(arch[adc]["adopted"], true, "ADC {adc}: {}", arch[adc]);
        let true_weights: Vec<f64> = truth["adcs"][adc]["weights_unit_caps"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let planted = dncal_host::model::camera::Architecture::Sar { weight_error_lsb: true_weights.iter().enumerate().map(|(b, w)| w - (1u64 << b) as f64).collect() };
        let relative = |a: &dncal_host::model::camera::Architecture| {
            let w = dncal_host::model::camera::AdcTransfer::from_architecture(a, 12).unwrap().widths();
            let m = w[1..4095].iter().sum::<f64>() / 4094.0;
            w.iter().map(|x| x / m).collect::<Vec<f64>>()
        };
        let (ours, theirs) = (relative(&model.adc.architecture[adc]), relative(&planted));
        let diff: Vec<f64> = (1..4095).map(|k| ours[k] - theirs[k]).collect();
        let rms = (diff.iter().map(|d| d * d).sum::<f64>() / diff.len() as f64).sqrt();
        let worst = diff.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        assert!(rms < 0.02 && worst < 0.3, "ADC {adc}: widths {rms:.4} rms, {worst:.3} at worst off adctoolbox's");
    }
}

/// The fixture's four ramps (`tests/fixtures/arduino-adc-tester/counts.csv`) as a
/// histogram set of four rows, written by dncal's own writer.
fn arduino_set(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/arduino-adc-tester/counts.csv")).unwrap();
    let mut counts = vec![Vec::new(); 4];
    for line in text.lines().skip(1) {
        for (row, v) in counts.iter_mut().zip(line.split(',').skip(1)) {
            row.push(v.trim().parse::<u64>().unwrap());
        }
    }
    let path = dir.join("arduino.fits");
    dncal_host::formats::fits::write_histograms(&path, &dncal_host::formats::fits::AdcHistograms { bit_depth: 10, counts }).unwrap();
    path
}

#[test]
fn real_arduino_ramps_at_8_counts_a_code_are_analysed_with_their_resolution_stated() {
    // Two real boards, about 8 counts a code: not refused, the resolution they allow
    // stated (±1.06 LSB per code at 3 sigma), no code named at it, the counts recognized
    // as a stepped ramp's (not independent), the numpy oracle's DNL and INL, and the
    // largest |DNL| of the software-timed ramps as the data's own authors report it.
    let py = venv_python();
    let dir = tempfile::tempdir().unwrap();
    let hist = arduino_set(dir.path());
    let ours = dncal_linearity(&hist, "ramp", dir.path());
    let result = dir.path().join("arduino-oracle.json");
    oracle(&py, &["analyse", hist.to_str().unwrap(), "--input", "ramp", "--out", result.to_str().unwrap()]);
    let theirs = read_json(&result);
    for (row, l) in ours.iter().enumerate() {
        agree(l, &theirs["adcs"][row], 1e-9, &format!("Arduino ramp {row}"));
        let r = &l["resolution"];
        let sigma = r["dnl_sigma_lsb"].as_f64().unwrap();
        assert!((3.0 * sigma - 1.06).abs() < 0.03, "ramp {row}: {r}");
        assert!(l["named"].as_array().unwrap().is_empty(), "ramp {row}: {}", l["named"]);
        assert!(r["inl_over_noise"].as_f64().unwrap() < 0.3, "ramp {row}: {r}");
    }
    // The authors' results.html: board 1 -0.875 LSB, board 2 1.5 LSB (their ideal-ADC
    // counts a code against our mean: the same extremes on the software-timed ramps).
    let extreme = |l: &Value| floats(&l["dnl_lsb"]).into_iter().max_by(|a, b| a.abs().total_cmp(&b.abs())).unwrap();
    assert!((extreme(&ours[1]) - -0.875).abs() < 0.01, "{}", extreme(&ours[1]));
    assert!((extreme(&ours[3]) - 1.5).abs() < 0.01, "{}", extreme(&ours[3]));
}
