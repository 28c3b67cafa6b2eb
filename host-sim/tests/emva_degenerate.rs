//! EMVA 1288 sets the standard cannot characterize, as a user would meet them: `dncal
//! emva` must refuse them with one clear line naming the descriptor (exit 1), or give
//! each quantity it cannot measure as `null` with its reason; never NaN, inf or a
//! negative gain printed as a result.

mod support;

use std::path::Path;
use std::process::Output;

use rand_distr::{Distribution, Normal};
use support::{dncal_here as dncal, linear, photons, write_set};

fn assert_refused(out: &Output, descriptor: &Path, words: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr: {stderr}\nstdout: {}", String::from_utf8_lossy(&out.stdout));
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "one line: {stderr}");
    assert!(stderr.contains(&descriptor.display().to_string()), "{stderr} should name the descriptor");
    assert!(stderr.to_lowercase().contains(&words.to_lowercase()), "{stderr:?} should say {words:?}");
}

/// No NaN, inf or negative gain anywhere in the text or JSON output.
fn assert_finite_output(descriptor: &Path) -> serde_json::Value {
    let d = descriptor.to_str().unwrap();
    let text = dncal(&["emva", d]);
    assert!(text.status.success(), "{}", String::from_utf8_lossy(&text.stderr));
    let text = String::from_utf8_lossy(&text.stdout).to_string();
    for bad in ["NaN", "nan", "inf"] {
        assert!(!text.contains(bad), "{bad} in:\n{text}");
    }
    let json = dncal(&["emva", d, "--json"]);
    assert!(json.status.success());
    let raw = String::from_utf8_lossy(&json.stdout).to_string();
    let v: serde_json::Value = serde_json::from_str(&raw).expect("valid JSON (NaN would not parse)");
    assert!(v["gain_dn_per_e"].as_f64().unwrap() > 0.0);
    v
}

#[test]
fn all_frames_equal_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = write_set(dir.path(), &photons(20, 20000.0), |level, _, _| vec![100 + level as u16; 32 * 32]);
    assert_refused(&dncal(&["emva", d.to_str().unwrap()]), &d, "no temporal noise");
}

#[test]
fn a_variance_falling_with_the_signal_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Noise that shrinks as the light grows: the variance line has a negative slope.
    let d = write_set(dir.path(), &photons(20, 20000.0), |level, _, rng| {
        let noise = Normal::new(0.0, 20.0 / (1.0 + level as f64)).unwrap();
        (0..32 * 32).map(|_| (100.0 + 100.0 * level as f64 + noise.sample(rng)).round() as u16).collect()
    });
    let out = dncal(&["emva", d.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("does not rise") || stderr.contains("above dark"), "{stderr}");
}

#[test]
fn too_few_levels_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = write_set(dir.path(), &photons(4, 20000.0), linear);
    assert_refused(&dncal(&["emva", d.to_str().unwrap()]), &d, "at least 6 are needed");
}

#[test]
fn saturation_never_reached_gives_nulls_with_reasons() {
    let dir = tempfile::tempdir().unwrap();
    // Up to 8000 photons: 1000 DN, far from the 4095 clip; the variance still rises.
    let d = write_set(dir.path(), &photons(20, 8000.0), linear);
    let v = assert_finite_output(&d);
    assert!((v["gain_dn_per_e"].as_f64().unwrap() - 0.25).abs() < 0.03, "K {}", v["gain_dn_per_e"]);
    assert_eq!(v["saturation_reached"], false);
    for key in ["saturation_capacity_e", "snr_max", "dynamic_range", "saturation_photons"] {
        assert!(v[key].is_null(), "{key}: {}", v[key]);
        assert!(v["why"][key].as_str().unwrap().contains("saturation not reached"), "{key}: {}", v["why"][key]);
    }
    // No spatial series, no dark-current series: null with reasons too.
    for key in ["dsnu_e", "prnu_pct", "dark_current_mean_e_per_s"] {
        assert!(v[key].is_null() && v["why"][key].is_string(), "{key}");
    }
}

#[test]
fn a_clean_linear_camera_that_saturates_is_characterized() {
    let dir = tempfile::tempdir().unwrap();
    // Up to 40000 photons: 5000 DN would be above the 4095 clip, so the variance turns
    // over; planted K 0.25 DN/e-, QE 0.5.
    let d = write_set(dir.path(), &photons(30, 40000.0), linear);
    let v = assert_finite_output(&d);
    assert_eq!(v["saturation_reached"], true);
    let (k, qe) = (v["gain_dn_per_e"].as_f64().unwrap(), v["quantum_efficiency"].as_f64().unwrap());
    assert!((k - 0.25).abs() < 0.02 && (qe - 0.5).abs() < 0.04, "K {k}, QE {qe}");
    // The dark noise 2 DN with the 1/12 DN^2 of rounding: sigma_d = 2 / K = 8 e-.
    let sigma_d = v["dark_noise_e"].as_f64().unwrap();
    assert!((sigma_d - 8.0).abs() < 0.8, "sigma_d {sigma_d}");
}

/// Photon counts copied from one line to every level (0, or a real count): each level
/// repeats the first's exposure and photons; refused, as the reference implementation
/// refuses it (with 0 photons R would also be 0/0).
#[test]
fn photon_counts_copied_to_every_level_are_refused() {
    for count in ["0", "5000"] {
        let dir = tempfile::tempdir().unwrap();
        let d = write_set(dir.path(), &photons(20, 20000.0), linear);
        let text = std::fs::read_to_string(&d).unwrap();
        let same: String = text.lines().map(|l| if l.starts_with("b ") { format!("b 1000.0 {count}\n") } else { format!("{l}\n") }).collect();
        std::fs::write(&d, same).unwrap();
        assert_refused(&dncal(&["emva", d.to_str().unwrap()]), &d, "one level per exposure and photon count");
    }
}
