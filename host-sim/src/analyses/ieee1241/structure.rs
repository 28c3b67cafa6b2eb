//! Where an ADC's DNL comes from, at every scale: named codes that recur at a period or
//! at a bit boundary, periodic patterns of the DNL at every power of two up to half the
//! range, and a binary-weighted SAR's capacitor weights fitted to the DNL.
//!
//! ## Recurrence of named codes
//! The named codes of one kind (wide; narrow or missing) are grouped by `code mod P` for
//! every `P = 2^p` up to the range. A class *recurs* when it holds two or more named codes
//! and at least half the codes of that class in the analysed range, and as many codes
//! named at random would fill it so with probability below 0.001 over all the classes
//! tested (binomial tail; Bonferroni over about `2n` classes of all periods, or over the
//! `B^2` carry-aligned ones for a class below a carry: 60 wide codes placed at random
//! made "recurrences" of 2 of 4 codes on every ADC without this); the period kept is
//! the one whose recurring classes hold the most named codes, then cover the most of
//! their codes, then the smallest (four wide codes 511, 1535, 2559, 3583 recur at 511 mod
//! 1024, four of four, and also at 511 mod 512, four of eight). A class `c` with `c + 1 = 2^j (mod P)`, j below p, is the code
//! below a carry into bit `j` (the transition `c -> c + 1` flips bit `j` up and every
//! lower bit down), where a SAR's bit-`j` capacitor decides alone.
//!
//! ## Periodic patterns
//! Held out across repetitions: with the DNL detrended by a cubic over the analysed codes
//! (a slow trend, such as a ramp's own curvature, is not periodic but would correlate the
//! two halves of a long period) and the named codes left out (one wide code is not a
//! pattern), the codes of each period `P` go to halves by the parity of their repetition
//! `k / P`. With `a_c` and `b_c` the two halves' mean DNL of class `c`, a pattern shared by
//! the repetitions makes `sum_c a_c b_c` positive; noise makes it zero with variance
//! `sum_c var(a_c) var(b_c)`, so `z = sum_c a_c b_c / sqrt(sum_c var(a_c) var(b_c))`.
//! `mean_c a_c b_c` estimates the pattern's variance; its share of the DNL's variance
//! beyond the counts' noise is the explained fraction. Named when that variance beyond
//! noise is itself significant (3 sigma), z exceeds 5 (8 below 16 classes, where a sum of
//! a few products has heavy tails) and it explains at least 10%.
//!
//! ## SAR capacitor weights
//! A binary-weighted SAR's transition into code `k` is `T_k = sum_j bit_j(k) W_j`, so
//! code `k` is `sum_j (bit_j(k+1) - bit_j(k)) W_j` wide. The transition `k -> k+1` flips
//! bit `t = tz(k+1)` (the trailing zeros of `k + 1`, the carry depth) up and every lower
//! bit down, so the width is `W_t - sum_{j<t} W_j`: **the DNL of a code depends only on
//! its carry depth**, `f_t = e_t - sum_{j<t} e_j` with `e_j = W_j - 2^j` LSB. The model
//! is therefore one DNL per carry depth, the weighted mean of its codes (`2^(B-1-t)` of
//! them; weights `1/sigma^2`), and the weight errors follow by `e_t = f_t + sum_{j<t}
//! e_j`. Held out: each depth's codes go alternately to two halves; each half's means
//! predict the other's codes (depths with a single code, the MSB's, cannot be held out
//! and are left out of that score). The explained fraction is of the DNL's variance
//! beyond the counts' noise; it is a share of all the DNL, so a sharp structure of a few
//! codes is a small share at low counts. The model *explains* the data when a bit is
//! named (below) and its depth's two halves agree: `a b / (sigma_a sigma_b) > 5`.
//!
//! `f_t` is what the data fix well (bit `t`'s capacitor against the sum of the lower
//! ones plus one LSB). One wrong capacitor `t` shows in every depth from `t` up (`+e` at
//! `t`, `-e` above), so the weights are attributed sparsely, from the LSB up: bit `t`'s
//! error is what `f_t` departs from the named lower bits' prediction,
//! `r_t = f_t + sum_{j<t} e_j`, named when `|r_t| > 5 sigma` and at least half an LSB
//! (else 0: every real SAR's capacitors differ a little, and at 400 counts a code the
//! small differences of the low bits are significant; attributed one by one they would
//! pile up into the high bits). A depth with a missing code is censored (its width is
//! only known to be at most 0): no weight is attributed from it or above it. The absolute
//! weights themselves are not measured to that precision: `W_t` is the sum of `2^t` code
//! widths, uncertain by the INL's noise (2 LSB at bit 9 with 100 counts a code), and a
//! common gain of all weights is the mean width itself.

