//! Per-ADC lookup tables: the cumulative normalized code histogram in integers.
//!
//! ## What an entry means
//! If code `j` of an ADC is `w_j` ideal DN wide (the normalized, flattened histogram of a
//! smooth illumination ramp estimates `w_j`, de Wijn 2018 section 4), then code `k`
//! covers the analog interval from `sum_{j<k} w_j` to `sum_{j<=k} w_j` DN above the
//! bottom of code 0, and the best single value for it is the interval's center. The
//! entry is that center in units of 2^-F DN, `F` the set's fractional bits
//! ([`frac_bits`]: 11 up to 12-bit ADCs, `23 - B` for B = 13..=16 bits):
//!
//! ```text
//! entry_k = RNE( 2^F * ( sum_{j<k} w_j + w_k / 2 ) )
//! ```
//!
//! with `RNE` round-half-to-even, evaluated exactly in integers: the weights are
//! [`Weight`] values (unsigned, 24 fractional bits), so with `n_k = 2 sum_{j<k} w_j + w_k`
//! counted in units of 2^-24, `entry_k = RNE(n_k / 2^(25 - F))`. An ideal ADC (`w_j = 1`)
//! gives `entry_k = (k + 1/2) 2^F`. The host's float reference reproduces every entry
//! from this rule, bit for bit.
//!
//! ## Why the fractional bits depend on the depth
//! The paper's entries are 23 bits so that 512 frames sum into 32 bits; for its 12-bit
//! ADCs that leaves 11 fractional bits. A 14-bit ADC's top code is 2^14 DN, so with 11
//! fractional bits its entries would need 25 bits and no table could be loaded; the 23-bit
//! width (and with it the 512 exact frames) is what the accumulators rely on, so deeper
//! ADCs give up fractional bits instead: 9 at 14 bits, 7 at 16 bits (an entry rounded to
//! 2^-8 DN at most, against DN errors of a few hundredths of a DN). Shallower ADCs keep
//! 11: their entries' range is smaller still, and one scale for every set up to 12 bits
//! keeps their images and files as they were.
//!
//! ## Why the center and not the paper's inclusive sum
//! The paper's table returns `sum_{j<=k} w_j`, the *top* of code k. For a 12-bit ADC
//! whose normalized weights average 1 the top code's entry is then 4096 DN = 2^23 units,
//! one past the 23-bit range, and 512 such frames sum to exactly 2^32: one count of
//! overflow. The center differs from the top by half the code's own width, `w_k / 2`:
//! a constant half code (which dark subtraction removes) only for an ideal ADC, for a
//! real one a per-code shift of a few hundredths of a DN, and the center is the better
//! estimate of the code's value. It keeps the top entry at 4095.5 DN < 2^23 for any
//! normalized histogram whose last code is set to 1, as the paper's flattening does.
//!
//! ## Invariants a [`LutSet`] carries
//! Every table is non-decreasing and every entry is below 2^23 ([`LUT_ENTRY_LIMIT`]), so
//! 512 frames of any entries sum below 2^32 (see [`crate::accumulate`]).

use fixed::types::U8F24;

use crate::adc::CodeCount;
use crate::error::Quantity;
use crate::CoreError;

/// Every LUT entry is strictly below this: 2^23 raw units (the paper's 12 integer + 11
/// fractional bits; `B` integer and `23 - B` fractional bits above 12 bits).
pub const LUT_ENTRY_LIMIT: u32 = 1 << 23;

/// The width of an entry in bits: 23, so that [`crate::accumulate::EXACT_FRAMES`] = 512
/// frames of any entries sum below 2^32.
pub const LUT_ENTRY_BITS: u32 = LUT_ENTRY_LIMIT.trailing_zeros();

/// Fractional bits of the LUT entries of a `bits`-bit ADC: 11 up to 12 bits (the table
/// adds 11 bits of resolution below one DN), `23 - bits` above, so that the top code's
/// entry stays below 2^23 (module documentation). `None` above 16 bits, the widest code
/// the core reads.
pub const fn frac_bits(bits: u32) -> Option<u32> {
    match bits {
        0..=12 => Some(11),
        13..=16 => Some(LUT_ENTRY_BITS - bits),
        _ => None,
    }
}

