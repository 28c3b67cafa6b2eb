//! The core is generic over the number of ADCs `N` and codes `CODES` at compile time;
//! files and camera configurations say them at run time. This is the one place that maps
//! one to the other.

use dncal_core::LutSet;

use crate::{HostError, Origin};

/// The core's LUT set of `tables` (`tables[adc][code]`, `N` of `CODES` entries, units of
/// 2^-11 DN), checked as the core checks every set it loads; tables of another layout
/// are [`HostError::UnsupportedDims`]. `origin` names the tables in errors.
pub fn lut_set<const N: usize, const CODES: usize>(tables: &[Vec<u32>], origin: &Origin) -> Result<Box<LutSet<N, CODES>>, HostError> {
    let layout = || HostError::UnsupportedDims { origin: origin.clone(), n_adc: tables.len(), codes: tables.iter().map(Vec::len).find(|&c| c != CODES).unwrap_or(CODES) };
    if tables.len() != N || tables.iter().any(|t| t.len() != CODES) {
        return Err(layout());
    }
    let mut bits = vec![[0u32; CODES]; N];
    for (dst, src) in bits.iter_mut().zip(tables) {
        dst.copy_from_slice(src);
    }
    let bits: Box<[[u32; CODES]; N]> = bits.into_boxed_slice().try_into().map_err(|_| layout())?;
    LutSet::<N, CODES>::from_bits(&bits).map(Box::new).map_err(|e| HostError::core(origin.to_string(), e))
}

/// Calls `$f::<N, CODES>(args...)` for the supported (ADCs, codes) pairs, or returns a
/// `HostError::UnsupportedDims` naming `$origin` (anything `Into<Origin>`: a path or a
/// `Subject`) for any other pair.
#[macro_export]
macro_rules! dispatch_lut_dims {
    ($n:expr, $codes:expr, $origin:expr, $f:ident ( $($arg:expr),* $(,)? )) => {
        match ($n, $codes) {
            (1, 256) => $f::<1, 256>($($arg),*),
            (1, 1024) => $f::<1, 1024>($($arg),*),
            (1, 4096) => $f::<1, 4096>($($arg),*),
            (1, 16384) => $f::<1, 16384>($($arg),*),
            (1, 65536) => $f::<1, 65536>($($arg),*),
            (2, 256) => $f::<2, 256>($($arg),*),
            (2, 1024) => $f::<2, 1024>($($arg),*),
            (2, 4096) => $f::<2, 4096>($($arg),*),
            (2, 16384) => $f::<2, 16384>($($arg),*),
            (2, 65536) => $f::<2, 65536>($($arg),*),
            (4, 256) => $f::<4, 256>($($arg),*),
            (4, 1024) => $f::<4, 1024>($($arg),*),
            (4, 4096) => $f::<4, 4096>($($arg),*),
            (4, 16384) => $f::<4, 16384>($($arg),*),
            (4, 65536) => $f::<4, 65536>($($arg),*),
            (8, 256) => $f::<8, 256>($($arg),*),
            (8, 1024) => $f::<8, 1024>($($arg),*),
            (8, 4096) => $f::<8, 4096>($($arg),*),
            (n_adc, codes) => Err($crate::HostError::UnsupportedDims { origin: $crate::Origin::from($origin), n_adc, codes }),
        }
    };
}

/// The fractional bits of the LUT entries of `bit_depth`-bit codes: the core's
/// ([`dncal_core::frac_bits`]: 11 up to 12 bits, `23 - bits` above), and beyond the 16
/// bits it reads the same 23-bit rule continued rather than a panic (files of such depths
/// are refused for their depth, not their scale).
pub fn lut_frac_bits(bit_depth: u32) -> u32 {
    dncal_core::frac_bits(bit_depth).unwrap_or_else(|| dncal_core::LUT_ENTRY_BITS.saturating_sub(bit_depth))
}

/// LUT units per DN of tables of `codes` codes: 2^[`lut_frac_bits`] of their depth. Every
/// table the host holds has passed [`lut_set`] or was built for a supported depth.
pub fn units_per_dn(codes: usize) -> f64 {
    (1u64 << lut_frac_bits(codes.trailing_zeros())) as f64
}

/// A value in LUT units of tables of `codes` codes (an entry or a sum of entries) in DN,
/// exactly (the scale is a power of two).
pub fn units_to_dn(units: u64, codes: usize) -> f64 {
    units as f64 / units_per_dn(codes)
}

/// Scales the inner codes of `w` (all but the first and last) to sum to their number:
/// the normalization of LUT weights, with the open end codes left as they are.
pub fn normalize_inner(w: &mut [f64]) {
    let n = w.len();
    if n < 3 {
        return;
    }
    let inner: f64 = w[1..n - 1].iter().sum();
    let scale = (n - 2) as f64 / inner;
    for x in &mut w[1..n - 1] {
        *x *= scale;
    }
}

#[cfg(test)]
mod tests {
    use super::units_to_dn;

    /// The host's scale is the core's for every depth it dispatches to.
    #[test]
    fn the_scale_is_the_cores_for_every_depth() {
        assert_eq!(units_to_dn(2048, 4096), 1.0);
        assert_eq!(units_to_dn(2048, 256), 1.0);
        assert_eq!(units_to_dn(512, 16384), 1.0);
        assert_eq!(units_to_dn(128, 65536), 1.0);
        assert_eq!(units_to_dn(64, 1 << 17), 1.0);
    }
}
