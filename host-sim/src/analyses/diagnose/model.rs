//! The camera model a diagnosis extends (`model.toml`, `docs/diagnose.md` "Closing the
//! loop"): the default camera with what the data measured and the findings the model
//! carries ([`super::Effect::in_model`]). The command writes it; the mapping lives here.

use super::{DiagnoseError, Diagnosis, Effect};
use crate::analyses::flatten::FlattenParams;

/// The camera model with the accepted findings of a histogram diagnosis: the default
/// camera at the data's bit depth and ADC count. When every ADC that shows `adc-dnl` has
/// an adopted architecture ([`crate::analyses::diagnose::AdcArchitecture`]), `adc.architecture`:
/// that architecture fitted again on all the ADC's counts, the others ideal. Otherwise
/// `adc.widths`: the code widths flattened from all the counts of each `adc-dnl` ADC (the
/// others ideal), a missing code kept at 1e-6 DN (measured widths need increasing
/// transition levels).
pub fn extended_model(hist: &crate::formats::fits::AdcHistograms, d: &Diagnosis, flatten: &FlattenParams) -> Result<crate::model::camera::CameraConfig, DiagnoseError> {
    let codes = 1usize << hist.bit_depth;
    let trimmed = crate::analyses::diagnose::trimmed_params(flatten);
    let dnl = |adc: usize| d.findings.iter().any(|f| f.effect == Effect::AdcDnl && f.adc == Some(adc));
    let adopted = |adc: usize| d.adc_architecture.as_ref().and_then(|v| v.get(adc)).and_then(Option::as_ref).filter(|a| a.adopted);
    let mut c = crate::model::camera::CameraConfig { bits: hist.bit_depth, n_adc: hist.counts.len(), ..Default::default() };
    c.name = "model extended by dncal diagnose".into();
    c.adc = crate::model::camera::AdcConfig::ideal(hist.bit_depth);
    if (0..hist.counts.len()).any(dnl) && (0..hist.counts.len()).all(|a| !dnl(a) || adopted(a).is_some()) {
        c.adc.architecture = (0..hist.counts.len())
            .map(|adc| match adopted(adc) {
                Some(arch) => {
                    // The same layout, fitted on the test of all the counts the diagnosis
                    // already ran (A's fit if that test could not run).
                    let all = d.adc_linearity.as_ref().and_then(|v| v.get(adc)).and_then(Option::as_ref);
                    let refit = all.into_iter().flat_map(crate::analyses::ieee1241::architecture::candidates).find(|c| c.architecture.name() == arch.name);
                    refit.map_or_else(|| arch.architecture.clone(), |c| c.architecture)
                }
                None => crate::model::camera::Architecture::Ideal {},
            })
            .collect();
        return Ok(c);
    }
    let mut widths = Vec::new();
    for (adc, counts) in hist.counts.iter().enumerate() {
        if dnl(adc) {
            let (f, _) = crate::analyses::flatten::flatten_narrowing(counts, &trimmed).map_err(|source| DiagnoseError::Flatten { adc, source })?;
            widths.push(f.weights.iter().map(|w| w.max(1e-6)).collect());
        } else {
            widths.push(vec![1.0; codes]);
        }
    }
    c.adc.widths = widths;
    Ok(c)
}

