//! Hidden-effect generator: measured-looking data with effects planted at random, for
//! blind tests of `dncal diagnose` (the tests know what was hidden; diagnose does not).
//!
//! Linearity sets are drawn at the level of their sufficient statistics rather than frame
//! by frame (a 64 x 64 x 41 x 256-frame set would take minutes): per pixel and level the
//! mean of `N` Gaussian frames is `Normal(mu, var / N)` and their sample variance is
//! `var chi^2_(N-1) / (N-1)`, independent of it, which is exactly what averaging `N`
//! frames gives. `var` is read noise, shot noise and one code's quantization
//! (`r^2 + S / K + 1/12` DN^2 for a linear camera; the shot noise through the slope of
//! the pixel's response and both through the ADC's, `h'^2 (r^2 + G'^2 S / K) + 1/12`,
//! where they bend); with 4 DN of read noise the mean of quantized frames is
//! unbiased to far below its noise (`crate::analyses::quantization`).
//!
//! The camera, in DN: pixel `p` on ADC `a` (column mod 4) at reference `x` reads
//! `h_a(o + d_p + G_p(g_p S_max x))`, `G_p(S) = S (1 + c2_p S/T + c3 (S/T)^2)`, where `h_a`
//! is the ADC's transfer (identity, or a gain, offset or curvature mismatch acting on the
//! whole analog level), `d_p` the DSNU, `g_p` the PRNU and `T` the top code.
//!
//! Lab imperfections common to every pixel of a level ([`Hidden::LevelErrors`]): the light
//! at level `l` is `x_l (1 + eps_l)` where the reference detector reads `x_l` (source
//! flicker against a diode that does not see it), and the black level is off by
//! `delta_l` (a clamp that settles differently per acquisition). Both are drawn
//! independently per level: a scientist who takes the levels in random order turns a slow
//! drift into exactly that; a drift over levels taken in order is smooth in `x` and no
//! analysis of one set can tell it from a shared nonlinearity.
//! [`Plant::excess_noise`] makes the means noisier than the frames' standard deviations
//! say (correlated frames), by a fraction of their variance.

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::{ChiSquared, Distribution, Normal};

use crate::formats::fits::LinearitySet;

/// One planted effect.
#[derive(Debug, Clone, PartialEq)]
pub enum Hidden {
    /// A shared curvature: `c2` (relative bend at full scale).
    GlobalNonlinearity { c2: f64 },
    /// Per-pixel spread of `c2`, rms.
    PixelNonlinearity { rms: f64 },
    /// ADC `adc`'s gain is `1 + rel` times the others'.
    AdcGain { adc: usize, rel: f64 },
    /// ADC `adc` adds `dn` DN.
    AdcOffset { adc: usize, dn: f64 },
    /// ADC `adc` bends: `h(v) = v (1 + e v / T)`.
    AdcCurvature { adc: usize, e: f64 },
    /// `count` pixels are dead (no response), hot (always the top code) or kinked (a step
    /// of 20-100 DN at a random level).
    BadPixels { count: usize },
    /// Per-level errors common to all pixels: the light off from the reference by
    /// `rel_rms` (relative, rms) and the black level off by `offset_dn` (rms).
    LevelErrors { rel_rms: f64, offset_dn: f64 },
    /// `count` pixels whose mean jumps by `dn` rms from level to level (telegraph-like
    /// pixels): below the bad-pixel threshold each, structure all the same. Not in
    /// [`pick`]: diagnose names it `unexplained`.
    SubtleBad { count: usize, dn: f64 },
    /// A charge loss every pixel shares at low signal: `S - dn (1 - exp(-S / 100 DN))`.
    /// Not in [`pick`]: diagnose names it `low-signal-nonlinearity`.
    ChargeLoss { dn: f64 },
    /// The light's spatial pattern changes from level to level by `rms` (relative, over
    /// the sensor): [`crate::model::camera::calibration::illumination_change`], the
    /// camera model's `[bench] illumination_change_rms`.
    IlluminationChange { rms: f64 },
    /// A colour filter array: the pixel at row `r`, column `c` responds `response[(r mod
    /// 2) * 2 + c mod 2]` times (a Bayer filter: one diagonal's two cells alike). Not in
    /// [`pick`]: diagnose names it `cfa-pattern`.
    Cfa { response: [f64; 4] },
    /// The light of each frame off its level's by `rms` (relative, drawn per frame and
    /// alike for every pixel: a source that flickers, a shutter that jitters): the
    /// frames' means carry it as a level error, their spread as a variance `rms^2 S^2`
    /// over the photon transfer. Not in [`pick`]: diagnose names it `light-jitter`.
    LightJitter { rms: f64 },
    /// The levels taken as two series (the odd levels the second: a consumer camera's
    /// exposure series at two apertures, interleaved in reference), the second's light
    /// `1 + rel` times what the reference says (daylight that drifted between them, an
    /// aperture off its marked value). Not in [`pick`]: diagnose names it `level-errors`.
    SeriesDrift { rel: f64 },
}

