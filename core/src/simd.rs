//! The exact-mode line loop as a vector gather, for the host (feature `simd`, x86-64).
//!
//! The LUT application is one table read per pixel at an address that depends on the
//! pixel's code: a gather. x86-64 has one as an instruction (`vpgatherdd`): AVX2 reads
//! 8 entries at once, AVX-512 16. This module applies a line with it, chosen at run
//! time by what the CPU has ([`Kernel::detected`]). It computes exactly what the
//! portable loop of [`crate::accumulate`] computes in its exact mode, `sums[i] +=
//! lut[adc(first_column + i)][codes[i] & (CODES - 1)]` in wrapping arithmetic, and
//! returns the bitwise OR of the codes, from which the caller learns whether any code
//! was out of range and takes those back by the same rule as the portable loop. So the
//! control (checks, counts, out-of-range codes, the saturating mode) stays in one place
//! and only the inner loop differs; `tests` and the host's property tests hold the two
//! bit-exact over random tables, lines, widths and first columns.
//!
//! The feature is off by default and off in the firmware, where the core stays free of
//! `unsafe` and of `std` (`std` here only answers which instructions the CPU has).
//!
//! Only layouts whose ADC pattern repeats within a vector are taken: N dividing 8
//! (AVX2) or 16 (AVX-512), as the K-Coronagraph's 4 ADCs do; others run the portable
//! loop. The saturating mode (frames beyond 512 in a state) always runs the portable
//! loop: a clipped addition has no vector form as cheap as the wrapping one, and a
//! camera stays in the exact mode.
#![allow(unsafe_code)]

extern crate std;

use crate::adc::AdcMap;
use crate::lut::LutEntry;
use core::arch::x86_64::*;
use core::sync::atomic::{AtomicU8, Ordering};

/// The inner loop a line runs through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// The portable loop of [`crate::accumulate`].
    Portable,
    /// 8 entries a gather (AVX2).
    Avx2,
    /// 16 entries a gather (AVX-512F).
    Avx512,
}

impl Kernel {
    /// The widest kernel this CPU runs, asked once a process. `DNCAL_CORE_KERNEL`
    /// (`portable`, `avx2`, `avx512`) narrows it, for comparing kernels on one machine;
    /// a kernel the CPU lacks is never taken.
    pub fn detected() -> Kernel {
        static CHOSEN: AtomicU8 = AtomicU8::new(0);
        match CHOSEN.load(Ordering::Relaxed) {
            1 => Kernel::Portable,
            2 => Kernel::Avx2,
            3 => Kernel::Avx512,
            _ => {
                let has = Kernel::available();
                let asked = std::env::var("DNCAL_CORE_KERNEL").ok().and_then(|s| Kernel::named(&s));
                let k = match asked {
                    Some(a) if a <= has => a,
                    _ => has,
                };
                CHOSEN.store(k as u8 + 1, Ordering::Relaxed);
                k
            }
        }
    }

    /// The widest kernel the CPU (and the operating system) supports.
    pub fn available() -> Kernel {
        if std::is_x86_feature_detected!("avx512f") {
            Kernel::Avx512
        } else if std::is_x86_feature_detected!("avx2") {
            Kernel::Avx2
        } else {
            Kernel::Portable
        }
    }

    /// The kernel of a name (`portable`, `avx2`, `avx512`).
    pub fn named(name: &str) -> Option<Kernel> {
        match name {
            "portable" => Some(Kernel::Portable),
            "avx2" => Some(Kernel::Avx2),
            "avx512" => Some(Kernel::Avx512),
            _ => None,
        }
    }

    /// The kernel's name, as [`named`](Self::named) reads it.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Portable => "portable",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512 => "avx512",
        }
    }

    /// Entries read a gather; the ADC count must divide it.
    const fn lanes(self) -> usize {
        match self {
            Kernel::Portable => 1,
            Kernel::Avx2 => 8,
            Kernel::Avx512 => 16,
        }
    }
}

impl PartialOrd for Kernel {
    fn partial_cmp(&self, other: &Self) -> Option<core::cmp::Ordering> {
        Some((*self as u8).cmp(&(*other as u8)))
    }
}

