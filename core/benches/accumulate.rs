//! Line accumulation against the plainest possible loop (per-pixel `%` for the ADC,
//! clamp, checked add), same process, same data: the ratio is what to read, not the
//! absolute time on a shared machine.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use dncal_core::{Corrector, Geometry, LutBanks, Mvd1024eLuts};

const WIDTH: usize = 1024;

fn naive_line(tables: &[[u32; 4096]; 4], first_column: usize, codes: &[u16], sums: &mut [u32]) {
    for (i, (&c, s)) in codes.iter().zip(sums.iter_mut()).enumerate() {
        let code = (c as usize).min(4095);
        *s = s.checked_add(tables[(first_column + i) % 4][code]).unwrap_or(u32::MAX);
    }
}

fn bench(c: &mut Criterion) {
    let luts = Box::new(Mvd1024eLuts::ideal());
    let tables: Box<[[u32; 4096]; 4]> = Box::new(core::array::from_fn(|a| core::array::from_fn(|k| luts.tables()[a][k].to_bits())));
    let codes: Vec<u16> = (0..WIDTH).map(|i| ((i * 2654435761) % 4096) as u16).collect();
    let g = Geometry::new(WIDTH as u16, 1, 1, 3).unwrap();
    let mut group = c.benchmark_group("accumulate_line_1024");
    group.throughput(Throughput::Elements(WIDTH as u64));

    let mut banks = Box::new(LutBanks::new((*luts).clone()));
    let mut sums = vec![0u32; WIDTH];
    let mut corrector = Corrector::new(&mut banks, g, &mut sums).unwrap();
    group.bench_function("core", |b| {
        b.iter_batched(
            || (),
            |_| {
                corrector.begin_frame(0).unwrap();
                corrector.accumulate_line(0, &codes).unwrap();
                corrector.end_frame().unwrap();
                if corrector.sums().frames(0).get() >= 500 {
                    corrector.clear_sums().unwrap();
                }
            },
            BatchSize::SmallInput,
        )
    });
    let mut naive_sums = vec![0u32; WIDTH];
    group.bench_function("naive_reference", |b| b.iter(|| naive_line(&tables, 3, std::hint::black_box(&codes), &mut naive_sums)));
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
