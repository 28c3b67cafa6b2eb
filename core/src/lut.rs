//! Per-ADC lookup tables: the cumulative normalized code histogram in integers.
//!
//! ## What an entry means
//! If code `j` of an ADC is `w_j` ideal DN wide (the normalized, flattened histogram of a
//! smooth illumination ramp estimates `w_j`, de Wijn 2018 section 4), then code `k`
//! covers the analog interval from `sum_{j<k} w_j` to `sum_{j<=k} w_j` DN above the
//! bottom of code 0, and the best single value for it is the interval's center. The
//! entry is that center in units of 2^-11 DN:
//!
//! ```text
//! entry_k = RNE( 2^11 * ( sum_{j<k} w_j + w_k / 2 ) )
//! ```
//!
//! with `RNE` round-half-to-even, evaluated exactly in integers: the weights are
//! [`Weight`] values (unsigned, 24 fractional bits), so with `n_k = 2 sum_{j<k} w_j + w_k`
//! counted in units of 2^-24, `entry_k = RNE(n_k / 2^14)`. An ideal ADC (`w_j = 1`)
//! gives `entry_k = (k + 1/2) 2^11`. The host's float reference reproduces every entry
//! from this rule, bit for bit.
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

use fixed::types::{U21F11, U8F24};

use crate::adc::CodeCount;
use crate::error::Quantity;
use crate::CoreError;

/// Fractional bits of a LUT entry: the table adds 11 bits of resolution below one DN.
pub const FRAC_BITS: u32 = 11;

/// LUT units (of an entry, or of a sum of entries) per DN: 2^11. The host converts with
/// [`units_to_dn`] and this, never with its own constant.
pub const UNITS_PER_DN: f64 = (1u32 << FRAC_BITS) as f64;

/// A value in LUT units (an entry's bits, or a sum of entries such as the corrector's
/// 32-bit sums) in DN. Exact: the scale is a power of two.
#[inline]
pub fn units_to_dn(units: u64) -> f64 {
    units as f64 / UNITS_PER_DN
}

/// Half a LUT unit, DN (2^-12): the most an entry rounded to the nearest unit departs from
/// its exact value, so a sum of N frames' entries departs from the exact (f64) sum by at
/// most N times this. The host's bit-exactness checks take their bound from here.
pub const HALF_UNIT_DN: f64 = 0.5 / UNITS_PER_DN;

/// Every LUT entry is strictly below this: 2^23 raw units (12 integer + 11 fractional bits).
pub const LUT_ENTRY_LIMIT: u32 = 1 << 23;

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
/// `n_k` is in units of 2^-24 and counts twice the interval's center; one entry unit is
/// 2^-11 DN, so `entry = n_k / 2^(24 - 11 + 1)`.
const ENTRY_SHIFT: u32 = WEIGHT_FRAC_BITS - FRAC_BITS + 1;

/// One LUT entry: a corrected value in DN, 11 fractional bits, always below 2^23 raw units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[repr(transparent)]
pub struct LutEntry(U21F11);

impl LutEntry {
    /// The entry of an ideal code `k`: `k + 1/2` DN.
    pub const fn ideal(code: u16) -> Self {
        LutEntry(U21F11::from_bits(((code as u32) << FRAC_BITS) | (1 << (FRAC_BITS - 1))))
    }

    /// An entry from raw bits (units of 2^-11 DN), or `None` at or above 2^23.
    pub const fn from_bits(bits: u32) -> Option<Self> {
        if bits < LUT_ENTRY_LIMIT {
            Some(LutEntry(U21F11::from_bits(bits)))
        } else {
            None
        }
    }

    /// Raw bits, units of 2^-11 DN; always below 2^23.
    #[inline]
    pub const fn to_bits(self) -> u32 {
        self.0.to_bits()
    }

    /// The entry as a fixed-point number of DN.
    pub const fn to_fixed(self) -> U21F11 {
        self.0
    }

    /// The entry in DN (exact).
    pub fn to_dn(self) -> f64 {
        units_to_dn(self.to_bits() as u64)
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for LutEntry {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "{=u32}/2048 DN", self.to_bits())
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
    /// The tables of an ideal ADC: code `k` reads `k + 1/2` DN. The datapath boots with
    /// these so it corrects nothing, and changes nothing, until a calibration is loaded.
    pub fn ideal() -> Self {
        let () = CodeCount::<CODES>::VALID;
        let mut table = [LutEntry::default(); CODES];
        for (k, e) in table.iter_mut().enumerate() {
            *e = LutEntry::ideal(k as u16);
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
        let last = round_half_even_shift(2 * below_last + weights[CODES - 1].to_bits() as u64, ENTRY_SHIFT);
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
            *entry = LutEntry(U21F11::from_bits(round_half_even_shift(2 * below + w, ENTRY_SHIFT) as u32));
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
                *e = LutEntry(U21F11::from_bits(b));
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
    use super::{units_to_dn, LutEntry, HALF_UNIT_DN, UNITS_PER_DN};

    #[test]
    fn entries_and_sums_read_in_dn_exactly() {
        // An ideal code k reads k + 1/2 DN; a sum of 512 top entries is 512 times the
        // entry, with no rounding (2^-11 is a power of two and the sums fit f64's 53 bits).
        for k in [0u16, 1, 1000, 4095] {
            assert_eq!(LutEntry::ideal(k).to_dn(), k as f64 + 0.5);
        }
        let top = LutEntry::from_bits((1 << 23) - 1).unwrap();
        assert_eq!(units_to_dn(512 * top.to_bits() as u64), 512.0 * top.to_dn());
        assert_eq!(units_to_dn(u32::MAX as u64) * UNITS_PER_DN, u32::MAX as f64);
        assert_eq!(top.to_dn(), ((1u32 << 23) - 1) as f64 / 2048.0);
        // Half a unit: 2^-12 DN, exactly.
        assert_eq!(HALF_UNIT_DN, 1.0 / 4096.0);
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
        assert_eq!(set.table(3).unwrap()[7], LutEntry::ideal(7));
        assert_eq!(set.table(4), None);
        assert_eq!((LutSet::<4, 4096>::bits(), LutSet::<1, 32>::bits()), (12, 5));
        assert_eq!(std::format!("{set:?}"), "LutSet<4 ADCs, 4096 codes>");
    }
}