/// (What `diagnose` should name for each is `Hidden::expected`, in
/// [`crate::analyses::diagnose`].)
impl Hidden {
    /// The ADC the effect is planted in, where it is one ADC's.
    pub fn adc(&self) -> Option<usize> {
        match self {
            Hidden::AdcGain { adc, .. } | Hidden::AdcOffset { adc, .. } | Hidden::AdcCurvature { adc, .. } => Some(*adc),
            _ => None,
        }
    }
}

/// The camera of the generator (defaults: 64 x 64 pixels, 4 ADCs, 12 bits, 41 levels,
/// 256 frames, 3600 DN at full reference, 44 e-/DN, 4 DN read noise, 1% PRNU, 1 DN DSNU).
#[derive(Debug, Clone)]
pub struct Plant {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// ADCs.
    pub n_adc: usize,
    /// Levels including dark.
    pub levels: usize,
    /// Frames per level.
    pub frames: u32,
    /// Mean signal at the brightest level, DN.
    pub full_dn: f64,
    /// e- per DN (shot noise).
    pub gain_e_per_dn: f64,
    /// Read noise, DN.
    pub read_dn: f64,
    /// PRNU, relative rms.
    pub prnu: f64,
    /// DSNU, DN rms.
    pub dsnu_dn: f64,
    /// Black level, DN.
    pub offset_dn: f64,
    /// Extra variance of the means beyond `var / N`, as a fraction of it (frames that are
    /// not independent): a noise model off by a few percent, which is not structure.
    pub excess_noise: f64,
    /// Draw every frame and round it to a code (slow: for low-noise sets, where the
    /// sufficient statistics' Gaussian shortcut does not hold).
    pub quantized: bool,
    /// The reference of level 0 as a fraction of the largest: 0 is a dark level; above,
    /// a set without one (a consumer camera's shortest exposure), the levels spread
    /// evenly from there.
    pub reference_start: f64,
}

impl Default for Plant {
    fn default() -> Self {
        Plant { width: 64, height: 64, n_adc: 4, levels: 41, frames: 256, full_dn: 3600.0, gain_e_per_dn: 44.0, read_dn: 4.0, prnu: 0.01, dsnu_dn: 1.0, offset_dn: 60.0, excess_noise: 0.0, quantized: false, reference_start: 0.0 }
    }
}

/// Picks 0 to 2 effects at random (kind, ADC, amplitude) at amplitudes a careful
/// scientist would detect in a 64 x 64 set; never two on one ADC.
pub fn pick(rng: &mut StdRng, n_adc: usize, how_many: usize) -> Vec<Hidden> {
    let mut out: Vec<Hidden> = Vec::new();
    let sign = |rng: &mut StdRng| if rng.random::<bool>() { 1.0 } else { -1.0 };
    while out.len() < how_many {
        let kind = rng.random_range(0..8);
        let adc = rng.random_range(0..n_adc);
        let h = match kind {
            0 => Hidden::GlobalNonlinearity { c2: sign(rng) * rng.random_range(0.01..0.04) },
            1 => Hidden::PixelNonlinearity { rms: rng.random_range(0.002..0.01) },
            2 => Hidden::AdcGain { adc, rel: sign(rng) * rng.random_range(0.01..0.03) },
            3 => Hidden::AdcOffset { adc, dn: sign(rng) * rng.random_range(1.0..3.0) },
            4 => Hidden::AdcCurvature { adc, e: sign(rng) * rng.random_range(0.005..0.02) },
            5 => Hidden::BadPixels { count: rng.random_range(5..40) },
            // The paper's bench needs about 3e-4 (`docs/paper.md`); from about 3.5e-4 on
            // this set the pattern's part that no model can tell from the pixels' own
            // curves stands out by itself (`docs/diagnose.md`).
            6 => Hidden::IlluminationChange { rms: rng.random_range(2e-4..3.2e-4) },
            // Either part or both, each at 0.5-3 times the noise of one pixel's mean at
            // full scale (0.6 DN) or at dark (0.25 DN).
            _ => match rng.random_range(0..3) {
                0 => Hidden::LevelErrors { rel_rms: rng.random_range(1e-4..5e-4), offset_dn: 0.0 },
                1 => Hidden::LevelErrors { rel_rms: 0.0, offset_dn: rng.random_range(0.1..0.8) },
                _ => Hidden::LevelErrors { rel_rms: rng.random_range(1e-4..5e-4), offset_dn: rng.random_range(0.1..0.8) },
            },
        };
        let clash = out.iter().any(|o| std::mem::discriminant(o) == std::mem::discriminant(&h) || (o.adc().is_some() && o.adc() == h.adc()));
        if !clash {
            out.push(h);
        }
    }
    out
}