use serde::Serialize;

use super::{CodeKind, CodeWidth};

/// Least z of a period, and of a SAR bit's weight error, to be named.
pub const SIGNIFICANCE: f64 = 5.0;
/// Least share of the DNL's variance beyond noise for a period to be named: any pattern
/// also leaves a trace at the periods below it (a spike that always falls in one half),
/// significant at high counts but not a structure of its own.
pub const PERIOD_EXPLAINS: f64 = 0.1;

/// Which named codes a recurrence is of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Side {
    /// Wide codes.
    #[serde(rename = "wide")]
    Wide,
    /// Narrow and missing codes.
    #[serde(rename = "narrow or missing")]
    Narrow,
}

impl Side {
    /// The name in the text and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Side::Wide => "wide",
            Side::Narrow => "narrow or missing",
        }
    }

    /// Whether a code named `kind` is on this side.
    pub fn holds(self, kind: CodeKind) -> bool {
        (kind == CodeKind::Wide) == (self == Side::Wide)
    }
}

/// Named codes that recur at a period.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Recurrence {
    /// Wide, or narrow and missing.
    pub kind: Side,
    /// The period, codes.
    pub period: usize,
    /// The class, `code mod period`.
    pub residue: usize,
    /// The named codes in the class.
    pub codes: Vec<usize>,
    /// Codes of the class in the analysed range.
    pub repetitions: usize,
    /// The bit whose carry the codes sit below (`residue + 1 = 2^bit mod period`).
    pub below_carry_into_bit: Option<u32>,
}

impl Recurrence {
    /// "wide codes 511, 1535, 2559, 3583 recur every 1024 codes (511 mod 1024, 4 of 4): the code below each carry into bit 9"
    pub fn sentence(&self) -> String {
        let codes = self.codes.iter().map(usize::to_string).collect::<Vec<_>>().join(", ");
        let carry = self.below_carry_into_bit.map_or(String::new(), |b| format!(": the code below each carry into bit {b}"));
        format!("{} codes {codes} recur every {} codes ({} mod {}, {} of {}){carry}", self.kind.name(), self.period, self.residue, self.period, self.codes.len(), self.repetitions)
    }
}

/// A periodic pattern's score at one period.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PeriodScore {
    /// The period, codes.
    pub period: usize,
    /// Held-out z (module documentation).
    pub z: f64,
    /// RMS of the pattern shared by the repetitions, LSB (0 when not positive).
    pub pattern_rms_lsb: f64,
    /// Its share of the DNL's variance beyond the counts' noise.
    pub explained: f64,
}

/// One carry depth of a SAR fit: the codes `k` with `tz(k + 1) = bit`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SarCarry {
    /// The bit the carry flips up (0 = LSB: the even codes).
    pub bit: u32,
    /// Analysed codes at this depth.
    pub codes: usize,
    /// Their mean DNL, LSB: `W_bit - sum_{j<bit} W_j - 1`.
    pub dnl_lsb: f64,
    /// Its one-sigma uncertainty, LSB.
    pub sigma_lsb: f64,
    /// Bit `bit`'s weight error attributed sparsely (module documentation), LSB; 0 when
    /// the depth's DNL is what the lower bits' errors predict.
    pub weight_error_lsb: f64,
    /// Its one-sigma uncertainty, LSB.
    pub weight_sigma_lsb: f64,
    /// Held out: the product of the two halves' mean DNL over its noise, `a b /
    /// (sigma_a sigma_b)` (None for a depth of one code).
    pub halves_z: Option<f64>,
    /// A code of this depth is missing: its width is only bounded (at most 0), so no
    /// weight is attributed from it.
    pub censored: bool,
}

impl SarCarry {
    /// The first code at this depth: `2^bit - 1`.
    pub fn first_code(&self) -> usize {
        (1usize << self.bit) - 1
    }

