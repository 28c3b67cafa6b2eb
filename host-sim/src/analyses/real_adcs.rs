//! Real ADCs measured from their deployed DN-error tables (`dncal adc --from-luts`): what
//! a K-Coronagraph table ([`crate::formats::lut::kcor`]) says about the ADC it corrects.
//!
//! A table maps code k to the top of its analog interval, `t_k` DN (full scale 4095 DN), so
//! `t_k - t_{k-1}` is code k's width as the calibration measured it. The recipe set the
//! first 150 and the last histogram values to one (de Wijn 2018 section 4; the tables'
//! entries 0-149 are identical across a camera's four ADCs), so only codes 150-4094 carry
//! the ADC. The K-Cor tables also carry a global response correction (their mean step
//! grows about 1.6 times across the range): the **slow trend**, a cubic `P(x)` in
//! `x = k / 4095` fitted to the table over the calibrated codes. What is left is the ADC:
//!
//! ```text
//! DN error            r_k = (t_k - t_{k-1}) / (P(x_k) - P(x_{k-1})) - 1      (per code)
//! cumulative offset   o_k = t_k - P(x_k)                                       (DN)
//! ```
//!
//! The pipelined-stage model of `docs/model.md` says `o_k` (the transition into code k+1)
//! is `sum_s e_{s, d_s(k+1)}` plus a constant: one offset per stage and digit. It is fitted
//! by least squares (beside a cubic, so the trend can move) for several stage layouts, on
//! a random half of the codes and scored on the other half (held-out explained fraction),
//! and on all codes for the per-stage sizes; three of the models add an inter-stage gain
//! per sub-range of the first stage ([`STAGE_MODELS`]).

use serde::Serialize;

use crate::formats::lut::kcor::{x, Detrended, KcorTable, FIRST_CALIBRATED, KCOR_CODES, LAST_CALIBRATED};
use crate::analyses::width_statistics::{residue_explained, WidthStatistics};
use crate::infra::stats::{lstsq, mean, variance};

/// The stage models tried: the layout, most significant stage first (12 bits each), and
/// whether each sub-range of the first stage has its own **inter-stage gain** (a slope
/// of the offsets over the lower stages' value within the sub-range: the residue passed
/// on is amplified by a gain that is off, differently in each sub-range, so the
/// transitions below it drift linearly and snap back at the next sub-range: the ramp
/// between the real tables' narrow codes). `[4, 8]` is any pattern of period 256 codes
/// plus an offset per 256-code block: the real tables' DN error repeats with a period of
/// 128 or 256 codes (their periodograms peak at 128 and its harmonics 64, 42.7, 32, 25.6,
/// 21.3), with several narrow codes per period at positions no binary stage boundary
/// explains.
pub const STAGE_MODELS: [(&[u32], bool); 8] = [(&[1; 12], false), (&[2; 6], false), (&[3; 4], false), (&[4; 3], false), (&[4, 8], false), (&[4; 3], true), (&[4, 8], true), (&[5, 7], true)];

/// One stage layout's fit to the cumulative offsets.
#[derive(Debug, Clone, Serialize)]
pub struct StageFit {
    /// Bits per stage, most significant first.
    pub stages: Vec<u32>,
    /// With a gain per sub-range of the first stage ([`STAGE_MODELS`]).
    pub segment_gains: bool,
    /// Parameters fitted (a constant, three trend terms, one offset per stage and non-zero digit).
    pub parameters: usize,
    /// Share of the offsets' variance the model explains on all codes.
    pub explained: f64,
    /// The same on held-out codes (fitted on a random half, scored on the other).
    pub held_out_explained: f64,
    /// RMS of the offsets the model leaves, all codes, DN.
    pub residual_rms_dn: f64,
    /// RMS over digits of each stage's offsets `e_{s,d}` (d = 0 is 0), DN.
    pub stage_rms_dn: Vec<f64>,
    /// The fit on all codes as a camera model's ADC (`[[adc.architecture]]`): the offsets
    /// and gains without the constant and the trend. Codes below [`FIRST_CALIBRATED`]
    /// follow the same stages (the tables do not measure them).
    pub architecture: crate::model::camera::Architecture,
}

