//! The core on several threads, as a host DAQ would run it: the frame cut into bands of
//! whole rows, one [`Corrector`] per band with its own copy of the LUT banks and its own
//! sums, every band on its own thread. The arithmetic is the core's, untouched: a band's
//! sums are the rows of the whole frame's sums (a sum depends only on its own pixel), so
//! the bands put back together are bit for bit what one corrector gives (tested).

use dncal_core::{Corrector, CoreError, Geometry, LutBanks, Mvd1024eLuts};
use rayon::prelude::*;

/// One band: rows `first_row..first_row + geometry.height()` of the frame.
struct Band {
    first_row: usize,
    geometry: Geometry,
    banks: Box<LutBanks<4, 4096>>,
    sums: Vec<u32>,
}

/// The frame in bands (see the module documentation).
pub struct Bands {
    geometry: Geometry,
    bands: Vec<Band>,
}

/// What a run of frames did, summed over the bands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BandsReport {
    /// Codes above the top code.
    pub out_of_range_codes: u64,
    /// Additions that clipped.
    pub saturated_additions: u64,
}

impl Bands {
    /// `count` bands (at least 1, at most one per row) of nearly equal height over
    /// `geometry`, each with `luts`.
    pub fn new(luts: &Mvd1024eLuts, geometry: Geometry, count: usize) -> Result<Self, CoreError> {
        let height = geometry.height() as usize;
        let count = count.clamp(1, height);
        let mut bands = Vec::with_capacity(count);
        for b in 0..count {
            let (first_row, end) = (b * height / count, (b + 1) * height / count);
            let g = Geometry::new(geometry.width(), (end - first_row) as u16, geometry.states(), geometry.first_column())?;
            bands.push(Band { first_row, geometry: g, banks: Box::new(LutBanks::new(luts.clone())), sums: vec![0; g.sum_len()] });
        }
        Ok(Bands { geometry, bands })
    }

    /// Bands.
    pub fn count(&self) -> usize {
        self.bands.len()
    }

    /// Clears the sums and adds `frames` (state, codes of the whole frame, row-major),
    /// each band on its own thread; the first error any band meets is returned.
    pub fn run(&mut self, frames: &[(u8, &[u16])]) -> Result<BandsReport, CoreError> {
        let width = self.geometry.width() as usize;
        let pixels = self.geometry.pixels();
        if let Some(&(_, bad)) = frames.iter().find(|(_, codes)| codes.len() != pixels) {
            return Err(CoreError::Length { what: dncal_core::error::Quantity::BlockPixels, expected: pixels as u32, got: bad.len() as u32 });
        }
        let reports: Vec<Result<BandsReport, CoreError>> = self
            .bands
            .par_iter_mut()
            .map(|band| {
                let rows = band.geometry.height() as usize;
                let span = band.first_row * width..(band.first_row + rows) * width;
                let mut c = Corrector::new(&mut band.banks, band.geometry, &mut band.sums)?;
                let mut r = BandsReport::default();
                for &(state, codes) in frames {
                    c.begin_frame(state)?;
                    let line = c.accumulate_lines(0, &codes[span.clone()])?;
                    c.end_frame()?;
                    r.out_of_range_codes += line.out_of_range_codes as u64;
                    r.saturated_additions += line.saturated_additions as u64;
                }
                Ok(r)
            })
            .collect();
        let mut total = BandsReport::default();
        for r in reports {
            let r = r?;
            total.out_of_range_codes += r.out_of_range_codes;
            total.saturated_additions += r.saturated_additions;
        }
        Ok(total)
    }

    /// The whole frame's sums, state-major as [`dncal_core::SumImages`] lays them out.
    pub fn sums(&self) -> Vec<u32> {
        let width = self.geometry.width() as usize;
        let height = self.geometry.height() as usize;
        let mut out = vec![0u32; self.geometry.sum_len()];
        for band in &self.bands {
            let rows = band.geometry.height() as usize;
            for s in 0..self.geometry.states() as usize {
                let from = &band.sums[s * rows * width..(s + 1) * rows * width];
                let at = (s * height + band.first_row) * width;
                out[at..at + rows * width].copy_from_slice(from);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dncal_core::LutSet;

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
        let oor = c.status().out_of_range_codes as u64;
        assert!(oor > 0);
        let input: Vec<(u8, &[u16])> = frames.iter().enumerate().map(|(f, c)| ((f % 2) as u8, c.as_slice())).collect();
        for count in [1, 2, 3, 7] {
            let mut bands = Bands::new(&luts, g, count).unwrap();
            assert_eq!(bands.count(), count);
            let r = bands.run(&input).unwrap();
            assert_eq!(r.out_of_range_codes, oor, "{count} bands");
            assert!(bands.sums() == want, "{count} bands");
        }
        // A frame of the wrong size is refused before any band runs.
        let mut bands = Bands::new(&luts, g, 2).unwrap();
        assert!(matches!(bands.run(&[(0, &frames[0][1..])]), Err(CoreError::Length { .. })));
    }
}
