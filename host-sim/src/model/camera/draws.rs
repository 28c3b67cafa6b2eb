//! The sampler's random draws: a pixel's Poisson photoelectrons and its read noise's
//! Gaussian, eight streams to a line so a vector unit draws eight pixels at once.
//!
//! **The seed contract** (docs/model.md says the same). A line (frame seed, row) has 16
//! Xoshiro256++ streams, each seeded by SplitMix64 as `rand_xoshiro`'s `seed_from_u64`
//! seeds it (held to it by a test), from the first 16 outputs of SplitMix64 started at
//! the line's seed ([`lane_seed`]): streams 0-7 are the [`LANES`] = 8 lanes' first
//! streams, 8-15 their retry streams. Pixel `i` of a span (counted from the span's first
//! column) is drawn by lane `i mod 8`, each lane taking its pixels in order:
//! 1. its first stream gives two uniforms `u`, `v` (52 random bits each, [`unit`]);
//! 2. from a mean of 10, PTRS (Hoermann 1993) is tried on `(u - 1/2, v)`; below, Knuth's
//!    product of uniforms starts with `v`; a mean that is not positive and finite gives
//!    0. Any further trial or factor comes from the lane's retry stream;
//! 3. at the lane's 1st, 3rd, 5th ... pixel its first stream gives two more uniforms
//!    `u1`, `u2`, a Box-Muller pair: radius `sqrt(-2 ln(1 - u1))`, angle
//!    `2 pi u2 - pi/4` ([`sin_cos`]); the cosine is that pixel's Gaussian, the sine the
//!    lane's next pixel's.
//!
//! Nothing in this depends on how many lanes the CPU computes at once: the AVX-512,
//! AVX2 and portable builds of [`LineDraws::draw`] are one source compiled three times,
//! with IEEE arithmetic only (no fused or reordered operations, the logarithm and the
//! sine and cosine written here rather than taken from libm), so they give the same
//! bits; a test holds each to a one-stream-at-a-time walk of the contract.
//!
//! Both draws are exact in distribution up to the uniforms' 2^-52 grid and the last
//! bit of [`ln`], [`sin_cos`] (within 1 and 2 units in the last place of libm's; tested):
//! the Poisson draws are held to the PMF by chi-square, the Gaussians by their moments
//! and CDF.

use rand::RngCore;

/// Streams per line: pixel `i` of a span is drawn from stream `i mod LANES`.
pub const LANES: usize = 8;

/// A uniform double in [0, 1): the top 52 bits of `x` as a mantissa (exact, and a
/// few integer operations on every vector unit, where u64 -> f64 conversion is not).
#[inline(always)]
pub fn unit(x: u64) -> f64 {
    f64::from_bits(0x3FF0_0000_0000_0000 | (x >> 12)) - 1.0
}

/// SplitMix64's step: the seeding generator of `rand_xoshiro`.
#[inline]
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// One Xoshiro256++ stream (Blackman and Vigna 2019), the scalar form of a lane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stream([u64; 4]);

impl Stream {
    /// The stream `rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed)` is.
    pub fn from_seed(seed: u64) -> Self {
        let mut sm = seed;
        Stream([splitmix(&mut sm), splitmix(&mut sm), splitmix(&mut sm), splitmix(&mut sm)])
    }
}

/// The generator's step on one lane's words.
#[inline(always)]
fn step(s0: &mut u64, s1: &mut u64, s2: &mut u64, s3: &mut u64) -> u64 {
    let out = s0.wrapping_add(*s3).rotate_left(23).wrapping_add(*s0);
    let t = *s1 << 17;
    *s2 ^= *s0;
    *s3 ^= *s1;
    *s1 ^= *s2;
    *s0 ^= *s3;
    *s2 ^= t;
    *s3 = s3.rotate_left(45);
    out
}

impl RngCore for Stream {
    fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    fn next_u64(&mut self) -> u64 {
        let [s0, s1, s2, s3] = &mut self.0;
        step(s0, s1, s2, s3)
    }

    fn fill_bytes(&mut self, dst: &mut [u8]) {
        for chunk in dst.chunks_mut(8) {
            let bytes = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&bytes[..chunk.len()]);
        }
    }
}

/// The seeds of a line's 2 x [`LANES`] streams (first streams, then retry streams): the
/// line's seed (as the single-stream sampler had it) run through SplitMix64, one output
/// a stream.
pub fn line_seeds(frame_seed: u64, row: usize) -> [u64; 2 * LANES] {
    let mut line = frame_seed ^ (row as u64 + 1).wrapping_mul(0xA076_1D64_78BD_642F);
    std::array::from_fn(|_| splitmix(&mut line))
}

/// The seed of stream `lane` (0-15) of line `row` of the frame seeded `frame_seed`.
pub fn lane_seed(frame_seed: u64, row: usize, lane: usize) -> u64 {
    line_seeds(frame_seed, row)[lane]
}