/// The fractional bits of `bits`-bit entries, for the bit depths the core reads (a
/// const context: a depth above 16 bits fails to compile where it is a constant).
const fn frac_bits_of(bits: u32) -> u32 {
    match frac_bits(bits) {
        Some(f) => f,
        None => panic!("the core reads codes of at most 16 bits"),
    }
}

/// LUT units (of an entry, or of a sum of entries) per DN for a `bits`-bit ADC: 2^11 up
/// to 12 bits, 2^(23 - bits) above. The host converts with [`units_to_dn`] and this,
/// never with its own constant. `None` above 16 bits.
pub fn units_per_dn(bits: u32) -> Option<f64> {
    frac_bits(bits).map(|f| (1u32 << f) as f64)
}

/// A value in LUT units of a `bits`-bit set (an entry's bits, or a sum of entries such as
/// the corrector's 32-bit sums) in DN. Exact: the scale is a power of two. `None` above
/// 16 bits.
#[inline]
pub fn units_to_dn(units: u64, bits: u32) -> Option<f64> {
    units_per_dn(bits).map(|u| units as f64 / u)
}

/// Half a LUT unit of a `bits`-bit set, DN (2^-12 up to 12 bits, 2^-8 at 16 bits): the
/// most an entry rounded to the nearest unit departs from its exact value, so a sum of N
/// frames' entries departs from the exact (f64) sum by at most N times this. The host's
/// bit-exactness checks take their bound from here. `None` above 16 bits.
pub fn half_unit_dn(bits: u32) -> Option<f64> {
    units_per_dn(bits).map(|u| 0.5 / u)
}

/// A per-code weight: the normalized code width in DN (1.0 for an ideal code), unsigned
/// with 24 fractional bits, 0 to just under 256.
pub type Weight = U8F24;

/// Fractional bits of a [`Weight`]: the weights' grid is 2^-24 DN.
pub const WEIGHT_FRAC_BITS: u32 = 24;

/// The weight nearest `dn` (a code width, DN) on the 2^-24 DN grid, ties to even: the
/// rounding rule of every weight the host computes in floating point. `None` for NaN,
/// infinite or negative widths and for widths that round to 256 DN or more; never
/// clamped. Below 256, `dn * 2^24` is exact in `f64`, so this is the only rounding.
pub fn weight_nearest(dn: f64) -> Option<Weight> {
    if dn.is_finite() && dn >= 0.0 {
        Weight::checked_from_num(dn)
    } else {
        None
    }
}
/// One LUT entry: a corrected value in units of 2^-F DN (`F` the fractional bits of its
/// set's depth, [`frac_bits`]), always below 2^23 raw units. The entry holds its units
/// only; the scale is the set's ([`LutSet::FRAC_BITS`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[repr(transparent)]
pub struct LutEntry(u32);

impl LutEntry {
    /// The entry of an ideal code `k` of a `CODES`-code ADC: `k + 1/2` DN.
    pub const fn ideal<const CODES: usize>(code: u16) -> Self {
        let f = frac_bits_of(CodeCount::<CODES>::BITS);
        LutEntry(((code as u32) << f) | (1 << (f - 1)))
    }

    /// An entry from raw bits (LUT units), or `None` at or above 2^23.
    pub const fn from_bits(bits: u32) -> Option<Self> {
        if bits < LUT_ENTRY_LIMIT {
            Some(LutEntry(bits))
        } else {
            None
        }
    }

    /// Raw bits, LUT units; always below 2^23.
    #[inline]
    pub const fn to_bits(self) -> u32 {
        self.0
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for LutEntry {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "{=u32} LUT units", self.to_bits())
    }
}

/// Round-half-to-even of `n / 2^shift`, exact.
#[inline]
const fn round_half_even_shift(n: u64, shift: u32) -> u64 {
    let q = n >> shift;
    let r = n & ((1u64 << shift) - 1);
    let half = 1u64 << (shift - 1);
    if r > half || (r == half && q & 1 == 1) {
        q + 1
    } else {
        q
    }
}

