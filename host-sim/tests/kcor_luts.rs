//! The K-Coronagraph's deployed tables (../shared/data/kcor-luts, read in place, never
//! copied): `lut import --kcor` and `lut export --format kcor` round-trip every shared
//! file byte for byte, the imported LUT loads in the core (`lut inspect` of its FITS and
//! device image), damaged tables are refused with the file named and nothing written, and
//! the core's sums with a camera's tables are numpy's indexing of them.

mod support;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;
use support::dncal_here as dncal;

use support::kcor_luts_dir as luts_dir;

fn json(out: Output, what: &str) -> Value {
    assert!(out.status.success(), "{what}: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

const CAMERAS: [&str; 3] = ["08888", "11461", "13889"];
const DATES: [(&str, u64); 2] = [("20131106", 22), ("20131203", 23)];

#[test]
fn every_shared_table_round_trips_byte_for_byte() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    for cam in CAMERAS {
        for (date, bits) in DATES {
            let spec = dir.join(format!("Photonfocus_MV-D1024E_{cam}_adc{{adc}}_{date}.bin"));
            let out = tmp.path().join(format!("{cam}_{date}"));
            let imported = json(dncal(&["lut", "import", "--kcor", spec.to_str().unwrap(), "-o", out.to_str().unwrap(), "--json"]), "lut import");
            assert_eq!(imported["kcor_bits"], bits);
            for a in imported["adcs"].as_array().unwrap() {
                // Our entries are the K-Cor values less half a step, to within the rounding
                // to 2^-11 DN (2^-12) and the weights' grid.
                assert!(a["max_rounding_dn"].as_f64().unwrap() <= 2f64.powi(-12) + 1e-6, "{a}");
            }
            let prefix = tmp.path().join(format!("exported_{cam}_{date}"));
            let fits = format!("{}.fits", out.display());
            json(dncal(&["lut", "export", "--format", "kcor", &fits, "-o", prefix.to_str().unwrap(), "--json"]), "lut export");
            for adc in 0..4 {
                let deployed = std::fs::read(dir.join(format!("Photonfocus_MV-D1024E_{cam}_adc{adc}_{date}.bin"))).unwrap();
                let exported = std::fs::read(format!("{}_adc{adc}.bin", prefix.display())).unwrap();
                assert!(deployed == exported, "camera {cam}, {date}, ADC {adc}: the export differs from the deployed table");
            }
            // The imported LUT loads in the core, as a FITS and as a device image, with
            // the K-Cor table's steps.
            for file in [fits.clone(), format!("{}.bin", out.display())] {
                let inspected = json(dncal(&["lut", "inspect", &file, "--json"]), "lut inspect");
                assert_eq!(inspected["bit_depth"], 12);
                assert_eq!(inspected["adcs"].as_array().unwrap().len(), 4);
            }
        }
    }
}

/// `lut convert` over the LUT home, from one deployed table file (its siblings found by
/// name): K-Cor to our FITS to K-Cor is the deployed files byte for byte; K-Cor to the
/// device image is the image `lut import` writes; a device image, which has no code
/// widths, is refused as K-Cor tables with the reason and nothing written; `inspect`
/// takes the K-Cor file as it is.
#[test]
fn convert_goes_between_every_format_through_one_home() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let t = |name: &str| tmp.path().join(name).to_str().unwrap().to_string();
    let one = dir.join("Photonfocus_MV-D1024E_11461_adc2_20131203.bin");
    let one = one.to_str().unwrap();
    let to_fits = json(dncal(&["lut", "convert", one, "--to", "fits", "-o", &t("c"), "--json"]), "convert to fits");
    assert_eq!((to_fits["from"].as_str(), to_fits["to"].as_str()), (Some("kcor-tables"), Some("lut-fits")));
    let back = json(dncal(&["lut", "convert", &t("c.fits"), "--to", "kcor", "-o", &t("k"), "--json"]), "convert to kcor");
    assert_eq!(back["kcor_bits"], 23);
    for adc in 0..4 {
        let deployed = std::fs::read(dir.join(format!("Photonfocus_MV-D1024E_11461_adc{adc}_20131203.bin"))).unwrap();
        assert!(deployed == std::fs::read(t(&format!("k_adc{adc}.bin"))).unwrap(), "ADC {adc}: the round trip differs from the deployed table");
    }
    json(dncal(&["lut", "convert", one, "--to", "image", "-o", &t("i"), "--json"]), "convert to image");
    let spec = dir.join("Photonfocus_MV-D1024E_11461_adc{adc}_20131203.bin");
    json(dncal(&["lut", "import", "--kcor", spec.to_str().unwrap(), "-o", &t("imp"), "--json"]), "import");
    assert!(std::fs::read(t("i.bin")).unwrap() == std::fs::read(t("imp.bin")).unwrap(), "convert's device image differs from import's");
    let refused = dncal(&["lut", "convert", &t("i.bin"), "--to", "kcor", "-o", &t("none")]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{err}");
    assert!(err.contains("i.bin") && err.contains("code widths"), "{err}");
    assert!(!tmp.path().join("none_adc0.bin").exists());
    let inspected = json(dncal(&["lut", "inspect", one, "--json"]), "inspect a K-Cor table");
    assert_eq!((inspected["kind"].as_str(), inspected["bit_depth"].as_u64()), (Some("kcor-tables"), Some(12)));
}

/// `lut inspect` of a deployed K-Cor table (issue 44) names the response curve the four
/// tables share and gives each ADC's offset with its cubic trend taken out: against numpy
/// (polyfit of degree 3 over codes 150-4094 of the entries `lut inspect` reports, the
/// largest |residual|, and the trend's departure from its chord) to 1e-6 DN; and, as a
/// check of the whole reading, within 0.02 DN of the same fit on the deployed file's own
/// values (our entries are code centres, the file's the codes' tops: half a code's DN
/// error apart).
#[test]
fn inspect_names_the_kcor_tables_response_curve_and_takes_it_out() {
    let Some(dir) = luts_dir() else { return };
    let script = r#"
import json, sys, numpy as np
report, raw_spec = json.load(open(sys.argv[1])), sys.argv[2]
k = np.arange(4096); sel = np.arange(150, 4095); x = k / 4095
out = []
for a, adc in enumerate(report["adcs"]):
    fits = []
    for e in (np.array(adc["entries"], dtype=float) / 2048,
              np.fromfile(raw_spec.replace("{adc}", str(a)), dtype="<u4").astype(float) * 4095 / (2**23 - 1)):
        c = np.polyfit(x[sel], e[sel], 3)
        tr = np.polyval(c, x)
        chord = tr[0] + (tr[-1] - tr[0]) * x
        fits.append({"offset": float(np.abs(e[sel] - tr[sel]).max()), "bow": float(np.abs(tr - chord).max())})
    out.append(fits)
print(json.dumps(out))
"#;
    let tmp = tempfile::tempdir().unwrap();
    for cam in CAMERAS {
        let spec = dir.join(format!("Photonfocus_MV-D1024E_{cam}_adc{{adc}}_20131203.bin"));
        let one = dir.join(format!("Photonfocus_MV-D1024E_{cam}_adc0_20131203.bin"));
        let out = dncal(&["lut", "inspect", one.to_str().unwrap(), "--json"]);
        let report_path = tmp.path().join(format!("{cam}.json"));
        std::fs::write(&report_path, &out.stdout).unwrap();
        let report = json(out, "lut inspect");
        let py = support::python().arg("-c").arg(script).arg(&report_path).arg(&spec).output().unwrap();
        let numpy = json(py, "numpy oracle");
        let common = &report["common_trend"];
        assert!(common["bow_dn"].as_f64().is_some_and(|b| (200.0..=262.0).contains(&b)), "camera {cam}: {common}");
        for (a, (ours, theirs)) in report["adcs"].as_array().unwrap().iter().zip(numpy.as_array().unwrap()).enumerate() {
            let (offset, bow) = (ours["detrended_max_abs_offset_dn"].as_f64().unwrap(), ours["trend_bow_dn"].as_f64().unwrap());
            assert!((offset - theirs[0]["offset"].as_f64().unwrap()).abs() < 1e-6, "camera {cam} ADC {a}: {offset} vs {}", theirs[0]);
            assert!((bow - theirs[0]["bow"].as_f64().unwrap()).abs() < 1e-6, "camera {cam} ADC {a}: bow {bow} vs {}", theirs[0]);
            assert!((offset - theirs[1]["offset"].as_f64().unwrap()).abs() < 0.02, "camera {cam} ADC {a}: {offset} vs the file's {}", theirs[1]);
            assert!(ours["max_abs_offset_dn"].as_f64().unwrap() > 150.0, "the raw offset is the response curve's: {}", ours["max_abs_offset_dn"]);
        }
        let text = String::from_utf8_lossy(&dncal(&["lut", "inspect", one.to_str().unwrap()]).stdout).into_owned();
        assert!(text.contains("common trend: the 4 tables share a smooth response curve") && text.contains("DN with the trend taken out"), "{text}");
    }
}

/// The same tables at the other scaling: the 2^22 and 2^23 files are two roundings of one
/// table, so exporting the 23-bit import at 22 bits gives the 22-bit file to within one
/// unit per entry (measured: not byte for byte).
#[test]
fn the_two_scalings_are_one_table() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let spec = dir.join("Photonfocus_MV-D1024E_08888_adc{adc}_20131203.bin");
    let out = tmp.path().join("lut");
    json(dncal(&["lut", "import", "--kcor", spec.to_str().unwrap(), "-o", out.to_str().unwrap(), "--json"]), "lut import");
    let prefix = tmp.path().join("at22");
    json(dncal(&["lut", "export", "--format", "kcor", &format!("{}.fits", out.display()), "-o", prefix.to_str().unwrap(), "--bits", "22", "--json"]), "export");
    let words = |b: Vec<u8>| -> Vec<i64> { b.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as i64).collect() };
    for adc in 0..4 {
        let deployed = words(std::fs::read(dir.join(format!("Photonfocus_MV-D1024E_08888_adc{adc}_20131106.bin"))).unwrap());
        let ours = words(std::fs::read(format!("{}_adc{adc}.bin", prefix.display())).unwrap());
        let worst = deployed.iter().zip(&ours).map(|(a, b)| (a - b).abs()).max().unwrap();
        assert!(worst <= 1, "ADC {adc}: {worst} units");
    }
}

