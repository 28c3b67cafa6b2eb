//! 16-bit histogram sets end to end (issue 56): a 16-bit scientific CMOS camera's ramps
//! made `dncal diagnose` fit a dense SVD over 4,114 parameters (minutes, gigabytes, then
//! an abort under a memory limit). The sets here are written by numpy and astropy, and
//! the planted ADCs' code widths come from numpy's own reading of the architectures'
//! definitions (a SAR's transition into code k at `sum_b bit_b(k) W_b - 1/2`; a pipeline's
//! at `k - 1/2` plus each stage's offset for its digit), not from the simulator.

mod support;

use std::path::Path;

use support::{dncal, python, stdout_json, succeed};

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

/// Checks a LUT FITS file in astropy (argv: the file, bits, ADCs, planted set or '', and
/// a LUT FITS file whose entries it must equal or ''): its keys, its entries from its own
/// WEIGHTS extension (when it has one: a device image carries entries only) by the rule of docs/formats.md
/// in Python's exact integers (`entry_k = RNE((2 sum_{j<k} W_j + W_k) / 2^(25 - F))`,
/// `W` in units of 2^-24 DN, `F` = 11 up to 12 bits and `23 - bits` above, so that the
/// top entry stays below 2^23), and, given the planted set written by `WRITE`, ADC 0's
/// weights against the planted SAR's widths. Prints the largest |weight - planted|
/// over the SAR's carry codes and the rms over all codes.
const CHECK_LUT: &str = r#"
import sys, numpy as np
from astropy.io import fits
path, bits, nadc, planted, same = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5]
with fits.open(path) as f:
    h = f[0].header
    entries = np.asarray(f[0].data, dtype=np.int64)
    weights = np.asarray(f['WEIGHTS'].data, dtype=np.int64) if 'WEIGHTS' in f else None
if same:
    assert (np.asarray(fits.getdata(same), dtype=np.int64) == entries).all(), same
frac = 11 if bits <= 12 else 23 - bits
assert h['BITDEPTH'] == bits and h['NADC'] == nadc and h['FRACBITS'] == frac, repr(h)
assert entries.shape == (nadc, 1 << bits), entries.shape
assert entries.max() < 2**23 and (np.diff(entries, axis=1) >= 0).all()
shift = 25 - frac
for a in range(nadc if weights is not None else 0):
    W = [int(x) for x in weights[a]]
    below = 0
    for k, w in enumerate(W):
        n = 2 * below + w
        q, r = divmod(n, 1 << shift)
        half = 1 << (shift - 1)
        e = q + 1 if (r > half or (r == half and q % 2 == 1)) else q
        assert e == entries[a, k], (a, k, e, entries[a, k])
        below += w
if planted:
    k = np.arange(65536)
    e = np.zeros(16); e[13] = 3.0; e[7] = -0.5
    wts = 2.0 ** np.arange(16) + e
    bits_k = (k[1:, None] >> np.arange(16)) & 1
    levels = bits_k @ wts - 0.5
    # As WRITE: a code whose levels cross is missing (0 wide).
    true = np.ones(65536); true[1:-1] = np.maximum(np.diff(levels), 0.0)
    got = weights[0] / 2.0**24
    # The LUT's flattening analyses codes 150 to 2^16 - 150 (the ends' density is
    # uncertain) and gives the others width 1.
    inner = slice(150, 65536 - 150)
    carry = [8191, 8191 + 16384, 8191 + 32768, 8191 + 49152, 16383, 32767, 255 + 128, 1151, 40063]
    print(max(abs(got[c] - true[c]) for c in carry), np.sqrt(np.mean((got[inner] - true[inner]) ** 2)))
"#;

/// Writes a 14-bit set of `nadc` ideal ADCs at about 10^4 counts a code (argv: dir).
const WRITE_14: &str = r#"
import sys, numpy as np
from astropy.io import fits
rng = np.random.default_rng(14)
h = fits.PrimaryHDU(rng.poisson(1e4, (2, 16384)).astype(np.int64))
h.header['BITDEPTH'] = 14; h.header['NADC'] = 2; h.header['ADCMAP'] = 'COLMOD'
h.writeto(sys.argv[1] + '/h14.fits')
"#;

fn check_lut(dir: &Path, file: &str, bits: u32, n_adc: usize, planted: bool, same_as: Option<&str>) -> String {
    let same = same_as.map_or_else(Default::default, |f| dir.join(f));
    let out = python().arg("-c").arg(CHECK_LUT).arg(dir.join(file)).arg(bits.to_string()).arg(n_adc.to_string()).arg(if planted { "1" } else { "" }).arg(same).output().expect("the astropy venv's python runs");
    assert!(out.status.success(), "{file}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// 14- and 16-bit LUTs, built and carried through every format (issue 56). The core's
/// entries are 23 bits so that 512 frames sum into 32; with the paper's 11 fractional
/// bits a 14-bit table's top entry needs 25, so every 14-bit `lut build` failed ("LUT
/// entry ADC 0 code 16383 = 33553408 is not below 2^23") and 16 bits were refused as
/// unsupported. Deeper ADCs now give up fractional bits (9 at 14 bits, 7 at 16). Checked
/// in astropy: the keys, every entry from the file's own weights by the rounding rule
/// in exact integers, and a planted 16-bit SAR's widths at 10^5 counts a code (the bit-13
/// carry codes 4 LSB wide, the bit-7 ones 0.5). `adc --hist` writes the same scale; the
/// device image and the FITS file convert into each other unchanged.
#[test]
fn deep_adcs_get_luts_on_their_own_scale() {
    let dir = tempfile::tempdir().unwrap();
    let set = write_set(dir.path(), "planted4", "planted", 1e5, 4, 5);
    succeed(&["lut", "build", &set, "-o", "lut16"], dir.path());
    let fit = check_lut(dir.path(), "lut16.fits", 16, 4, true, None);
    let [carry, rms]: [f64; 2] = fit.split_whitespace().map(|x| x.parse().unwrap()).collect::<Vec<_>>().try_into().unwrap();
    // Count noise: 1/sqrt(10^5) = 0.0032 of a width (4x at the 4-LSB codes).
    assert!(carry < 0.05 && rms < 0.006, "{fit}");
    succeed(&["lut", "convert", "lut16.bin", "--to", "fits", "-o", "back16.fits"], dir.path());
    check_lut(dir.path(), "back16.fits", 16, 4, false, Some("lut16.fits"));
    succeed(&["lut", "convert", "back16.fits", "--to", "image", "-o", "again16.bin"], dir.path());
    assert_eq!(std::fs::read(dir.path().join("lut16.bin")).unwrap(), std::fs::read(dir.path().join("again16.bin")).unwrap());
    succeed(&["adc", "--hist", &set, "-o", "adc16"], dir.path());
    check_lut(dir.path(), "adc16/lut.fits", 16, 4, false, None);

    let out = python().arg("-c").arg(WRITE_14).arg(dir.path()).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    succeed(&["lut", "build", "h14.fits", "-o", "lut14"], dir.path());
    check_lut(dir.path(), "lut14.fits", 14, 2, false, None);
    let inspect = stdout_json(&succeed(&["lut", "inspect", "lut14.bin", "--json"], dir.path()));
    assert_eq!(inspect["bit_depth"], 14, "{inspect}");
}