/// How much of the DN error's variance the mean by code residue explains.
#[derive(Debug, Clone, Serialize)]
pub struct Residue {
    /// The modulus, 2^j.
    pub modulus: usize,
    /// Share of `var(r)` the residue means explain.
    pub explained: f64,
    /// What chance gives: `(modulus - 1) / (codes - 1)`.
    pub chance: f64,
}

/// One real ADC.
#[derive(Debug, Clone, Serialize)]
pub struct RealAdc {
    /// Camera label (the file name without the ADC tag).
    pub camera: String,
    /// ADC index.
    pub adc: usize,
    /// RMS DN error over the calibrated codes, %.
    pub dn_error_rms_pct: f64,
    /// The five codes of largest |DN error|: (code, %).
    pub worst_codes: Vec<(usize, f64)>,
    /// Largest |cumulative offset| and its RMS, DN.
    pub offset_max_dn: f64,
    /// RMS cumulative offset, DN.
    pub offset_rms_dn: f64,
    /// The trend `P(x) = p0 + p1 x + p2 x^2 + p3 x^3`, DN.
    pub trend_dn: [f64; 4],
    /// The trend's largest departure from the straight line through its ends, DN.
    pub trend_bow_dn: f64,
    /// Residue structure of the DN error (moduli 2 to 512).
    pub residues: Vec<Residue>,
    /// The smallest power-of-two period whose residue means explain at least half of the
    /// DN error's variance, codes (None: none up to 512).
    pub period_codes: Option<usize>,
    /// Stage-model fits.
    pub stage_fits: Vec<StageFit>,
    /// The statistics a model ADC is compared by ([`WidthStatistics`]).
    pub statistics: WidthStatistics,
    /// The DN error by code, `r_k` for k in 151..=4094 (for plots and comparisons).
    #[serde(skip)]
    pub dn_error: Vec<f64>,
    /// The cumulative offsets `o_k`, k in 150..=4094.
    #[serde(skip)]
    pub offsets: Vec<f64>,
}




/// Characterizes one table.
pub fn characterize(table: &KcorTable, camera: &str, adc: usize) -> RealAdc {
    let cal: Vec<usize> = (FIRST_CALIBRATED..=LAST_CALIBRATED).collect();
    let Detrended { c, dn_error, offsets } = table.detrended();
    let mut worst: Vec<(usize, f64)> = dn_error.iter().enumerate().map(|(i, &r)| (i + FIRST_CALIBRATED + 1, 100.0 * r)).collect();
    worst.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    worst.truncate(5);
    let trend_bow_dn = crate::infra::stats::cubic_bow(&c, KCOR_CODES);
    let var_r = variance(&dn_error);
    let residues: Vec<Residue> = (1..=9)
        .map(|j| {
            let m = 1usize << j;
            Residue { modulus: m, explained: residue_explained(&dn_error, FIRST_CALIBRATED + 1, m), chance: (m - 1) as f64 / (dn_error.len() - 1) as f64 }
        })
        .collect();
    // A fixed random half of the codes for the held-out score (a 64-bit LCG, so the split
    // is the same on every machine).
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ adc as u64;
    let fit_half: Vec<bool> = cal
        .iter()
        .map(|_| {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            state >> 63 == 1
        })
        .collect();
    let var_o = variance(&offsets);
    let stage_fits = STAGE_MODELS
        .iter()
        .map(|&(stages, segment_gains)| {
            // The offset o_k is the transition into code k + 1.
            let design: Vec<Vec<f64>> = cal.iter().map(|&k| crate::analyses::ieee1241::architecture::stage_row(stages, segment_gains, (k + 1) % KCOR_CODES, x(k))).collect();
            let pick = |want: bool| -> (Vec<Vec<f64>>, Vec<f64>) {
                design.iter().zip(&offsets).zip(&fit_half).filter(|(_, h)| **h == want).map(|((d, o), _)| (d.clone(), *o)).unzip()
            };
            let (xf, yf) = pick(true);
            let (xt, yt) = pick(false);
            let predict = |b: &[f64], row: &[f64]| row.iter().zip(b).map(|(r, b)| r * b).sum::<f64>();
            let held_out_explained = lstsq(&xf, &yf).map_or(f64::NAN, |b| {
                let res: Vec<f64> = xt.iter().zip(&yt).map(|(r, y)| y - predict(&b, r)).collect();
                1.0 - variance(&res) / variance(&yt)
            });
            let b = lstsq(&design, &offsets).unwrap_or_else(|| vec![0.0; design[0].len()]);
            let res: Vec<f64> = design.iter().zip(&offsets).map(|(r, y)| y - predict(&b, r)).collect();
            let mut at = 4;
            let stage_rms_dn = stages
                .iter()
                .map(|&s| {
                    let n = (1usize << s) - 1;
                    // Digit 0's offset is 0; the rms is over all 2^s digits.
                    let sum2: f64 = b[at..at + n].iter().map(|v| v * v).sum();
                    at += n;
                    (sum2 / (n + 1) as f64).sqrt()
                })
                .collect();
            StageFit {
                architecture: crate::analyses::ieee1241::architecture::pipelined_from(stages, segment_gains, &b, KCOR_CODES.trailing_zeros()),
                stages: stages.to_vec(),
                segment_gains,
                parameters: design[0].len(),
                explained: 1.0 - variance(&res) / var_o,
                held_out_explained,
                residual_rms_dn: variance(&res).sqrt(),
                stage_rms_dn,
            }
        })
        .collect();
    RealAdc {
        camera: camera.to_string(),
        adc,
        dn_error_rms_pct: 100.0 * var_r.sqrt(),
        worst_codes: worst,
        offset_max_dn: offsets.iter().fold(0.0, |m: f64, o| m.max(o.abs())),
        offset_rms_dn: variance(&offsets).sqrt(),
        trend_dn: [c[0], c[1], c[2], c[3]],
        trend_bow_dn,
        period_codes: residues.iter().find(|r| r.explained >= 0.5).map(|r| r.modulus),
        residues,
        stage_fits,
        statistics: WidthStatistics::of(&dn_error, FIRST_CALIBRATED + 1),
        dn_error,
        offsets,
    }
}