// fdlibm's e_log.c (Sun Microsystems, 1993): ln 2 in two parts (high, low) and the
// minimax coefficients Lg1..Lg7 of (ln(1+f) - 2s)/s, s = f / (2 + f), on
// |f| < sqrt(2) - 1, written as fdlibm prints them (the same doubles; clippy would have
// them cut).
#[allow(clippy::excessive_precision)]
const LN2: (f64, f64) = (6.931_471_803_691_238_164_90e-01, 1.908_214_929_270_587_700_02e-10);
#[allow(clippy::excessive_precision)]
const LG: [f64; 7] = [
    6.666_666_666_666_735_130e-01,
    3.999_999_999_940_941_908e-01,
    2.857_142_874_366_239_149e-01,
    2.222_219_843_214_978_396e-01,
    1.818_357_216_161_805_012e-01,
    1.531_383_769_920_937_332e-01,
    1.479_819_860_511_658_591e-01,
];

/// ln x, within a unit in the last place of libm's (fdlibm's reduction and polynomial,
/// written without branches so a vector unit runs it): x > 0 normal. Zero and
/// subnormals give -inf, negatives and NaN give NaN, +inf gives a finite ~709.8 (never
/// asked: the sampler's arguments are finite).
#[inline(always)]
pub fn ln(x: f64) -> f64 {
    let bits = x.to_bits();
    let biased = (bits >> 52) & 0x7FF;
    let mantissa = f64::from_bits((bits & 0x000F_FFFF_FFFF_FFFF) | 0x3FF0_0000_0000_0000);
    let high = mantissa > std::f64::consts::SQRT_2;
    let m = if high { mantissa * 0.5 } else { mantissa };
    let biased = biased + u64::from(high);
    // The exponent as a double without an integer conversion: 2^52 + biased, less
    // 2^52 + 1023, both exact.
    let dk = f64::from_bits(0x4330_0000_0000_0000 | biased) - (4_503_599_627_370_496.0 + 1023.0);
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let z = s * s;
    let w = z * z;
    let r = z * (LG[0] + w * (LG[2] + w * (LG[4] + w * LG[6]))) + w * (LG[1] + w * (LG[3] + w * LG[5]));
    let hfsq = 0.5 * f * f;
    let y = dk * LN2.0 - ((hfsq - (s * (hfsq + r) + dk * LN2.1)) - f);
    if x >= f64::MIN_POSITIVE {
        y
    } else if x >= 0.0 {
        f64::NEG_INFINITY
    } else {
        f64::NAN
    }
}

// Taylor coefficients of sin x / x - 1 and cos x - 1 + x^2/2 in x^2, enough for
// |x| <= pi/4 to a unit in the last place (the first left out: x^17/17! < 5e-17,
// x^18/18! < 3e-18).
const S: [f64; 7] = [
    -1.0 / 6.0,
    1.0 / 120.0,
    -1.0 / 5040.0,
    1.0 / 362_880.0,
    -1.0 / 39_916_800.0,
    1.0 / 6_227_020_800.0,
    -1.0 / 1_307_674_368_000.0,
];
const C: [f64; 7] = [
    1.0 / 24.0,
    -1.0 / 720.0,
    1.0 / 40320.0,
    -1.0 / 3_628_800.0,
    1.0 / 479_001_600.0,
    -1.0 / 87_178_291_200.0,
    1.0 / 20_922_789_888_000.0,
];

/// (cos 2 pi t', sin 2 pi t') for a uniform `t` in [0, 1), where t' is `t` less an
/// eighth of a turn: the quarter `q = floor(4 t)` turns (cos x, sin x) of the angle
/// x = (4 t - q - 1/2) pi/2 in [-pi/4, pi/4), exactly (signs and a swap). Uniform
/// `t` gives a uniform angle either way.
#[inline(always)]
pub fn sin_cos(t: f64) -> (f64, f64) {
    let t4 = 4.0 * t;
    let q = floor(t4);
    let x = (t4 - q - 0.5) * std::f64::consts::FRAC_PI_2;
    let x2 = x * x;
    let ps = S[0] + x2 * (S[1] + x2 * (S[2] + x2 * (S[3] + x2 * (S[4] + x2 * (S[5] + x2 * S[6])))));
    let s = x + x * x2 * ps;
    let pc = C[0] + x2 * (C[1] + x2 * (C[2] + x2 * (C[3] + x2 * (C[4] + x2 * (C[5] + x2 * C[6])))));
    let c = 1.0 - 0.5 * x2 + x2 * x2 * pc;
    // Quarter turns: (c, s), (-s, c), (-c, -s), (s, -c).
    let (odd, back) = (q == 1.0 || q == 3.0, q >= 2.0);
    let (cc, ss) = if odd { (-s, c) } else { (c, s) };
    if back { (-cc, -ss) } else { (cc, ss) }
}

/// floor(x) for 0 <= x < 2^52 by the rounding of an addition (exact: `f64::floor` is a
/// libm call on baseline x86-64, which no vector unit runs); x itself from 2^52 up (an
/// integer already), and -1 for any negative x (PTRS rejects a negative count; a
/// quarter turn is never negative). NaN stays NaN.
#[inline(always)]
fn floor(x: f64) -> f64 {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    let t = (x + TWO_52) - TWO_52;
    let f = if t > x { t - 1.0 } else { t };
    if x >= TWO_52 {
        x
    } else if x < 0.0 {
        -1.0
    } else {
        f
    }
}

