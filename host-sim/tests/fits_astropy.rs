//! FITS interchange against astropy, the reference implementation astronomers use.
//!
//! Both directions: files astropy wrote (`tests/fixtures/`, made by
//! `scripts/make_fits_fixtures.py`) must read with every value equal to the formulas
//! documented there, written out again here; files dncal writes must open in astropy
//! (the project's astropy venv, checked with `verify('exception')`) with the shapes, dtypes, keys and values
//! of `docs/formats.md`.
//!
//! Needs Python 3 with venv and pip: `scripts/astropy-venv.sh` makes target/astropy-venv
//! (astropy, numpy) when missing. Without it these tests fail, on purpose; they do not skip.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use dncal_host::formats::fits::{
    read_histograms, read_linearity, read_lut, write_histograms, write_linearity, write_lut, AdcHistograms,
    LinearitySet, LutTables,
};
use serde_json::Value;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

// The fixture formulas of scripts/make_fits_fixtures.py: a = ADC, k = code, l = level,
// r = row, c = column.
const N_ADC: usize = 4;
const CODES: usize = 16;
const TWO_63: u64 = 1 << 63;

fn count_int32(a: u64, k: u64) -> u64 {
    1000 * (a + 1) + k * k + (a * k) % 7
}
fn count_uint16(a: u64, k: u64) -> u64 {
    40000 + 100 * a + k
}
fn count_uint64(a: u64, k: u64) -> u64 {
    TWO_63 + 1000 * a + k
}
fn mean_dn(l: usize, r: usize, c: usize) -> f64 {
    100.0 + 1000.0 * l as f64 + 10.0 * r as f64 + c as f64 + 0.25
}
fn std_dn(l: usize, r: usize, c: usize) -> f64 {
    0.5 + 0.125 * l as f64 + 0.0625 * r as f64 + 0.03125 * c as f64
}
fn mask_bad(r: usize, c: usize) -> u8 {
    u8::from((5 * r + c).is_multiple_of(7))
}
fn voltage_v(l: usize) -> f64 {
    0.25 * l as f64
}
fn lut_entry(a: u32, k: u32) -> u32 {
    if (a, k) == (3, 15) {
        u32::MAX - 15
    } else {
        1024 * (2 * k + 1) + a
    }
}

fn check_fixture_histograms(name: &str, count: fn(u64, u64) -> u64) {
    let h = read_histograms(&fixture(name)).unwrap();
    assert_eq!(h.bit_depth, 4, "{name}");
    assert_eq!(h.n_adc(), N_ADC, "{name}");
    for (a, row) in h.counts.iter().enumerate() {
        assert_eq!(row.len(), CODES, "{name}");
        for (k, &n) in row.iter().enumerate() {
            assert_eq!(n, count(a as u64, k as u64), "{name}: ADC {a}, code {k}");
        }
    }
}

#[test]
fn astropy_int32_histograms_read_value_for_value() {
    check_fixture_histograms("histograms_int32.fits", count_int32);
}

#[test]
fn astropy_uint16_histograms_read_through_bzero() {
    check_fixture_histograms("histograms_uint16.fits", count_uint16);
}

#[test]
fn astropy_uint64_histograms_read_above_the_int64_range() {
    check_fixture_histograms("histograms_uint64.fits", count_uint64);
}

#[test]
fn astropy_linearity_set_reads_value_for_value() {
    let s = read_linearity(&fixture("linearity.fits")).unwrap();
    assert_eq!((s.bit_depth, s.n_adc, s.n_frames), (12, 4, 64));
    assert_eq!((s.width, s.height, s.levels), (5, 3, 4));
    let mask = s.mask.as_ref().expect("the fixture has a MASK");
    for l in 0..4 {
        assert_eq!(s.voltage[l], voltage_v(l));
        for r in 0..3 {
            for c in 0..5 {
                let i = (l * 3 + r) * 5 + c;
                assert_eq!(s.mean[i], mean_dn(l, r, c), "mean at level {l}, row {r}, column {c}");
                assert_eq!(s.std[i], std_dn(l, r, c), "std at level {l}, row {r}, column {c}");
                assert_eq!(mask[r * 5 + c], mask_bad(r, c), "mask at row {r}, column {c}");
            }
        }
    }
    assert_eq!(s.voltage.len(), 4);
    assert_eq!(mask.iter().filter(|&&m| m == 1).count(), 3);
}