#[test]
fn damaged_tables_are_refused_naming_the_file() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let good: Vec<PathBuf> = (0..4).map(|a| dir.join(format!("Photonfocus_MV-D1024E_13889_adc{a}_20131203.bin"))).collect();
    let bytes = std::fs::read(&good[2]).unwrap();
    let mut cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("short.bin", bytes[..16380].to_vec(), "16380 bytes"),
        ("decreasing.bin", {
            let mut b = bytes.clone();
            b[4 * 1000..4 * 1000 + 4].copy_from_slice(&0u32.to_le_bytes());
            b
        }, "entry 1000 (0) is below entry 999"),
        ("top.bin", {
            let mut b = bytes.clone();
            let n = b.len();
            b[n - 4..].copy_from_slice(&12345u32.to_le_bytes());
            b
        }, "the last entry is 12345"),
    ];
    for (name, content, expected) in cases.drain(..) {
        let bad = tmp.path().join(name);
        std::fs::write(&bad, content).unwrap();
        let out = tmp.path().join(format!("out_{name}"));
        let files = [good[0].to_str().unwrap(), good[1].to_str().unwrap(), bad.to_str().unwrap(), good[3].to_str().unwrap()];
        let r = dncal(&["lut", "import", "--kcor", files[0], files[1], files[2], files[3], "-o", out.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && err.contains(name) && err.contains(expected), "{name}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!Path::new(&format!("{}.fits", out.display())).exists() && !Path::new(&format!("{}.bin", out.display())).exists());
    }
    // Mixed scalings, and a prefix that matches both dates.
    let mixed = dir.join("Photonfocus_MV-D1024E_13889_adc3_20131106.bin");
    let r = dncal(&["lut", "import", "--kcor", good[0].to_str().unwrap(), good[1].to_str().unwrap(), good[2].to_str().unwrap(), mixed.to_str().unwrap(), "-o", tmp.path().join("m").to_str().unwrap()]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("share a scaling"));
    let prefix = dir.join("Photonfocus_MV-D1024E_13889");
    let r = dncal(&["lut", "import", "--kcor", prefix.to_str().unwrap(), "-o", tmp.path().join("p").to_str().unwrap()]);
    assert!(!r.status.success() && String::from_utf8_lossy(&r.stderr).contains("2 files for ADC 0"), "{}", String::from_utf8_lossy(&r.stderr));
}

/// `adc --from-luts` on the twelve real ADCs, against numpy (polyfit of the table over codes
/// 150-4094, steps over the cubic's steps): the DN error's rms, the largest cumulative
/// offset and the trend's bow agree to 1e-6; the DN error repeats with a period of 64 to
/// 256 codes on every ADC, and the four ADCs of a camera are independent (|mean
/// correlation| below 0.05).
/// `adc --from-luts` of the three cameras' 20131203 tables in `dir`, its outputs in
/// `tmp`: the table specs (one per camera, `{adc}` in each) and the JSON report.
fn from_luts_report(dir: &Path, tmp: &Path) -> (Vec<String>, Value) {
    let specs: Vec<String> = CAMERAS.iter().map(|c| dir.join(format!("Photonfocus_MV-D1024E_{c}_adc{{adc}}_20131203.bin")).to_string_lossy().into_owned()).collect();
    let mut args = vec!["adc".to_string()];
    for s in &specs {
        args.extend(["--from-luts".to_string(), s.clone()]);
    }
    args.extend(["-o".to_string(), tmp.join("out").to_string_lossy().into_owned(), "--json".to_string()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let report = json(dncal(&args), "adc --from-luts");
    (specs, report)
}

#[test]
fn real_adcs_are_characterized_as_numpy_computes_them() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let (specs, report) = from_luts_report(&dir, tmp.path());
    let script = r#"
import json, sys, numpy as np
out = []
for spec in sys.argv[1:]:
    for a in range(4):
        e = np.fromfile(spec.replace("{adc}", str(a)), dtype="<u4").astype(float) * 4095 / (2**23 - 1)
        k = np.arange(4096); sel = np.arange(150, 4095); x = k / 4095
        c = np.polyfit(x[sel], e[sel], 3)
        tr = np.polyval(c, x)
        r = (np.diff(e) / np.diff(tr) - 1)[150:4094]
        o = e[sel] - tr[sel]
        chord = tr[0] + (tr[-1] - tr[0]) * x
        out.append({"rms": 100 * r.std(), "offset": np.abs(o).max(), "bow": np.abs(tr - chord).max()})
print(json.dumps(out))
"#;
    let py = support::python().arg("-c").arg(script).args(&specs).output().unwrap();
    let numpy = json(py, "numpy oracle");
    let adcs = report["adcs"].as_array().unwrap();
    assert_eq!(adcs.len(), 12);
    for (i, (ours, theirs)) in adcs.iter().zip(numpy.as_array().unwrap()).enumerate() {
        for (a, b) in [("dn_error_rms_pct", "rms"), ("offset_max_dn", "offset"), ("trend_bow_dn", "bow")] {
            let (x, y) = (ours[a].as_f64().unwrap(), theirs[b].as_f64().unwrap());
            assert!((x - y).abs() <= 1e-6 * y.abs().max(1.0), "ADC {i}: {a} {x} vs numpy {y}");
        }
        let period = ours["period_codes"].as_u64();
        assert!(matches!(period, Some(64 | 128 | 256)), "ADC {i}: period {period:?}");
    }
    assert!(report["mean_correlation_same_camera"].as_f64().unwrap().abs() < 0.05, "{}", report["mean_correlation_same_camera"]);
    // Each camera's fitted stages as a camera model: its ADCs' transition levels follow
    // the table's offsets as far as the best stage fit explains them on all codes (the
    // model leaves out the fit's constant and cubic: a line and a cubic taken out of
    // both again).
    for (c, camera) in CAMERAS.iter().enumerate() {
        let path = tmp.path().join(format!("out/Photonfocus_MV-D1024E_{camera}_20131203-architecture.toml"));
        let config = dncal_host::model::camera::CameraConfig::from_toml_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let model = dncal_host::model::camera::Camera::new(config).unwrap();
        for adc in 0..4 {
            let ours = &adcs[4 * c + adc];
            let best = ours["stage_fits"].as_array().unwrap().iter().max_by(|a, b| a["held_out_explained"].as_f64().unwrap().total_cmp(&b["held_out_explained"].as_f64().unwrap())).unwrap();
            let table = dncal_host::formats::lut::kcor::KcorTable::read(Path::new(&specs[c].replace("{adc}", &adc.to_string()))).unwrap();
            let real = dncal_host::analyses::real_adcs::characterize(&table, camera, adc);
            let cal = dncal_host::formats::lut::kcor::FIRST_CALIBRATED..=dncal_host::formats::lut::kcor::LAST_CALIBRATED;
            // o_k is the transition into code k + 1.
            let modelled: Vec<f64> = cal.clone().map(|k| model.adcs[adc].level(k + 1) - (k as f64 + 0.5)).collect();
            let explained = explained_beside_cubic(&real.offsets, &modelled);
            let want = best["explained"].as_f64().unwrap();
            assert!((explained - want).abs() < 0.02, "camera {camera} ADC {adc}: model explains {explained:.3} of the offsets, the fit {want:.3}");
        }
    }
}

/// The share of `var(y)` that `m` explains beside a cubic in the index (least squares of
/// `y - m` on the cubic, then `1 - var(residual) / var(y)`).
fn explained_beside_cubic(y: &[f64], m: &[f64]) -> f64 {
    let n = y.len();
    let x = |i: usize| i as f64 / (n - 1) as f64;
    let a = nalgebra::DMatrix::from_fn(n, 4, |r, c| x(r).powi(c as i32));
    let d = nalgebra::DVector::from_iterator(n, y.iter().zip(m).map(|(y, m)| y - m));
    let b = a.clone().svd(true, true).solve(&d, 1e-12).unwrap();
    let r = d - a * b;
    let var = |v: &mut dyn Iterator<Item = f64>| {
        let v: Vec<f64> = v.collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64
    };
    1.0 - var(&mut r.iter().copied()) / var(&mut y.iter().copied())
}

/// `adc.widths_from = "kcor:SPEC"`: the camera model's ADCs take a real camera's code
/// widths (the tables' DN error, trend divided out: the ADC's DN error is that of the
/// table to 0.1% of a percent), relative to the TOML's folder; bad uses are errors naming
/// the TOML file.
#[test]
fn the_camera_model_takes_real_adcs() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let spec = dir.join("Photonfocus_MV-D1024E_13889_adc{adc}_20131203.bin");
    let toml = tmp.path().join("real.toml");
    std::fs::write(&toml, format!("[adc]\nwidths_from = \"kcor:{}\"\n", spec.display())).unwrap();
    let config = dncal_host::model::camera::CameraConfig::from_toml_file(&toml).unwrap();
    let camera = dncal_host::model::camera::Camera::new(config).unwrap();
    for adc in 0..4 {
        let table = dncal_host::formats::lut::kcor::KcorTable::read(Path::new(&spec.to_string_lossy().replace("{adc}", &adc.to_string()))).unwrap();
        let real = dncal_host::analyses::real_adcs::characterize(&table, "13889", adc);
        // The model ADC's widths over the calibrated codes, relative to their mean.
        let w = camera.adcs[adc].widths();
        let inner = &w[dncal_host::formats::lut::kcor::FIRST_CALIBRATED + 1..=dncal_host::formats::lut::kcor::LAST_CALIBRATED];
        let m = inner.iter().sum::<f64>() / inner.len() as f64;
        let rms = 100.0 * (inner.iter().map(|v| (v / m - 1.0).powi(2)).sum::<f64>() / inner.len() as f64).sqrt();
        assert!((rms - real.dn_error_rms_pct).abs() < 0.1, "ADC {adc}: model {rms}% vs table {}%", real.dn_error_rms_pct);
    }
    // Relative to the TOML's folder, and the errors.
    std::fs::write(tmp.path().join("rel.toml"), "[adc]\nwidths_from = \"kcor:tables/cam_adc{adc}.bin\"\n").unwrap();
    std::fs::create_dir(tmp.path().join("tables")).unwrap();
    for adc in 0..4 {
        std::fs::copy(spec.to_string_lossy().replace("{adc}", &adc.to_string()), tmp.path().join(format!("tables/cam_adc{adc}.bin"))).unwrap();
    }
    assert!(dncal_host::model::camera::CameraConfig::from_toml_file(&tmp.path().join("rel.toml")).is_ok());
    for (body, expected) in [
        (format!("bits = 10\n[adc]\nwidths_from = \"kcor:{}\"\n", spec.display()), "four 12-bit ADCs"),
        ("[adc]\nwidths_from = \"csv:x\"\n".to_string(), "the only source is kcor:SPEC"),
        (format!("[adc]\nwidths_from = \"kcor:{}\"\n", tmp.path().join("missing_adc{adc}.bin").display()), "missing_adc0.bin"),
    ] {
        let bad = tmp.path().join("bad.toml");
        std::fs::write(&bad, body).unwrap();
        let e = dncal_host::model::camera::CameraConfig::from_toml_file(&bad).unwrap_err().to_string();
        assert!(e.contains(expected), "{e}");
    }
}

/// Histogram sets simulated from real ADCs (`widths_from`, the paper's ramps): `diagnose`
/// names `adc-dnl` on each of the four (their DN error, 2.2-4.7% rms, is far above
/// detection at these counts), and a LUT built from them recovers the real code widths:
/// the correlation of neighbouring-width means (what a LUT step is) with the truth is at
/// least 0.98 over codes 200-4000 at 2e5 counts per code (measured on camera 11461: 0.994-0.998;
/// at 5e5, 0.996-0.999).
#[test]
fn histograms_of_real_adcs_are_diagnosed_and_their_widths_recovered() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let spec = dir.join("Photonfocus_MV-D1024E_11461_adc{adc}_20131203.bin");
    std::fs::write(d.join("real.toml"), format!("[adc]\nwidths_from = \"kcor:{}\"\n", spec.display())).unwrap();
    let run = |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_dncal")).args(args).current_dir(d).output().unwrap();
    // 6554 pixels per ADC (of the default 16384): about 2e5 counts per code.
    json(run(&["simulate", "histograms", "--config", "real.toml", "--pixels-per-adc", "6554", "-o", "h.fits", "--json"]), "simulate histograms");
    let diagnosis = json(run(&["diagnose", "h.fits", "--json"]), "diagnose");
    let mut named: Vec<u64> = diagnosis["findings"].as_array().unwrap().iter().filter(|f| f["effect"] == "adc-dnl").map(|f| f["adc"].as_u64().unwrap()).collect();
    named.sort();
    assert_eq!(named, vec![0, 1, 2, 3], "{diagnosis}");
    let built = json(run(&["lut", "build", "h.fits", "-o", "lut", "--truth", "real.toml", "--json"]), "lut build");
    // --truth judges each LUT against the camera the set was simulated with: better code
    // values than raw, and the paper's Fig. 5 beside the limit of these counts (2e5 a
    // code: 0.22% noise).
    for adc in 0..4 {
        let t = &built["truth"][adc];
        let (raw, lut) = (t["rms_raw_dn"].as_f64().unwrap(), t["rms_lut_dn"].as_f64().unwrap());
        let (reduction, ratio, noise) = (t["fig5"]["reduction"].as_f64().unwrap(), t["fig5"]["ratio_to_limit"].as_f64().unwrap(), t["fig5"]["lut_noise"].as_f64().unwrap());
        eprintln!("ADC {adc}: lut build --truth: rms {raw:.4} -> {lut:.4} DN, Fig. 5 {reduction:.2}x, {ratio:.2} of the limit at {:.3}% a code", 100.0 * noise);
        assert!(lut < raw, "ADC {adc}: {lut} DN with the LUT, {raw} raw");
        assert!(reduction > 1.0 && ratio > 0.0 && ratio < 1.0, "ADC {adc}: {reduction}x, {ratio} of the limit");
        assert!((0.0018..0.0026).contains(&noise), "ADC {adc}: {noise}");
    }
    // A camera of other ADCs than the set's is refused before anything is written,
    // naming both files.
    std::fs::write(d.join("two.toml"), "n_adc = 2\n").unwrap();
    let refused = run(&["lut", "build", "h.fits", "-o", "other", "--truth", "two.toml"]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("two.toml") && err.contains("h.fits") && err.contains("2 ADCs"), "{err}");
    assert!(!d.join("other.fits").exists() && !d.join("other.bin").exists());
    let lut = dncal_host::formats::fits::read_lut(&d.join("lut.fits")).unwrap();
    let hist = dncal_host::formats::fits::read_histograms(&d.join("h.fits")).unwrap();
    let config = dncal_host::model::camera::CameraConfig::from_toml_file(&d.join("real.toml")).unwrap();
    let camera = dncal_host::model::camera::Camera::new(config).unwrap();
    for adc in 0..4 {
        let truth = camera.adcs[adc].widths();
        let built: Vec<f64> = lut.weights.as_ref().unwrap()[adc].iter().map(|&b| b as f64 / (1u64 << 24) as f64).collect();
        let pairs = |w: &[f64]| -> Vec<f64> { (200..4000).map(|k| (w[k] + w[k + 1]) / 2.0).collect() };
        let (t, b) = (pairs(&truth), pairs(&built));
        let r = dncal_host::analyses::real_adcs::correlation(&t, &b);
        let per_code = hist.counts[adc][200..4000].iter().sum::<u64>() as f64 / 3800.0;
        eprintln!("ADC {adc}: {per_code:.0} counts per code, correlation {r:.4}");
        assert!(r >= 0.98, "ADC {adc}: correlation {r} at {per_code:.0} counts per code");
    }
}