/// A camera model of one camera's four tables (`dncal adc --from-luts` writes it as
/// `CAMERA-architecture.toml`): 12 bits, four ADCs, each ADC the stage model that
/// explains most of its table's offsets held out, as `[[adc.architecture]]`.
pub fn architecture_model(camera: &str, adcs: &[RealAdc]) -> crate::model::camera::CameraConfig {
    let mut c = crate::model::camera::CameraConfig { bits: KCOR_CODES.trailing_zeros(), n_adc: adcs.len(), ..Default::default() };
    c.name = format!("{camera}: the stage models fitted to its K-Cor tables by dncal adc --from-luts");
    c.adc = crate::model::camera::AdcConfig::ideal(c.bits);
    c.adc.architecture = adcs
        .iter()
        .map(|a| a.stage_fits.iter().filter(|f| f.held_out_explained.is_finite()).max_by(|x, y| x.held_out_explained.total_cmp(&y.held_out_explained)).map_or(crate::model::camera::Architecture::Ideal {}, |f| f.architecture.clone()))
        .collect();
    c
}

/// The Pearson correlation of two equally long series.
pub fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let (ma, mb) = (mean(a), mean(b));
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let (va, vb): (f64, f64) = (a.iter().map(|x| (x - ma).powi(2)).sum(), b.iter().map(|y| (y - mb).powi(2)).sum());
    cov / (va * vb).sqrt()
}


#[cfg(test)]
mod tests {
    use super::*;
    use dncal_core::Weight;