/// `base` with what `d` measured and accepted: conversion gain, read noise, dark level,
/// DSNU, PRNU, a colour filter's cells, full well (1.1 times the full scale, in electrons), bad pixels, the shared response
/// curve (`y = S + b2 S^2 + ...` DN becomes the camera's `a_k = b_k (FW / G)^(k-1)` of
/// `y/FW = x + a2 x^2 + ...`) and, with `pixel-nonlinearity`, the spread of `a2`. What
/// the data do not measure keeps `base`'s value.
pub fn apply_measured(mut c: crate::model::camera::CameraConfig, d: &Diagnosis) -> crate::model::camera::CameraConfig {
    let m = &d.measured;
    let g = m.gain_e_per_dn.unwrap_or(c.gain_e_per_dn);
    c.gain_e_per_dn = g;
    if let Some(s) = m.dsnu_dn {
        c.dsnu_rms_e = s * g;
    }
    // The dark level as a dark signal of 5 DSNU (so that the simulator's non-negative
    // dark keeps the whole spread; with none, half the pixels clipped at zero and the
    // re-diagnosis read 17 e- of DSNU for 40) on a black level; its shot noise comes out
    // of the read noise.
    if let Some(o) = m.offset_dn {
        c.dark_e = (5.0 * c.dsnu_rms_e).min(o.max(0.0) * g);
        c.offset_dn = o - c.dark_e / g;
    }
    if let Some(r) = m.read_noise_dn {
        c.read_noise_e = ((r * g).powi(2) - c.dark_e).max(0.0).sqrt();
    }
    if let Some(p) = m.prnu_rms {
        c.prnu_rms = p;
    }
    // The full well 10% above the measured full scale: the data show where the signal
    // clips, not whether the well or the ADC clips it; a well at exactly the full scale
    // made pixels of higher gain clip early and bend the top levels of a re-simulation.
    if let Some(f) = m.full_scale_dn.filter(|f| *f > 0.0) {
        c.full_well_e = 1.1 * f * g;
    }
    if let Some(b) = m.bad_fraction {
        c.bad_pixel_fraction = b;
    }
    // A colour filter's cells as measured (the PRNU above is then within a channel, as
    // the model applies it: cell times `1 + PRNU`).
    if let Some(cfa) = &m.cfa {
        c.cfa = Some(crate::model::camera::config::CfaConfig { period: cfa.period, cells: cfa.response.clone(), bayer: cfa.bayer });
    }
    if let Some(r) = m.illumination_change_rms {
        c.bench.illumination_change_rms = r.min(crate::model::camera::config::MAX_ILLUMINATION_CHANGE_RMS);
    }
    // The light's errors as the bench's, so that a set simulated from the model has them
    // (a consumer camera's series: its shutter's and aperture's errors, its jitter).
    let light = |r: f64| r.min(crate::model::camera::config::MAX_LIGHT_ERROR_RMS);
    if let Some(r) = m.light_level_rms {
        c.bench.level_error_rms = light(r);
    }
    if let Some(r) = m.light_jitter_rms {
        c.bench.frame_jitter_rms = light(r);
    }
    c.bench.reference = m.reference;
    let scale = c.full_well_e / g;
    c.nonlinearity = d.curve_per_dn.as_ref().map_or(Vec::new(), |b| b.iter().enumerate().map(|(k, b)| b * scale.powi(k as i32 + 1)).collect());
    c.pixel_nonlinearity_rms = match (m.pixel_b2_rms_per_dn, d.findings.iter().any(|f| f.effect == Effect::PixelNonlinearity)) {
        (Some(r), true) => {
            // A spread needs a term to spread: a zero shared a2 when no shared curve was found.
            if c.nonlinearity.is_empty() {
                c.nonlinearity = vec![0.0];
            }
            vec![r * scale]
        }
        _ => Vec::new(),
    };
    c
}

/// The camera model of a linearity set's diagnosis: the default camera at the set's size,
/// bit depth and ADC count with what the set measured ([`apply_measured`]) and an ideal ADC
/// (a linearity set cannot see code widths). Not yet in the camera model: per-ADC offset,
/// gain and curvature (an `adc-mismatch` is named in the file's header, not simulated).
pub fn linearity_model(set: &impl crate::formats::fits::LinearityKeys, d: &Diagnosis) -> crate::model::camera::CameraConfig {
    let (bit_depth, n_adc, [width, height, _]) = (set.bit_depth(), set.n_adc(), set.shape());
    let mut c = crate::model::camera::CameraConfig { bits: bit_depth, n_adc, width, height, ..Default::default() };
    c.name = "linearity set, model extended by dncal diagnose".into();
    c.adc = crate::model::camera::AdcConfig::ideal(bit_depth);
    // (A linearity set measures the bench's pattern change: none unless it was found.)
    c.bench.illumination_change_rms = 0.0;
    apply_measured(c, d)
}