#[test]
fn astropy_uint32_lut_reads_value_for_value() {
    let lut = read_lut(&fixture("lut_uint32.fits")).unwrap();
    assert_eq!(lut.frac_bits, 11);
    assert_eq!(lut.n_adc(), N_ADC);
    for (a, table) in lut.tables.iter().enumerate() {
        assert_eq!(table.len(), CODES);
        for (k, &e) in table.iter().enumerate() {
            assert_eq!(e, lut_entry(a as u32, k as u32), "ADC {a}, code {k}");
        }
    }
}

/// What astropy sees in a FITS file: per HDU its name, class, some header keys (read before
/// the data, while BZERO is still in the header) and the data: shape, dtype and values.
const DESCRIBE: &str = r#"
import json, sys
from astropy.io import fits
out = []
with fits.open(sys.argv[1]) as hdul:
    hdul.verify("exception")
    for hdu in hdul:
        keys = ("BITPIX", "NAXIS", "BZERO", "BSCALE", "BITDEPTH", "NADC", "ADCMAP", "FRACBITS", "KCORBITS", "NFRAMES", "BUNIT", "EXTNAME", "BAYERPAT", "XBAYROFF", "YBAYROFF", "ROWORDER")
        d = {"name": hdu.name, "class": type(hdu).__name__, "header": {k: hdu.header[k] for k in keys if k in hdu.header}}
        if isinstance(hdu, fits.BinTableHDU):
            d["columns"] = {
                c.name: {"format": c.format, "unit": c.unit, "dtype": hdu.data[c.name].dtype.name,
                         "values": hdu.data[c.name].tolist()}
                for c in hdu.columns
            }
        else:
            d["shape"] = list(hdu.data.shape)
            d["dtype"] = hdu.data.dtype.name
            d["values"] = hdu.data.ravel().tolist()
        out.append(d)
print(json.dumps(out))
"#;

fn astropy_describe(path: &Path) -> Vec<Value> {
    let out = support::python()
        .arg("-c")
        .arg(DESCRIBE)
        .arg(path)
        .output()
        .expect("the astropy venv's python runs");
    assert!(
        out.status.success(),
        "astropy could not open {} (scripts/astropy-venv.sh makes its venv):\n{}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice::<Value>(&out.stdout).unwrap().as_array().unwrap().clone()
}

fn json_u64(values: &Value) -> Vec<u64> {
    values.as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect()
}

fn json_f64(values: &Value) -> Vec<f64> {
    values.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
}

/// Each JSON float is the shortest decimal that round-trips; allow for a last-bit
/// difference in parsing it back.
fn assert_close(got: &[f64], expected: &[f64], what: &str) {
    assert_eq!(got.len(), expected.len(), "{what}");
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        assert!((g - e).abs() <= 1e-15 * e.abs().max(1.0), "{what}[{i}]: astropy {g}, dncal {e}");
    }
}

/// The keys every format carries, as astropy reports them.
fn assert_adc_keys(hdu: &Value, bit_depth: u64, n_adc: u64) {
    let h = &hdu["header"];
    assert_eq!(h["BITDEPTH"], bit_depth);
    assert_eq!(h["NADC"], n_adc);
    assert_eq!(h["ADCMAP"], "COLMOD");
}

#[test]
fn astropy_opens_our_histograms_as_int64_nadc_by_codes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("histograms.fits");
    let counts: Vec<Vec<u64>> = (0..3u64).map(|a| (0..8u64).map(|k| 1000 * a + k + (1 << 40)).collect()).collect();
    write_histograms(&path, &AdcHistograms { bit_depth: 3, counts: counts.clone() }).unwrap();
    let hdus = astropy_describe(&path);
    assert_eq!(hdus.len(), 1);
    let p = &hdus[0];
    assert_eq!(p["name"], "PRIMARY");
    assert_eq!(p["class"], "PrimaryHDU");
    assert_eq!(p["header"]["BITPIX"], 64);
    assert!(p["header"].get("BZERO").is_none());
    assert!(p["header"].get("EXTNAME").is_none(), "the primary HDU must not be named");
    assert_adc_keys(p, 3, 3);
    assert_eq!(p["shape"], serde_json::json!([3, 8]), "astropy's shape is (NADC, codes)");
    assert_eq!(p["dtype"], "int64");
    assert_eq!(json_u64(&p["values"]), counts.concat());
}

