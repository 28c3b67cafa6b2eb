//! Sampled frames, line by line: the model of [`super`] with random draws. Each line
//! has its own eight streams seeded from (frame seed, row) ([`super::draws`], whose
//! module comment is the seed contract), so lines can be drawn in any order or in
//! parallel, a frame is reproducible from its seed, and a vector unit draws eight
//! pixels of a line at once.
//!
//! Every pixel has its own Poisson mean (PRNU, DSNU), so a sampler that builds its
//! constants once per mean (rand_distr's `Poisson`: ten of them, divisions and powers)
//! pays that per pixel. The draw is PTRS instead (Hoermann 1993, the transformed
//! rejection numpy uses for means of 10 and up): a square root and a few divisions per
//! mean, two uniforms per trial, accepted at once 35% of the time at a mean of 10 and
//! 80% at large means (the rest through a logarithmic test); below 10 it multiplies
//! uniforms (Knuth). The read noise's Gaussian is Box-Muller, a pair every second
//! pixel of a stream. Both are exact in distribution (tested against the Poisson PMF by
//! chi-square and the normal's moments and CDF).

use super::draws::{Build, LineDraws, CHUNK};
use super::{Camera, PixelState};

/// The seed of frame `frame` of a run seeded `seed`: what `stream` and the Python
/// `simulate_frames` draw frame `frame` with.
pub fn frame_seed(seed: u64, frame: u64) -> u64 {
    seed.wrapping_mul(0x2545_F491_4F6C_DD1D).wrapping_add(frame)
}

impl Camera {
    /// Draws line `row` of a frame with seed `frame_seed`; `photons(column)` is the mean
    /// number of photons reaching each pixel in the frame.
    pub fn sample_line(&self, row: usize, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        self.sample_span(row, 0..self.config.width, frame_seed, photons)
    }

    /// Draws the pixels `columns` of line `row` (a ROI readout), as [`Self::sample_line`].
    pub fn sample_span(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        let mut out = vec![0; columns.len()];
        self.sample_span_into(row, columns, frame_seed, photons, &mut out);
        out
    }

    /// As [`Self::sample_span`], into `out` (one code per column of `columns`; extra
    /// columns or codes are left alone). Each call lays out the ADCs' edges anew: a
    /// caller drawing many lines keeps a [`Camera::sampler`].
    pub fn sample_span_into(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64, out: &mut [u16]) {
        self.sampler().sample_span_into(row, columns, frame_seed, photons, out)
    }

    /// A sampler of this camera's lines.
    pub fn sampler(&self) -> Sampler<'_> {
        Sampler::new(self)
    }
}

/// A camera's lines drawn into codes, eight pixels side by side: the draws
/// ([`super::draws`]), then each pixel's response, read noise and ADC code in loops a
/// vector unit runs, the ADCs' transition levels laid out in one table so that a gather
/// reads each pixel's edges whatever its ADC. The same codes as the model pixel by pixel
/// ([`Camera::response_e`], [`super::AdcTransfer::code`]) on every build: the same
/// operations in the same order, and a scalar walk where one step from the ideal code
/// does not reach the code (tested).
pub struct Sampler<'a> {
    camera: &'a Camera,
    /// ADC `a`'s `T_k` at `a * codes + k` (`T_0` = -inf), DN.
    edges: Vec<f64>,
    /// `bases[j]` = `(j mod n_adc) * codes`: the first edge of the ADC of the chunk's
    /// pixel `t` is `bases[adc0 + t]` for a chunk starting at ADC `adc0`.
    bases: Vec<u32>,
    build: Build,
}

impl<'a> Sampler<'a> {
    fn new(camera: &'a Camera) -> Self {
        let codes = camera.config.codes();
        let edges: Vec<f64> = camera.adcs.iter().flat_map(|a| a.edges().iter().copied()).collect();
        let n_adc = camera.adcs.len();
        let bases = (0..CHUNK + n_adc).map(|j| ((j % n_adc) * codes) as u32).collect();
        Sampler { camera, edges, bases, build: Build::best() }
    }

    /// The sampler with a given build, `Portable` where the CPU lacks the one asked
    /// ([`Build::available`]).
    pub fn with_build(mut self, build: Build) -> Self {
        self.build = if build.available() { build } else { Build::Portable };
        self
    }

    /// [`Camera::sample_span`].
    pub fn sample_span(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        let mut out = vec![0; columns.len()];
        self.sample_span_into(row, columns, frame_seed, photons, &mut out);
        out
    }

