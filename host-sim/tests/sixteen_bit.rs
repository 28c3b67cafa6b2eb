//! 16-bit histogram sets end to end (issue 56): a 16-bit scientific CMOS camera's ramps
//! made `dncal diagnose` fit a dense SVD over 4,114 parameters (minutes, gigabytes, then
//! an abort under a memory limit). The sets here are written by numpy and astropy, and
//! the planted ADCs' code widths come from numpy's own reading of the architectures'
//! definitions (a SAR's transition into code k at `sum_b bit_b(k) W_b - 1/2`; a pipeline's
//! at `k - 1/2` plus each stage's offset for its digit), not from the simulator.

mod support;

use std::path::Path;

use support::{dncal, python, stdout_json};

/// Writes `NAME.fits` in `dir` (argv: dir, name, kind, per-code count scale, ADCs, seed):
/// kind `random` draws every code's expected count uniformly in [0.5, 1.5] times the
/// scale (independent widths, the issue's reproducer); `planted` gives ADC 0 a SAR with
/// bit 13 three LSB heavy and bit 7 half an LSB light, ADC 1 (when there is one) a
/// 4+4+4+4 pipeline with first-stage offsets up to 0.8 LSB, the others ideal, under a
/// smooth ramp density; the counts are Poisson.
const WRITE: &str = r#"
import sys, numpy as np
from astropy.io import fits
d, name, kind, scale, nadc, seed = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6])
rng = np.random.default_rng(seed)
k = np.arange(65536)
def widths_of(levels):
    # levels[j] = transition into code j + 1; code 0 and the top code are open.
    w = np.ones(65536)
    w[1:-1] = np.maximum(np.diff(levels), 0.0)
    return w
def sar(errors):
    weights = 2.0 ** np.arange(16) + np.asarray(errors)
    bits = (k[1:, None] >> np.arange(16)) & 1
    return widths_of(bits @ weights - 0.5)
def pipeline(offsets):
    level = k[1:] - 0.5
    for s, off in enumerate(offsets):
        level = level + np.asarray(off)[(k[1:] >> (12 - 4 * s)) & 15]
    return widths_of(level)
counts = []
for adc in range(nadc):
    if kind == 'random':
        expected = scale * rng.uniform(0.5, 1.5, 65536)
    else:
        w = np.ones(65536)
        if adc == 0:
            e = np.zeros(16); e[13] = 3.0; e[7] = -0.5
            w = sar(e)
        elif adc == 1:
            amp = [0.8, 0.25, 0.1, 0.05]
            offs = [np.concatenate([[0.0], a * rng.uniform(-1, 1, 15)]) for a in amp]
            w = pipeline(offs)
        density = 1.0 + 0.3 * np.sin(2 * np.pi * k / 65536.0)
        expected = scale * density * w
    counts.append(rng.poisson(expected))
h = fits.PrimaryHDU(np.asarray(counts, dtype=np.int64))
h.header['BITDEPTH'] = 16
h.header['NADC'] = nadc
h.header['ADCMAP'] = 'COLMOD'
h.writeto(f'{d}/{name}.fits')
"#;

fn write_set(dir: &Path, name: &str, kind: &str, scale: f64, n_adc: usize, seed: u64) -> String {
    let out = python().arg("-c").arg(WRITE).arg(dir).arg(name).arg(kind).arg(scale.to_string()).arg(n_adc.to_string()).arg(seed.to_string()).output().expect("the astropy venv's python runs");
    assert!(out.status.success(), "writing {name}: {}", String::from_utf8_lossy(&out.stderr));
    format!("{name}.fits")
}

fn findings(report: &serde_json::Value, effect: &str) -> Vec<serde_json::Value> {
    report["findings"].as_array().expect("findings").iter().filter(|f| f["effect"] == effect).cloned().collect()
}