/// The default recipe's Fig. 5 reduction (|Q| <= 0.01 I_max, `kcor-model --lut` of
/// `dncal adc`'s LUT) on the twelve real ADCs, measured with the median of the ADCs
/// below code 300 (issue 57; the mean alone gave 1.3/1.3/2.9/4.5, 1.2/1.5/4.1/5.5 and
/// 2.0/2.6/4.6/6.7; the paper's recipe 2.8-10.7).
const FIG5_SHARED: [(&str, [f64; 4]); 3] = [("08888", [3.4, 3.2, 8.6, 13.8]), ("11461", [3.0, 3.7, 12.0, 16.8]), ("13889", [4.4, 5.5, 7.9, 11.3])];

/// The LUT recipes on the twelve real ADCs (docs/kcor-luts.md, "The recipe's error"):
/// `dncal adc` simulates the paper's ramps through each camera's four ADCs (about 5e5
/// counts per code) and compares the LUT's code values with the true centres (offset and
/// gain removed). The shared illumination (the default) puts every ADC within 0.065 DN
/// rms (measured 0.028-0.062) and below its raw error; the paper's recipe, kept as
/// `--recipe paper`, is worse than no LUT on camera 11461's ADC 0 (measured 0.141 against
/// 0.076 raw). The paper's Fig. 5 figure of the default LUT is pinned to 10%
/// ([`FIG5_SHARED`], a deterministic run) and set beside the limit (true widths with the
/// counts' own noise, median of 5 draws): measured 0.26-0.44 of it, where the target of
/// issue 57 is 0.5.
#[test]
fn the_shared_recipe_beats_the_raw_codes_on_every_real_adc() {
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let truth = |v: &Value, adc: usize, what: &str| v["adcs"][adc]["truth"][what].as_f64().unwrap();
    for camera in CAMERAS {
        let spec = dir.join(format!("Photonfocus_MV-D1024E_{camera}_adc{{adc}}_20131203.bin"));
        std::fs::write(d.join("real.toml"), format!("[adc]\nwidths_from = \"kcor:{}\"\n", spec.display())).unwrap();
        let run = |recipe: &str| json(Command::new(env!("CARGO_BIN_EXE_dncal")).args(["adc", "--config", "real.toml", "--recipe", recipe, "-o", recipe, "--json"]).current_dir(d).output().unwrap(), "adc");
        let shared = run("shared");
        let hist = dncal_host::formats::fits::read_histograms(&d.join("shared/histograms.fits")).unwrap();
        let pinned = FIG5_SHARED.iter().find(|(c, _)| *c == camera).unwrap().1;
        for adc in 0..4 {
            let (raw, rms) = (truth(&shared, adc, "rms_raw_dn"), truth(&shared, adc, "rms_lut_dn"));
            // `adc` judges each LUT by Fig. 5 beside the limit; the limit's noise is the
            // counts' own, recomputed here from the histograms it wrote.
            let fig5 = &shared["adcs"][adc]["truth"]["fig5"];
            let (reduction, limit, ratio, noise) = (fig5["reduction"].as_f64().unwrap(), fig5["limit_reduction"].as_f64().unwrap(), fig5["ratio_to_limit"].as_f64().unwrap(), fig5["lut_noise"].as_f64().unwrap());
            let counts = hist.counts[adc][150..4095].iter().sum::<u64>() as f64 / 3945.0;
            eprintln!("{camera} ADC {adc}: raw {raw:.4} DN, shared {rms:.4} DN; Fig. 5 {reduction:.2}x, limit {limit:.2}x (noise {noise:.5}): {ratio:.2} of it");
            assert!(rms < 0.065 && rms < raw, "{camera} ADC {adc}: shared {rms} DN, raw {raw} DN");
            assert!((noise * counts.sqrt() - 1.0).abs() < 1e-9, "{camera} ADC {adc}: limit noise {noise} for {counts} counts a code");
            assert!((reduction / pinned[adc] - 1.0).abs() < 0.1, "{camera} ADC {adc}: Fig. 5 {reduction}x where {}x was measured", pinned[adc]);
            // Measured 0.26-0.44 of the limit (docs/kcor-luts.md).
            assert!((0.2..0.6).contains(&ratio), "{camera} ADC {adc}: {ratio} of the limit {limit}x");
        }
        if camera == "13889" {
            // `kcor-model --lut --limit-from` gives the same figures as `adc` (same LUT,
            // same counts, same draws).
            let k = json(
                Command::new(env!("CARGO_BIN_EXE_dncal"))
                    .args(["kcor-model", "--config", "real.toml", "--adc", "3", "--lut", "shared/lut.fits", "--limit-from", "shared/histograms.fits", "--q-fraction", "0.01", "--json"])
                    .current_dir(d)
                    .output()
                    .unwrap(),
                "kcor-model --limit-from",
            );
            let fig5 = &shared["adcs"][3]["truth"]["fig5"];
            for key in ["reduction", "limit_reduction", "lut_noise"] {
                let (a, b) = (k["against_limit"][key].as_f64().unwrap(), fig5[key].as_f64().unwrap());
                assert!((a - b).abs() <= 1e-12 * b.abs(), "{key}: kcor-model {a}, adc {b}");
            }
            assert!((k["reduction"].as_f64().unwrap() - fig5["reduction"].as_f64().unwrap()).abs() < 1e-9);
            let no_lut = Command::new(env!("CARGO_BIN_EXE_dncal")).args(["kcor-model", "--config", "real.toml", "--limit-from", "shared/histograms.fits"]).current_dir(d).output().unwrap();
            assert_eq!(no_lut.status.code(), Some(2), "{}", String::from_utf8_lossy(&no_lut.stderr));
        }
        if camera == "11461" {
            let paper = run("paper");
            let (raw, lut) = (truth(&paper, 0, "rms_raw_dn"), truth(&paper, 0, "rms_lut_dn"));
            assert!(lut > raw && lut > 2.0 * truth(&shared, 0, "rms_lut_dn"), "paper's recipe on 11461 ADC 0: {lut} DN, raw {raw} DN");
        }
    }
}