/// One table per ADC, `CODES` entries each; non-decreasing, every entry below 2^23.
#[derive(Clone, PartialEq, Eq)]
pub struct LutSet<const N: usize, const CODES: usize> {
    tables: [[LutEntry; CODES]; N],
}

impl<const N: usize, const CODES: usize> core::fmt::Debug for LutSet<N, CODES> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "LutSet<{N} ADCs, {CODES} codes>")
    }
}

impl<const N: usize, const CODES: usize> LutSet<N, CODES> {
    /// Fractional bits of this set's entries ([`frac_bits`] of its depth): 11 up to 12
    /// bits, 9 at 14, 7 at 16.
    pub const FRAC_BITS: u32 = frac_bits_of(CodeCount::<CODES>::BITS);

    /// `n_k` is in units of 2^-24 and counts twice the interval's center; one entry unit
    /// is 2^-F DN, so `entry = n_k / 2^(24 - F + 1)`.
    const ENTRY_SHIFT: u32 = WEIGHT_FRAC_BITS - Self::FRAC_BITS + 1;

    /// The tables of an ideal ADC: code `k` reads `k + 1/2` DN. The datapath boots with
    /// these so it corrects nothing, and changes nothing, until a calibration is loaded.
    pub fn ideal() -> Self {
        let () = CodeCount::<CODES>::VALID;
        let mut table = [LutEntry::default(); CODES];
        for (k, e) in table.iter_mut().enumerate() {
            *e = LutEntry::ideal::<CODES>(k as u16);
        }
        LutSet { tables: [table; N] }
    }

    /// Builds every table from per-code weights, `weights[adc]` holding `CODES` values,
    /// by the rounding rule of the module documentation.
    pub fn from_weights(weights: &[&[Weight]; N]) -> Result<Self, CoreError> {
        let mut set = Self::ideal();
        for (adc, w) in weights.iter().enumerate() {
            set.set_from_weights(adc, w)?;
        }
        Ok(set)
    }

    /// Replaces the table of ADC `adc` with one built from `weights` (`CODES` values).
    /// On error the table is left as it was.
    pub fn set_from_weights(&mut self, adc: usize, weights: &[Weight]) -> Result<(), CoreError> {
        let Some(table) = self.tables.get_mut(adc) else {
            return Err(CoreError::Adc { adc: adc as u16, adcs: N as u16 });
        };
        if weights.len() != CODES {
            return Err(CoreError::Length {
                what: Quantity::Weights,
                expected: CODES as u32,
                got: weights.len() as u32,
            });
        }
        // Monotonic by construction: n_{k+1} - n_k = w_k + w_{k+1} >= 0 and rounding is
        // monotonic, so the last entry is the largest and the only one to range-check.
        let below_last: u64 = weights[..CODES - 1].iter().map(|w| w.to_bits() as u64).sum();
        let last = round_half_even_shift(2 * below_last + weights[CODES - 1].to_bits() as u64, Self::ENTRY_SHIFT);
        if last >= LUT_ENTRY_LIMIT as u64 {
            return Err(CoreError::EntryOutOfRange {
                adc: adc as u16,
                code: (CODES - 1) as u16,
                bits: last.min(u32::MAX as u64) as u32,
            });
        }
        let mut below: u64 = 0;
        for (entry, w) in table.iter_mut().zip(weights) {
            let w = w.to_bits() as u64;
            // Cannot fail: bounded by `last` above.
            *entry = LutEntry(round_half_even_shift(2 * below + w, Self::ENTRY_SHIFT) as u32);
            below += w;
        }
        Ok(())
    }

    /// A set from raw entry bits, validated for range and monotonicity.
    pub fn from_bits(bits: &[[u32; CODES]; N]) -> Result<Self, CoreError> {
        let mut set = Self::ideal();
        for (adc, (table, raw)) in set.tables.iter_mut().zip(bits).enumerate() {
            validate_table(adc, raw.iter().copied())?;
            for (e, &b) in table.iter_mut().zip(raw) {
                *e = LutEntry(b);
            }
        }
        Ok(set)
    }

    /// The table of ADC `adc`, if it exists.
    #[inline]
    pub fn table(&self, adc: usize) -> Option<&[LutEntry; CODES]> {
        self.tables.get(adc)
    }

