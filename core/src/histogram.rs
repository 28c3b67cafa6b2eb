//! Per-ADC code histograms over a region of interest: the acquisition side of the
//! calibration of DN error (de Wijn 2018, section 4: histograms "for each of the ADCs in
//! an area near the center of the sensor", summed over illumination ramps). The host
//! flattens them into per-code weights and builds the LUTs.

use crate::accumulate::or_of;
use crate::adc::{count_above_top, AdcMap, Code};
use crate::{CoreError, Geometry};

/// A rectangle of sensor lines and columns, half-open: `rows.0 <= row < rows.1`,
/// `columns.0 <= column < columns.1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Roi {
    rows: (u16, u16),
    columns: (u16, u16),
}

impl Roi {
    /// A ROI, non-empty and inside `geometry` (columns are sensor columns, so they lie in
    /// `first_column..first_column + width`).
    pub fn new(rows: (u16, u16), columns: (u16, u16), geometry: Geometry) -> Result<Self, CoreError> {
        let first = geometry.first_column() as u32;
        let ok = rows.0 < rows.1
            && rows.1 <= geometry.height()
            && columns.0 < columns.1
            && columns.0 as u32 >= first
            && columns.1 as u32 <= first + geometry.width() as u32;
        if ok {
            Ok(Roi { rows, columns })
        } else {
            Err(CoreError::Roi)
        }
    }
    /// Pixels in the ROI.
    pub fn pixels(&self) -> u32 {
        (self.rows.1 - self.rows.0) as u32 * (self.columns.1 - self.columns.0) as u32
    }
}

/// Code counts per ADC, saturating at `u32::MAX`.
#[derive(Clone, PartialEq, Eq)]
pub struct HistogramSet<const N: usize, const CODES: usize> {
    counts: [[u32; CODES]; N],
    out_of_range: u32,
}

impl<const N: usize, const CODES: usize> Default for HistogramSet<N, CODES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const CODES: usize> HistogramSet<N, CODES> {
    /// Empty histograms.
    pub fn new() -> Self {
        let () = crate::adc::CodeCount::<CODES>::VALID;
        HistogramSet { counts: [[0; CODES]; N], out_of_range: 0 }
    }

    /// Counts the codes of line `row` that fall in `roi`; the line's first pixel is
    /// sensor column `first_column`. Codes above the top code count as the top code and
    /// in [`out_of_range`](Self::out_of_range). Returns the pixels counted.
    ///
    /// Written like the correction's loop (`accumulate`): the span's OR says whether
    /// every code is in range, so a camera's line takes the code masked to `CODES - 1`
    /// (no clamp, no bounds check, no count a pixel), and the span is walked as a head,
    /// whole groups of N columns in ADC order (no column arithmetic a pixel) and a tail.
    /// On the Cortex-M4 that took the pass from 15.8 instructions a pixel (20 once the
    /// firmware stopped unrolling loops of unknown count) to 8.6 (docs/firmware.md).
    pub fn capture_line(&mut self, roi: &Roi, row: u16, first_column: u16, codes: &[u16]) -> u32 {
        if row < roi.rows.0 || row >= roi.rows.1 {
            return 0;
        }
        let first = first_column as u32;
        let start = (roi.columns.0 as u32).saturating_sub(first) as usize;
        let end = ((roi.columns.1 as u32).saturating_sub(first) as usize).min(codes.len());
        let Some(span) = codes.get(start..end) else { return 0 };
        let first = first + start as u32;
        let top = Code::<CODES>::MAX.index();
        if (or_of(span) as usize) <= top {
            self.count_indexed(first, span, |raw| raw as usize & top);
        } else {
            self.count_indexed(first, span, |raw| Code::<CODES>::clamped(raw).0.index());
            self.out_of_range = self.out_of_range.saturating_add(count_above_top::<CODES>(span));
        }
        span.len() as u32
    }

    /// Adds one to `counts[adc][index(raw)]` for each code of `span`, whose first pixel
    /// is sensor column `first_column`; `index` gives a value below `CODES`.
    #[inline(always)]
    fn count_indexed(&mut self, first_column: u32, span: &[u16], index: impl Fn(u16) -> usize) {
        let bump = |table: &mut [u32; CODES], raw: u16| {
            if let Some(c) = table.get_mut(index(raw)) {
                *c = c.saturating_add(1);
            }
        };
        let head = AdcMap::<N>::head(first_column, span.len());
        let (head, body) = span.split_at(head);
        for (i, &raw) in head.iter().enumerate() {
            if let Some(table) = self.counts.get_mut(AdcMap::<N>::adc(first_column + i as u32)) {
                bump(table, raw);
            }
        }
        let mut groups = body.chunks_exact(N);
        for group in &mut groups {
            for (table, &raw) in self.counts.iter_mut().zip(group) {
                bump(table, raw);
            }
        }
        for (table, &raw) in self.counts.iter_mut().zip(groups.remainder()) {
            bump(table, raw);
        }
    }

    /// The counts of ADC `adc`.
    pub fn counts(&self, adc: usize) -> Option<&[u32; CODES]> {
        self.counts.get(adc)
    }

    /// Codes seen above the top code.
    pub fn out_of_range(&self) -> u32 {
        self.out_of_range
    }

    /// Zeroes every count.
    pub fn clear(&mut self) {
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_by_column_mod_n_inside_the_roi() {
        let g = Geometry::new(8, 4, 1, 10).unwrap();
        let roi = Roi::new((1, 3), (11, 15), g).unwrap();
        assert_eq!(roi.pixels(), 8);
        let mut h = HistogramSet::<4, 16>::new();
        let line = [0, 1, 2, 3, 4, 5, 99, 7];
        assert_eq!(h.capture_line(&roi, 0, 10, &line), 0);
        assert_eq!(h.capture_line(&roi, 1, 10, &line), 4);
        // Sensor columns 11..15 hold codes 1, 2, 3, 4 and go to ADCs 3, 0, 1, 2.
        assert_eq!(h.counts(3).unwrap()[1], 1);
        assert_eq!(h.counts(0).unwrap()[2], 1);
        assert_eq!(h.counts(1).unwrap()[3], 1);
        assert_eq!(h.counts(2).unwrap()[4], 1);
        let roi_all = Roi::new((0, 4), (10, 18), g).unwrap();
        h.capture_line(&roi_all, 2, 10, &line);
        assert_eq!(h.out_of_range(), 1);
        assert_eq!(h.counts(0).unwrap()[15], 1);
        assert!(Roi::new((0, 5), (10, 18), g).is_err());
        assert!(Roi::new((0, 4), (9, 18), g).is_err());
        assert!(Roi::new((2, 2), (10, 18), g).is_err());
    }

    /// Out-of-range codes are counted one by one, and clearing forgets counts and them.
    #[test]
    fn clearing_forgets_counts_and_out_of_range_codes() {
        let g = Geometry::new(4, 1, 1, 0).unwrap();
        let roi = Roi::new((0, 1), (0, 4), g).unwrap();
        let mut h = HistogramSet::<4, 16>::new();
        h.capture_line(&roi, 0, 0, &[16, 17, 3, 99]);
        assert_eq!(h.out_of_range(), 3);
        assert_eq!(h.counts(2).unwrap()[3], 1);
        h.clear();
        assert_eq!(h.out_of_range(), 0);
        assert!((0..4).all(|a| h.counts(a).unwrap().iter().all(|&n| n == 0)));
    }
}