    /// Whether the depth's DNL is significant.
    pub fn significant(&self) -> bool {
        self.dnl_lsb.abs() > SIGNIFICANCE * self.sigma_lsb
    }

    /// Whether a weight error is attributed to this bit.
    pub fn named(&self) -> bool {
        self.weight_error_lsb != 0.0
    }
}

/// A binary-weighted SAR fitted to the DNL.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SarFit {
    /// Every carry depth present in the analysed codes.
    pub carries: Vec<SarCarry>,
    /// Share of the DNL's variance beyond noise that one half's means explain on the
    /// other half's codes (both ways; depths of one code left out).
    pub held_out_explained: f64,
    /// The same share on all codes, fitted on all.
    pub explained: f64,
    /// Whether the fit explains the data: a bit with a weight error named whose depth's
    /// two halves agree at [`SIGNIFICANCE`] (the explained share of all the DNL can be
    /// small: two codes of 4096 are a sharp structure but a small share of the noise).
    pub explains: bool,
}

impl SarFit {
    /// The bits with a weight error, largest first.
    pub fn named_bits(&self) -> Vec<&SarCarry> {
        let mut v: Vec<&SarCarry> = self.carries.iter().filter(|c| c.named()).collect();
        v.sort_by(|a, b| b.weight_error_lsb.abs().total_cmp(&a.weight_error_lsb.abs()));
        v
    }

    /// "binary-weighted SAR explains the DNL (97% held out): bit-9 weight error +8.0 ± 0.3 LSB; codes below the bit-9 carry (511 -> 512, every 1024 codes) +8.0 ± 0.3 LSB ...".
    pub fn sentence(&self) -> String {
        let weights: Vec<String> = self.named_bits().iter().take(4).map(|c| format!("bit-{} weight error {:+.3} ± {:.3} LSB", c.bit, c.weight_error_lsb, c.weight_sigma_lsb)).collect();
        let mut carries: Vec<&SarCarry> = self.carries.iter().filter(|c| c.significant()).collect();
        carries.sort_by(|a, b| b.dnl_lsb.abs().total_cmp(&a.dnl_lsb.abs()));
        let carries: Vec<String> = carries
            .iter()
            .take(4)
            .map(|c| {
                let below = c.first_code();
                let every = if c.codes > 1 { format!(", every {} codes", 2usize << c.bit) } else { String::new() };
                format!("codes below the bit-{} carry ({below} -> {}{every}) {:+.3} ± {:.3} LSB", c.bit, below + 1, c.dnl_lsb, c.sigma_lsb)
            })
            .collect();
        let verdict = if self.explains { "explains" } else { "does not explain" };
        let parts: Vec<String> = weights.into_iter().chain(carries).collect();
        format!("binary-weighted SAR {verdict} the DNL ({:.0}% held out, {:.0}% on all codes){}{}", 100.0 * self.held_out_explained, 100.0 * self.explained, if parts.is_empty() { "" } else { ": " }, parts.join("; "))
    }
}

/// The structure of one ADC's DNL.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Structure {
    /// Named codes that recur.
    pub recurrences: Vec<Recurrence>,
    /// Every period `2 .. 2^(B-1)` tested.
    pub periods: Vec<PeriodScore>,
    /// The smallest period significant at [`SIGNIFICANCE`], explaining at least
    /// [`PERIOD_EXPLAINS`] and at least 90% of what the best one does (a pattern of
    /// period P is also one of 2P).
    pub fundamental_period: Option<usize>,
    /// The SAR fit.
    pub sar: Option<SarFit>,
}

