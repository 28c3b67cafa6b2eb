//! The core on several threads, as a host DAQ would run it: the frame cut into bands of
//! whole rows, one [`Corrector`] per band with its own copy of the LUT banks and its own
//! sums, every band on its own thread. The arithmetic is the core's, untouched: a band's
//! sums are the rows of the whole frame's sums (a sum depends only on its own pixel), so
//! the bands put back together are bit for bit what one corrector gives (tested).

use dncal_core::{Corrector, CoreError, FrameCount, Geometry, LineReport, LutBanks, LutSet, Status};
use rayon::prelude::*;

/// One band: rows `first_row..first_row + geometry.height()` of the frame.
struct Band<const N: usize, const CODES: usize> {
    first_row: usize,
    geometry: Geometry,
    banks: Box<LutBanks<N, CODES>>,
    sums: Vec<u32>,
}

/// The frame in bands (see the module documentation): the bands' LUT banks and sums.
pub struct Bands<const N: usize = 4, const CODES: usize = 4096> {
    geometry: Geometry,
    bands: Vec<Band<N, CODES>>,
}

/// What a run of frames did, summed over the bands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BandsReport {
    /// Codes above the top code.
    pub out_of_range_codes: u64,
    /// Additions that clipped.
    pub saturated_additions: u64,
}

impl BandsReport {
    fn add(&mut self, line: LineReport) {
        self.out_of_range_codes += line.out_of_range_codes as u64;
        self.saturated_additions += line.saturated_additions as u64;
    }
}

impl<const N: usize, const CODES: usize> Bands<N, CODES> {
    /// `count` bands (at least 1, at most one per row) of nearly equal height over
    /// `geometry`, each with `luts`.
    pub fn new(luts: &LutSet<N, CODES>, geometry: Geometry, count: usize) -> Result<Self, CoreError> {
        let height = geometry.height() as usize;
        let count = count.clamp(1, height);
        let mut bands = Vec::with_capacity(count);
        for b in 0..count {
            let rows = band_rows(height, count, b);
            let g = Geometry::new(geometry.width(), rows.len() as u16, geometry.states(), geometry.first_column())?;
            bands.push(Band { first_row: rows.start, geometry: g, banks: Box::new(LutBanks::new(luts.clone())), sums: Vec::new() });
        }
        Ok(Bands { geometry, bands })
    }

    /// Bands.
    pub fn count(&self) -> usize {
        self.bands.len()
    }

    /// A corrector on every band, its sums cleared (each band on its own thread, so that
    /// the first touch of a fresh buffer's pages is shared out too): frames are then
    /// added through them.
    pub fn correctors(&mut self) -> Result<BandCorrectors<'_, N, CODES>, CoreError> {
        let parts = self.bands.par_iter_mut().map(Band::part).collect::<Result<Vec<_>, CoreError>>()?;
        Ok(BandCorrectors { geometry: self.geometry, parts })
    }

    /// Clears the sums and adds `frames` (state, codes of the whole frame, row-major),
    /// each band on its own thread through all the frames, its sums cleared there too
    /// (one hand-over to the threads for the lot, as a readout's frames would be); the
    /// first error any band meets is returned.
    pub fn run(&mut self, frames: &[(u8, &[u16])]) -> Result<BandsReport, CoreError> {
        check_frames(self.geometry, frames)?;
        let width = self.geometry.width() as usize;
        total(on_threads(&mut self.bands, |band| band.part()?.add_frames(width, frames)))
    }

    /// The whole frame's sums, state-major as [`dncal_core::SumImages`] lays them out.
    pub fn sums(&self) -> Vec<u32> {
        let mut out = vec![0u32; self.geometry.sum_len()];
        for band in &self.bands {
            for (at, from) in spans(self.geometry, band.first_row, band.geometry, &band.sums) {
                out[at..at + from.len()].copy_from_slice(from);
            }
        }
        out
    }
}

/// The rows of band `b` of `count` over `height` rows: nearly equal heights, in order.
pub fn band_rows(height: usize, count: usize, b: usize) -> std::ops::Range<usize> {
    b * height / count..(b + 1) * height / count
}

impl<const N: usize, const CODES: usize> Band<N, CODES> {
    /// A corrector over this band's sums, cleared.
    fn part(&mut self) -> Result<Part<'_, N, CODES>, CoreError> {
        self.sums.resize(self.geometry.sum_len(), 0);
        Ok(Part { first_row: self.first_row, corrector: Corrector::new(&mut self.banks, self.geometry, &mut self.sums)? })
    }
}

/// A frame of the wrong size is refused before any band runs.
fn check_frames(geometry: Geometry, frames: &[(u8, &[u16])]) -> Result<(), CoreError> {
    let pixels = geometry.pixels();
    match frames.iter().find(|(_, codes)| codes.len() != pixels) {
        Some(&(_, bad)) => Err(CoreError::Length { what: dncal_core::error::Quantity::BlockPixels, expected: pixels as u32, got: bad.len() as u32 }),
        None => Ok(()),
    }
}