/// The LUT figure (`fig:kcormodellookup`) with real DN error, as docs/paper.md states it:
/// camera 13889 as the truth, the LUT from its true widths with 1% Gaussian noise per
/// code (20 draws, seeds 2018-2037), |Q| <= 0.01 I_max. The LUT's error is its noise's
/// random walk, not the ADC's: the same for all four ADCs, of the scale
/// `sigma sqrt(|Q| b)` (a sum of |Q| / b per-code errors of `sigma` DN each, `b` the
/// B_sun per DN) and growing as `sqrt(|Q|)`; the paper's ADC (index 3, the worst of the
/// four) gains the most, a median 5.8x (docs/paper.md), not an order of magnitude.
#[test]
fn the_lut_figure_with_real_adcs_is_set_by_the_random_walk_of_its_noise() {
    use dncal_host::analyses::kcor::run::kcor_model;
    use dncal_host::analyses::kcor::KcorParams;
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let spec = dir.join("Photonfocus_MV-D1024E_13889_adc{adc}_20131203.bin");
    let toml = tmp.path().join("real.toml");
    std::fs::write(&toml, format!("[adc]\nwidths_from = \"kcor:{}\"\n", spec.display())).unwrap();
    let camera = dncal_host::model::camera::Camera::new(dncal_host::model::camera::CameraConfig::from_toml_file(&toml).unwrap()).unwrap();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2 - 1] + v[v.len() / 2]) / 2.0
    };
    // (median LUT max |dQ|, median reduction) over the draws.
    let run = |adc: usize, q_fraction: f64| {
        let p = KcorParams { adc, steps: 60, q_fraction, lut_noise: 0.01, ..Default::default() };
        let s = kcor_model(&camera, &p, None, 20, None).unwrap();
        let floor = median(s.realizations.iter().map(|r| r.max_abs_sys_err_bsun_lut).collect());
        let reduction = median(s.realizations.iter().map(|r| r.reduction).collect());
        (floor, reduction, s.result)
    };
    let small: Vec<_> = (0..4).map(|adc| run(adc, 0.01)).collect();
    let r = &small[3].2;
    let scale = 0.01 * (0.01 * r.i_max_bsun * r.bsun_per_dn).sqrt();
    for (adc, (floor, reduction, _)) in small.iter().enumerate() {
        eprintln!("ADC {adc}: LUT floor {floor:.3e} B_sun = {:.2} sigma sqrt(Q b); median reduction {reduction:.2}x", floor / scale);
        assert!((floor / small[0].0 - 1.0).abs() < 0.05, "ADC {adc}: the floor is the noise's, not the ADC's");
        assert!((1.5..3.0).contains(&(floor / scale)), "ADC {adc}: floor {floor} against the random walk's scale {scale}");
        assert!(*reduction < 10.0, "ADC {adc}: {reduction}x");
    }
    let paper_adc = small[3].1;
    assert!((paper_adc - 5.8).abs() < 0.3, "the paper's ADC: {paper_adc}x where docs/paper.md says 5.8x");
    assert!(small.iter().all(|s| s.1 <= paper_adc), "ADC 3 gains the most");
    let (wide, _, _) = run(3, 0.1);
    let growth = wide / small[3].0;
    assert!((growth / 10f64.sqrt() - 1.0).abs() < 0.1, "ten times the Q range: the floor grows {growth}x, sqrt(10) for a random walk");
}

