//! Sums of floats that do not depend on the order of the additions: the linearity
//! statistics add one value per pixel and level, and a set split into blocks (on Dask
//! workers, any number, in any order) must give the bits that one pass over the whole set
//! gives. A float sum rounds at every addition, so its bits depend on the order; this one
//! is exact: every finite `f64` is an integer multiple of 2^-1074, and the sum is kept as
//! that integer, in 32-bit limbs held in `i64` (carried every 2^30 additions),
//! rounded to the nearest `f64` only when read. Adding is a few integer operations; two
//! sums merge by adding their limbs, so any split and any merge order give the same
//! integer and the same rounded value.

/// Limbs of 32 bits: the 2098 bits of `|v| * 2^1074` of any finite `v`, a limb of carry
/// room, and the top limb that holds the sign.
pub const LIMBS: usize = 67;

/// Additions between two carry propagations: each adds less than 2^32 to a limb, and a
/// limb holds 2^63. Tests carry every few additions, so that their sums go through it.
const BETWEEN_CARRIES: u32 = if cfg!(test) { 1 << 3 } else { 1 << 30 };

/// An exact sum of `f64` values (see the module's note).
#[derive(Debug, Clone, PartialEq)]
pub struct ExactSum {
    /// `sum * 2^1074 = sum_i limb[i] * 2^(32 i)`; the limbs need not be carried.
    limbs: [i64; LIMBS],
    /// Additions since the last carry propagation.
    pending: u32,
    /// The float sum of the non-finite values added (0 when none): infinities of one sign
    /// give that infinity, of both or any NaN give NaN, in any order.
    special: f64,
}

impl Default for ExactSum {
    fn default() -> Self {
        ExactSum { limbs: [0; LIMBS], pending: 0, special: 0.0 }
    }
}

impl ExactSum {
    /// Adds `v` exactly.
    pub fn add(&mut self, v: f64) {
        if !v.is_finite() {
            self.special += v;
            return;
        }
        let bits = v.to_bits();
        let field = ((bits >> 52) & 0x7ff) as u32;
        let fraction = bits & ((1 << 52) - 1);
        // v = m * 2^(e - 1074) with e = max(field, 1) - 1: the position of m's bit 0 in
        // the sum's integer.
        let (m, pos) = if field == 0 { (fraction, 0) } else { (fraction | 1 << 52, field - 1) };
        if m == 0 {
            return;
        }
        let (i, shift) = ((pos / 32) as usize, pos % 32);
        let t = u128::from(m) << shift;
        let parts = [(t & 0xffff_ffff) as i64, ((t >> 32) & 0xffff_ffff) as i64, (t >> 64) as i64];
        let negative = bits >> 63 == 1;
        for (limb, part) in self.limbs[i..i + 3].iter_mut().zip(parts) {
            if negative {
                *limb -= part;
            } else {
                *limb += part;
            }
        }
        self.pending += 1;
        if self.pending == BETWEEN_CARRIES {
            self.carry();
        }
    }

    /// Adds `other` exactly.
    pub fn merge(&mut self, other: &ExactSum) {
        self.carry();
        let mut o = other.clone();
        o.carry();
        for (a, b) in self.limbs.iter_mut().zip(o.limbs) {
            *a += b;
        }
        self.special += o.special;
        self.carry();
    }

    /// Propagates carries: every limb but the top in `[0, 2^32)`, the same integer.
    fn carry(&mut self) {
        let mut c = 0i64;
        for limb in &mut self.limbs[..LIMBS - 1] {
            let v = *limb + c;
            *limb = v & 0xffff_ffff;
            c = v >> 32;
        }
        self.limbs[LIMBS - 1] += c;
        self.pending = 0;
    }

    /// The limbs, carried, and the sum of the non-finite values: what a block sends to be
    /// merged ([`ExactSum::from_parts`]). Limbs of several sums may be added as integers
    /// (up to 2^31 of them) before they are read back.
    pub fn parts(&self) -> ([i64; LIMBS], f64) {
        let mut s = self.clone();
        s.carry();
        (s.limbs, s.special)
    }

    /// The sum whose limbs are `limbs` (any `i64` values, as [`ExactSum::parts`] gives or
    /// sums of them) and whose non-finite values summed to `special`.
    pub fn from_parts(limbs: [i64; LIMBS], special: f64) -> Self {
        // Limbs up to 2^63: carry through i128 once so that later additions have room.
        let mut out = [0i64; LIMBS];
        let mut c = 0i128;
        for (o, &l) in out[..LIMBS - 1].iter_mut().zip(&limbs) {
            let v = i128::from(l) + c;
            *o = (v & 0xffff_ffff) as i64;
            c = v >> 32;
        }
        out[LIMBS - 1] = (i128::from(limbs[LIMBS - 1]) + c) as i64;
        ExactSum { limbs: out, pending: 0, special }
    }

    /// The sum rounded to the nearest `f64` (ties to even); the non-finite values' sum if
    /// any was added.
    pub fn value(&self) -> f64 {
        if self.special != 0.0 {
            return self.special;
        }
        let mut s = self.clone();
        s.carry();
        let negative = s.limbs[LIMBS - 1] < 0;
        if negative {
            for l in &mut s.limbs {
                *l = -*l;
            }
            s.carry();
        }
        let Some(top) = s.limbs.iter().rposition(|&l| l != 0) else { return 0.0 };
        // The top three limbs (at least 65 significant bits when there are three), then
        // one bit below them for everything further down: the conversion to f64 rounds
        // the 97-bit integer as it would round the exact sum.
        let base = top.saturating_sub(2);
        let mut u = 0u128;
        for &l in s.limbs[base..=top].iter().rev() {
            u = u << 32 | l as u128;
        }
        let sticky = s.limbs[..base].iter().any(|&l| l != 0);
        let magnitude = scale(((u << 1) | u128::from(sticky)) as f64, 32 * base as i32 - 1075);
        if negative { -magnitude } else { magnitude }
    }
}

