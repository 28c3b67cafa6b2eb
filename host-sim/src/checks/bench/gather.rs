//! The bench's **gather loop**: the plain LUT loop of the bench (`sums[i] += lut[i mod
//! 4][code]`) as one vector gather (`vpgatherdd`) of 16 entries (AVX-512F) or 8 (AVX2)
//! per step, with nothing else: no range check, no OR of the codes, no line checks. It
//! is what a reader who knows the instruction would write for a frame of in-range codes
//! whose width is a multiple of 16, and what the core's host path must match (issue 59:
//! an independent harness measured such a loop at 1.05-1.15x the core's portable loop).
//!
//! Written here on its own, not through `dncal_core::simd`, so the row compares the
//! core's bookkeeping and dispatch against the bare instruction.
#![allow(unsafe_code)]

/// The widest gather this CPU has, as the row's name gives it; `None` where it has none.
pub fn available() -> Option<&'static str> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx512f") {
            return Some("AVX-512");
        } else if std::is_x86_feature_detected!("avx2") {
            return Some("AVX2");
        }
    }
    None
}

/// A frame's codes checked once for the gather: all in range, a multiple of 16 long.
#[derive(Clone, Copy)]
pub struct InRange<'a>(&'a [u16]);

impl<'a> InRange<'a> {
    /// The codes, if every one is below 4096 and they are a multiple of 16.
    pub fn new(codes: &'a [u16]) -> Option<Self> {
        (codes.len().is_multiple_of(16) && codes.iter().all(|&c| c < 4096)).then_some(InRange(codes))
    }
}

/// One frame through the widest gather the CPU has; false, having added nothing, where
/// it has none or `sums` is not as long as the codes.
pub fn gather_lut_frame(tables: &[[u32; 4096]; 4], codes: InRange<'_>, sums: &mut [u32]) -> bool {
    let codes = codes.0;
    #[cfg(target_arch = "x86_64")]
    {
        if codes.len() != sums.len() {
            return false;
        }
        // SAFETY: the CPU has the instructions (checked); offsets are `adc * 4096 + code`
        // with the code below 4096 (`InRange`), inside the 4 x 4096 tables; loads and
        // stores stay inside `codes` and `sums` (equal lengths, whole steps of 16).
        unsafe {
            if std::is_x86_feature_detected!("avx512f") {
                avx512(tables, codes, sums);
                return true;
            } else if std::is_x86_feature_detected!("avx2") {
                avx2(tables, codes, sums);
                return true;
            }
        }
    }
    false
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn avx512(tables: &[[u32; 4096]; 4], codes: &[u16], sums: &mut [u32]) {
    use std::arch::x86_64::*;
    let base = tables.as_ptr() as *const i32;
    let adc = _mm512_setr_epi32(0, 4096, 8192, 12288, 0, 4096, 8192, 12288, 0, 4096, 8192, 12288, 0, 4096, 8192, 12288);
    for (c, s) in codes.chunks_exact(16).zip(sums.chunks_exact_mut(16)) {
        let index = _mm512_add_epi32(_mm512_cvtepu16_epi32(_mm256_loadu_si256(c.as_ptr() as *const __m256i)), adc);
        let at = s.as_mut_ptr() as *mut __m512i;
        _mm512_storeu_si512(at, _mm512_add_epi32(_mm512_loadu_si512(at), _mm512_i32gather_epi32::<4>(index, base)));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn avx2(tables: &[[u32; 4096]; 4], codes: &[u16], sums: &mut [u32]) {
    use std::arch::x86_64::*;
    let base = tables.as_ptr() as *const i32;
    let adc = _mm256_setr_epi32(0, 4096, 8192, 12288, 0, 4096, 8192, 12288);
    for (c, s) in codes.chunks_exact(8).zip(sums.chunks_exact_mut(8)) {
        let index = _mm256_add_epi32(_mm256_cvtepu16_epi32(_mm_loadu_si128(c.as_ptr() as *const __m128i)), adc);
        let at = s.as_mut_ptr() as *mut __m256i;
        _mm256_storeu_si256(at, _mm256_add_epi32(_mm256_loadu_si256(at), _mm256_i32gather_epi32::<4>(base, index)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gather_loop_adds_what_the_plain_loop_adds() {
        let tables: [[u32; 4096]; 4] = core::array::from_fn(|a| core::array::from_fn(|k| (a as u32 * 7 + 1) * k as u32 + a as u32));
        let codes: Vec<u16> = (0..1024u32).map(|i| (i.wrapping_mul(2654435761) % 4096) as u16).collect();
        let mut sums: Vec<u32> = (0..1024).map(|i| i * 3).collect();
        let want: Vec<u32> = sums.iter().enumerate().map(|(i, &s)| s + tables[i % 4][codes[i] as usize]).collect();
        let ran = gather_lut_frame(&tables, InRange::new(&codes).unwrap(), &mut sums);
        assert_eq!(ran, available().is_some());
        if ran {
            assert_eq!(sums, want);
        }
        assert!(InRange::new(&codes[..8]).is_none(), "not a multiple of 16");
        assert!(InRange::new(&[4096; 16]).is_none(), "out of range");
        assert!(!gather_lut_frame(&tables, InRange::new(&codes[..16]).unwrap(), &mut sums[..32]), "sums of another length");
    }
}