    /// [`Camera::sample_span_into`].
    pub fn sample_span_into(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64, out: &mut [u16]) {
        // A chunk of means, then their draws eight streams at a time, then the codes: each
        // in a loop of its own, where a vector unit runs them.
        let camera = self.camera;
        let cfg = &camera.config;
        let mut draws = LineDraws::new(frame_seed, row);
        let base = row * cfg.width;
        let qe = cfg.qe;
        let n_adc = camera.adcs.len();
        let adc0 = dncal_core::adc_of_column(columns.start, n_adc);
        let count = columns.len().min(out.len());
        let (mut light, mut mu, mut n, mut z) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        for (start, out) in (0..count).step_by(CHUNK).zip(out[..count].chunks_mut(CHUNK)) {
            let first = columns.start + start;
            let len = out.len();
            // The light first, then each pixel's mean with no branch on its state.
            for (t, light) in light[..len].iter_mut().enumerate() {
                *light = photons(first + t);
            }
            let i0 = base + first;
            let (state, gain, dark) = (&camera.pixels.state[i0..i0 + len], &camera.pixels.gain[i0..i0 + len], &camera.pixels.dark_e[i0..i0 + len]);
            for ((((mu, &light), &state), &gain), &dark) in mu[..len].iter_mut().zip(&light[..len]).zip(state).zip(gain).zip(dark) {
                let (good, dead) = ((qe * light * gain + dark).max(0.0), dark.max(0.0));
                *mu = match state {
                    PixelState::Hot => 0.0,
                    PixelState::Dead => dead,
                    PixelState::Good => good,
                };
            }
            draws.draw_with(self.build, &mu[..len], &mut n[..len], &mut z[..len]);
            // (CHUNK is a multiple of every ADC count's period only where it divides it:
            // the chunk's first ADC walks on.)
            let adc = (adc0 + start) % n_adc;
            self.codes(base + first, adc, &n[..len], &z[..len], out);
        }
    }

