//! Codes and the column-to-ADC map.
//!
//! A `CODES`-code ADC (`CODES = 2^B`, B bits) returns codes `0..=CODES-1`. The sensor's
//! columns are shared round-robin between `N` ADCs: column `c` is digitized by ADC
//! `c mod N` (de Wijn 2018, section 4: "Column N of the sensor is digitized by ADC N mod 4").

use crate::CoreError;

/// Compile-time check that a code count is a power of two in `2..=2^16`.
pub(crate) struct CodeCount<const CODES: usize>;

impl<const CODES: usize> CodeCount<CODES> {
    /// Evaluated (and so checked) wherever a type with `CODES` codes is constructed.
    pub(crate) const VALID: () = assert!(
        CODES.is_power_of_two() && CODES >= 2 && CODES <= 1 << 16,
        "CODES must be a power of two in 2..=65536"
    );
    /// Bits per code, B = log2(CODES).
    pub(crate) const BITS: u32 = CODES.trailing_zeros();
    /// The top code, `2^B - 1`; it is also the saturation code.
    pub(crate) const MAX: u16 = (CODES - 1) as u16;
}

/// A code of a `CODES`-code ADC: never above `CODES - 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Code<const CODES: usize>(u16);

impl<const CODES: usize> Code<CODES> {
    /// The top code, `CODES - 1`.
    pub const MAX: Self = {
        let () = CodeCount::<CODES>::VALID;
        Code(CodeCount::<CODES>::MAX)
    };

    /// A code, or [`CoreError::CodeOutOfRange`] above the top code.
    pub const fn new(raw: u16) -> Result<Self, CoreError> {
        let () = CodeCount::<CODES>::VALID;
        if raw > CodeCount::<CODES>::MAX {
            Err(CoreError::CodeOutOfRange { code: raw, max: CodeCount::<CODES>::MAX })
        } else {
            Ok(Code(raw))
        }
    }

    /// The code a raw value stands for on the datapath: values above the top code are
    /// read as the top code (the ADC's saturation), and the flag says so.
    #[inline]
    pub const fn clamped(raw: u16) -> (Self, bool) {
        let () = CodeCount::<CODES>::VALID;
        let max = CodeCount::<CODES>::MAX;
        if raw > max {
            (Code(max), true)
        } else {
            (Code(raw), false)
        }
    }

    /// The code as an index into a table of `CODES` entries.
    #[inline]
    pub const fn index(self) -> usize {
        self.0 as usize
    }

    /// The raw value.
    pub const fn get(self) -> u16 {
        self.0
    }

    /// Bits per code, B.
    pub const fn bits() -> u32 {
        CodeCount::<CODES>::BITS
    }
}

/// The ADC that digitizes sensor column `column` of a camera with `n_adc` ADCs (at
/// least 1): column `c` goes to ADC `c mod n_adc`. For a count known only at run time
/// (read from a file); [`AdcMap`] is the same map with the count fixed at compile time.
#[inline]
pub const fn adc_of_column(column: usize, n_adc: usize) -> usize {
    column % if n_adc == 0 { 1 } else { n_adc }
}

/// The map from sensor column to ADC: column `c` goes to ADC `c mod N`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AdcMap<const N: usize>;

impl<const N: usize> AdcMap<N> {
    const VALID: () = assert!(N >= 1 && N <= 255, "1..=255 ADCs");

    /// The ADC that digitizes sensor column `column`.
    #[inline]
    pub const fn adc(column: u32) -> usize {
        let () = Self::VALID;
        adc_of_column(column as usize, N)
    }

    /// How many of `len` columns starting at sensor column `first_column` come before
    /// the first column of ADC 0: the head a loop takes one by one before it walks whole
    /// groups of N columns in ADC order.
    #[inline]
    pub const fn head(first_column: u32, len: usize) -> usize {
        let head = (N - Self::adc(first_column)) % N;
        if head < len {
            head
        } else {
            len
        }
    }
}

/// How many of `codes` lie above the top code of a `CODES`-code ADC (the ones the
/// datapath reads as the top code and counts).
#[inline]
pub fn count_above_top<const CODES: usize>(codes: &[u16]) -> u32 {
    codes.iter().filter(|&&raw| Code::<CODES>::clamped(raw).1).count() as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_head_runs_to_the_first_column_of_adc_zero_or_the_end() {
        assert_eq!(AdcMap::<4>::head(130, 64), 2, "130 is ADC 2: columns 130, 131, then 132 is ADC 0");
        assert_eq!(AdcMap::<4>::head(128, 64), 0);
        assert_eq!(AdcMap::<4>::head(129, 2), 2, "a line shorter than its head is all head");
        assert_eq!(AdcMap::<3>::head(7, 10), 2);
        assert_eq!(AdcMap::<1>::head(5, 10), 0);
        for first in 0..12u32 {
            let head = AdcMap::<4>::head(first, 100) as u32;
            assert!(head < 4 && AdcMap::<4>::adc(first + head) == 0 && (0..head).all(|i| AdcMap::<4>::adc(first + i) != 0));
        }
    }

    #[test]
    fn code_rejects_above_top_and_clamps() {
        assert_eq!(Code::<4096>::new(4095).unwrap().get(), 4095);
        assert_eq!(Code::<4096>::new(4096), Err(CoreError::CodeOutOfRange { code: 4096, max: 4095 }));
        assert_eq!(Code::<4096>::clamped(65535), (Code::<4096>::MAX, true));
        assert_eq!(Code::<256>::clamped(255).0.get(), 255);
        assert_eq!(Code::<4096>::bits(), 12);
        assert_eq!(count_above_top::<4096>(&[0, 4095, 4096, 65535, 7]), 2);
        assert_eq!(count_above_top::<16>(&[]), 0);
        assert_eq!(Code::<65536>::MAX.get(), 65535);
    }

    #[test]
    fn column_map_is_column_mod_n() {
        for c in 0..100u32 {
            assert_eq!(AdcMap::<4>::adc(c), (c % 4) as usize);
            assert_eq!(AdcMap::<3>::adc(c), (c % 3) as usize);
            // The run-time map is the same map; no ADC count means one ADC, not a panic.
            assert_eq!(adc_of_column(c as usize, 4), AdcMap::<4>::adc(c));
            assert_eq!(adc_of_column(c as usize, 0), 0);
        }
    }
}