impl Structure {
    /// The structure of `dnl` (of codes `first..`, per-code `sigma`) of a `bits`-bit ADC
    /// with the `named` codes.
    pub fn of(bits: u32, first: usize, dnl: &[f64], sigma: &[f64], named: &[CodeWidth]) -> Structure {
        let n_codes = 1usize << bits;
        let last = first + dnl.len() - 1;
        let mut recurrences = Vec::new();
        for kind in [Side::Wide, Side::Narrow] {
            let codes: Vec<usize> = named.iter().filter(|c| c.kind.is_some_and(|k| kind.holds(k))).map(|c| c.code).collect();
            recurrences.extend(recurring(kind, &codes, first, last, n_codes));
        }
        let excluded: std::collections::HashSet<usize> = named.iter().map(|c| c.code).collect();
        let keep: Vec<usize> = (0..dnl.len()).filter(|i| !excluded.contains(&(first + i))).collect();
        let detrended = detrend_cubic(&keep, dnl);
        let noise = keep.iter().map(|&i| sigma[i] * sigma[i]).sum::<f64>() / keep.len().max(1) as f64;
        let total = detrended.iter().map(|d| d * d).sum::<f64>() / keep.len().max(1) as f64 - noise;
        let periods: Vec<PeriodScore> = (1..bits).map(|p| period_score(1 << p, first, &keep, &detrended, sigma, total)).collect();
        // The structure beyond noise must itself be there: `total` is a mean over the kept
        // codes of `d^2 - sigma^2`, whose noise is `sqrt(2 / n)` of the noise's variance.
        let real = total > 3.0 * noise * (2.0 / keep.len().max(1) as f64).sqrt();
        let named = |p: &PeriodScore| real && p.z > period_threshold(p.period) && p.explained >= PERIOD_EXPLAINS;
        let best = periods.iter().filter(|p| named(p)).map(|p| p.explained).fold(f64::NEG_INFINITY, f64::max);
        let fundamental_period = periods.iter().find(|p| named(p) && p.explained >= 0.9 * best).map(|p| p.period);
        Structure { recurrences, periods, fundamental_period, sar: sar_fit(bits, first, dnl, sigma) }
    }

    /// One line per recurrence, the fundamental period and the SAR fit.
    pub fn lines(&self) -> Vec<String> {
        let mut v: Vec<String> = self.recurrences.iter().map(Recurrence::sentence).collect();
        match self.fundamental_period.and_then(|p| self.periods.iter().find(|s| s.period == p)) {
            Some(p) => v.push(format!(
                "periodic DNL: period {} codes, {:.3} LSB rms, {:.0}% of the DNL beyond noise (held out across repetitions, z {:.1}; named codes left out)",
                p.period,
                p.pattern_rms_lsb,
                100.0 * p.explained,
                p.z
            )),
            None => v.push("periodic DNL: none at any period from 2 to half the range (held out across repetitions)".into()),
        }
        if let Some(s) = &self.sar {
            v.push(s.sentence());
        }
        v
    }

    /// A short name of the strongest structure, for a finding's detail.
    pub fn headline(&self) -> Option<String> {
        if let Some(s) = self.sar.as_ref().filter(|s| s.explains) {
            return Some(s.sentence());
        }
        if let Some(r) = self.recurrences.first() {
            return Some(r.sentence());
        }
        self.fundamental_period.map(|p| format!("periodic DNL of period {p} codes"))
    }
}

/// Codes `k` in `first..=last` with `k mod period == residue`, in closed form.
fn repetitions(first: usize, last: usize, period: usize, residue: usize) -> usize {
    let start = first + (residue + period - first % period) % period;
    if start > last { 0 } else { (last - start) / period + 1 }
}

/// Chance a class of `repetitions` codes holds `members` or more of the named codes, if
/// each analysed code were named with probability `p` (binomial tail).
fn chance(members: usize, repetitions: usize, p: f64) -> f64 {
    use statrs::distribution::{Binomial, DiscreteCDF};
    if members == 0 {
        return 1.0;
    }
    Binomial::new(p.clamp(0.0, 1.0), repetitions as u64).map_or(1.0, |b| b.sf(members as u64 - 1))
}