    /// The codes of a chunk's pixels (the first at pixel index `i0`, read by ADC
    /// `adc0`) from their photoelectrons `n` and standard normals `z`.
    fn codes(&self, i0: usize, adc0: usize, n: &[f64], z: &[f64], out: &mut [u16]) {
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        {
            // SAFETY: `build` is only ever a build this CPU has (`new`, `with_build`).
            match self.build {
                Build::Avx512 => return unsafe { self.codes_avx512(i0, adc0, n, z, out) },
                Build::Avx2 => return unsafe { self.codes_avx2(i0, adc0, n, z, out) },
                Build::Portable => {}
            }
        }
        self.codes_body(i0, adc0, n, z, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq")]
    fn codes_avx512(&self, i0: usize, adc0: usize, n: &[f64], z: &[f64], out: &mut [u16]) {
        self.codes_body(i0, adc0, n, z, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn codes_avx2(&self, i0: usize, adc0: usize, n: &[f64], z: &[f64], out: &mut [u16]) {
        self.codes_body(i0, adc0, n, z, out)
    }

    #[inline(always)]
    fn codes_body(&self, i0: usize, adc0: usize, n: &[f64], z: &[f64], out: &mut [u16]) {
        let camera = self.camera;
        let cfg = &camera.config;
        let len = out.len().min(n.len()).min(z.len()).min(CHUNK);
        let (n, z, out) = (&n[..len], &z[..len], &mut out[..len]);
        let (fw, inv_gain, offset, read) = (cfg.full_well_e, 1.0 / cfg.gain_e_per_dn, cfg.offset_dn, cfg.read_noise_e);
        // The response p(x) = x + sum_m a_m x^m, the terms in the order
        // `Camera::response_e` adds them, each a loop over the chunk.
        let (mut x, mut xm, mut p) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        for (((x, xm), p), &n) in x.iter_mut().zip(&mut xm).zip(&mut p).zip(n) {
            *x = n.min(fw) / fw;
            *xm = *x;
            *p = *x;
        }
        let terms = camera.pixels.terms;
        let a = &camera.pixels.nonlinearity[i0 * terms..(i0 + len) * terms];
        let (x, xm, p) = (&x[..len], &mut xm[..len], &mut p[..len]);
        // (The usual term counts as constants: a vector unit loads a pixel's
        // coefficients at a stride it knows.)
        match terms {
            0 => {}
            1 => add_terms::<1>(a, x, xm, p),
            2 => add_terms::<2>(a, x, xm, p),
            3 => add_terms::<3>(a, x, xm, p),
            4 => add_terms::<4>(a, x, xm, p),
            _ => {
                for (((xm, p), &x), a) in xm.iter_mut().zip(p.iter_mut()).zip(x).zip(a.chunks_exact(terms)) {
                    for &a in a {
                        *xm *= x;
                        *p += a * *xm;
                    }
                }
            }
        }
        let mut v = [0.0; CHUNK];
        for ((v, &p), &z) in v.iter_mut().zip(p.iter()).zip(z) {
            *v = (fw * p + read * z) * inv_gain + offset;
        }
        let mut walk = [false; CHUNK];
        let top = cfg.codes() - 1;
        search(&self.edges, top, &self.bases[adc0..adc0 + len], &v[..len], out, &mut walk[..len]);
        // The few a step could not reach, pixel by pixel; hot pixels read the top code.
        let top = top as u16;
        let state = &camera.pixels.state[i0..i0 + len];
        for (t, (out, &s)) in out.iter_mut().zip(state).enumerate() {
            if walk[t] {
                *out = camera.adcs[(adc0 + t) % camera.adcs.len()].walk(usize::from(*out), v[t]);
            }
            if s == PixelState::Hot {
                *out = top;
            }
        }
    }
}

/// `p += a_m x^m` for each pixel's `T` coefficients `a` (m = 2..T+1, `xm` holding
/// `x^(m-1)` on entry), in `Camera::response_e`'s order.
#[inline(always)]
fn add_terms<const T: usize>(a: &[f64], x: &[f64], xm: &mut [f64], p: &mut [f64]) {
    let (a, _) = a.as_chunks::<T>();
    for (((xm, p), &x), a) in xm.iter_mut().zip(p.iter_mut()).zip(x).zip(a) {
        for &a in a {
            *xm *= x;
            *p += a * *xm;
        }
    }
}

/// The codes `out` of analog values `v` DN, value `t` read by the ADC whose edges
/// `T_0..T_top` start at `edges[base[t]]` (`T_0` = -inf, non-decreasing): one step from
/// the ideal code `clamp(floor(v + 1/2), 0, top)` as `AdcTransfer::code` takes it, and
/// `walk[t]` set where that step did not reach the code (an edge a code or more off).
#[inline(always)]
fn search(edges: &[f64], top: usize, base: &[u32], v: &[f64], out: &mut [u16], walk: &mut [bool]) {
    let len = out.len().min(walk.len()).min(v.len()).min(base.len());
    let (base, v, out, walk) = (&base[..len], &v[..len], &mut out[..len], &mut walk[..len]);
    // (Indices in wrapping arithmetic that cannot wrap: an edge index is at most
    // `edges.len() - 1` after the `min`, a code at most `top`; the overflow checks of
    // the `checked` build would keep the loop off the vector unit.)
    let Some(last) = edges.len().checked_sub(1) else { return };
    let top32 = top as i32;
    for t in 0..len {
        let (v, b) = (v[t], base[t] as usize);
        // (Truncation toward zero and a clamp at 0: floor's result after the clamp. A
        // NaN converts to 0, whose edge -inf is not above it: code 0, as `code` says.)
        let k = ((v + 0.5) as i32).clamp(0, top32) as usize;
        let up = k.wrapping_add(1).min(top);
        let lo = edges[b.wrapping_add(k).min(last)];
        let hi = edges[b.wrapping_add(up).min(last)];
        let (below, above) = (lo > v, (k < top) & (hi <= v));
        let k1 = k.wrapping_sub(usize::from(below)).wrapping_add(usize::from(above));
        // Whether the step reached the code: after a step down T_{k1+1} = T_k > v holds,
        // so only T_{k1} <= v is left to see; after a step up only T_{k1+1} > v; with
        // no step, both held already.
        let at = if below { k1 } else { k1.wrapping_add(1).min(top) };
        let next = edges[b.wrapping_add(at).min(last)];
        walk[t] = (below & (next > v)) | (above & (k1 < top) & (next <= v));
        out[t] = k1 as u16;
    }
}

#[cfg(test)]
mod sampler_tests {
    use super::*;
    use crate::model::camera::{AdcTransfer, CameraConfig};
    use proptest::prelude::*;

    const BUILDS: [Build; 3] = [Build::Portable, Build::Avx2, Build::Avx512];

    /// The model pixel by pixel, as the sampler was written before its codes went into
    /// loops of their own: a pixel's mean, the draws, then `response_e` and
    /// `AdcTransfer::code` one pixel at a time.
    fn pixel_by_pixel(camera: &Camera, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        let cfg = &camera.config;
        let base = row * cfg.width;
        let (mut mu, mut n, mut z) = (vec![0.0; columns.len()], vec![0.0; columns.len()], vec![0.0; columns.len()]);
        for (t, c) in columns.clone().enumerate() {
            let i = base + c;
            mu[t] = match camera.pixels.state[i] {
                PixelState::Hot => 0.0,
                PixelState::Dead => camera.pixels.dark_e[i].max(0.0),
                PixelState::Good => (cfg.qe * photons(c) * camera.pixels.gain[i] + camera.pixels.dark_e[i]).max(0.0),
            };
        }
        let mut draws = LineDraws::new(frame_seed, row);
        for ((mu, n), z) in mu.chunks(CHUNK).zip(n.chunks_mut(CHUNK)).zip(z.chunks_mut(CHUNK)) {
            draws.draw_with(Build::Portable, mu, n, z);
        }
        columns
            .enumerate()
            .map(|(t, c)| match camera.pixels.state[base + c] {
                PixelState::Hot => (cfg.codes() - 1) as u16,
                _ => {
                    let y = camera.response_e(n[t], camera.pixels.coefficients(row, c)) + cfg.read_noise_e * z[t];
                    camera.adc_of(c).code(y / cfg.gain_e_per_dn + cfg.offset_dn)
                }
            })
            .collect()
    }

    /// Widths of `codes` codes from `seed`, 0.3-2.3 DN (`wide`) or 0.2-1.2 DN: edges
    /// that drift tens of codes above or below the ideal ones, so one step from the ideal
    /// code seldom reaches the code, down or up.
    fn drifting_widths(codes: usize, seed: u64, wide: bool) -> Vec<f64> {
        let mut s = crate::model::camera::draws::Stream::from_seed(seed);
        let (least, span) = if wide { (0.3, 2.0) } else { (0.2, 1.0) };
        (0..codes).map(|_| least + span * crate::model::camera::draws::unit(rand::RngCore::next_u64(&mut s))).collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

        /// Every build's codes are the model's pixel by pixel: any ADC count, bit depth,
        /// nonlinearity terms, bad pixels, a span starting anywhere and of any length
        /// (chunks that end off a lane or ADC period), ADCs whose edges drift far off.
        #[test]
        fn the_samplers_codes_are_the_models_pixel_by_pixel(
            n_adc in 1usize..6,
            bits in 8u32..17,
            terms in 0usize..6,
            spread in 0.0f64..0.02,
            bad in 0.0f64..0.2,
            drift in any::<bool>(),
            start in 0usize..40,
            len in 0usize..700,
            peak in 0.0f64..1.3,
            seed in any::<u64>(),
        ) {
            let nonlinearity = [-0.02, 0.02, 0.005, -0.003, 0.001][..terms].to_vec();
            let mut cfg = CameraConfig {
                width: 768,
                height: 3,
                bits,
                n_adc,
                nonlinearity,
                pixel_nonlinearity_rms: vec![spread; terms],
                bad_pixel_fraction: bad,
                seed,
                ..Default::default()
            };
            cfg.offset_dn = cfg.offset_dn.min(((1u64 << bits) / 8) as f64);
            if drift {
                cfg.adc.widths = (0..n_adc).map(|a| drifting_widths(1 << bits, seed ^ a as u64, a % 2 == 0)).collect();
            }
            let camera = Camera::new(cfg).unwrap();
            let full = ((camera.config.codes() - 1) as f64 - camera.config.offset_dn) * camera.config.gain_e_per_dn / camera.config.qe;
            let photons = |c: usize| peak * full * (0.1 + 0.9 * (c % 97) as f64 / 96.0);
            let columns = start..(start + len).min(768);
            let want = pixel_by_pixel(&camera, 1, columns.clone(), seed ^ 7, photons);
            for build in BUILDS.into_iter().filter(|b| b.available()) {
                let got = camera.sampler().with_build(build).sample_span(1, columns.clone(), seed ^ 7, photons);
                prop_assert_eq!(&got, &want, "{:?}", build);
            }
        }
    }

    /// `search` and the walk give `AdcTransfer::code`'s code for values at, beside and
    /// far from the edges, NaN and the infinities, on ADCs with missing codes (equal
    /// neighbouring edges) and edges many codes off, whichever ADC a value falls to.
    #[test]
    fn the_search_is_the_adcs_code_for_any_value() {
        let codes = 256;
        let mut missing: Vec<f64> = (1..codes).map(|k| k as f64 - 0.5).collect();
        for k in [3, 4, 5, 100, 101, 200] {
            missing[k] = missing[k - 1];
        }
        let adcs = [
            AdcTransfer::ideal(8),
            AdcTransfer::from_widths(&drifting_widths(codes, 5, true)).unwrap(),
            AdcTransfer::from_monotone_levels(&missing).unwrap(),
            AdcTransfer::from_widths(&drifting_widths(codes, 6, false)).unwrap(),
        ];
        let edges: Vec<f64> = adcs.iter().flat_map(|a| a.edges().iter().copied()).collect();
        let mut values = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -1e300, 1e300, -0.5, 0.0, 3e9, -3e9, 255.5, 254.49];
        for a in &adcs {
            for k in 1..codes {
                let t = a.level(k);
                values.extend([t, t.next_up(), t.next_down(), t + 0.5, t - 0.5]);
            }
        }
        let n = values.len();
        let base: Vec<u32> = (0..n).map(|t| ((t % 4) * codes) as u32).collect();
        for a0 in 0..4 {
            let (mut out, mut walk) = (vec![0u16; n], vec![false; n]);
            let base: Vec<u32> = base.iter().map(|&b| ((b as usize / codes + a0) % 4 * codes) as u32).collect();
            search(&edges, codes - 1, &base, &values, &mut out, &mut walk);
            for t in 0..n {
                let adc = &adcs[base[t] as usize / codes];
                let got = if walk[t] { adc.walk(usize::from(out[t]), values[t]) } else { out[t] };
                assert_eq!(got, adc.code(values[t]), "value {} on ADC {}", values[t], base[t] as usize / codes);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::model::camera::{Camera, CameraConfig};

    #[test]
    fn sampled_codes_follow_the_exact_distribution() {
        // One ADC, uniform pixels: the sampled code histogram must match the exact PMF
        // (chi-square over bins with >= 20 expected) and its mean and variance within
        // 5 standard errors.
        let cfg = CameraConfig {
            width: 256,
            height: 64,
            n_adc: 1,
            prnu_rms: 0.0,
            dsnu_rms_e: 0.0,
            pixel_nonlinearity_rms: vec![],
            bad_pixel_fraction: 0.0,
            ..Default::default()
        };
        let cam = Camera::new(cfg).unwrap();
        let photons = 20_000.0;
        let mu = cam.config.qe * photons + cam.config.dark_e;
        let pmf = cam.code_pmf(&cam.adcs[0], mu, &cam.config.nonlinearity.clone());
        let mut counts = vec![0u64; 4096];
        let mut n = 0u64;
        for frame in 0..4u64 {
            for row in 0..64 {
                for c in cam.sample_line(row, 1000 + frame, |_| photons) {
                    counts[c as usize] += 1;
                    n += 1;
                }
            }
        }
        let mean = counts.iter().enumerate().map(|(k, &c)| k as f64 * c as f64).sum::<f64>() / n as f64;
        let var = counts.iter().enumerate().map(|(k, &c)| (k as f64 - mean).powi(2) * c as f64).sum::<f64>() / (n - 1) as f64;
        let se_mean = (pmf.variance() / n as f64).sqrt();
        assert!((mean - pmf.mean()).abs() < 5.0 * se_mean, "mean {mean} vs exact {}", pmf.mean());
        let se_var = pmf.variance() * (2.0 / n as f64).sqrt();
        assert!((var - pmf.variance()).abs() < 5.0 * se_var, "variance {var} vs exact {}", pmf.variance());
        let (mut chi2, mut dof) = (0.0, 0);
        for (k, &c) in counts.iter().enumerate() {
            let expected = pmf.prob(k) * n as f64;
            if expected >= 20.0 {
                chi2 += (c as f64 - expected).powi(2) / expected;
                dof += 1;
            }
        }
        // chi^2 with dof degrees of freedom: mean dof, sd sqrt(2 dof); 5 sd is a loose bound.
        assert!(dof > 10);
        assert!(chi2 < dof as f64 + 5.0 * (2.0 * dof as f64).sqrt(), "chi2 {chi2} with {dof} bins");
    }
}