/// A deployed camera's four 23-bit tables loaded into the core as they are, frames of
/// codes (the camera's range, a few codes above its top, an ROI whose first column is not
/// a multiple of four) summed per modulation state, and every sum equal to numpy's
/// `lut[adc, codes]` summed over the state's frames: an oracle we did not write, on the
/// tables a real instrument used.
#[test]
fn the_core_sums_a_deployed_camera_as_numpy_indexes_it() {
    use dncal_core::{Corrector, Geometry, LutBanks, LutSet};
    use dncal_host::formats::lut::kcor::{expand, KcorTable};
    let Some(dir) = luts_dir() else { return };
    let spec = dir.join("Photonfocus_MV-D1024E_13889_adc{adc}_20131203.bin").to_string_lossy().into_owned();
    let tables: [[u32; 4096]; 4] = expand(&spec).unwrap().map(|path| KcorTable::read(&path).unwrap().entries.try_into().unwrap());
    let luts = LutSet::<4, 4096>::from_bits(&tables).unwrap();
    // First column 2: a head of 2 codes, 254 groups of four, a tail of 3.
    let (width, height, states, first_column, frames) = (1021u16, 6u16, 2u8, 2u16, 10usize);
    let g = Geometry::new(width, height, states, first_column).unwrap();
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let codes: Vec<u16> = (0..frames * g.pixels())
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            match x % 1000 {
                0 => 4096 + (x >> 20) as u16 % 60000,
                _ => (x >> 40) as u16 % 4096,
            }
        })
        .collect();
    let mut banks = Box::new(LutBanks::new(luts));
    let mut sums = vec![0u32; g.sum_len()];
    let mut c = Corrector::new(&mut banks, g, &mut sums).unwrap();
    for (f, frame) in codes.chunks_exact(g.pixels()).enumerate() {
        c.begin_frame((f % states as usize) as u8).unwrap();
        c.accumulate_lines(0, frame).unwrap();
        c.end_frame().unwrap();
    }
    let above = codes.iter().filter(|&&k| k > 4095).count() as u32;
    assert!(above > 0);
    assert_eq!(c.status().out_of_range_codes, above);
    drop(c);

    let tmp = tempfile::tempdir().unwrap();
    let codes_path = tmp.path().join("codes.u16");
    std::fs::write(&codes_path, codes.iter().flat_map(|k| k.to_le_bytes()).collect::<Vec<u8>>()).unwrap();
    let sums_path = tmp.path().join("sums.u8");
    let script = r#"