    /// All tables, ADC-major.
    #[inline]
    pub fn tables(&self) -> &[[LutEntry; CODES]; N] {
        &self.tables
    }

    /// Bits per code of this set.
    pub const fn bits() -> u32 {
        CodeCount::<CODES>::BITS
    }

    /// LUT units per DN of this set: 2^[`Self::FRAC_BITS`].
    pub const UNITS_PER_DN: f64 = (1u32 << Self::FRAC_BITS) as f64;

    /// Half a LUT unit of this set, DN: see [`half_unit_dn`].
    pub const HALF_UNIT_DN: f64 = 0.5 / Self::UNITS_PER_DN;

    /// An entry of this set in DN (exact: the scale is a power of two).
    pub fn entry_dn(entry: LutEntry) -> f64 {
        Self::units_to_dn(entry.0 as u64)
    }

    /// A value in this set's LUT units (a sum of its entries) in DN, exactly.
    pub fn units_to_dn(units: u64) -> f64 {
        units as f64 / Self::UNITS_PER_DN
    }

    /// Raw write access for the image loader, which keeps the set private until it has
    /// validated every entry (see [`crate::banks`]).
    pub(crate) fn tables_mut(&mut self) -> &mut [[LutEntry; CODES]; N] {
        &mut self.tables
    }
}

/// Checks one table's raw entries: each below 2^23 and none below its predecessor.
pub(crate) fn validate_table(adc: usize, entries: impl Iterator<Item = u32>) -> Result<(), CoreError> {
    let mut previous = 0u32;
    for (code, bits) in entries.enumerate() {
        check_entry(adc, code, previous, bits)?;
        previous = bits;
    }
    Ok(())
}

/// Checks one raw entry against the range and its predecessor (`previous`, 0 for code 0).
#[inline]
pub(crate) fn check_entry(adc: usize, code: usize, previous: u32, bits: u32) -> Result<LutEntry, CoreError> {
    let Some(entry) = LutEntry::from_bits(bits) else {
        return Err(CoreError::EntryOutOfRange { adc: adc as u16, code: code as u16, bits });
    };
    if code > 0 && bits < previous {
        return Err(CoreError::NonMonotonic { adc: adc as u16, code: code as u16 });
    }
    Ok(entry)
}

#[cfg(test)]
mod tests {
    use super::{frac_bits, half_unit_dn, units_per_dn, units_to_dn, LutEntry};

    #[test]
    fn entries_and_sums_read_in_dn_exactly() {
        // An ideal code k reads k + 1/2 DN; a sum of 512 top entries is 512 times the
        // entry, with no rounding (2^-11 is a power of two and the sums fit f64's 53 bits).
        for k in [0u16, 1, 1000, 4095] {
            assert_eq!(LutSet::<1, 4096>::entry_dn(LutEntry::ideal::<4096>(k)), k as f64 + 0.5);
        }
        let top = LutEntry::from_bits((1 << 23) - 1).unwrap();
        let top_dn = LutSet::<1, 4096>::entry_dn(top);
        assert_eq!(units_to_dn(512 * top.to_bits() as u64, 12), Some(512.0 * top_dn));
        assert_eq!(units_to_dn(u32::MAX as u64, 12).unwrap() * units_per_dn(12).unwrap(), u32::MAX as f64);
        assert_eq!(top_dn, ((1u32 << 23) - 1) as f64 / 2048.0);
        // Half a unit: 2^-12 DN, exactly.
        assert_eq!(half_unit_dn(12), Some(1.0 / 4096.0));
    }