    /// A table built from a planted pipelined ADC (three 4-bit stages, offsets of 0.05,
    /// 0.02 and 0.01 DN rms) under a planted cubic trend: the trend, the DN error and the
    /// stage offsets come back.
    #[test]
    fn planted_stage_errors_and_trend_come_back() {
        let stages = [4u32, 4, 4];
        let sizes = [0.05, 0.02, 0.01];
        // Deterministic pseudo-random stage offsets.
        let mut s = 12345u64;
        let mut next = || {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        let e: Vec<Vec<f64>> = sizes.iter().map(|&sd| (0..16).map(|d| if d == 0 { 0.0 } else { sd * 1.732 * next() }).collect()).collect();
        let offset = |code: usize| -> f64 { (0..3).map(|i| e[i][(code >> (8 - 4 * i)) & 15]).sum() };
        // Transition into code k: k - 1/2 + E(k); then a response trend on top.
        let response = |v: f64| v + 0.08 * v * v / 4095.0;
        let widths: Vec<f64> = (0..KCOR_CODES)
            .map(|k| {
                let lo = if k == 0 { 0.0 } else { response(k as f64 - 0.5 + offset(k)) };
                let hi = if k == KCOR_CODES - 1 { response(4095.0) } else { response(k as f64 + 0.5 + offset(k + 1)) };
                (hi - lo).max(0.0)
            })
            .collect();
        let weights: Vec<Weight> = widths.iter().map(|&w| Weight::from_num(w)).collect();
        let table = KcorTable::from_weights(&weights, 23).unwrap();
        let a = characterize(&table, "planted", 0);
        // The DN error against the planted widths' own (trend divided out by the naive
        // derivative of the response).
        let planted_rms = {
            let r: Vec<f64> = (FIRST_CALIBRATED + 1..=LAST_CALIBRATED).map(|k| 1.0 + offset(k + 1) - offset(k) - 1.0).collect();
            variance(&r).sqrt() * 100.0
        };
        assert!((a.dn_error_rms_pct / planted_rms - 1.0).abs() < 0.05, "{} vs {planted_rms}", a.dn_error_rms_pct);
        let fit = a.stage_fits.iter().find(|f| f.stages == stages && !f.segment_gains).unwrap();
        assert!(fit.held_out_explained > 0.95, "{fit:?}");
        for (got, want) in fit.stage_rms_dn.iter().zip(&e) {
            let want = (want.iter().map(|v| v * v).sum::<f64>() / 16.0).sqrt();
            assert!((got - want).abs() < 0.15 * want + 2e-3, "{got} vs {want}");
        }
        // The trend's bow: 0.08 v^2 / 4095 departs from its chord by 0.08 * 4095 / 4 DN,
        // and the table rescales the response's top (1.08 x 4095 DN) to 4095 DN.
        assert!((a.trend_bow_dn - 0.08 * 4095.0 / 4.0 / 1.08).abs() < 0.5, "{}", a.trend_bow_dn);
    }

    /// A sub-ranging ADC whose 16 sub-ranges each pass the residue on with their own gain
    /// error (0.1-0.4 DN of drift across a sub-range, then a snap back: a ramp between
    /// narrow codes), plus small stage offsets: the model with a gain per sub-range explains
    /// it held out; offsets per digit alone explain less.
    #[test]
    fn a_ramp_within_each_sub_range_is_an_inter_stage_gain() {
        let mut s = 777u64;
        let mut next = || {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let gains: Vec<f64> = (0..16).map(|_| 0.1 + 0.3 * next()).collect();
        let e: Vec<f64> = (0..16).map(|d| if d == 0 { 0.0 } else { 0.02 * (next() - 0.5) }).collect();
        let offset = |code: usize| -> f64 { -gains[code >> 8] * (code & 255) as f64 / 256.0 + e[code >> 8] };
        let widths: Vec<f64> = (0..KCOR_CODES)
            .map(|k| {
                let lo = if k == 0 { 0.0 } else { k as f64 - 0.5 + offset(k) };
                let hi = if k == KCOR_CODES - 1 { 4095.0 } else { k as f64 + 0.5 + offset(k + 1) };
                (hi - lo).max(0.0)
            })
            .collect();
        let weights: Vec<Weight> = widths.iter().map(|&w| Weight::from_num(w)).collect();
        let a = characterize(&KcorTable::from_weights(&weights, 23).unwrap(), "planted", 0);
        let held = |stages: &[u32], g: bool| a.stage_fits.iter().find(|f| f.stages == stages && f.segment_gains == g).unwrap().held_out_explained;
        assert!(held(&[4, 4, 4], true) > 0.95, "{:?}", a.stage_fits);
        assert!(held(&[4, 4, 4], false) < held(&[4, 4, 4], true) - 0.05, "{:?}", a.stage_fits);
    }

    #[test]
    fn the_twelve_bit_layouts_are_the_stage_models() {
        let want: Vec<(Vec<u32>, bool)> = STAGE_MODELS.iter().map(|(s, g)| (s.to_vec(), *g)).collect();
        let mut got = crate::analyses::ieee1241::architecture::layouts(12);
        got.sort();
        let mut want = want;
        want.sort();
        assert_eq!(got, want);
    }
}