import sys, numpy as np
spec, codes_path, out, w, h, s, c0, n = sys.argv[1:9]
w, h, s, c0, n = int(w), int(h), int(s), int(c0), int(n)
lut = np.stack([np.fromfile(spec.replace("{adc}", str(a)), dtype="<u4") for a in range(4)]).astype(np.uint64)
codes = np.minimum(np.fromfile(codes_path, dtype="<u2").reshape(n, h, w), 4095)
adc = (c0 + np.arange(w)) % 4
sums = np.zeros((s, h, w), dtype=np.uint64)
for f in range(n):
    sums[f % s] += lut[adc[None, :], codes[f]]
sums.astype("<u8").tofile(out)
"#;
    let py = support::python()
        .arg("-c")
        .arg(script)
        .arg(&spec)
        .arg(&codes_path)
        .arg(&sums_path)
        .args([width.to_string(), height.to_string(), states.to_string(), first_column.to_string(), frames.to_string()])
        .output()
        .unwrap();
    assert!(py.status.success(), "numpy oracle: {}", String::from_utf8_lossy(&py.stderr));
    let theirs: Vec<u64> = std::fs::read(&sums_path).unwrap().chunks_exact(8).map(|b| u64::from_le_bytes(b.try_into().unwrap())).collect();
    assert_eq!(theirs.len(), sums.len());
    let differing = sums.iter().zip(&theirs).filter(|(&a, &b)| a as u64 != b).count();
    assert_eq!(differing, 0, "{differing} of {} sums differ from numpy", sums.len());
}