/// Adds `tables[adc(first_column + i)][codes[i] & (CODES - 1)]` to `sums[i]` (wrapping)
/// with `kernel` and returns the OR of all codes; `None`, having added nothing, where
/// the kernel is portable, the CPU lacks it, the ADC count does not divide its lanes,
/// the tables do not fit 32-bit offsets or the lengths differ.
pub fn add_exact<const N: usize, const CODES: usize>(kernel: Kernel, tables: &[[LutEntry; CODES]; N], first_column: u32, codes: &[u16], sums: &mut [u32]) -> Option<u32> {
    if kernel == Kernel::Portable || kernel > Kernel::available() || !kernel.lanes().is_multiple_of(N) || N * CODES > i32::MAX as usize || codes.len() != sums.len() || !CODES.is_power_of_two() {
        return None;
    }
    // SAFETY: the CPU has the kernel's instructions (checked above); every offset is
    // below N * CODES (a code masked to CODES - 1, an ADC below N), inside `tables`,
    // whose entries are `u32`s (`LutEntry` is `repr(transparent)`); the loads and stores
    // stay within `codes` and `sums`, of equal length.
    unsafe {
        Some(match kernel {
            Kernel::Avx512 => add_exact_avx512(tables, first_column, codes, sums),
            _ => add_exact_avx2(tables, first_column, codes, sums),
        })
    }
}

/// The offset into `tables` (in entries) of the ADC of each of `lanes` columns from
/// `first_column`: a vector's offsets wherever it starts a multiple of `lanes` on.
fn adc_offsets<const N: usize, const CODES: usize, const LANES: usize>(first_column: u32) -> [i32; LANES] {
    core::array::from_fn(|l| (AdcMap::<N>::adc(first_column + l as u32) * CODES) as i32)
}

/// The columns after the last whole vector, one by one.
fn add_rest<const N: usize, const CODES: usize>(tables: &[[LutEntry; CODES]; N], first_column: u32, from: usize, codes: &[u16], sums: &mut [u32]) -> u32 {
    let mut or = 0u32;
    for (i, (&raw, sum)) in codes.iter().zip(sums.iter_mut()).enumerate().skip(from) {
        or |= raw as u32;
        *sum = sum.wrapping_add(tables[AdcMap::<N>::adc(first_column + i as u32)][raw as usize & (CODES - 1)].to_bits());
    }
    or
}

#[target_feature(enable = "avx512f")]
unsafe fn add_exact_avx512<const N: usize, const CODES: usize>(tables: &[[LutEntry; CODES]; N], first_column: u32, codes: &[u16], sums: &mut [u32]) -> u32 {
    let base = tables.as_ptr() as *const i32;
    let offsets = adc_offsets::<N, CODES, 16>(first_column);
    let offsets = _mm512_loadu_si512(offsets.as_ptr() as *const __m512i);
    let mask = _mm512_set1_epi32((CODES - 1) as i32);
    let mut or = _mm512_setzero_si512();
    let whole = codes.len() / 16 * 16;
    let (c, s) = (codes.as_ptr(), sums.as_mut_ptr());
    let mut i = 0;
    while i < whole {
        let raw = _mm512_cvtepu16_epi32(_mm256_loadu_si256(c.add(i) as *const __m256i));
        or = _mm512_or_si512(or, raw);
        let entries = _mm512_i32gather_epi32::<4>(_mm512_add_epi32(_mm512_and_si512(raw, mask), offsets), base);
        let at = s.add(i) as *mut __m512i;
        _mm512_storeu_si512(at, _mm512_add_epi32(_mm512_loadu_si512(at), entries));
        i += 16;
    }
    _mm512_reduce_or_epi32(or) as u32 | add_rest(tables, first_column, whole, codes, sums)
}