/// The recurring classes of `codes` (module documentation).
fn recurring(kind: Side, codes: &[usize], first: usize, last: usize, n_codes: usize) -> Vec<Recurrence> {
    if codes.len() < 2 {
        return Vec::new();
    }
    // Against chance: as many codes named at random would fill a class this full with
    // probability `chance`; tested over every class of every period (about 2n classes),
    // or over the carry-aligned classes only (B periods x B bits) for one below a carry.
    let p = codes.len() as f64 / (last + 1 - first) as f64;
    let bits = n_codes.trailing_zeros() as f64;
    let (any_class, carry_class) = (2.0 * n_codes as f64, bits * bits);
    // Kept: the period whose recurring classes hold the most named codes, then the one
    // covering the most of its classes, then the smallest (two codes that share a class
    // of a long period by chance do not beat eight of sixteen codes of a short one).
    let mut best: Option<((usize, f64), Vec<Recurrence>)> = None;
    let mut period = 2;
    while period < n_codes {
        let mut classes: std::collections::BTreeMap<usize, Vec<usize>> = std::collections::BTreeMap::new();
        for &k in codes {
            classes.entry(k % period).or_default().push(k);
        }
        let found: Vec<Recurrence> = classes
            .into_iter()
            .filter_map(|(residue, members)| {
                let repetitions = repetitions(first, last, period, residue);
                let next = (residue + 1) % period;
                let below_carry_into_bit = (next != 0).then(|| next.trailing_zeros()).filter(|b| next == 1 << b && *b > 0);
                let trials = if below_carry_into_bit.is_some() { carry_class } else { any_class };
                (members.len() >= 2 && 2 * members.len() >= repetitions && chance(members.len(), repetitions, p) * trials < super::ALPHA)
                    .then_some(Recurrence { kind, period, residue, codes: members, repetitions, below_carry_into_bit })
            })
            .collect();
        if !found.is_empty() {
            let (hit, all): (usize, usize) = found.iter().fold((0, 0), |(h, a), r| (h + r.codes.len(), a + r.repetitions));
            let coverage = hit as f64 / all as f64;
            if best.as_ref().is_none_or(|((h, c), _)| hit > *h || (hit == *h && coverage > *c + 1e-12)) {
                best = Some(((hit, coverage), found));
            }
        }
        period *= 2;
    }
    best.map(|(_, v)| v).unwrap_or_default()
}

/// `dnl` at the indices `keep`, less its least-squares cubic in the code.
fn detrend_cubic(keep: &[usize], dnl: &[f64]) -> Vec<f64> {
    if keep.len() < 8 {
        return keep.iter().map(|&i| dnl[i]).collect();
    }
    let span = (keep[keep.len() - 1] - keep[0]).max(1) as f64;
    let x = |i: usize| 2.0 * (i - keep[0]) as f64 / span - 1.0;
    let a = nalgebra::DMatrix::from_fn(keep.len(), 4, |r, c| x(keep[r]).powi(c as i32));
    let y = nalgebra::DVector::from_iterator(keep.len(), keep.iter().map(|&i| dnl[i]));
    match a.clone().svd(true, true).solve(&y, 1e-12) {
        Ok(coef) => (y - a * coef).iter().copied().collect(),
        Err(_) => y.iter().copied().collect(),
    }
}

/// The z a period must exceed: [`SIGNIFICANCE`] from 16 classes on; 8 below, where `z` is
/// a sum of a few products of two normal means, whose tail is far heavier than a
/// normal's (for 2 classes `P(z > 5)` is 1.2e-4, `P(z > 8)` about 5e-6).
fn period_threshold(period: usize) -> f64 {
    if period >= 16 { SIGNIFICANCE } else { 8.0 }
}

/// The split-half score of period `period` (module documentation): `keep` indices into
/// the analysed codes (code `first + i`), `d` their detrended DNL, `total` the DNL's
/// variance beyond noise.
fn period_score(period: usize, first: usize, keep: &[usize], d: &[f64], sigma: &[f64], total: f64) -> PeriodScore {
    // Per class and half: sum of DNL, count, sum of variances.
    let mut acc = vec![[(0.0f64, 0usize, 0.0f64); 2]; period];
    for (j, &i) in keep.iter().enumerate() {
        let code = first + i;
        let half = (code / period) % 2;
        let a = &mut acc[code % period][half];
        a.0 += d[j];
        a.1 += 1;
        a.2 += sigma[i] * sigma[i];
    }
    // Each half's own mean is taken out: a pattern is how the classes differ.
    let half_mean = |h: usize| {
        let (s, n) = acc.iter().fold((0.0, 0usize), |(s, n), c| (s + c[h].0, n + c[h].1));
        s / n.max(1) as f64
    };
    let (mean_a, mean_b) = (half_mean(0), half_mean(1));
    // Codes differ beyond the counts' noise in ways no period describes (every code its
    // own width): that spread is in each class-half mean too, `extra / n`, and the null
    // of no pattern has it, so it is counted with the noise (without it a 16-bit ADC of
    // independent widths at 100 counts a code had its z inflated ninefold).
    let extra = residual_excess(keep.iter().enumerate().map(|(j, &i)| ((first + i) % period, d[j], sigma[i] * sigma[i])), period);
    let (mut cross, mut var, mut classes) = (0.0, 0.0, 0usize);
    for c in &acc {
        let [(sa, na, va), (sb, nb, vb)] = *c;
        if na == 0 || nb == 0 {
            continue;
        }
        let (ma, mb) = (sa / na as f64 - mean_a, sb / nb as f64 - mean_b);
        cross += ma * mb;
        var += (va / (na * na) as f64 + extra / na as f64) * (vb / (nb * nb) as f64 + extra / nb as f64);
        classes += 1;
    }
    let z = if var > 0.0 { cross / var.sqrt() } else { 0.0 };
    let pattern = if classes > 0 { (cross / classes as f64).max(0.0) } else { 0.0 };
    let explained = if total > 0.0 { (pattern / total).min(1.0) } else { 0.0 };
    PeriodScore { period, z, pattern_rms_lsb: pattern.sqrt(), explained }
}