/// A parallel fold whose result does not depend on the threads or on how the pool split
/// the work: `items` folded in fixed chunks of `chunk` items, each chunk in order, and the
/// chunks' results merged in order. A floating-point sum through rayon's own
/// `fold`/`reduce` changes in its last bits from run to run (the EMVA spectrograms did);
/// this one is the same on every run and on any number of threads.
pub fn fold_in_order<T: Sync, A: Send>(
    items: &[T],
    chunk: usize,
    init: impl Fn() -> A + Sync,
    fold: impl Fn(A, &T) -> A + Sync,
    merge: impl Fn(A, A) -> A,
) -> A {
    let parts: Vec<A> = items.par_chunks(chunk.max(1)).map(|c| c.iter().fold(init(), &fold)).collect();
    parts.into_iter().reduce(merge).unwrap_or_else(init)
}

/// `work` on every item, each on its own thread; a single item on the calling thread
/// (a hand-over to the pool and back costs tens of microseconds, as much as a band of
/// 64 K pixels takes).
fn on_threads<T: Send, R: Send>(items: &mut [T], work: impl Fn(&mut T) -> R + Sync + Send) -> Vec<R> {
    match items {
        [one] => vec![work(one)],
        _ => items.par_iter_mut().map(work).collect(),
    }
}

/// The bands' reports summed, or the first band's error.
fn total(reports: Vec<Result<BandsReport, CoreError>>) -> Result<BandsReport, CoreError> {
    let mut total = BandsReport::default();
    for r in reports {
        let r = r?;
        total.out_of_range_codes += r.out_of_range_codes;
        total.saturated_additions += r.saturated_additions;
    }
    Ok(total)
}

/// A band's sums of each state with where they sit in the whole frame's state-major
/// sums: (offset there, the band's rows of that state).
fn spans(whole: Geometry, first_row: usize, band: Geometry, sums: &[u32]) -> impl Iterator<Item = (usize, &[u32])> {
    let width = whole.width() as usize;
    let rows = band.height() as usize;
    let height = whole.height() as usize;
    sums.chunks_exact(rows * width).enumerate().map(move |(s, from)| ((s * height + first_row) * width, from))
}

/// A band's corrector.
struct Part<'a, const N: usize, const CODES: usize> {
    first_row: usize,
    corrector: Corrector<'a, N, CODES>,
}

/// The bands' correctors over their sums, from [`Bands::correctors`].
pub struct BandCorrectors<'a, const N: usize, const CODES: usize> {
    geometry: Geometry,
    parts: Vec<Part<'a, N, CODES>>,
}

impl<const N: usize, const CODES: usize> BandCorrectors<'_, N, CODES> {
    /// Adds `frames` (state, codes of the whole frame, row-major), each band on its own
    /// thread through all of them (one hand-over for the lot). A frame of the wrong size
    /// is refused before any band runs; otherwise the first error any band meets is
    /// returned.
    pub fn add_frames(&mut self, frames: &[(u8, &[u16])]) -> Result<BandsReport, CoreError> {
        check_frames(self.geometry, frames)?;
        let width = self.geometry.width() as usize;
        total(on_threads(&mut self.parts, |part| part.add_frames(width, frames)))
    }

    /// Adds one frame: [`add_frames`](Self::add_frames) of one.
    pub fn add_frame(&mut self, state: u8, codes: &[u16]) -> Result<BandsReport, CoreError> {
        self.add_frames(&[(state, codes)])
    }

    /// The counters of the whole frame: the pixels' (out-of-range codes, clipped
    /// additions) summed over the bands; the frames' (frames, incomplete frames, LUT
    /// swaps, rejected lines) from the first band, which every other band repeats (each
    /// sees every frame, and a frame refused is refused before any band sees it).
    pub fn status(&self) -> Status {
        let mut status = self.parts.first().map(|p| p.corrector.status()).unwrap_or_default();
        for p in self.parts.iter().skip(1) {
            let s = p.corrector.status();
            status.out_of_range_codes = status.out_of_range_codes.saturating_add(s.out_of_range_codes);
            status.saturated_additions = status.saturated_additions.saturating_add(s.saturated_additions);
        }
        status
    }

    /// Frames completed in `state` (every band's count).
    pub fn frames(&self, state: u8) -> FrameCount {
        self.parts.first().map(|p| p.corrector.sums().frames(state)).unwrap_or_default()
    }

    /// The sums, band by band and state by state: (offset in the whole frame's
    /// state-major sums, those rows' sums). Together they cover the whole frame once.
    pub fn spans(&self) -> Vec<(usize, &[u32])> {
        self.parts.iter().flat_map(|p| {
            let sums = p.corrector.sums();
            spans(self.geometry, p.first_row, sums.geometry(), sums.as_slice())
        }).collect()
    }
}