/// The camera model of a photon-transfer set's diagnosis: bit depth, size, one ADC,
/// conversion gain, QE, dark noise, dark level and saturation from the EMVA 1288
/// datasheet, the shared response curve if accepted, and the code widths of the frames'
/// code density if `adc-dnl` was accepted (ideal otherwise); PRNU and DSNU from the
/// spatial series and the share of `bad-pixels` where the set has one (zero, not guessed,
/// where it has none).
pub fn ptc_model(set: &crate::analyses::emva::EmvaSet, sheet: &crate::analyses::emva::Datasheet, dark_dn: f64, d: &mut Diagnosis) -> crate::model::camera::CameraConfig {
    let summary = &sheet.temporal;
    let mut c = crate::model::camera::CameraConfig {
        bits: set.bits,
        n_adc: 1,
        width: set.width,
        height: set.height,
        qe: summary.quantum_efficiency.clamp(1e-6, 1.0),
        prnu_rms: 0.0,
        dsnu_rms_e: 0.0,
        bad_pixel_fraction: 0.0,
        ..Default::default()
    };
    c.name = "EMVA 1288 set, model extended by dncal diagnose".into();
    // (A photon-transfer set does not measure the linearity bench's pattern change.)
    c.bench.illumination_change_rms = 0.0;
    c.adc = crate::model::camera::AdcConfig::ideal(set.bits);
    if d.findings.iter().any(|f| f.effect == Effect::AdcDnl) {
        if let Some(cd) = &d.code_density {
            c.adc.widths = vec![cd.widths.clone()];
        }
    }
    d.measured = crate::analyses::diagnose::Measured {
        gain_e_per_dn: Some(summary.gain_e_per_dn),
        read_noise_dn: Some(summary.dark_noise_dn),
        offset_dn: Some(dark_dn),
        full_scale_dn: Some(summary.saturation_dn),
        saturated: summary.saturation_reached,
        prnu_rms: sheet.spatial.nonuniformity.prnu_pct.map(|p| p / 100.0),
        dsnu_dn: sheet.spatial.nonuniformity.dsnu_dn,
        bad_fraction: d.findings.iter().find(|f| f.effect == Effect::BadPixels).and_then(|f| f.count).map(|n| n as f64 / (set.width * set.height).max(1) as f64),
        ..Default::default()
    };
    // A response pattern (a colour filter's channels, or column or row gains): its cells,
    // and the PRNU within a cell (the rms of the channels' own) where every channel has
    // one; never the whole image's, which holds the pattern (none then).
    let cells = sheet.spatial.defect_pixels.as_ref().and_then(|p| p.cells.as_ref());
    if let (Some(cells), Some(channels)) = (cells, &sheet.spatial.channels) {
        let within: Vec<f64> = channels.iter().map(|c| c.nonuniformity.prnu_pct.map_or(f64::NAN, |p| p / 100.0)).collect();
        d.measured.prnu_rms = within.iter().all(|v| v.is_finite()).then(|| crate::infra::stats::rms(&within));
        let each = crate::analyses::emva::channels::describe(channels);
        match d.findings.iter_mut().find(|f| f.effect == Effect::CfaPattern) {
            Some(f) => f.detail += &format!("; per channel (row, column), each on its own pixels: {each}"),
            None => d.not_tested.push(format!(
                "cfa-pattern: {}, but its rows and columns do not interact as a colour filter's do (column or row gains; or a filter whose R B is its greens' square): not named; the model takes its cells and the PRNU within them; per cell: {each}",
                cells.describe()
            )),
        }
        if d.measured.prnu_rms.is_none() {
            d.not_tested.push("prnu: within a channel not measured (a channel's image too small for its nonuniformity); the whole image's holds the pattern and is not the model's".into());
        }
        d.measured.cfa = Some(crate::analyses::diagnose::channels::CfaResponse { period: cells.period, response: cells.response.clone(), prnu_within: within, bayer: None });
    }
    apply_measured(c, d)
}

