//! A response pattern periodic in rows and columns in the averaged bright-minus-dark
//! image: a colour filter's channels (a Bayer filter's 2 x 2 cells, one at 0.55 of the
//! mean and two at 1.23 on issue 58's consumer camera), or interleaved column ADCs whose
//! gains differ. The defect test compares each pixel with its own cell's neighbours and
//! scales its departure by its cell's response: against a neighbourhood of all cells, a
//! simulated colour set's whole red channel (4,716 of 19,200 pixels) was high-PRNU and
//! 147 of its pixels dead, where 10 hot and 8 dead pixels were planted.
//!
//! The pattern is looked for at period 12 (which holds periods 2, 3, 4 and 6): a cell
//! whose median response is off the cells' mean by more than [`MIN_DEPARTURE`] and
//! [`CELL_SES`] of its standard errors is a pattern. Its period is then the smallest of
//! [`PERIODS`] whose cells, divided out, leave no cell at period 12 off by more than
//! [`CELL_SES`] standard errors (four ADCs' column gains read at period 2 leave their
//! own period's 1%). The tables are taken of the response over its quadratic surface, so
//! that a smooth illumination is not one.

use serde::Serialize;

use crate::infra::stats::robust;

/// Periods tried, rows and columns alike: Bayer (2), an X-Trans filter's 3 x 3 halves
/// (3) and whole (6), quad-Bayer or four interleaved ADCs (4), and all of them (12).
const PERIODS: [usize; 5] = [2, 3, 4, 6, 12];

/// A cell departs only by more than this share of the cells' mean response: 1% PRNU on
/// a 160 x 120 sensor gives cells of period 12 a standard error of 0.11%.
const MIN_DEPARTURE: f64 = 0.02;

/// ... and more than this many of its standard errors.
const CELL_SES: f64 = 5.0;

/// The fewest pixels a cell's median is taken over.
const MIN_CELL_PIXELS: usize = 9;

/// A response pattern of period `period` in rows and columns.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellPattern {
    /// Pixels a period, rows and columns.
    pub period: usize,
    /// Per cell `(row mod period) * period + column mod period`: its median response over
    /// the mean of the cells' medians.
    pub response: Vec<f64>,
}

impl CellPattern {
    /// The relative response of the cell of the pixel at `row`, `column`.
    pub fn at(&self, row: usize, column: usize) -> f64 {
        self.response[(row % self.period) * self.period + column % self.period]
    }

    /// The pattern in words: its period and each cell's response.
    pub fn describe(&self) -> String {
        let cells: Vec<String> = self.response.iter().map(|r| format!("{r:.3}")).collect();
        format!("a {p} x {p} response pattern (cells {} of their mean, row-major: a colour filter's channels or interleaved column ADCs)", cells.join(" "), p = self.period)
    }

    /// Finds the pattern of `response` (row-major, `cols` columns; values that are not
    /// finite left out), where there is one (module documentation).
    pub fn find(response: &[f64], cols: usize) -> Option<CellPattern> {
        let response = &flattened(response, cols)?;
        let whole = table(response, cols, 12)?;
        if !departs(&whole, MIN_DEPARTURE) {
            return None;
        }
        PERIODS.iter().find_map(|&p| {
            let t = table(response, cols, p)?;
            let cells: Vec<f64> = t.iter().map(|c| c.0).collect();
            let pattern = CellPattern { period: p, response: cells };
            let flat: Vec<f64> = response.iter().enumerate().map(|(i, v)| v / pattern.at(i / cols, i % cols)).collect();
            (p == 12 || table(&flat, cols, 12).is_some_and(|rest| !departs(&rest, 0.0))).then_some(pattern)
        })
    }
}

