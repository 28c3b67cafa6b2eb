//! Release 4.0's high-pass filter of the nonuniformity images (EMVA 1288 Release 4.0,
//! section 8.1 and appendix E.3): each averaged image minus its smoothing by a 7 x 7 box,
//! an 11 x 11 box and a 3 x 3 binomial filter, one after the other, so that the
//! illumination's fall-off and the lens shading do not count as the camera's
//! nonuniformity. Release 4.0 computes the DSNU, the PRNU, their row, column and pixel
//! parts, the spectrograms and the defect histograms from the filtered images (Release
//! 3.1 and the reference implementation: unfiltered, with a 5 x 5 box for the PRNU
//! histogram only).
//!
//! The three filters are separable and convolve to one 19-tap kernel per axis,
//! [`KERNEL`] (sum 308). The filter is kept in exact integers, `308^2 y - (K x K) * y`,
//! on the pixels whose 19 x 19 window lies inside the image: the standard does not say
//! what to do at the edges (its 5 x 5 filter of Release 3.1 leaves out the two border
//! lines, "because the filtering will not be exact in these areas"); we leave out the
//! nine the 19-tap kernel needs, so every filtered value is exact.

use rayon::prelude::*;

/// The smoothing kernel along one axis: `[1; 7] * [1; 11] * [1, 2, 1]` (convolutions).
pub const KERNEL: [i64; 19] = [1, 4, 8, 12, 16, 20, 24, 27, 28, 28, 28, 27, 24, 20, 16, 12, 8, 4, 1];
/// The sum of [`KERNEL`]: `7 * 11 * 4`.
pub const KERNEL_SUM: i64 = 308;
/// Pixels the filter needs on each side.
pub const RADIUS: usize = 9;
/// The filtered integers are this many times the filtered value: `308^2`.
pub const SCALE: i64 = KERNEL_SUM * KERNEL_SUM;

/// Whether a `rows x cols` image leaves at least a 2 x 2 filtered image.
pub fn fits(rows: usize, cols: usize) -> bool {
    rows >= 2 * RADIUS + 2 && cols >= 2 * RADIUS + 2
}

/// Why Release 4.0 gives no nonuniformity of a `rows x cols` image that does not
/// [`fits`].
pub fn too_small(rows: usize, cols: usize) -> String {
    format!("Release 4.0 high-pass filters the nonuniformity images over 19 x 19 pixels: a {rows} x {cols} image is too small (at least 20 x 20)")
}

/// The filtered `rows x cols` integer image, [`SCALE`] times the filtered value, on the
/// `(rows - 18) x (cols - 18)` pixels whose window lies inside; empty where it does not
/// [`fits`].
pub fn high_pass(image: &[i64], rows: usize, cols: usize) -> (Vec<i64>, usize, usize) {
    if !fits(rows, cols) || image.len() != rows * cols {
        return (Vec::new(), 0, 0);
    }
    let (out_rows, out_cols) = (rows - 2 * RADIUS, cols - 2 * RADIUS);
    // Along each row first (all rows, valid columns), then down the columns.
    let along: Vec<i64> = image
        .par_chunks_exact(cols)
        .flat_map_iter(|row| (0..out_cols).map(move |c| KERNEL.iter().zip(&row[c..c + KERNEL.len()]).map(|(k, v)| k * v).sum::<i64>()))
        .collect();
    let out = (0..out_rows)
        .into_par_iter()
        .flat_map_iter(|r| {
            let along = &along;
            (0..out_cols).map(move |c| {
                let smooth: i64 = KERNEL.iter().enumerate().map(|(i, k)| k * along[(r + i) * out_cols + c]).sum();
                SCALE * image[(r + RADIUS) * cols + c + RADIUS] - smooth
            })
        })
        .collect();
    (out, out_rows, out_cols)
}

/// What white noise of unit variance per pixel leaves after the filter: in a filtered
/// pixel, and in the mean of a filtered column (over its rows) and of a filtered row
/// (over its columns). The temporal noise the standard takes out of the spatial
/// variances (eqs. 37-40: `sigma^2 / L`, `/ (L M)`, `/ (L N)`) passes the filter with
/// these gains, so they replace `1`, `1/M` and `1/N` there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseGains {
    /// Variance of one pixel: `1` unfiltered, `1 - 2 h0^2 + (sum h^2)^2` = 0.9885 filtered.
    pub pixel: f64,
    /// Variance of a column's mean: `1/M` unfiltered, about `0.889 / M` filtered.
    pub col_mean: f64,
    /// Variance of a row's mean: `1/N` unfiltered, about `0.889 / N` filtered.
    pub row_mean: f64,
}

impl NoiseGains {
    /// The gains of the unfiltered `rows x cols` image.
    pub fn unfiltered(rows: usize, cols: usize) -> NoiseGains {
        NoiseGains { pixel: 1.0, col_mean: 1.0 / rows as f64, row_mean: 1.0 / cols as f64 }
    }

    /// The gains of a filtered image of `out_rows x out_cols` pixels, exact (edges
    /// included).
    pub fn filtered(out_rows: usize, out_cols: usize) -> NoiseGains {
        let h: Vec<f64> = KERNEL.iter().map(|&k| k as f64 / KERNEL_SUM as f64).collect();
        let h0 = h[RADIUS];
        let h2: f64 = h.iter().map(|v| v * v).sum();
        NoiseGains { pixel: 1.0 - 2.0 * h0 * h0 + h2 * h2, col_mean: line_mean_gain(out_rows, &h), row_mean: line_mean_gain(out_cols, &h) }
    }
}