/// A Box-Muller pair of independent standard normals from uniforms `u1`, `u2` in [0, 1).
#[inline(always)]
pub fn box_muller(u1: f64, u2: f64) -> (f64, f64) {
    let r = (-2.0 * ln(1.0 - u1)).sqrt();
    let (c, s) = sin_cos(u2);
    (r * c, r * s)
}

/// k! for k = 0..15, exact (15! < 2^53).
const FACTORIALS: [f64; 16] = {
    let mut f = [1.0; 16];
    let mut k = 2;
    while k < 16 {
        f[k] = f[k - 1] * k as f64;
        k += 1;
    }
    f
};

/// Stirling's series for ln Gamma(x) - (x - 1/2) ln x + x - ln(2 pi)/2 at r = 1/x:
/// 1/(12 x) - 1/(360 x^3) + 1/(1260 x^5) - 1/(1680 x^7) + 1/(1188 x^9).
#[inline(always)]
fn stirling_series(r: f64) -> f64 {
    let r2 = r * r;
    r * (1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0 - r2 * (1.0 / 1680.0 - r2 / 1188.0))))
}

/// ln A - ln Pois(k; mu): where it is not positive, PTRS accepts the candidate `k` whose
/// hat ratio is `A` (log A <= log(mu^k e^-mu / k!)). Below k = 16 with k! from the
/// table; above with Stirling's series for ln k! (five terms; the first left out,
/// 691 / (360360 x^11), is under 1e-16 at x = k + 1 = 17), rearranged so that one
/// logarithm carries the ratio x / mu, near 1, and one carries A^2 x:
///   ln A + ln k! - k ln mu + mu = ln(A^2 x) / 2 + k ln(x / mu) - x + mu + ln(2 pi)/2 + S(1/x).
/// Two logarithms and one division either way (1/(x mu) gives both 1/x and x/mu), with
/// no branch, so a vector unit runs it; the rearranged form also keeps the large terms
/// k ln mu and ln k! (2 x 10^6 at a full well) from cancelling.
#[inline(always)]
fn log_margin(mu: f64, k: f64, ratio: f64) -> f64 {
    const HALF_LN_TAU: f64 = 0.918_938_533_204_672_8;
    let x = k + 1.0;
    let small = k < 16.0;
    let inv = 1.0 / (x * mu);
    let r = mu * inv;
    let x_over_mu = x * x * inv;
    // `as` saturates (NaN and negatives to 0): the index stays in the table.
    let factorial = FACTORIALS[(k as usize).min(15)];
    let l1 = ln(if small { ratio * factorial } else { ratio * ratio * x });
    let l2 = ln(if small { mu } else { x_over_mu });
    let series = HALF_LN_TAU + stirling_series(r);
    // mu - x is exact where it matters (Sterbenz: x within a factor of 2 of mu).
    if small { l1 - k * l2 + mu } else { 0.5 * l1 + k * l2 + (mu - x) + series }
}

/// The constants of a PTRS trial at mean `mu` (Hoermann's b, a, v_r and 1/alpha): one
/// square root and one division.
#[inline(always)]
fn ptrs_constants(mu: f64) -> (f64, f64, f64, f64) {
    let b = 0.931 + 2.53 * mu.sqrt();
    let a = -0.059 + 0.02483 * b;
    // 1/(b - 2) and 1/(b - 3.4) from one division.
    let d = 1.0 / ((b - 2.0) * (b - 3.4));
    let vr = 0.9277 - 3.6224 * ((b - 3.4) * d);
    let inv_alpha = 1.1239 + 1.1328 * ((b - 2.0) * d);
    (b, a, vr, inv_alpha)
}

/// One PTRS trial at mean `mu` >= 10 on `u` in [-1/2, 1/2) and `v` in [0, 1): the
/// candidate count and whether it is accepted (the immediate acceptance, else the
/// logarithmic test), with no branch.
#[inline(always)]
fn ptrs_trial(mu: f64, u: f64, v: f64) -> (f64, bool) {
    let (b, a, vr, inv_alpha) = ptrs_constants(mu);
    let (k, immediate, us) = ptrs_candidate(mu, b, a, vr, u, v);
    (k, immediate || ptrs_log_test(mu, b, a, inv_alpha, us, v, k))
}

/// The candidate count of a trial, whether it is accepted at once, and |1/2 - |u||.
#[inline(always)]
fn ptrs_candidate(mu: f64, b: f64, a: f64, vr: f64, u: f64, v: f64) -> (f64, bool, f64) {
    let us = 0.5 - u.abs();
    let k = floor((2.0 * a / us + b) * u + mu + 0.43);
    (k, us >= 0.07 && v <= vr, us)
}

/// The trial's logarithmic test, for a candidate not accepted at once:
/// log(v) + log(inv_alpha) - log(a / us^2 + b) <= log(mu^k e^-mu / k!).
#[inline(always)]
fn ptrs_log_test(mu: f64, b: f64, a: f64, inv_alpha: f64, us: f64, v: f64, k: f64) -> bool {
    let valid = !(k < 0.0 || (us < 0.013 && v > us));
    let us2 = us * us;
    valid && log_margin(mu, k, v * inv_alpha * us2 / (a + b * us2)) <= 0.0
}

/// Whether PTRS draws at mean `mu` (10 and up, finite); below, Knuth.
#[inline(always)]
fn is_ptrs(mu: f64) -> bool {
    mu >= 10.0 && mu.is_finite()
}