/// `response` over its least-squares quadratic surface in the row and column: a smooth
/// illumination or vignetting taken out, which falls on the cells of a long period
/// unevenly (a 20% gradient across 160 columns is 1.4% across 12 of them, as much as a
/// pattern); the pattern itself, spread evenly over the image, is not fitted. `None`
/// where the surface cannot be fitted.
fn flattened(response: &[f64], cols: usize) -> Option<Vec<f64>> {
    let rows = response.len() / cols.max(1);
    let unit = |k: usize, n: usize| if n > 1 { 2.0 * k as f64 / (n - 1) as f64 - 1.0 } else { 0.0 };
    let basis = |i: usize| {
        let (y, x) = (unit(i / cols, rows), unit(i % cols, cols));
        nalgebra::SVector::<f64, 6>::from([1.0, x, y, x * x, x * y, y * y])
    };
    let (mut a, mut b) = (nalgebra::SMatrix::<f64, 6, 6>::zeros(), nalgebra::SVector::<f64, 6>::zeros());
    for (i, &v) in response.iter().enumerate().filter(|(_, v)| v.is_finite()) {
        let f = basis(i);
        a += f * f.transpose();
        b += f * v;
    }
    let c = a.try_inverse()? * b;
    Some(response.iter().enumerate().map(|(i, &v)| {
        let s = c.dot(&basis(i));
        if s > 0.0 { v / s } else { f64::NAN }
    }).collect())
}

/// Per cell of period `p`: its median over the mean of the cells' medians and that
/// ratio's standard error (`1.2533 sigma / sqrt(n)`, `sigma` the cell's robust scatter);
/// `None` where a cell has fewer than [`MIN_CELL_PIXELS`] finite values or the mean is
/// not positive.
fn table(response: &[f64], cols: usize, p: usize) -> Option<Vec<(f64, f64)>> {
    let mut cells: Vec<Vec<f64>> = vec![Vec::new(); p * p];
    for (i, &v) in response.iter().enumerate().filter(|(_, v)| v.is_finite()) {
        cells[((i / cols) % p) * p + (i % cols) % p].push(v);
    }
    if cells.iter().any(|c| c.len() < MIN_CELL_PIXELS) {
        return None;
    }
    let stats: Vec<(f64, f64)> = cells.iter().map(|c| {
        let (centre, sigma) = robust(c);
        (centre, 1.2533 * sigma / (c.len() as f64).sqrt())
    }).collect();
    let mean = stats.iter().map(|s| s.0).sum::<f64>() / stats.len() as f64;
    (mean > 0.0).then(|| stats.iter().map(|&(c, se)| (c / mean, se / mean)).collect())
}

/// Whether a cell of the table departs from the cells' mean by more than `floor` and
/// [`CELL_SES`] standard errors.
fn departs(table: &[(f64, f64)], floor: f64) -> bool {
    table.iter().any(|&(r, se)| (r - 1.0).abs() > floor.max(CELL_SES * se))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A 160 x 120 response with 1% PRNU and a gradient of 20% across: planted 2 x 2
    /// cells, four ADCs' column gains and a 3 x 3 pattern are found at their own periods
    /// with each cell within 0.3% of the planted (relative to the cells' mean); the plain
    /// one, and one whose cells differ by 1%, have none.
    #[test]
    fn planted_patterns_are_found_at_their_periods() {
        let (rows, cols) = (120, 160);
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        let prnu = Normal::new(1.0, 0.01).unwrap();
        let base: Vec<f64> = (0..rows * cols).map(|i| 1000.0 * (1.0 + 0.2 * (i % cols) as f64 / cols as f64) * prnu.sample(&mut rng)).collect();
        let bayer = [1.23, 0.99, 0.55, 1.23];
        let adcs: Vec<f64> = (0..16).map(|k| [1.0, 1.03, 0.98, 1.0][k % 4]).collect();
        let xtrans = [1.1, 0.9, 1.0, 0.9, 1.1, 1.0, 1.0, 1.0, 1.0];
        for (p, planted) in [(2, &bayer[..]), (4, &adcs[..]), (3, &xtrans[..])] {
            let v: Vec<f64> = base.iter().enumerate().map(|(i, b)| b * planted[((i / cols) % p) * p + (i % cols) % p]).collect();
            let found = CellPattern::find(&v, cols).unwrap_or_else(|| panic!("{planted:?}: no pattern"));
            assert_eq!(found.period, p, "{planted:?}: {found:?}");
            let mean = planted.iter().sum::<f64>() / planted.len() as f64;
            for (got, want) in found.response.iter().zip(planted) {
                assert!((got - want / mean).abs() < 0.003, "{planted:?}: {found:?}");
            }
        }
        assert_eq!(CellPattern::find(&base, cols), None);
        let small: Vec<f64> = base.iter().enumerate().map(|(i, b)| b * if (i / cols) % 2 == 0 && i % 2 == 0 { 1.01 } else { 1.0 }).collect();
        assert_eq!(CellPattern::find(&small, cols), None);
    }
}
