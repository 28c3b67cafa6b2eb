//! The pixel-wise nonlinearity fit of `dncal linearity` (paper section 5) at the paper's
//! size, 1024 x 1024 pixels x 41 levels, and against a per-pixel least-squares solve (the
//! plain way: one SVD per pixel) on 256 x 256 pixels in the same process.
//!
//! `cargo bench -p dncal-host --bench linearity`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use dncal_host::formats::fits::LinearitySet;
use dncal_host::analyses::linearity::analyze;
use nalgebra::{DMatrix, DVector};

/// Quartic pixels with a little structure, 2 DN std, no saturation.
fn set(side: usize, levels: usize) -> LinearitySet {
    let np = side * side;
    let mut mean = vec![0.0; levels * np];
    for l in 0..levels {
        let x = l as f64 / (levels - 1) as f64;
        for p in 0..np {
            let g = 1.0 + 0.01 * ((p * 7919 % 1000) as f64 / 1000.0 - 0.5);
            mean[l * np + p] = 100.0 + g * (3400.0 * x - 150.0 * x * x + 40.0 * x.powi(3) - 12.0 * x.powi(4));
        }
    }
    LinearitySet { bit_depth: 12, n_adc: 4, n_frames: 256, width: side, height: side, levels, std: vec![2.0; levels * np], mean, voltage: (0..levels).map(|l| l as f64).collect(), mask: None, keys: Default::default() }
}

/// The plain way: a least-squares solve per pixel.
fn per_pixel_svd(s: &LinearitySet) -> Vec<f64> {
    let np = s.width * s.height;
    let a = DMatrix::from_fn(s.levels, 5, |r, c| (r as f64 / (s.levels - 1) as f64).powi(c as i32));
    (0..np)
        .flat_map(|p| {
            let y = DVector::from_iterator(s.levels, (0..s.levels).map(|l| s.mean[l * np + p]));
            a.clone().svd(true, true).solve(&y, 1e-13).map(|v| v.iter().copied().collect::<Vec<_>>()).unwrap_or_default()
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let small = set(256, 41);
    let mut g = c.benchmark_group("linearity 256x256x41");
    g.sample_size(10);
    g.bench_with_input(BenchmarkId::new("dncal analyze (fit, invert, statistics)", "256"), &small, |b, s| b.iter(|| analyze(s, 4).expect("the bench's set is analysable")));
    g.bench_with_input(BenchmarkId::new("per-pixel SVD fit only", "256"), &small, |b, s| b.iter(|| per_pixel_svd(s)));
    g.finish();
    let full = set(1024, 41);
    let mut g = c.benchmark_group("linearity 1024x1024x41");
    g.sample_size(10);
    g.bench_with_input(BenchmarkId::new("dncal analyze", "1024"), &full, |b, s| b.iter(|| analyze(s, 4).expect("the bench's set is analysable")));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