/// The first trial of a pixel's Poisson draw at mean `mu` on its first two uniforms: the
/// candidate count, and whether PTRS accepted it (false where [`finish`] must go on).
#[inline(always)]
fn first_trial(mu: f64, u: f64, v: f64) -> (f64, bool) {
    let (k, ok) = ptrs_trial(mu, u - 0.5, v);
    (k, ok && is_ptrs(mu))
}

/// [`first_trial`]'s count and its immediate acceptance alone (the logarithmic test
/// left out): true only where `first_trial` accepts.
#[inline(always)]
fn first_immediate(mu: f64, u: f64, v: f64) -> (f64, bool) {
    let (b, a, vr, _) = ptrs_constants(mu);
    let (k, immediate, _) = ptrs_candidate(mu, b, a, vr, u - 0.5, v);
    (k, immediate && is_ptrs(mu))
}

/// The rest of a pixel's Poisson draw when [`first_trial`] did not accept: PTRS on
/// fresh pairs, or Knuth with `v` its first factor, or 0 for a mean that is not
/// positive and finite.
#[cold]
#[inline(never)]
fn finish(rng: &mut Stream, mu: f64, v: f64) -> f64 {
    if is_ptrs(mu) {
        // The trial of `ptrs_trial`, its logarithms only where the immediate
        // acceptance fails (the same answer: they are a second chance).
        let (b, a, vr, inv_alpha) = ptrs_constants(mu);
        loop {
            let (u, v) = (unit(rng.next_u64()) - 0.5, unit(rng.next_u64()));
            let (k, immediate, us) = ptrs_candidate(mu, b, a, vr, u, v);
            if immediate || ptrs_log_test(mu, b, a, inv_alpha, us, v, k) {
                return k;
            }
        }
    } else if mu > 0.0 && mu < 10.0 {
        // Knuth: the count of uniforms whose running product stays above exp(-mu).
        let limit = (-mu).exp();
        let (mut k, mut p) = (0.0, v);
        while p > limit {
            k += 1.0;
            p *= unit(rng.next_u64());
        }
        k
    } else {
        0.0
    }
}

/// One Poisson draw of mean `mu` as a lane draws it (steps 1 and 2 of the contract):
/// the first pair from `first`, any more from `retry`; 0 for a mean that is not
/// positive and finite.
pub fn poisson(first: &mut Stream, retry: &mut Stream, mu: f64) -> f64 {
    let (u, v) = (unit(first.next_u64()), unit(first.next_u64()));
    let (k, ok) = first_trial(mu, u, v);
    if ok { k } else { finish(retry, mu, v) }
}

/// The pixels [`LineDraws::draw`] takes at a time (its scratch is on the stack), and a
/// good length for a caller's buffers.
pub const CHUNK: usize = 256;

/// A line's streams: the eight first streams side by side (word `w` of lane `j` at
/// `s[w][j]`, so a vector unit steps them all at once), the eight retry streams, the
/// sines kept for the next pixel of each lane, and how many pixels each lane has drawn.
#[derive(Debug, Clone)]
pub struct LineDraws {
    s: [[u64; LANES]; 4],
    retry: [Stream; LANES],
    spare: [f64; LANES],
    drawn: usize,
    /// A call ended on a partial block: the lanes are out of step with the pixels.
    ended: bool,
}

impl LineDraws {
    /// The streams of line `row` of the frame seeded `frame_seed`.
    pub fn new(frame_seed: u64, row: usize) -> Self {
        let seeds = line_seeds(frame_seed, row);
        let first: [Stream; LANES] = std::array::from_fn(|lane| Stream::from_seed(seeds[lane]));
        let s = std::array::from_fn(|w| std::array::from_fn(|lane| first[lane].0[w]));
        let retry = std::array::from_fn(|lane| Stream::from_seed(seeds[LANES + lane]));
        LineDraws { s, retry, spare: [0.0; LANES], drawn: 0, ended: false }
    }

    /// The next pixels' photoelectrons `n` and standard normals `z` for their means `mu`:
    /// as many as the shortest of the three holds, [`CHUNK`] at a time. Every call but a
    /// span's last must take a multiple of [`LANES`]: a shorter last block leaves the
    /// rest of its streams' draws unused, and pixels drawn after it would not follow the
    /// contract (a debug build panics there; `sample_span_into` never does it).
    pub fn draw(&mut self, mu: &[f64], n: &mut [f64], z: &mut [f64]) {
        self.draw_with(Build::best(), mu, n, z)
    }