/// The issue's reproducer, 1 and 4 ADCs of 65,536 codes at 50-150 counts a code with
/// independent widths: diagnose ends with every ADC's code widths named and, in this
/// noise, nothing unexplained (the per-code widths' residual was scored with a variance
/// biased low by `1/A`: mean z^2 1.016, an "unexplained" finding at 5.5 sigma, before).
#[test]
fn random_16_bit_widths_are_code_widths_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    for (n_adc, seed) in [(1usize, 1u64), (4, 2)] {
        let set = write_set(dir.path(), &format!("random{n_adc}"), "random", 100.0, n_adc, seed);
        let out = dncal(&["diagnose", &set, "--json"], dir.path());
        let report = stdout_json(&out);
        let dnl: Vec<u64> = findings(&report, "adc-dnl").iter().map(|f| f["adc"].as_u64().unwrap()).collect();
        assert_eq!(dnl, (0..n_adc as u64).collect::<Vec<_>>(), "{n_adc} ADCs: {}", report["findings"]);
        assert!(findings(&report, "unexplained").is_empty(), "{n_adc} ADCs: {}", report["findings"]);
        for f in findings(&report, "adc-dnl") {
            // Widths uniform in [0.5, 1.5]: 1/sqrt(12) = 28.9% rms, plus the counts' noise.
            let detail = f["detail"].as_str().unwrap();
            let pct: f64 = detail.split("% rms").next().unwrap().rsplit(' ').next().unwrap().parse().unwrap();
            assert!((28.0..35.0).contains(&pct), "{detail}");
        }
    }
}

/// Planted architectures at 16 bits, 1 and 4 ADCs. At about 10^5 counts a code, the
/// SAR of ADC 0 and the 4+4+4+4 pipeline of ADC 1 are explained (at least 99% of their
/// per-code widths' held-out gain) by the architecture kept, which is written into
/// model.toml, and the ideal ADCs get no finding. (At these counts the kept model of the
/// SAR can be the 2+2+...+2 pipeline that nests it, which scores better by 1e-4 in mean
/// z^2 over 62,000 codes: the SAR is then listed significant among the candidates.) The
/// SAR's is adopted. At 50-150 counts a code (1 ADC) the SAR, or that pipeline, explains
/// 90% of the widths' gain.
#[test]
fn planted_16_bit_architectures_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let set = write_set(dir.path(), "planted4", "planted", 1e5, 4, 3);
    let out = dncal(&["diagnose", &set, "-o", "d4", "--json"], dir.path());
    let report = stdout_json(&out);
    let dnl: Vec<u64> = findings(&report, "adc-dnl").iter().map(|f| f["adc"].as_u64().unwrap()).collect();
    assert_eq!(dnl, vec![0, 1], "{}", report["findings"]);
    let arch = report["adc_architecture"].as_array().expect("architectures");
    for (adc, family) in [(0, ["binary-weighted SAR", "pipelined 2+2"]), (1, ["pipelined 4+4+4+4", "pipelined 4+12"])] {
        let a = &arch[adc];
        let name = a["name"].as_str().unwrap();
        assert!(family.iter().any(|f| name.starts_with(f)), "ADC {adc}: {a}");
        assert!(a["explained"].as_f64().unwrap() > 0.99, "ADC {adc}: {a}");
    }
    assert_eq!(arch[0]["adopted"], true, "{}", arch[0]);
    assert!(arch[0]["candidates"].as_array().unwrap().iter().any(|c| c["name"] == "binary-weighted SAR" && c["significance"].as_f64().unwrap() > 5.0), "{}", arch[0]);
    let model: toml::Value = toml::from_str(&std::fs::read_to_string(dir.path().join("d4/model.toml")).unwrap()).unwrap();
    // The architectures go into the model when every ADC with code widths has one
    // adopted; the pipeline's held-out mean z^2 at 10^5 counts a code can stay more than
    // 5 sigma above its per-code widths', and then the model carries the widths.
    match model["adc"].get("architecture").and_then(|a| a.as_array()) {
        Some(list) => {
            let kinds: Vec<&str> = list.iter().map(|a| a["kind"].as_str().unwrap()).collect();
            assert_eq!(&kinds[2..], &["ideal", "ideal"], "{kinds:?}");
            assert!(kinds[..2].iter().all(|k| *k != "ideal"), "{kinds:?}");
        }
        None => {
            assert_eq!(arch[1]["adopted"], false, "{}", arch[1]);
            let widths = model["adc"]["widths"].as_array().expect("per-code widths");
            assert_eq!(widths.len(), 4);
            assert!(widths[2].as_array().unwrap().iter().all(|w| w.as_float() == Some(1.0)), "ADC 2 is ideal");
        }
    }

    let set = write_set(dir.path(), "planted1", "planted", 100.0, 1, 4);
    let report = stdout_json(&dncal(&["diagnose", &set, "--json"], dir.path()));
    let a = &report["adc_architecture"][0];
    let name = a["name"].as_str().unwrap();
    assert!(name == "binary-weighted SAR" || name == "pipelined 2+2+2+2+2+2+2+2", "{a}");
    assert!(a["explained"].as_f64().unwrap() > 0.9, "{a}");
}