/// The variance of the codes' DNL about their class's mean beyond their own noise, LSB^2
/// (a random effect: what makes codes of one class differ when each has its own width),
/// from `(class, dnl, noise variance)` of each code over `classes` classes: `sum_c
/// sum_{i in c} ((d_i - m_c)^2 - v_i (n_c - 1) / n_c) / sum_c n_c` over the classes of two
/// codes or more (`m_c` the class's plain mean; the factor takes out the mean's own share
/// of the noise), 0 when the codes scatter no more than their noise.
fn residual_excess(codes: impl Iterator<Item = (usize, f64, f64)> + Clone, classes: usize) -> f64 {
    let mut sums = vec![(0.0f64, 0usize); classes];
    for (c, d, _) in codes.clone() {
        sums[c].0 += d;
        sums[c].1 += 1;
    }
    let (mut excess, mut n) = (0.0, 0usize);
    for (c, d, v) in codes {
        let (s, nc) = sums[c];
        if nc >= 2 {
            excess += (d - s / nc as f64).powi(2) - v * (nc - 1) as f64 / nc as f64;
            n += 1;
        }
    }
    if n > 0 { (excess / n as f64).max(0.0) } else { 0.0 }
}

/// Carry depth of code `k`: the bit the transition `k -> k + 1` flips up.
fn carry_depth(k: usize) -> u32 {
    (k + 1).trailing_zeros()
}

