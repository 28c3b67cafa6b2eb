//! A colour camera's channels, each characterized on its own pixels.
//!
//! EMVA 1288 takes a colour camera's channels apart: each is the image of its own
//! pixels (a Bayer filter's red pixels, rows and columns of one parity), measured as a
//! monochrome camera is. Where the averaged response has a pattern periodic in rows and
//! columns ([`CellPattern`]), every cell of it gets the whole set's temporal datasheet
//! (gain, quantum efficiency, dark noise, saturation, from its own photon transfer) and
//! its DSNU and PRNU from its own sub-image. The whole set's PRNU mixes the channels: a
//! Bayer filter's cells at 1.23 / 0.99 / 0.55 / 1.23 of their mean make it about 26%,
//! where each channel's own is the sensor's 1%.
//!
//! Release 4.0 high-pass filters each channel's image as the whole one's, so a channel
//! needs 20 x 20 pixels of its own (a 2 x 2 filter: 40 x 40 of the sensor's).

use std::collections::BTreeMap;

use serde::Serialize;

use super::cells::CellPattern;
use super::datasheet::{PtcSummary, Release};
use super::highpass;
use super::spatial::{Nonuniformity, SpatialSeries, NONUNIFORMITY_KEYS};
use super::temporal::photon_transfer_cells;
use super::EmvaSet;
use crate::HostError;

/// One cell of the pattern (a colour channel) characterized on its own pixels.
#[derive(Debug, Clone, Serialize)]
pub struct Channel {
    /// The cell's row within the period.
    pub row: usize,
    /// The cell's column within the period.
    pub column: usize,
    /// Its response over the cells' mean, as the pattern found it.
    pub response: f64,
    /// Pixels of the channel's image.
    pub pixels: usize,
    /// Its temporal datasheet, keys as the whole set's (`gain_dn_per_e`,
    /// `quantum_efficiency`, ..., `why`); absent where its photon transfer cannot be
    /// summarized (`refused` says why).
    #[serde(flatten)]
    pub temporal: Option<PtcSummary>,
    /// Why the channel has no temporal datasheet.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refused: Option<String>,
    /// Its DSNU and PRNU, of its own sub-image.
    #[serde(flatten)]
    pub nonuniformity: Nonuniformity,
}

/// The channels in a line: each cell's gain, quantum efficiency and PRNU within it (`-`
/// where its datasheet has none).
pub fn describe(channels: &[Channel]) -> String {
    let or_dash = |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    let each: Vec<String> = channels
        .iter()
        .map(|c| {
            let t = c.temporal.as_ref();
            format!(
                "({}, {}) K {} DN/e-, QE {} %, PRNU {} %",
                c.row,
                c.column,
                or_dash(t.map(|t| t.gain_dn_per_e), 4),
                or_dash(t.map(|t| 100.0 * t.quantum_efficiency), 1),
                or_dash(c.nonuniformity.prnu_pct, 3)
            )
        })
        .collect();
    each.join("; ")
}

/// Each cell of `cells` characterized on its own pixels: its photon transfer from the
/// set's temporal series (decoded once for all the cells), its DSNU and PRNU from the
/// `bright` and `dark` spatial series' sub-images, with `release`'s definitions.
pub fn channels(set: &EmvaSet, bright: &SpatialSeries, dark: &SpatialSeries, cells: &CellPattern, release: Release) -> Result<Vec<Channel>, HostError> {
    let p = cells.period;
    let curves = photon_transfer_cells(set, p)?;
    Ok(curves
        .into_iter()
        .enumerate()
        .map(|(i, points)| {
            let (row, column) = (i / p, i % p);
            let (mut temporal, refused) = match super::summarize(&set.path, &points, release) {
                Ok(t) => (Some(t), None),
                Err(e) => (None, Some(e.to_string())),
            };
            let k = temporal.as_ref().map_or(f64::NAN, |t| t.gain_dn_per_e);
            let mut spare = BTreeMap::new();
            let why = temporal.as_mut().map_or(&mut spare, |t| &mut t.why);
            let (b, d) = (bright.cell(row, column, p), dark.cell(row, column, p));
            let pixels = b.as_ref().map_or(0, |b| b.rows * b.cols);
            let nonuniformity = match (b, d) {
                (Some(b), Some(d)) if release == Release::R3 || highpass::fits(b.rows, b.cols) => Nonuniformity::of(why, &b.components(release), &d.components(release), k),
                (b, _) => {
                    let (rows, cols) = b.map_or((0, 0), |b| (b.rows, b.cols));
                    for key in NONUNIFORMITY_KEYS {
                        why.insert(key.into(), highpass::too_small(rows, cols));
                    }
                    Nonuniformity::default()
                }
            };
            Channel { row, column, response: cells.response[i], pixels, temporal, refused, nonuniformity }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sub-image is the cell's pixels in their order: on a 5 x 5 image of values
    /// `10 row + column`, the cell (1, 0) of period 2 is rows 1, 3 and columns 0, 2, 4.
    #[test]
    fn a_cells_sub_image_holds_its_pixels() {
        let sum: Vec<i64> = (0..25).map(|i| 10 * (i / 5) + i % 5).collect();
        let s = SpatialSeries { frames: 1, rows: 5, cols: 5, photons: 0.0, exposure: 1.0, line: 1, sum_sq: sum.iter().map(|v| v * v).collect(), sum };
        let c = s.cell(1, 0, 2).unwrap();
        assert_eq!((c.rows, c.cols), (2, 3));
        assert_eq!(c.sum, vec![10, 12, 14, 30, 32, 34]);
        assert_eq!(c.sum_sq, vec![100, 144, 196, 900, 1024, 1156]);
        let c = s.cell(0, 0, 2).unwrap();
        assert_eq!((c.rows, c.cols, c.sum[8]), (3, 3, 44));
        assert!(s.cell(5, 0, 2).is_none());
        // (Period 1 is the whole image.)
        assert_eq!(s.cell(0, 0, 1).unwrap().sum, s.sum);
    }
}