/// Draws a linearity set of `plant` with `hidden` planted; `seed` drives every draw.
pub fn linearity_set(plant: &Plant, hidden: &[Hidden], seed: u64) -> LinearitySet {
    let mut rng = StdRng::seed_from_u64(seed);
    let (w, h, nl) = (plant.width, plant.height, plant.levels);
    let np = w * h;
    let top = 4095.0;
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    let mut c2 = vec![0.0; np];
    let (mut adc_gain, mut adc_offset, mut adc_bend) = (vec![1.0; plant.n_adc], vec![0.0; plant.n_adc], vec![0.0; plant.n_adc]);
    let mut bad_count = 0;
    let (mut light, mut black) = (vec![0.0; nl], vec![0.0; nl]);
    let (mut subtle, mut subtle_dn) = (0, 0.0);
    let mut loss = 0.0;
    let mut pattern: Option<(f64, u64)> = None;
    let mut cfa: Option<[f64; 4]> = None;
    let mut jitter = 0.0;
    let mut series = 0.0;
    for e in hidden {
        match *e {
            Hidden::GlobalNonlinearity { c2: c } => c2.iter_mut().for_each(|v| *v += c),
            Hidden::PixelNonlinearity { rms } => c2.iter_mut().for_each(|v| *v += rms * unit.sample(&mut rng)),
            Hidden::AdcGain { adc, rel } => adc_gain[adc] = 1.0 + rel,
            Hidden::AdcOffset { adc, dn } => adc_offset[adc] = dn,
            Hidden::AdcCurvature { adc, e } => adc_bend[adc] = e,
            Hidden::BadPixels { count } => bad_count = count,
            Hidden::SubtleBad { count, dn } => (subtle, subtle_dn) = (count, dn),
            Hidden::ChargeLoss { dn } => loss = dn,
            Hidden::IlluminationChange { rms } => pattern = Some((rms, rng.random())),
            Hidden::Cfa { response } => cfa = Some(response),
            Hidden::LightJitter { rms } => jitter = rms,
            Hidden::SeriesDrift { rel } => series = rel,
            Hidden::LevelErrors { rel_rms, offset_dn } => {
                light.iter_mut().for_each(|v| *v = rel_rms * unit.sample(&mut rng));
                black.iter_mut().for_each(|v| *v = offset_dn * unit.sample(&mut rng));
            }
        }
    }
    let channel = |p: usize| cfa.map_or(1.0, |r| r[crate::model::camera::config::cfa_cell(p % w, p / w, 2)]);
    let gain: Vec<f64> = (0..np).map(|p| channel(p) * (1.0 + plant.prnu * unit.sample(&mut rng))).collect();
    let dark: Vec<f64> = (0..np).map(|_| plant.dsnu_dn * unit.sample(&mut rng)).collect();
    // Bad pixels: distinct, each dead, hot or kinked.
    let mut kind = vec![0u8; np];
    let mut kink = vec![(0usize, 0.0); np];
    let mut placed = 0;
    while placed < bad_count {
        let p = rng.random_range(0..np);
        if kind[p] == 0 {
            kind[p] = rng.random_range(1..=3);
            kink[p] = (rng.random_range(5..nl - 5), rng.random_range(20.0..100.0));
            placed += 1;
        }
    }
    // Subtle pixels: distinct from the bad ones.
    let mut jumpy = vec![false; np];
    let mut placed = 0;
    while placed < subtle.min(np - bad_count) {
        let p = rng.random_range(0..np);
        if kind[p] == 0 && !jumpy[p] {
            jumpy[p] = true;
            placed += 1;
        }
    }
    let chi = ChiSquared::new(f64::from(plant.frames - 1)).expect("frames > 1");
    // (At a dark level 0, `l / (nl - 1)` as it always was: the same sets, bit for bit.)
    let reference = |l: usize| if plant.reference_start == 0.0 { l as f64 / (nl - 1) as f64 } else { plant.reference_start + (1.0 - plant.reference_start) * l as f64 / (nl - 1) as f64 };
    let n = f64::from(plant.frames);
    let (mut mean, mut std) = (vec![0.0; nl * np], vec![0.0; nl * np]);
    // Below `N - 1` degrees of freedom, what is left of a pixel's frames' spread beside
    // the jitter's direction (with jitter only).
    // (With two frames nothing is left: `chi^2_0` is 0.)
    let rest = (jitter > 0.0).then(|| (plant.frames > 2).then(|| ChiSquared::new(f64::from(plant.frames - 2)).expect("frames > 2")));
    for l in 0..nl {
        // The light of each frame relative to the level's (with jitter): their mean, and
        // their deviations' length `sqrt(sum (e_f - mean)^2)`.
        let frames: Vec<f64> = if jitter > 0.0 { (0..plant.frames).map(|_| jitter * unit.sample(&mut rng)).collect() } else { Vec::new() };
        let e_mean = if frames.is_empty() { 0.0 } else { frames.iter().sum::<f64>() / n };
        let e_len = frames.iter().map(|e| (e - e_mean).powi(2)).sum::<f64>().sqrt();
        let x_level = reference(l) * (1.0 + light[l]) * if l % 2 == 1 { 1.0 + series } else { 1.0 };
        let change = pattern.map(|(rms, seed)| crate::model::camera::calibration::illumination_change(rms, w, h, seed, l));
        for p in 0..np {
            let a = (p % w) % plant.n_adc;
            let x_p = change.as_ref().map_or(x_level, |c| x_level * (1.0 + c[p]));
            let extra = if jumpy[p] { subtle_dn * unit.sample(&mut rng) } else { 0.0 };
            // The pixel's code and signal at a light `e` off the level's (relative).
            let respond = |e: f64| {
                let x = x_p * (1.0 + e);
                let s_lin = if kind[p] == 1 { 0.0 } else { gain[p] * plant.full_dn * x };
                let s = s_lin * (1.0 + c2[p] * s_lin / top) - loss * (1.0 - (-s_lin / 100.0).exp());
                let mut v = plant.offset_dn + black[l] + dark[p] + s + extra;
                if kind[p] == 3 && l >= kink[p].0 {
                    v += kink[p].1;
                }
                (adc_gain[a] * v * (1.0 + adc_bend[a] * v / top) + adc_offset[a], s_lin, v)
            };
            let (code, s_lin, v) = respond(e_mean);
            // The noise where it arises, carried through the slopes after it: the shot
            // noise of the pixel's charge through its own response's slope, with the read
            // noise through the ADC's (a nonlinearity of the conversion bends the photon
            // transfer too: `var = f'(N)^2 N`).
            let (slope_s, slope_adc) = (1.0 + 2.0 * c2[p] * s_lin / top - loss * (-s_lin / 100.0).exp() / 100.0, adc_gain[a] * (1.0 + 2.0 * adc_bend[a] * v / top));
            let var = slope_adc * slope_adc * (plant.read_dn.powi(2) + slope_s * slope_s * s_lin.max(0.0) / plant.gain_e_per_dn) + 1.0 / 12.0;
            let i = l * np + p;
            if kind[p] == 2 {
                (mean[i], std[i]) = (top, 0.0);
            } else if plant.quantized {
                let sd = (var - 1.0 / 12.0).max(0.0).sqrt();
                let (mut s1, mut s2) = (0.0, 0.0);
                for f in 0..plant.frames as usize {
                    let c = frames.get(f).map_or(code, |&e| respond(e).0);
                    let q = (c + sd * unit.sample(&mut rng)).round().clamp(0.0, top);
                    s1 += q;
                    s2 += q * q;
                }
                mean[i] = s1 / n;
                std[i] = ((s2 - s1 * s1 / n) / (n - 1.0)).max(0.0).sqrt();
            } else if let Some(rest) = &rest {
                // The frames `c(e_f) + n_f` to first order in the jitter, `c + A e_f + n_f`
                // with `A` the code's slope in `e`: their mean `c(mean e) + mean n`, their
                // sum of squares `(A |e - mean e| + sd z)^2 + sd^2 chi^2_(N-2)` (the
                // noise's part along the jitter's direction, and the rest).
                let slope = (respond(e_mean + 1e-4).0 - respond(e_mean - 1e-4).0) / 2e-4;
                let sd = var.sqrt();
                mean[i] = (code + (var * (1.0 + plant.excess_noise) / n).sqrt() * unit.sample(&mut rng)).min(top);
                let along = slope * e_len + sd * unit.sample(&mut rng);
                let left = rest.as_ref().map_or(0.0, |c| c.sample(&mut rng));
                std[i] = ((along * along + var * left) / (n - 1.0)).sqrt();
            } else {
                mean[i] = (code + (var * (1.0 + plant.excess_noise) / n).sqrt() * unit.sample(&mut rng)).min(top);
                std[i] = (var * chi.sample(&mut rng) / (n - 1.0)).sqrt();
            }
        }
    }
    LinearitySet {
        bit_depth: 12,
        n_adc: plant.n_adc,
        n_frames: plant.frames,
        width: w,
        height: h,
        levels: nl,
        mean,
        std,
        voltage: (0..nl).map(|l| if plant.reference_start == 0.0 { 2.5 * l as f64 / (nl - 1) as f64 } else { 2.5 * reference(l) }).collect(),
        mask: None,
        keys: Default::default(),
    }
}