    /// [`Self::draw`] with a given build, `Portable` where the CPU lacks the one asked
    /// ([`Build::available`]).
    pub fn draw_with(&mut self, build: Build, mu: &[f64], n: &mut [f64], z: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        if build.available() {
            // SAFETY: the CPU has the build's instructions (`available`).
            match build {
                Build::Avx512 => return unsafe { self.draw_avx512(mu, n, z) },
                Build::Avx2 => return unsafe { self.draw_avx2(mu, n, z) },
                Build::Portable => {}
            }
        }
        self.draw_chunks(mu, n, z)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512dq")]
    fn draw_avx512(&mut self, mu: &[f64], n: &mut [f64], z: &mut [f64]) {
        self.draw_chunks(mu, n, z)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn draw_avx2(&mut self, mu: &[f64], n: &mut [f64], z: &mut [f64]) {
        self.draw_chunks(mu, n, z)
    }

    /// All eight first streams step together.
    #[inline(always)]
    fn next(&mut self) -> [u64; LANES] {
        let [s0, s1, s2, s3] = &mut self.s;
        let mut out = [0; LANES];
        for j in 0..LANES {
            out[j] = step(&mut s0[j], &mut s1[j], &mut s2[j], &mut s3[j]);
        }
        out
    }

    /// The pixels a [`CHUNK`] at a time (its scratch is on the stack).
    #[inline(always)]
    fn draw_chunks(&mut self, mu: &[f64], n: &mut [f64], z: &mut [f64]) {
        let len = mu.len().min(n.len()).min(z.len());
        for ((mu, n), z) in mu[..len].chunks(CHUNK).zip(n[..len].chunks_mut(CHUNK)).zip(z[..len].chunks_mut(CHUNK)) {
            self.draw_chunk(mu, n, z);
        }
    }

    /// At most [`CHUNK`] pixels: the first streams' uniforms and Gaussians, a block of
    /// eight pixels (one from each lane) at a time; then every pixel's first PTRS trial,
    /// in a loop of its own; then, pixel by pixel, the few that need more, each from its
    /// lane's retry stream.
    #[inline(always)]
    fn draw_chunk(&mut self, mu: &[f64], n: &mut [f64], z: &mut [f64]) {
        debug_assert!(!self.ended, "pixels drawn after a partial block");
        let len = mu.len().min(n.len()).min(z.len()).min(CHUNK);
        self.ended = !len.is_multiple_of(LANES);
        let (mu, n, z) = (&mu[..len], &mut n[..len], &mut z[..len]);
        let blocks = len.div_ceil(LANES);
        let (mut u, mut v, mut zz) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        let (u_blocks, _) = u[..blocks * LANES].as_chunks_mut::<LANES>();
        let (v_blocks, _) = v[..blocks * LANES].as_chunks_mut::<LANES>();
        let (z_blocks, _) = zz[..blocks * LANES].as_chunks_mut::<LANES>();
        for ((u, v), z) in u_blocks.iter_mut().zip(v_blocks).zip(z_blocks) {
            let (a, b) = (self.next(), self.next());
            for j in 0..LANES {
                u[j] = unit(a[j]);
                v[j] = unit(b[j]);
            }
            if self.drawn.is_multiple_of(2) {
                let (c, d) = (self.next(), self.next());
                for j in 0..LANES {
                    let (cos, sin) = box_muller(unit(c[j]), unit(d[j]));
                    z[j] = cos;
                    self.spare[j] = sin;
                }
            } else {
                *z = self.spare;
            }
            self.drawn += 1;
        }
        z.copy_from_slice(&zz[..len]);
        // The immediate acceptance for every pixel (a square root and two divisions);
        // the logarithmic test of the same first trial only for the fifth or so that
        // missed it, gathered side by side (two logarithms and four divisions more); the
        // same answer as `first_trial`, whose `||` this splits.
        let mut done = [false; CHUNK];
        for ((((n, done), &mu), &u), &v) in n.iter_mut().zip(&mut done).zip(mu).zip(&u).zip(&v) {
            let (k, immediate) = first_immediate(mu, u, v);
            *n = k;
            *done = immediate;
        }
        let mut missed = [0u16; CHUNK];
        let mut count = 0;
        for (i, (&done, &mu)) in done.iter().zip(mu).enumerate() {
            missed[count] = i as u16;
            count += usize::from(!done && is_ptrs(mu));
        }
        let (mut gm, mut gu, mut gv) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        for (t, &i) in missed[..count].iter().enumerate() {
            let i = usize::from(i);
            (gm[t], gu[t], gv[t]) = (mu[i], u[i], v[i]);
        }
        let mut ok = [false; CHUNK];
        for (((ok, &mu), &u), &v) in ok[..count].iter_mut().zip(&gm).zip(&gu).zip(&gv) {
            *ok = first_trial(mu, u, v).1;
        }
        for (&i, &ok) in missed[..count].iter().zip(&ok) {
            done[usize::from(i)] = ok;
        }
        for (i, ((n, &mu), &v)) in n.iter_mut().zip(mu).zip(&v).enumerate() {
            if !done[i] {
                *n = finish(&mut self.retry[i % LANES], mu, v);
            }
        }
    }
}

/// Which compiled form of the lanes' arithmetic draws (the same bits from each).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Build {
    /// Eight doubles a vector (AVX-512F and DQ).
    Avx512,
    /// Four doubles a vector (AVX2).
    Avx2,
    /// Whatever the baseline target gives (SSE2 on x86-64).
    Portable,
}

impl Build {
    /// The widest build this CPU has.
    pub fn best() -> Self {
        [Build::Avx512, Build::Avx2].into_iter().find(|b| b.available()).unwrap_or(Build::Portable)
    }