#[test]
fn astropy_opens_our_lut_as_uint32() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lut.fits");
    let mut tables: Vec<Vec<u32>> = (0..2u32).map(|a| (0..16u32).map(|k| 1024 * (2 * k + 1) + a).collect()).collect();
    tables[1][15] = u32::MAX; // above 2^31: astropy reads it right only through BZERO
    write_lut(&path, &LutTables { frac_bits: 11, tables: tables.clone(), weights: None, kcor_bits: None }).unwrap();
    let hdus = astropy_describe(&path);
    assert_eq!(hdus.len(), 1);
    let p = &hdus[0];
    assert_eq!(p["name"], "PRIMARY");
    assert_eq!(p["header"]["BITPIX"], 32);
    assert_eq!(p["header"]["BZERO"], 2_147_483_648u64);
    assert_eq!(p["header"]["FRACBITS"], 11);
    assert_adc_keys(p, 4, 2);
    assert_eq!(p["shape"], serde_json::json!([2, 16]), "astropy's shape is (NADC, codes)");
    assert_eq!(p["dtype"], "uint32");
    let expected: Vec<u64> = tables.concat().into_iter().map(u64::from).collect();
    assert_eq!(json_u64(&p["values"]), expected);

    // With the code widths (extension WEIGHTS) and an imported K-Cor scaling.
    let weights: Vec<Vec<u32>> = (0..2u32).map(|a| (0..16u32).map(|k| (1 << 24) + 977 * k + a).collect()).collect();
    write_lut(&path, &LutTables { frac_bits: 11, tables, weights: Some(weights.clone()), kcor_bits: Some(22) }).unwrap();
    let hdus = astropy_describe(&path);
    assert_eq!(hdus.len(), 2);
    assert_eq!(hdus[0]["header"]["KCORBITS"], 22);
    let w = &hdus[1];
    assert_eq!(w["name"], "WEIGHTS");
    assert_eq!(w["header"]["FRACBITS"], 24);
    assert_eq!(w["shape"], serde_json::json!([2, 16]));
    assert_eq!(w["dtype"], "uint32");
    assert_eq!(json_u64(&w["values"]), weights.concat().into_iter().map(u64::from).collect::<Vec<u64>>());
}

#[test]
fn astropy_opens_our_linearity_set_levels_by_rows_by_columns() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("linearity.fits");
    let (width, height, levels) = (5, 3, 4);
    let cube = width * height * levels;
    let set = LinearitySet {
        bit_depth: 12,
        n_adc: 4,
        n_frames: 32,
        width,
        height,
        levels,
        mean: (0..cube).map(|i| 10.0 + 0.1 * i as f64).collect(),
        std: (0..cube).map(|i| 0.3 + 0.01 * i as f64).collect(),
        voltage: (0..levels).map(|l| 0.1 * l as f64).collect(),
        mask: Some((0..width * height).map(|i| u8::from(i % 6 == 2)).collect()),
        keys: dncal_host::formats::fits::SetKeys { bayer: Some(dncal_host::formats::bayer::Bayer::Gbrg), reference: dncal_host::formats::fits::Reference::Exposure, bayer_unread: false },
    };
    write_linearity(&path, &set).unwrap();
    let hdus = astropy_describe(&path);
    let by_name = |name: &str| hdus.iter().find(|h| h["name"] == name).unwrap_or_else(|| panic!("no HDU {name}"));
    assert_eq!(hdus.len(), 4);

    let p = &hdus[0];
    assert_eq!(p["name"], "PRIMARY");
    assert_eq!(p["header"]["BITPIX"], -64);
    assert_eq!(p["header"]["NFRAMES"], 32);
    assert_eq!(p["header"]["BUNIT"], "DN");
    // The colour layout as the Bayer convention's keys.
    assert_eq!((&p["header"]["BAYERPAT"], &p["header"]["XBAYROFF"], &p["header"]["YBAYROFF"], &p["header"]["ROWORDER"]), (&serde_json::json!("GBRG"), &serde_json::json!(0), &serde_json::json!(0), &serde_json::json!("TOP-DOWN")));
    assert_adc_keys(p, 12, 4);
    assert_eq!(p["shape"], serde_json::json!([4, 3, 5]), "astropy's shape is (levels, rows, columns)");
    assert_eq!(p["dtype"], "float64");
    assert_close(&json_f64(&p["values"]), &set.mean, "mean");

    let std = by_name("STD");
    assert_eq!(std["class"], "ImageHDU");
    assert_eq!(std["shape"], serde_json::json!([4, 3, 5]));
    assert_eq!(std["dtype"], "float64");
    assert_close(&json_f64(&std["values"]), &set.std, "std");

    let mask = by_name("MASK");
    assert_eq!(mask["class"], "ImageHDU");
    assert_eq!(mask["header"]["BITPIX"], 8);
    assert_eq!(mask["shape"], serde_json::json!([3, 5]), "astropy's shape is (rows, columns)");
    assert_eq!(mask["dtype"], "uint8");
    let expected: Vec<u64> = set.mask.as_ref().unwrap().iter().map(|&m| u64::from(m)).collect();
    assert_eq!(json_u64(&mask["values"]), expected);

    let reference = by_name("REFERENCE");
    assert_eq!(reference["class"], "BinTableHDU");
    // (A relative exposure, t / N^2, in its own column: a photodiode's would be VOLTAGE, V.)
    let voltage = &reference["columns"]["EXPOSURE"];
    // cfitsio writes TFORM '1D', astropy 'D': both one float64 per row.
    assert!(matches!(voltage["format"].as_str(), Some("D" | "1D")), "EXPOSURE format {}", voltage["format"]);
    assert_eq!(voltage["unit"], "s");
    assert_eq!(voltage["dtype"], "float64");
    assert_close(&json_f64(&voltage["values"]), &set.voltage, "voltage");
}