/// Issue 57, item 4: the built-in camera's ADCs (the nested pipeline) have the real ADCs'
/// statistics, not the tables' values. The twelve shared ADCs' statistics, as
/// `adc --from-luts` reports them, are first checked against numpy's (an implementation
/// of docs/model.md's definitions written apart from ours); then the median of the
/// built-in camera's four ADCs is held within 25% of the twelve's median on each, each
/// ADC inside the twelve's range, with the same period and ADCs as independent as the real
/// ones. The stage model of before
/// (jumps at the same binary boundaries in every ADC) fails the same check.
#[test]
fn the_built_in_adcs_have_the_real_adcs_statistics() {
    use dncal_host::analyses::width_statistics::WidthStatistics;
    use dncal_host::model::camera::{AdcConfig, Camera, CameraConfig};
    let Some(dir) = luts_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let (specs, report) = from_luts_report(&dir, tmp.path());
    let script = r#"
import json, sys, numpy as np
out = []
for spec in sys.argv[1:]:
    for a in range(4):
        e = np.fromfile(spec.replace("{adc}", str(a)), dtype="<u4").astype(float) * 4095 / (2**23 - 1)
        x = np.arange(4096) / 4095; sel = np.arange(150, 4095)
        tr = np.polyval(np.polyfit(x[sel], e[sel], 3), x)
        r = (np.diff(e) / np.diff(tr) - 1)[150:4094]
        r = r - r.mean(); k = np.arange(151, 4095); sd = r.std()
        def explained(m):
            means = np.array([r[k % m == q].mean() for q in range(m)])
            return means[k % m].var() / r.var()
        o = np.cumsum(r); i = np.arange(len(o))
        o = o - np.polyval(np.polyfit(i, o, 1), i)
        fold = np.array([o[k % 128 == q].mean() for q in range(128)])
        out.append({"rms_pct": 100 * sd, "narrow_spacing_codes": len(r) / max(np.sum(r < -3 * sd), 1),
                    "period_codes": next((2**j for j in range(1, 10) if explained(2**j) >= 0.5), None),
                    "sawtooth_dn": np.ptp(fold), "offsets_p2p_dn": np.ptp(o), "share_256": explained(256)})
print(json.dumps(out))
"#;
    let numpy = json(support::python().arg("-c").arg(script).args(&specs).output().unwrap(), "numpy oracle");
    let adcs = report["adcs"].as_array().unwrap();
    assert_eq!(adcs.len(), 12);
    let mut real = Vec::new();
    for (ours, theirs) in adcs.iter().zip(numpy.as_array().unwrap()) {
        let s = &ours["statistics"];
        assert_eq!(s["period_codes"], theirs["period_codes"], "{}", ours["camera"]);
        for key in ["rms_pct", "narrow_spacing_codes", "sawtooth_dn", "offsets_p2p_dn", "share_256"] {
            let (a, b) = (s[key].as_f64().unwrap(), theirs[key].as_f64().unwrap());
            assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{} ADC {}: {key} {a} against numpy's {b}", ours["camera"], ours["adc"]);
        }
        real.push(serde_json::from_value::<WidthStatistics>(s.clone()).unwrap());
    }
    let real_median = WidthStatistics::median(&real);
    assert_eq!(serde_json::to_value(real_median).unwrap(), report["median_statistics"]);
    // The real ADCs are independent: their mean correlation within a camera is 0.004.
    assert!(report["mean_correlation_same_camera"].as_f64().unwrap().abs() < 0.05, "{report}");
    let judge = |adc: AdcConfig| -> Result<(), String> {
        let camera = Camera::new(CameraConfig { adc, ..CameraConfig::default() }).unwrap();
        let stats: Vec<WidthStatistics> = camera.adcs.iter().map(|a| WidthStatistics::of_widths(&a.widths(), 151..=4094)).collect();
        let model = WidthStatistics::median(&stats);
        let mut wrong = Vec::new();
        // Each ADC inside the real ADCs' range on each statistic but the period.
        for (adc, s) in stats.iter().enumerate() {
            for (i, (name, v)) in s.named().into_iter().enumerate().filter(|&(i, _)| i != 2) {
                let (lo, hi) = real.iter().map(|r| r.named()[i].1).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
                if !(lo..=hi).contains(&v) {
                    wrong.push(format!("ADC {adc}: {name} {v:.3} outside the real {lo:.3}-{hi:.3}"));
                }
            }
        }
        if model.period_codes != real_median.period_codes {
            wrong.push(format!("period {:?} against {:?}", model.period_codes, real_median.period_codes));
        }
        for ((name, m), (_, r)) in model.named().into_iter().zip(real_median.named()) {
            if (m / r - 1.0).abs() > 0.25 {
                wrong.push(format!("{name} {m:.3} against the real median {r:.3}"));
            }
        }
        let r: Vec<Vec<f64>> = camera.adcs.iter().map(|a| a.widths()[151..=4094].to_vec()).collect();
        let pairs: Vec<f64> = (0..4).flat_map(|i| (i + 1..4).map(move |j| (i, j))).map(|(i, j)| dncal_host::analyses::real_adcs::correlation(&r[i], &r[j])).collect();
        let mean_corr = pairs.iter().sum::<f64>() / pairs.len() as f64;
        if mean_corr.abs() > 0.1 {
            wrong.push(format!("mean correlation between ADCs {mean_corr:.3}"));
        }
        if wrong.is_empty() { Ok(()) } else { Err(wrong.join("; ")) }
    };
    judge(AdcConfig::default()).unwrap_or_else(|e| panic!("the built-in camera's ADCs: {e}"));
    assert!(judge(AdcConfig::stages()).is_err(), "the stage model passed: the check cannot tell ADCs apart");
}