    /// Whether this CPU has the build's instructions (the portable one: always).
    pub fn available(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Build::Avx512 => std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512dq"),
            #[cfg(target_arch = "x86_64")]
            Build::Avx2 => std::is_x86_feature_detected!("avx2"),
            Build::Portable => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngCore;
    use proptest::prelude::*;
    use rand::SeedableRng;
    use statrs::distribution::{ContinuousCDF, Discrete, Normal, Poisson as Pmf};

    /// Distance in units in the last place between two finite doubles of one sign.
    fn ulps(a: f64, b: f64) -> u64 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
    }

    #[test]
    fn streams_are_rand_xoshiros() {
        // The generator and its seeding against the crate's own (an implementation we
        // did not write): the same 1000 words from five seeds.
        for seed in [0, 1, 735, u64::MAX, 0x0123_4567_89AB_CDEF] {
            let mut ours = Stream::from_seed(seed);
            let mut theirs = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
            for _ in 0..1000 {
                assert_eq!(ours.next_u64(), theirs.next_u64(), "seed {seed}");
            }
        }
    }

    #[test]
    fn ln_is_within_a_unit_of_libms() {
        let mut g = Stream::from_seed(5);
        let mut worst = 0;
        for i in 0..2_000_000 {
            // Mantissas all over, exponents from 2^-1000 to 2^1000, and 1 +- tiny.
            let x = match i % 3 {
                0 => f64::from_bits((g.next_u64() >> 12) | ((23 + g.next_u64() % 2000) << 52)),
                1 => 1.0 + (unit(g.next_u64()) - 0.5) * 1e-6,
                _ => unit(g.next_u64()) * 4.0 + f64::MIN_POSITIVE,
            };
            let (ours, libm) = (ln(x), x.ln());
            if ours != libm {
                assert_eq!(ours.signum(), libm.signum(), "{x}");
                worst = worst.max(ulps(ours, libm));
            }
        }
        assert!(worst <= 1, "{worst} ulps");
        assert_eq!(ln(1.0), 0.0);
        assert_eq!(ln(0.0), f64::NEG_INFINITY);
        assert!(ln(-1.0).is_nan() && ln(f64::NAN).is_nan());
    }

    #[test]
    fn sin_cos_are_within_two_units_of_libms() {
        // The angle the quarter turns mean: 2 pi t less an eighth of a turn.
        let mut g = Stream::from_seed(6);
        for _ in 0..1_000_000 {
            let t = unit(g.next_u64());
            let (c, s) = sin_cos(t);
            let q = (4.0 * t).floor();
            let x = (4.0 * t - q - 0.5) * std::f64::consts::FRAC_PI_2;
            let (lc, ls) = match q as u32 {
                0 => (x.cos(), x.sin()),
                1 => (-x.sin(), x.cos()),
                2 => (-x.cos(), -x.sin()),
                _ => (x.sin(), -x.cos()),
            };
            for (ours, libm) in [(c, lc), (s, ls)] {
                // Near zero (x near 0) compare absolutely, to 2e-3 of an ulp of 1.
                assert!(ulps(ours, libm) <= 2 || (ours - libm).abs() <= 2.0 * f64::EPSILON * 1e-3, "t {t}: {ours} vs {libm}");
            }
            assert!((c * c + s * s - 1.0).abs() < 4.0 * f64::EPSILON);
        }
    }

    #[test]
    fn the_log_test_is_statrs_ln_pmf() {
        // With a ratio of 1 the margin is -ln Pois(k; mu): against statrs' ln_pmf (its
        // ln_gamma), both sides of k = 16 and out to ten deviations at a full well, to
        // the rounding of the terms it sums (ln k! is 2 x 10^6 at 182,000).
        for mu in [10.0, 12.5, 37.5, 1000.0, 5432.1, 182_000.0] {
            let pmf = Pmf::new(mu).unwrap();
            let sd = f64::sqrt(mu);
            let ks = (0..40).chain(((mu - 10.0 * sd).max(0.0) as u64..(mu + 10.0 * sd) as u64).step_by((sd / 4.0).max(1.0) as usize));
            for k in ks {
                let want = -pmf.ln_pmf(k);
                let got = log_margin(mu, k as f64, 1.0);
                // The size of the terms summed: k ln mu, mu and ln k! (< k ln(k + 1)).
                let scale = k as f64 * mu.ln() + mu + k as f64 * (k as f64 + 1.0).ln() + 1.0;
                assert!((got - want).abs() <= 1e-14 * scale, "mu {mu} k {k}: {got} vs {want}");
            }
            // A ratio scales in as its logarithm.
            let k = mu.round();
            assert!((log_margin(mu, k, 0.25) - (log_margin(mu, k, 1.0) + 0.25f64.ln())).abs() < 1e-12 * mu.ln() * k);
        }
    }

    #[test]
    fn stirlings_series_is_the_decimal_one() {
        // ln (x-1)! - (x - 1/2) ln x + x - ln(2 pi)/2 from 60-digit decimal logarithms
        // (Python's decimal module): the series to its truncation, under 6e-17 at 17.
        for (x, want) in [
            (17.0, 0.004901395948434738),
            (18.0, 0.004629153749334028),
            (20.0, 0.004166319691996922),
            (25.0, 0.003333155636728093),
            (40.0, 0.0020832899383024218),
            (1000.0, 8.333333055555635e-05),
        ] {
            let got = stirling_series(1.0 / x);
            assert!((got - want).abs() < 1e-16, "x {x}: {got} vs {want}");
        }
    }