    /// The scale by depth, from the 23-bit entry and the paper's 11 fractional bits at 12
    /// bits: 11 at and below 12 bits, one fewer for each bit above, none beyond 16 bits;
    /// the ideal top code of every depth the core reads is below 2^23, and with 11
    /// fractional bits a 14-bit one would not be (16383.5 x 2048 = 33,553,408).
    #[test]
    fn deeper_adcs_give_up_fractional_bits_to_stay_in_23_bits() {
        let expected = [(1, 11), (8, 11), (10, 11), (12, 11), (13, 10), (14, 9), (15, 8), (16, 7)];
        for (bits, f) in expected {
            assert_eq!(frac_bits(bits), Some(f), "{bits} bits");
            assert_eq!(units_per_dn(bits), Some((1u32 << f) as f64));
        }
        assert_eq!((frac_bits(17), units_to_dn(1, 17), half_unit_dn(32)), (None, None, None));
        assert_eq!(LutSet::<1, 16384>::FRAC_BITS, 9);
        assert_eq!(LutSet::<1, 65536>::FRAC_BITS, 7);
        assert_eq!(LutEntry::ideal::<16384>(16383).to_bits(), 16383 * 512 + 256);
        assert_eq!(LutEntry::ideal::<65536>(65535).to_bits(), 65535 * 128 + 64);
        assert!(LutEntry::ideal::<65536>(65535).to_bits() < LUT_ENTRY_LIMIT);
        assert_eq!(LutSet::<1, 65536>::entry_dn(LutEntry::ideal::<65536>(40000)), 40000.5);
        assert!(16383.5 * 2048.0 >= LUT_ENTRY_LIMIT as f64);
    }

    /// A 14- and a 16-bit table from weights on the 2^-24 grid against the f64 rule with
    /// their own scale (exact sums, so f64 round-half-even must agree bit for bit), and
    /// the range check at 16 bits where it is at 12: weights averaging just above 1 DN
    /// overflow the top entry.
    #[test]
    fn deep_tables_match_a_float_cumulative_sum() {
        extern crate std;
        use std::vec::Vec;
        fn check<const CODES: usize>() {
            let weights: Vec<Weight> = (0..CODES).map(|k| Weight::from_bits(0x0100_0000 + (k as u32 * 7919 % 200_000) - 100_000)).collect();
            let mut set = std::boxed::Box::new(LutSet::<1, CODES>::ideal());
            set.set_from_weights(0, &weights).unwrap();
            let scale = (1u32 << LutSet::<1, CODES>::FRAC_BITS) as f64;
            let mut below = 0.0f64;
            for (k, w) in weights.iter().enumerate() {
                let wk = w.to_num::<f64>();
                let center = (below + wk / 2.0) * scale;
                assert_eq!(set.tables()[0][k].to_bits() as f64, center.round_ties_even(), "{CODES} codes, code {k}");
                below += wk;
            }
            let wide: Vec<Weight> = (0..CODES).map(|_| w(1.0 + 1.0 / 1024.0)).collect();
            assert!(matches!(set.set_from_weights(0, &wide), Err(CoreError::EntryOutOfRange { .. })));
        }
        check::<16384>();
        check::<65536>();
    }

    use super::*;

    fn w(x: f64) -> Weight {
        Weight::from_num(x)
    }

    #[test]
    fn ideal_weights_give_code_centers() {
        let weights = [w(1.0); 16];
        let set = LutSet::<1, 16>::from_weights(&[&weights]).unwrap();
        for k in 0..16 {
            assert_eq!(set.tables()[0][k].to_bits(), (2 * k as u32 + 1) << 10);
        }
        assert_eq!(set, LutSet::<1, 16>::ideal());
    }

    #[test]
    fn rounding_is_half_to_even_at_exact_ties() {
        // n_0 = w_0; entry_0 = RNE(w_0 / 2^14) in raw weight bits.
        let tie_even = Weight::from_bits((2 << 14) | (1 << 13)); // 2.5 units -> 2
        let tie_odd = Weight::from_bits((3 << 14) | (1 << 13)); // 3.5 units -> 4
        let above = Weight::from_bits((2 << 14) | ((1 << 13) + 1)); // 2.5+ -> 3
        for (weight, expected) in [(tie_even, 2), (tie_odd, 4), (above, 3)] {
            let mut weights = [w(0.0); 4];
            weights[0] = weight;
            let set = LutSet::<1, 4>::from_weights(&[&weights]).unwrap();
            assert_eq!(set.tables()[0][0].to_bits(), expected);
        }
    }

