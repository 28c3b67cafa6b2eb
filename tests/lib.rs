//! The *naive* references the core is checked against, written as plainly as possible
//! and independently of the core's code paths: a double loop with `%` for the ADC, `u64`
//! sums, no grouping, no early exits.

use dncal_core::Geometry;

/// Sums: for every frame, line and pixel, add `lut[(first_column + x) % n_adc][min(code,
/// top)]` in `u64` into the sum of state `frame mod states`.
pub fn naive_sums(lut_bits: &[Vec<u32>], g: Geometry, frames: &[Vec<u16>]) -> Vec<u64> {
    let (w, h, n_adc) = (g.width() as usize, g.height() as usize, lut_bits.len());
    let top = lut_bits[0].len() - 1;
    let mut sums = vec![0u64; g.sum_len()];
    for (f, frame) in frames.iter().enumerate() {
        let state = f % g.states() as usize;
        for y in 0..h {
            for x in 0..w {
                let adc = (g.first_column() as usize + x) % n_adc;
                let code = (frame[y * w + x] as usize).min(top);
                sums[(state * h + y) * w + x] += lut_bits[adc][code] as u64;
            }
        }
    }
    sums
}

/// Histograms: counts per ADC of every code (clamped to the top), ADC-major.
pub fn naive_histograms(g: Geometry, frames: &[Vec<u16>], n_adc: usize, codes: usize) -> Vec<u32> {
    let w = g.width() as usize;
    let mut hist = vec![0u32; n_adc * codes];
    for frame in frames {
        for (i, &c) in frame.iter().enumerate() {
            let adc = (g.first_column() as usize + i % w) % n_adc;
            hist[adc * codes + (c as usize).min(codes - 1)] += 1;
        }
    }
    hist
}

/// Raw entry bits of every table of a LUT set, ADC-major.
pub fn lut_bits<const N: usize, const CODES: usize>(luts: &dncal_core::LutSet<N, CODES>) -> Vec<Vec<u32>> {
    luts.tables().iter().map(|t| t.iter().map(|e| e.to_bits()).collect()).collect()
}