impl<const N: usize, const CODES: usize> Part<'_, N, CODES> {
    /// This band's rows of whole frames (`width` pixels a row), one after the other.
    fn add_frames(&mut self, width: usize, frames: &[(u8, &[u16])]) -> Result<BandsReport, CoreError> {
        let mut r = BandsReport::default();
        for &(state, codes) in frames {
            r.add(self.add_frame(width, state, codes)?);
        }
        Ok(r)
    }

    /// This band's rows of a whole frame `codes` (`width` pixels a row).
    fn add_frame(&mut self, width: usize, state: u8, codes: &[u16]) -> Result<LineReport, CoreError> {
        let rows = self.corrector.sums().geometry().height() as usize;
        let c = &mut self.corrector;
        c.begin_frame(state)?;
        let line = c.accumulate_lines(0, &codes[self.first_row * width..(self.first_row + rows) * width])?;
        c.end_frame()?;
        Ok(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dncal_core::LutSet;

    /// The same sum on one thread and on four, equal to the naive chunked sum in order,
    /// though the values are chosen so that a different order changes the last bits.
    #[test]
    fn fold_in_order_is_the_same_on_any_number_of_threads() {
        let items: Vec<f64> = (0..10_000).map(|i| 1.0 / (1.0 + i as f64) * if i % 3 == 0 { 1e8 } else { 1e-3 }).collect();
        let naive = items.chunks(37).map(|c| c.iter().fold(0.0, |a, x| a + x)).fold(0.0, |a, x| a + x);
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().map(|pool| pool.install(|| fold_in_order(&items, 37, || 0.0, |a, x| a + x, |a, b| a + b)))
        };
        assert_eq!(on(1).ok().map(f64::to_bits), Some(naive.to_bits()));
        assert_eq!(on(4).ok().map(f64::to_bits), Some(naive.to_bits()));
        // The order matters for these values: a plain left-to-right sum differs.
        let plain: f64 = items.iter().sum();
        assert_ne!(plain.to_bits(), naive.to_bits());
        assert_eq!(fold_in_order(&[] as &[f64], 37, || 0.5, |a, x| a + x, |a, b| a + b), 0.5);
    }

    #[test]
    fn bands_put_together_are_one_corrector_bit_for_bit() {
        // An odd height (uneven bands), a first column off the ADC grid, out-of-range
        // codes, 2 states; 1, 2, 3 and 7 bands against one corrector line by line.
        let g = Geometry::new(37, 13, 2, 3).unwrap();
        let mut x = 12345u64;
        let mut next = || {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            x >> 33
        };
        let bits: Box<[[u32; 4096]; 4]> = Box::new(core::array::from_fn(|_| {
            let mut acc = 0u32;
            core::array::from_fn(|_| {
                acc += (next() % 2000) as u32;
                acc
            })
        }));
        let luts = LutSet::from_bits(&bits).unwrap();
        let frames: Vec<Vec<u16>> = (0..6).map(|_| (0..g.pixels()).map(|_| (next() % 4200) as u16).collect()).collect();
        let mut banks = LutBanks::new(luts.clone());
        let mut want = vec![0u32; g.sum_len()];
        let mut c = Corrector::new(&mut banks, g, &mut want).unwrap();
        for (f, codes) in frames.iter().enumerate() {
            c.begin_frame((f % 2) as u8).unwrap();
            for (row, line) in codes.chunks_exact(37).enumerate() {
                c.accumulate_line(row as u16, line).unwrap();
            }
            c.end_frame().unwrap();
        }
        let one = c.status();
        let oor = one.out_of_range_codes as u64;
        assert!(oor > 0);
        let input: Vec<(u8, &[u16])> = frames.iter().enumerate().map(|(f, c)| ((f % 2) as u8, c.as_slice())).collect();
        for count in [1, 2, 3, 7] {
            let mut bands = Bands::new(&luts, g, count).unwrap();
            assert_eq!(bands.count(), count);
            let r = bands.run(&input).unwrap();
            assert_eq!(r.out_of_range_codes, oor, "{count} bands");
            assert!(bands.sums() == want, "{count} bands");
            // Frame by frame through the correctors: the same sums, laid out by spans
            // that cover the frame once; the counters as one corrector's.
            let mut core = bands.correctors().unwrap();
            for &(state, codes) in &input {
                core.add_frame(state, codes).unwrap();
            }
            assert_eq!(core.status(), one, "{count} bands");
            assert_eq!((core.frames(0).get(), core.frames(1).get()), (3, 3));
            let mut rebuilt = vec![None; g.sum_len()];
            for (at, sums) in core.spans() {
                for (k, &s) in sums.iter().enumerate() {
                    assert!(rebuilt[at + k].replace(s).is_none(), "{count} bands: sum {} twice", at + k);
                }
            }
            assert!(rebuilt.iter().zip(&want).all(|(r, &w)| *r == Some(w)), "{count} bands");
        }
        // A frame of the wrong size is refused before any band runs.
        let mut bands = Bands::new(&luts, g, 2).unwrap();
        assert!(matches!(bands.run(&[(0, &frames[0][1..])]), Err(CoreError::Length { .. })));
    }
}