    #[test]
    fn box_muller_partners_are_independent() {
        // A pair's cosine and sine go to a lane's pixels t and t + 1 (pixels i and i + 8
        // of the span): uncorrelated, and z1^2 + z2^2 exponential with mean 2, so
        // exp(-(z1^2 + z2^2) / 2) is uniform (Kolmogorov-Smirnov at 0.1%).
        let (mut nn, mut zz) = ([0.0; CHUNK], [0.0; CHUNK]);
        let mut pairs = Vec::new();
        for row in 0..64 {
            let mut d = LineDraws::new(5, row);
            for _ in 0..16 {
                d.draw(&[100.0; CHUNK], &mut nn, &mut zz);
                for block in zz.chunks_exact(2 * LANES) {
                    pairs.extend((0..LANES).map(|j| (block[j], block[LANES + j])));
                }
            }
        }
        let n = pairs.len() as f64;
        let corr = pairs.iter().map(|(a, b)| a * b).sum::<f64>() / n;
        assert!(corr.abs() < 5.0 / n.sqrt(), "correlation {corr}");
        let mut u: Vec<f64> = pairs.iter().map(|(a, b)| (-(a * a + b * b) / 2.0).exp()).collect();
        u.sort_by(f64::total_cmp);
        let d = u.iter().enumerate().map(|(i, &x)| (x - i as f64 / n).abs().max(((i + 1) as f64 / n - x).abs())).fold(0.0, f64::max);
        assert!(d < 1.95 / n.sqrt(), "KS distance {d}");
    }

    /// Chi-square of `draws` draws of [`poisson`] against statrs' Poisson PMF over the
    /// values with at least 20 expected (the rest pooled): (chi2, degrees of freedom,
    /// mean, variance).
    fn chi_square(lambda: f64, draws: usize, seed: u64) -> (f64, usize, f64, f64) {
        let (mut first, mut retry) = (Stream::from_seed(seed), Stream::from_seed(!seed));
        let mut counts = std::collections::BTreeMap::<u64, u64>::new();
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..draws {
            let k = poisson(&mut first, &mut retry, lambda);
            assert!(k >= 0.0 && k.fract() == 0.0, "{k}");
            *counts.entry(k as u64).or_default() += 1;
            sum += k;
            sum2 += k * k;
        }
        let pmf = Pmf::new(lambda).unwrap();
        let (mut chi2, mut dof, mut rest_obs, mut rest_exp) = (0.0, 0usize, 0.0, draws as f64);
        let hi = (lambda + 12.0 * lambda.sqrt() + 20.0) as u64;
        for k in 0..=hi {
            let e = pmf.pmf(k) * draws as f64;
            if e >= 20.0 {
                let o = *counts.get(&k).unwrap_or(&0) as f64;
                chi2 += (o - e).powi(2) / e;
                dof += 1;
                rest_exp -= e;
                rest_obs += o;
            }
        }
        let rest_obs = draws as f64 - rest_obs;
        if rest_exp >= 20.0 {
            chi2 += (rest_obs - rest_exp).powi(2) / rest_exp;
            dof += 1;
        }
        let mean = sum / draws as f64;
        (chi2, dof - 1, mean, sum2 / draws as f64 - mean * mean)
    }

    #[test]
    fn poisson_draws_follow_the_pmf_on_both_branches() {
        // Knuth below 10, PTRS from 10 (the boundary both sides), up to a full well.
        for (i, &lambda) in [0.3, 4.0, 9.99, 10.0, 12.5, 37.5, 1000.0, 182_000.0].iter().enumerate() {
            let n = 400_000;
            let (chi2, dof, mean, var) = chi_square(lambda, n, 17 + i as u64);
            // chi^2 with dof degrees of freedom: mean dof, sd sqrt(2 dof); 5 sd.
            assert!(chi2 < dof as f64 + 5.0 * (2.0 * dof as f64).sqrt(), "lambda {lambda}: chi2 {chi2} on {dof}");
            // Mean and variance both lambda; 5 standard errors (var of s^2 ~ lambda (1 + 2 lambda) / n).
            assert!((mean - lambda).abs() < 5.0 * (lambda / n as f64).sqrt(), "lambda {lambda}: mean {mean}");
            assert!((var - lambda).abs() < 5.0 * (lambda * (1.0 + 2.0 * lambda) / n as f64).sqrt(), "lambda {lambda}: var {var}");
        }
        for degenerate in [0.0, -3.0, f64::NAN, f64::INFINITY] {
            assert_eq!(poisson(&mut Stream::from_seed(1), &mut Stream::from_seed(2), degenerate), 0.0, "{degenerate}");
        }
    }

