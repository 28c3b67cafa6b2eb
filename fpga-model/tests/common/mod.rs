//! LUT sets and their device images for the model's tests, built by the core.

use dncal_core::{encode_image, image_len, Mvd1024eLuts, Weight};

/// The LUT set of per-code `weights` (4 ADCs of 4096 codes), by the core's rounding.
pub fn luts(weights: &[Vec<f64>]) -> Mvd1024eLuts {
    let w: Vec<Vec<Weight>> = weights.iter().map(|t| t.iter().map(|&x| Weight::from_num(x)).collect()).collect();
    let refs: [&[Weight]; 4] = [&w[0], &w[1], &w[2], &w[3]];
    Mvd1024eLuts::from_weights(&refs).unwrap()
}

/// The device image of `l`.
pub fn image(l: &Mvd1024eLuts) -> Vec<u8> {
    let mut buf = vec![0u8; image_len::<4, 4096>()];
    encode_image(l, &mut buf).unwrap();
    buf
}

/// Random widths in [0.9, 1.1) per code, scaled to sum to 4095 DN (an entry must stay
/// below 2^23), from a seed (a cheap LCG: the test needs variety, not quality).
pub fn weights(seed: u64) -> Vec<Vec<f64>> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (0..4)
        .map(|_| {
            (0..4096)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    0.9 + 0.2 * ((s >> 11) as f64 / (1u64 << 53) as f64)
                })
                .collect::<Vec<f64>>()
        })
        .map(|t| {
            let sum: f64 = t.iter().sum();
            t.iter().map(|w| w * 4095.0 / sum).collect()
        })
        .collect()
}