/// The SAR fit by carry depth (module documentation); None with fewer than two depths.
fn sar_fit(bits: u32, first: usize, dnl: &[f64], sigma: &[f64]) -> Option<SarFit> {
    let depths = bits as usize;
    let depth = |i: usize| (carry_depth(first + i) as usize).min(depths - 1);
    // Each code's noise variance (a code `1 + dnl` LSB wide has that many times a
    // mean-width code's variance).
    let noise = |i: usize| sigma[i] * sigma[i] * (1.0 + dnl[i]).max(0.01);
    // Codes of one depth differ beyond their noise when each code has its own width (a
    // real ADC's, or a random one's): that spread is in every depth's mean, and two
    // codes of one depth (bit 14 of a 16-bit ADC) agree by chance half the time, so it
    // counts as noise in the means, their variances and the halves' agreement. Without
    // it a 16-bit ADC of independent widths (sd 0.29 LSB) at 100 counts a code had its
    // two bit-14 codes, 0.5 LSB wide of the mean by chance, named a weight error at 5.6
    // sigma and "explained". A SAR's own codes do not differ within a depth: 0 there.
    let extra = residual_excess((0..dnl.len()).map(|i| (depth(i), dnl[i], noise(i))), depths);
    let w: Vec<f64> = sigma.iter().map(|s| 1.0 / (s * s + extra).max(1e-300)).collect();
    // The held-out score is of the DNL beyond the counts' noise alone.
    let w_noise: Vec<f64> = sigma.iter().map(|s| 1.0 / (s * s).max(1e-300)).collect();
    // Per depth and half (alternate codes of the depth): sum of w d and of w; and per
    // depth the variance sum of the weighted mean, `sum w^2 var_i`, with each code's own
    // noise (a code `w` LSB wide has `w` times a mean-width code's variance: the bit-9
    // depth of an RP2040-like ADC, codes 9 LSB wide, read ±0.051 LSB for ±0.15).
    let mut acc = vec![[(0.0f64, 0.0f64, 0usize); 2]; depths];
    let mut var_sum = vec![0.0f64; depths];
    let mut half = vec![0usize; dnl.len()];
    let mut seen = vec![0usize; depths];
    for i in 0..dnl.len() {
        let t = depth(i);
        half[i] = seen[t] % 2;
        seen[t] += 1;
        let a = &mut acc[t][half[i]];
        a.0 += w[i] * dnl[i];
        a.1 += w[i];
        a.2 += 1;
        var_sum[t] += w[i] * w[i] * (noise(i) + extra);
    }
    if seen.iter().filter(|&&n| n > 0).count() < 2 {
        return None;
    }
    let mean = |t: usize, halves: &[usize]| {
        let (s, n) = halves.iter().fold((0.0, 0.0), |(s, n), &h| (s + acc[t][h].0, n + acc[t][h].1));
        (n > 0.0).then(|| s / n)
    };
    let score = |predict: &dyn Fn(usize) -> Option<f64>| {
        let (mut before, mut after, mut n) = (0.0, 0.0, 0usize);
        for i in 0..dnl.len() {
            if let Some(p) = predict(i) {
                before += w_noise[i] * dnl[i] * dnl[i];
                after += w_noise[i] * (dnl[i] - p).powi(2);
                n += 1;
            }
        }
        let beyond = before - n as f64;
        if beyond > 0.0 { ((before - after) / beyond).min(1.0) } else { 0.0 }
    };
    let held_out = score(&|i| {
        let t = depth(i);
        (acc[t][1 - half[i]].2 > 0).then(|| mean(t, &[1 - half[i]])).flatten()
    });
    let explained = score(&|i| mean(depth(i), &[0, 1]));
    // f_t and its variance; the weights attributed from the LSB up.
    let f: Vec<(f64, f64)> = (0..depths).map(|t| mean(t, &[0, 1]).map_or((0.0, 0.0), |m| (m, var_sum[t] / (acc[t][0].1 + acc[t][1].1).powi(2)))).collect();
    // A depth with a missing code (DNL -1) is censored: its width is at most 0, and how
    // far below no count can say (a bit 1.5 LSB heavy makes the next carry's codes
    // missing, not -1.5 wide), so no weight is attributed from it.
    let mut censored = vec![false; depths];
    for (i, d) in dnl.iter().enumerate() {
        censored[depth(i)] |= *d <= -1.0 + 1e-9;
    }
    // Each attributed error is a sum of depths' DNL, `e_t = f_t + sum_{named j<t} e_j`:
    // kept as its coefficients over the f's, so that its variance counts each f once
    // with its whole coefficient (bit 9 named twice over reaches e_11 with 2 f_9).
    // Above a censored depth nothing is attributed: that depth's error is unknown, and
    // the next depth would take it (bit 10 1.6 LSB light read as bit 11 1.6 heavy).
    let mut carries = Vec::new();
    let mut below = vec![0.0f64; depths];
    let mut blind = false;
    for t in (0..depths).filter(|&t| seen[t] > 0) {
        let mut coef = below.clone();
        coef[t] += 1.0;
        let r: f64 = coef.iter().zip(&f).map(|(c, f)| c * f.0).sum();
        let var: f64 = coef.iter().zip(&f).map(|(c, f)| c * c * f.1).sum();
        blind |= censored[t];
        let named = !blind && r.abs() > SIGNIFICANCE * var.sqrt() && r.abs() >= super::GROSS_LSB;
        let error = if named { r } else { 0.0 };
        if named {
            below.iter_mut().zip(&coef).for_each(|(b, c)| *b += c);
        }
        let halves_z = match (mean(t, &[0]), mean(t, &[1])) {
            (Some(a), Some(b)) if acc[t][0].1 > 0.0 && acc[t][1].1 > 0.0 => Some(a * b * (acc[t][0].1 * acc[t][1].1).sqrt()),
            _ => None,
        };
        carries.push(SarCarry { bit: t as u32, codes: seen[t], dnl_lsb: f[t].0, sigma_lsb: f[t].1.sqrt(), weight_error_lsb: error, weight_sigma_lsb: var.sqrt(), halves_z, censored: censored[t] });
    }
    let explains = carries.iter().any(|c| c.named() && c.halves_z.is_some_and(|z| z > SIGNIFICANCE));
    Some(SarFit { carries, held_out_explained: held_out, explained, explains })
}