    #[test]
    fn a_lines_gaussians_are_standard_normal() {
        // 2^20 Gaussians of a few lines (cosines and sines both): mean 0, variance 1,
        // kurtosis 3 within 5 standard errors, and the empirical CDF within the
        // Kolmogorov-Smirnov bound at 0.1% (1.95 / sqrt(n)) of statrs' normal CDF.
        let mut z = Vec::new();
        let mut nn = [0.0; CHUNK];
        let mut zz = [0.0; CHUNK];
        for row in 0..16 {
            let mut d = LineDraws::new(99, row);
            for _ in 0..256 {
                d.draw(&[50.0; CHUNK], &mut nn, &mut zz);
                z.extend_from_slice(&zz);
            }
        }
        let n = z.len() as f64;
        let mean = z.iter().sum::<f64>() / n;
        let var = z.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        let kurt = z.iter().map(|x| (x - mean).powi(4)).sum::<f64>() / n / (var * var);
        assert!(mean.abs() < 5.0 / n.sqrt(), "mean {mean}");
        assert!((var - 1.0).abs() < 5.0 * (2.0 / n).sqrt(), "variance {var}");
        assert!((kurt - 3.0).abs() < 5.0 * (24.0 / n).sqrt(), "kurtosis {kurt}");
        z.sort_by(f64::total_cmp);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let d = z.iter().enumerate().map(|(i, &x)| {
            let f = normal.cdf(x);
            (f - i as f64 / n).abs().max(((i + 1) as f64 / n - f).abs())
        });
        let d = d.fold(0.0, f64::max);
        assert!(d < 1.95 / n.sqrt(), "KS distance {d}");
    }

    #[test]
    fn lanes_and_lines_draw_independent_streams() {
        // Neighbouring lanes of a line, the same lane of neighbouring lines and frames:
        // correlations within 5 / sqrt(n).
        let n = 1 << 16;
        let lane = |seed: u64, row: usize, j: usize| {
            let (mut f, mut r) = (Stream::from_seed(lane_seed(seed, row, j)), Stream::from_seed(lane_seed(seed, row, LANES + j)));
            (0..n).map(|_| poisson(&mut f, &mut r, 50.0) - 50.0).collect::<Vec<f64>>()
        };
        let corr = |a: &[f64], b: &[f64]| {
            let ab: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            ab / (a.iter().map(|x| x * x).sum::<f64>() * b.iter().map(|y| y * y).sum::<f64>()).sqrt()
        };
        let base = lane(735, 3, 0);
        for other in [lane(735, 3, 1), lane(735, 3, 7), lane(735, 4, 0), lane(736, 3, 0), lane(735 ^ 1, 2, 0)] {
            assert!(corr(&base, &other).abs() < 5.0 / (n as f64).sqrt());
        }
        let seeds: std::collections::HashSet<u64> = (0..4).flat_map(|row| (0..2 * LANES).map(move |j| lane_seed(9, row, j))).collect();
        assert_eq!(seeds.len(), 4 * 2 * LANES);
    }

    /// The contract walked one stream at a time: lane `j` takes pixels j, j + 8, ... in
    /// order, its first stream two uniforms each and a Box-Muller pair at its 1st, 3rd,
    /// ... pixel, its retry stream whatever PTRS or Knuth needs beyond.
    fn one_lane_at_a_time(frame_seed: u64, row: usize, mu: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let (mut n, mut z) = (vec![0.0; mu.len()], vec![0.0; mu.len()]);
        for j in 0..LANES {
            let mut first = Stream::from_seed(lane_seed(frame_seed, row, j));
            let mut retry = Stream::from_seed(lane_seed(frame_seed, row, LANES + j));
            let mut spare = 0.0;
            for (t, i) in (j..mu.len()).step_by(LANES).enumerate() {
                n[i] = poisson(&mut first, &mut retry, mu[i]);
                if t % 2 == 0 {
                    let (u1, u2) = (unit(first.next_u64()), unit(first.next_u64()));
                    let (c, s) = box_muller(u1, u2);
                    z[i] = c;
                    spare = s;
                } else {
                    z[i] = spare;
                }
            }
        }
        (n, z)
    }

    fn by_build(build: Build, frame_seed: u64, row: usize, mu: &[f64], chunk: usize) -> (Vec<f64>, Vec<f64>) {
        let (mut n, mut z) = (vec![0.0; mu.len()], vec![0.0; mu.len()]);
        let mut d = LineDraws::new(frame_seed, row);
        for ((mu, n), z) in mu.chunks(chunk).zip(n.chunks_mut(chunk)).zip(z.chunks_mut(chunk)) {
            d.draw_with(build, mu, n, z);
        }
        (n, z)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        /// Every build, in chunks of any multiple of eight, gives the bits of the
        /// contract walked a stream at a time: means across Knuth's range, PTRS's edge
        /// and a full well, dead (0) and broken (NaN, negative) ones, spans of any length.
        #[test]
        fn every_build_draws_the_contracts_bits(
            seed in any::<u64>(),
            row in 0usize..5000,
            mu in prop::collection::vec(prop_oneof![0.0..10.0, 9.0..40.0, 40.0..200_000.0, Just(0.0), Just(f64::NAN), Just(-1.0)], 0..700),
            chunk in 1usize..=32,
        ) {
            let want = one_lane_at_a_time(seed, row, &mu);
            for build in [Build::Portable, Build::Avx2, Build::Avx512].into_iter().filter(|b| b.available()) {
                let got = by_build(build, seed, row, &mu, chunk * LANES);
                prop_assert_eq!(got.0.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), want.0.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), "{:?} counts", build);
                prop_assert_eq!(got.1.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), want.1.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), "{:?} Gaussians", build);
            }
        }
    }
}