/// The variance of the mean of `n` consecutive filtered pixels along one axis, for unit
/// white noise. Input pixel `p` (of the `n + 18` the mean reads) enters the mean with
/// `a(p) delta - b(p) h` across the other axis: `a(p) = 1/n` on the `n` centres,
/// `b(p) = (1/n) sum_m h[p - m]` (the smoothing along this axis), so the variance is
/// `sum a^2 - 2 h0 sum a b + sum b^2 * sum h^2`.
fn line_mean_gain(n: usize, h: &[f64]) -> f64 {
    if n == 0 {
        return f64::NAN;
    }
    let inv = 1.0 / n as f64;
    let h2: f64 = h.iter().map(|v| v * v).sum();
    let (mut aa, mut ab, mut bb) = (0.0, 0.0, 0.0);
    for p in 0..n + 2 * RADIUS {
        let a = if (RADIUS..RADIUS + n).contains(&p) { inv } else { 0.0 };
        // Centres m = 0..n see input p through tap p - m.
        let b: f64 = (p.saturating_sub(2 * RADIUS)..=p.min(n - 1)).map(|m| h[p - m]).sum::<f64>() * inv;
        aa += a * a;
        ab += a * b;
        bb += b * b;
    }
    aa - 2.0 * h[RADIUS] * ab + bb * h2
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::Distribution;

    #[test]
    fn kernel_is_the_three_filters_convolved() {
        // Naive convolution of the 7-box, the 11-box and the binomial.
        let conv = |a: &[i64], b: &[i64]| -> Vec<i64> {
            let mut out = vec![0; a.len() + b.len() - 1];
            for (i, x) in a.iter().enumerate() {
                for (j, y) in b.iter().enumerate() {
                    out[i + j] += x * y;
                }
            }
            out
        };
        assert_eq!(conv(&conv(&[1; 7], &[1; 11]), &[1, 2, 1]), KERNEL.to_vec());
        assert_eq!(KERNEL.iter().sum::<i64>(), KERNEL_SUM);
    }

    #[test]
    fn planes_vanish_and_a_spike_keeps_its_share() {
        // Symmetric kernels reproduce a plane, so the filtered plane is exactly zero.
        let (rows, cols) = (30, 41);
        let plane: Vec<i64> = (0..rows * cols).map(|i| 1000 + 7 * (i / cols) as i64 - 3 * (i % cols) as i64).collect();
        let (f, r, c) = high_pass(&plane, rows, cols);
        assert_eq!((r, c), (12, 23));
        assert!(f.iter().all(|&v| v == 0));
        // A spike of 1 at an output pixel: SCALE - K[9]^2 there, -K[i] K[j] around it.
        let mut spike = vec![0i64; rows * cols];
        spike[15 * cols + 20] = 1;
        let (f, _, c) = high_pass(&spike, rows, cols);
        assert_eq!(f[(15 - RADIUS) * c + 20 - RADIUS], SCALE - 28 * 28);
        assert_eq!(f[(15 - RADIUS + 1) * c + 20 - RADIUS + 2], -28 * 27);
        assert!(high_pass(&spike, 19, cols).0.is_empty());
    }

    /// The gains against white noise filtered by this module: pixel variance and the
    /// variances of column and row means, over 300 images (Monte Carlo, an oracle the
    /// closed forms above did not write).
    #[test]
    fn noise_gains_match_filtered_white_noise() {
        let (rows, cols) = (48, 40);
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let normal = rand_distr::Normal::new(0.0f64, 100.0).unwrap();
        let (mut pix, mut colm, mut rowm, mut n_pix, mut n_col, mut n_row) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let g = NoiseGains::filtered(rows - 18, cols - 18);
        for _ in 0..300 {
            let img: Vec<i64> = (0..rows * cols).map(|_| normal.sample(&mut rng).round() as i64).collect();
            let (f, r, c) = high_pass(&img, rows, cols);
            let f: Vec<f64> = f.iter().map(|&v| v as f64 / SCALE as f64 / 100.0).collect();
            pix += f.iter().map(|v| v * v).sum::<f64>();
            n_pix += f.len() as f64;
            for col in 0..c {
                colm += ((0..r).map(|row| f[row * c + col]).sum::<f64>() / r as f64).powi(2);
                n_col += 1.0;
            }
            for row in f.chunks_exact(c) {
                rowm += (row.iter().sum::<f64>() / c as f64).powi(2);
                n_row += 1.0;
            }
        }
        // Rounding the noise to integers adds 1/12 of a unit in 100^2: negligible.
        let (pix, colm, rowm) = (pix / n_pix, colm / n_col, rowm / n_row);
        assert!((pix / g.pixel - 1.0).abs() < 0.02, "pixel {pix} vs {}", g.pixel);
        assert!((colm / g.col_mean - 1.0).abs() < 0.06, "column mean {colm} vs {}", g.col_mean);
        assert!((rowm / g.row_mean - 1.0).abs() < 0.06, "row mean {rowm} vs {}", g.row_mean);
        // Far from the edges the line gain tends to (1 - 2 h0 + sum h^2) / n.
        let big = NoiseGains::filtered(10_000, 10_000);
        assert!((big.col_mean * 10_000.0 - 0.889_06).abs() < 2e-3, "{}", big.col_mean * 10_000.0);
        assert!((g.pixel - 0.988_495).abs() < 1e-6);
    }
}