/// A root mean square whose bits do not depend on the order of its values: the exact sum
/// of the squares of the finite values ([`ExactSum`]) and their count.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExactRms {
    squares: ExactSum,
    n: u64,
}

impl ExactRms {
    /// Counts `v` if it is finite.
    pub fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.squares.add(v * v);
            self.n += 1;
        }
    }

    /// Adds `other`'s values.
    pub fn merge(&mut self, other: &ExactRms) {
        self.squares.merge(&other.squares);
        self.n += other.n;
    }

    /// The RMS of the values counted; NaN when there are none.
    pub fn rms(&self) -> f64 {
        if self.n == 0 { f64::NAN } else { (self.squares.value() / self.n as f64).sqrt() }
    }

    /// The sum of squares' parts ([`ExactSum::parts`]) and the count.
    pub fn parts(&self) -> ([i64; LIMBS], f64, u64) {
        let (limbs, special) = self.squares.parts();
        (limbs, special, self.n)
    }

    /// The RMS of [`ExactRms::parts`] (or their sums).
    pub fn from_parts(limbs: [i64; LIMBS], special: f64, n: u64) -> Self {
        ExactRms { squares: ExactSum::from_parts(limbs, special), n }
    }
}

/// `f * 2^k`, exact where the result is a normal `f64`.
fn scale(mut f: f64, mut k: i32) -> f64 {
    let pow2 = |e: i32| f64::from_bits(((e + 1023) as u64) << 52);
    while k > 1000 {
        f *= pow2(1000);
        k -= 1000;
    }
    while k < -1000 {
        f *= pow2(-1000);
        k += 1000;
    }
    f * pow2(k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn sum_of(v: &[f64]) -> ExactSum {
        let mut s = ExactSum::default();
        v.iter().for_each(|&x| s.add(x));
        s
    }

    /// An oracle we did not round: values `k * 2^-40` with `|k| < 2^62` summed as i128
    /// integers, converted once by Rust's correctly rounded `i128 as f64`.
    fn fixed_point(ks: &[i64]) -> f64 {
        let total: i128 = ks.iter().map(|&k| i128::from(k)).sum();
        total as f64 * 2f64.powi(-40)
    }

    #[test]
    fn a_sum_that_floats_get_wrong_comes_out_exact() {
        // 1e16 + 1 - 1e16 in floats is 0 or 2 depending on the order; exactly it is 1.
        for order in [[1e16, 1.0, -1e16], [1.0, 1e16, -1e16], [1e16, -1e16, 1.0]] {
            assert_eq!(sum_of(&order).value(), 1.0);
        }
        // Ten 0.1s: the float loop gives 0.9999999999999999; the exact sum of the ten
        // doubles nearest 0.1 rounds to 1.0.
        assert_eq!(sum_of(&[0.1; 10]).value(), 1.0);
        assert_eq!(sum_of(&[f64::MAX, f64::MAX, -f64::MAX]).value(), f64::MAX);
        assert_eq!(sum_of(&[f64::from_bits(1), f64::from_bits(1)]).value(), f64::from_bits(2));
        assert_eq!(sum_of(&[-2.5, 0.5]).value(), -2.0);
        assert_eq!(sum_of(&[]).value(), 0.0);
        assert!(sum_of(&[1.0, f64::INFINITY, f64::NEG_INFINITY]).value().is_nan());
        assert_eq!(sum_of(&[1.0, f64::INFINITY]).value(), f64::INFINITY);
    }

    proptest! {
        #[test]
        fn the_sum_is_the_correctly_rounded_exact_one(ks in prop::collection::vec(-(1i64 << 61)..(1i64 << 61), 0..200)) {
            let v: Vec<f64> = ks.iter().map(|&k| k as f64 * 2f64.powi(-40)).collect();
            // The values themselves are rounded to 53 bits: the oracle sums those.
            let exact: Vec<i64> = v.iter().map(|x| (x * 2f64.powi(40)) as i64).collect();
            prop_assert_eq!(sum_of(&v).value(), fixed_point(&exact));
        }

        #[test]
        fn any_split_and_merge_order_gives_the_same_bits(v in prop::collection::vec(prop::num::f64::ANY, 0..300), cuts in prop::collection::vec(0usize..300, 0..6), rotate in 0usize..300) {
            let whole = sum_of(&v);
            let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c.min(v.len())).collect();
            cuts.sort_unstable();
            let mut bounds = vec![0];
            bounds.extend(cuts);
            bounds.push(v.len());
            let mut blocks: Vec<ExactSum> = bounds.windows(2).map(|w| sum_of(&v[w[0]..w[1]])).collect();
            let n = blocks.len();
            blocks.rotate_left(rotate % n);
            let mut merged = ExactSum::default();
            blocks.iter().for_each(|b| merged.merge(b));
            // Through parts added as integers, as a reduction of blocks' limbs does.
            let mut limbs = [0i64; LIMBS];
            let mut special = 0.0;
            for b in &blocks {
                let (l, s) = b.parts();
                limbs.iter_mut().zip(l).for_each(|(a, b)| *a += b);
                special += s;
            }
            let w = whole.value();
            let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
            prop_assert!(same(merged.value(), w), "{} vs {}", merged.value(), w);
            prop_assert!(same(ExactSum::from_parts(limbs, special).value(), w));
            let mut reversed = v.clone();
            reversed.reverse();
            prop_assert!(same(sum_of(&reversed).value(), w));
        }
    }
}