/// Every HDU of each of the three kinds carries DATASUM and CHECKSUM that astropy (the
/// reference implementation of the FITS checksum convention) verifies, and the primary
/// HDU its provenance (DATE, CREATOR, ORIGIN, the command line as HISTORY). A byte changed
/// in the data afterwards fails astropy's check and our reader refuses the file.
#[test]
fn astropy_verifies_our_checksums_and_reads_our_provenance() {
    const VERIFY: &str = r#"
import json, sys, warnings
from astropy.io import fits
warnings.simplefilter("ignore")
out = []
with fits.open(sys.argv[1]) as hdul:
    for hdu in hdul:
        h = hdu.header
        out.append({"name": hdu.name, "checksum": hdu.verify_checksum(), "datasum": hdu.verify_datasum(),
                    "date": h.get("DATE"), "creator": h.get("CREATOR"), "origin": h.get("ORIGIN"),
                    "history": " ".join(str(c) for c in h.get("HISTORY", []))})
print(json.dumps(out))
"#;
    let verify = |path: &Path| -> Vec<Value> {
        let out = support::python().arg("-c").arg(VERIFY).arg(path).output().expect("python3 with astropy");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice::<Value>(&out.stdout).unwrap().as_array().unwrap().clone()
    };
    let dir = tempfile::tempdir().unwrap();
    let (h, l, s) = (dir.path().join("h.fits"), dir.path().join("l.fits"), dir.path().join("s.fits"));
    write_histograms(&h, &AdcHistograms { bit_depth: 3, counts: vec![vec![5; 8]; 3] }).unwrap();
    write_lut(&l, &LutTables { frac_bits: 11, tables: vec![(0..16u32).map(|k| 2048 * k + 1024).collect(); 2], weights: Some(vec![vec![1 << 24; 16]; 2]), kcor_bits: None }).unwrap();
    let n = 5 * 3 * 4;
    let set = LinearitySet { bit_depth: 12, n_adc: 4, n_frames: 32, width: 5, height: 3, levels: 4, mean: (0..n).map(|i| i as f64).collect(), std: vec![1.0; n], voltage: vec![0.0, 1.0, 2.0, 3.0], mask: Some(vec![0; 15]), keys: Default::default() };
    write_linearity(&s, &set).unwrap();
    for (path, hdus) in [(&h, 1), (&l, 2), (&s, 4)] {
        let v = verify(path);
        assert_eq!(v.len(), hdus, "{v:?}");
        for hdu in &v {
            assert_eq!((hdu["checksum"].as_i64(), hdu["datasum"].as_i64()), (Some(1), Some(1)), "{}: {hdu}", path.display());
        }
        let p = &v[0];
        assert_eq!(p["creator"], format!("dncal {}", env!("CARGO_PKG_VERSION")));
        assert_eq!(p["origin"], "dncal");
        assert!(p["date"].as_str().is_some_and(|d| d.len() == 19 && d.starts_with("20") && d.as_bytes()[10] == b'T'), "{p}");
        // The test binary's own command line.
        assert!(p["history"].as_str().is_some_and(|h| h.starts_with("command: ")), "{p}");
    }
    // One data byte of the linearity set's STD extension changed: astropy's DATASUM check
    // fails, and our reader refuses the file naming the HDU.
    let mut bytes = std::fs::read(&s).unwrap();
    let std_header = bytes.windows(19).position(|w| w == b"EXTNAME = 'STD     ").unwrap();
    let std_data = (std_header / 2880 + 1) * 2880;
    bytes[std_data + 7] ^= 0x01;
    std::fs::write(&s, &bytes).unwrap();
    let v = verify(&s);
    assert_eq!(v[1]["name"], "STD");
    assert_eq!(v[1]["datasum"].as_i64(), Some(0), "astropy must see the damage: {:?}", v[1]);
    let e = read_linearity(&s).unwrap_err().to_string();
    assert!(e.contains("the HDU 1 fails its checksum: its data do not match DATASUM (the file was changed or damaged after it was written;"), "{e}");
}