    #[test]
    fn entries_match_a_float_cumulative_sum() {
        // Weights on a 2^-24 grid: the f64 sums are exact, so f64 round-half-even of the
        // scaled center must agree with the integer rule bit for bit.
        let weights: [Weight; 64] = core::array::from_fn(|k| Weight::from_bits(0x0100_0000 + (k as u32 * 7919 % 200_000) - 100_000));
        let set = LutSet::<1, 64>::from_weights(&[&weights]).unwrap();
        let mut below = 0.0f64;
        for (k, w) in weights.iter().enumerate() {
            let wk = w.to_num::<f64>();
            let center = (below + wk / 2.0) * 2048.0;
            let rne = {
                let f = center.floor();
                let d = center - f;
                if d > 0.5 || (d == 0.5 && f % 2.0 == 1.0) { f + 1.0 } else { f }
            };
            assert_eq!(set.tables()[0][k].to_bits() as f64, rne, "code {k}");
            below += wk;
        }
    }

    #[test]
    fn overflowing_weights_are_rejected_and_leave_the_table() {
        let mut set = LutSet::<1, 4>::ideal();
        let weights = [w(255.0); 4];
        assert!(matches!(set.set_from_weights(0, &weights), Ok(())));
        let mut set = LutSet::<1, 4096>::ideal();
        let big = [w(2.0); 4096];
        assert!(matches!(set.set_from_weights(0, &big), Err(CoreError::EntryOutOfRange { code: 4095, .. })));
        assert_eq!(set, LutSet::<1, 4096>::ideal());
        let short = [w(1.0); 10];
        assert!(matches!(set.set_from_weights(0, &short), Err(CoreError::Length { expected: 4096, got: 10, .. })));
    }

    #[test]
    fn from_bits_rejects_decreasing_and_out_of_range() {
        assert_eq!(
            LutSet::<1, 4>::from_bits(&[[1, 2, 1, 3]]),
            Err(CoreError::NonMonotonic { adc: 0, code: 2 })
        );
        assert_eq!(
            LutSet::<2, 4>::from_bits(&[[1, 2, 3, 4], [0, 0, 0, 1 << 23]]),
            Err(CoreError::EntryOutOfRange { adc: 1, code: 3, bits: 1 << 23 })
        );
        assert!(LutSet::<1, 4>::from_bits(&[[5, 5, 5, (1 << 23) - 1]]).is_ok());
    }

    /// The range check at its boundary, derived by hand: 31 weights of 130 DN and a last
    /// weight `v` give the last entry `RNE((2 * 31 * 130 * 2^24 + v_bits) / 2^14)` units
    /// = 8253440 + v_bits / 2^14; `v_bits = 135167 * 2^14` makes it `2^23 - 1` (accepted),
    /// one unit more `2^23` (refused, naming code 31 and the bits).
    #[test]
    fn the_last_entry_is_range_checked_at_exactly_2_pow_23() {
        let mut weights = [w(130.0); 32];
        weights[31] = Weight::from_bits(135_167 << 14);
        let set = LutSet::<1, 32>::from_weights(&[&weights]).unwrap();
        assert_eq!(set.table(0).unwrap()[31].to_bits(), LUT_ENTRY_LIMIT - 1);
        assert_eq!(set.table(0).unwrap()[30].to_bits(), (30 * 130 * 2048) + 65 * 2048);
        weights[31] = Weight::from_bits(135_168 << 14);
        assert_eq!(
            LutSet::<1, 32>::from_weights(&[&weights]),
            Err(CoreError::EntryOutOfRange { adc: 0, code: 31, bits: LUT_ENTRY_LIMIT })
        );
    }

    /// What a set says of itself: its tables by ADC (none beyond the last), its bits per
    /// code, and a Debug line that does not print 4 x 4096 entries.
    #[test]
    fn a_set_describes_itself() {
        extern crate std;
        let set = LutSet::<4, 4096>::ideal();
        assert_eq!(set.table(3), Some(&set.tables()[3]));
        assert_eq!(set.table(3).unwrap()[7], LutEntry::ideal::<4096>(7));
        assert_eq!(set.table(4), None);
        assert_eq!((LutSet::<4, 4096>::bits(), LutSet::<1, 32>::bits()), (12, 5));
        assert_eq!(std::format!("{set:?}"), "LutSet<4 ADCs, 4096 codes>");
    }
}