#[target_feature(enable = "avx2")]
unsafe fn add_exact_avx2<const N: usize, const CODES: usize>(tables: &[[LutEntry; CODES]; N], first_column: u32, codes: &[u16], sums: &mut [u32]) -> u32 {
    let base = tables.as_ptr() as *const i32;
    let offsets = adc_offsets::<N, CODES, 8>(first_column);
    let offsets = _mm256_loadu_si256(offsets.as_ptr() as *const __m256i);
    let mask = _mm256_set1_epi32((CODES - 1) as i32);
    let mut or = _mm256_setzero_si256();
    let whole = codes.len() / 8 * 8;
    let (c, s) = (codes.as_ptr(), sums.as_mut_ptr());
    let mut i = 0;
    while i < whole {
        let raw = _mm256_cvtepu16_epi32(_mm_loadu_si128(c.add(i) as *const __m128i));
        or = _mm256_or_si256(or, raw);
        let entries = _mm256_i32gather_epi32::<4>(base, _mm256_add_epi32(_mm256_and_si256(raw, mask), offsets));
        let at = s.add(i) as *mut __m256i;
        _mm256_storeu_si256(at, _mm256_add_epi32(_mm256_loadu_si256(at), entries));
        i += 8;
    }
    let mut lanes = [0u32; 8];
    _mm256_storeu_si256(lanes.as_mut_ptr() as *mut __m256i, or);
    lanes.iter().fold(0, |a, &l| a | l) | add_rest(tables, first_column, whole, codes, sums)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lut::LutSet;
    use proptest::prelude::*;
    use std::vec::Vec;

    /// The rule written out, one pixel at a time: what both kernels must add.
    fn naive<const N: usize, const CODES: usize>(tables: &[[LutEntry; CODES]; N], first_column: u32, codes: &[u16], sums: &mut [u32]) -> u32 {
        let mut or = 0;
        for (i, &raw) in codes.iter().enumerate() {
            or |= raw as u32;
            let adc = (first_column as usize + i) % N;
            sums[i] = sums[i].wrapping_add(tables[adc][raw as usize % CODES].to_bits());
        }
        or
    }

    fn tables_of<const N: usize>(bits: &[u32]) -> LutSet<N, 4096> {
        // Random steps of 1 to 2047 units: monotonic, as a table must be, and below 2^23.
        let b: [[u32; 4096]; N] = core::array::from_fn(|a| {
            let mut at = 0u32;
            core::array::from_fn(|k| {
                at += 1 + bits[(a * 4096 + k) % bits.len()] % 2047;
                at
            })
        });
        LutSet::from_bits(&b).unwrap()
    }

    fn each_kernel_matches<const N: usize>(bits: &[u32], first_column: u32, codes: &[u16], start: &[u32]) -> Result<(), TestCaseError> {
        let luts = tables_of::<N>(bits);
        let mut want = start.to_vec();
        let want_or = naive(luts.tables(), first_column, codes, &mut want);
        for kernel in [Kernel::Avx2, Kernel::Avx512].into_iter().filter(|&k| k <= Kernel::available()) {
            let mut got = start.to_vec();
            let or = add_exact(kernel, luts.tables(), first_column, codes, &mut got);
            if kernel.lanes() % N == 0 {
                prop_assert_eq!(or, Some(want_or), "{:?}", kernel);
                prop_assert_eq!(&got, &want, "{:?}", kernel);
            } else {
                prop_assert_eq!(or, None);
                prop_assert_eq!(&got, start);
            }
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// Random tables, lines of every length round the vector widths, any first
        /// column, codes in and out of range, sums near wrapping.
        #[test]
        fn the_gather_kernels_add_what_the_rule_says(
            bits in proptest::collection::vec(any::<u32>(), 1..64),
            first_column in 0u32..1000,
            codes in proptest::collection::vec(prop_oneof![0u16..4096, any::<u16>()], 0..70),
            seed in any::<u32>(),
        ) {
            let start: Vec<u32> = (0..codes.len() as u32).map(|i| seed.wrapping_mul(2654435761).wrapping_add(i.wrapping_mul(40503))).collect();
            each_kernel_matches::<4>(&bits, first_column, &codes, &start)?;
            each_kernel_matches::<1>(&bits, first_column, &codes, &start)?;
            each_kernel_matches::<16>(&bits, first_column, &codes, &start)?;
            each_kernel_matches::<3>(&bits, first_column, &codes, &start)?;
        }
    }

    #[test]
    fn a_kernel_is_named_by_its_name_and_never_exceeds_the_cpu() {
        for k in [Kernel::Portable, Kernel::Avx2, Kernel::Avx512] {
            assert_eq!(Kernel::named(k.name()), Some(k));
        }
        assert!(Kernel::detected() <= Kernel::available());
        assert_eq!(Kernel::named("sse"), None);
    }
}