/// A file written by the command records, beside its command line, every parameter the
/// command ran with, defaults marked: astropy reads them back from HISTORY.
#[test]
fn astropy_reads_the_parameters_a_file_was_made_with() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_dncal"))
        .args(["simulate", "linearity", "--roi", "16x16+0+0", "--frames", "2", "-o", "p.fits", "-q"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    const HISTORY: &str = "import sys\nfrom astropy.io import fits\nprint(''.join(str(c) for c in fits.getheader(sys.argv[1])['HISTORY']))";
    let py = support::python().arg("-c").arg(HISTORY).arg(dir.path().join("p.fits")).output().expect("python3 with astropy");
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    // cfitsio continues a long record on further cards: joined, it is the record again.
    let history = String::from_utf8_lossy(&py.stdout).trim().to_string();
    let parameters = &history[history.find("parameters: ").expect("a parameters record")..];
    assert!(parameters.starts_with("parameters: simulate linearity: "), "{parameters}");
    for want in ["roi=16x16+0+0 ", "frames=2 ", "out=p.fits ", "levels=41 (default)", "seed=41 (default)"] {
        assert!(parameters.contains(want), "{want:?} missing from {parameters}");
    }
    // A global flag given once is recorded once.
    assert_eq!(parameters.matches("quiet=true").count(), 1, "{parameters}");
}

/// Every `BUNIT` the commands write is a unit astropy parses (its generic format, which
/// `CCDData` and `Quantity` use: `DN` is not in the FITS standard's list, `adu` is, but DN
/// is what camera users read and astropy knows it), and the one each quantity has: counts
/// per code, DN for means, deviations and coefficients, dimensionless for a cube
/// normalized to the reference. A LUT carries none: its entries are in `2^-FRACBITS` DN,
/// which `FRACBITS` says.
#[test]
fn every_bunit_written_is_the_quantitys_unit_for_astropy() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_dncal")).args(args).arg("-q").current_dir(dir.path()).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    };
    run(&["simulate", "linearity", "--roi", "16x16+0+0", "--frames", "4", "-o", "lin.fits"]);
    run(&["linearity", "lin.fits", "-o", "corr"]);
    write_histograms(&dir.path().join("h.fits"), &AdcHistograms { bit_depth: 3, counts: vec![vec![5; 8]; 2] }).unwrap();
    const UNITS: &str = r#"
import json, sys
import astropy.units as u
from astropy.io import fits
out = {}
for path in sys.argv[1:]:
    with fits.open(path) as hdul:
        for hdu in hdul:
            if "BUNIT" in hdu.header:
                unit = u.Unit(hdu.header["BUNIT"])
                out[path.split("/")[-1] + ":" + hdu.name] = "dimensionless" if unit == u.dimensionless_unscaled else unit.to_string()
print(json.dumps(out))
"#;
    let files = ["lin.fits", "corr/coefficients.fits", "corr/corrected.fits", "h.fits"].map(|f| dir.path().join(f));
    let py = support::python().arg("-c").arg(UNITS).args(&files).output().expect("python3 with astropy");
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    let got: Value = serde_json::from_slice(&py.stdout).unwrap();
    let want = serde_json::json!({
        "lin.fits:PRIMARY": "DN",
        "lin.fits:STD": "DN",
        "coefficients.fits:PRIMARY": "DN",
        "corrected.fits:PRIMARY": "dimensionless",
        "h.fits:PRIMARY": "ct",
    });
    assert_eq!(got, want);
}
