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
//! [`EXPLAINED`] and [`CELL_SES`] standard errors (four ADCs' column gains read at
//! period 2 leave their own period's 1%). Only periods the image holds [`MIN_PERIODS`]
//! of both ways are looked for, the longest of them standing for 12. The tables are taken of the response over its quadratic surface, so
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

/// A period is looked for only where the image holds this many of it both ways: on 13
/// rows a quadratic surface took part of a 2 x 2 pattern and the pattern came out at
/// period 12 (an independent review's port), where most pixels have too few of their
/// own cell's neighbours for a window (at least 3 x 3 of them at 8 periods).
const MIN_PERIODS: usize = 8;

/// A shorter period explains the pattern where the cells of the longest, divided by it,
/// are off by no more than this share (and [`CELL_SES`] standard errors): a Bayer pattern
/// beside 0.3-0.5% column noise drifted to periods 4-12 without it.
const EXPLAINED: f64 = 0.005;

/// A cell responding less than this share of the mean is dead columns or rows (every
/// fourth column dead gave cells of 0 and pixels neither dead nor high-PRNU), not a
/// colour channel (a blue channel under tungsten light is about 0.3).
const MIN_CELL_RESPONSE: f64 = 0.1;

/// A response pattern of period `period` in rows and columns.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellPattern {
    /// Pixels a period, rows and columns.
    pub period: usize,
    /// Per cell `(row mod period) * period + column mod period`: its median response over
    /// the mean of the cells' medians.
    pub response: Vec<f64>,
    /// Per cell, the standard error of its response (relative to the cells' mean).
    pub se: Vec<f64>,
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
        let rows = response.len() / cols.max(1);
        // The periods the image holds [`MIN_PERIODS`] of, both ways; the longest of them
        // holds the others.
        let periods: Vec<usize> = PERIODS.iter().copied().filter(|&p| rows >= MIN_PERIODS * p && cols >= MIN_PERIODS * p).collect();
        let longest = *periods.last()?;
        let response = &flattened(response, cols)?;
        let whole = table(response, cols, longest)?;
        if !departs(&whole, MIN_DEPARTURE) {
            return None;
        }
        let found = periods.iter().find_map(|&p| {
            let t = table(response, cols, p)?;
            let pattern = CellPattern { period: p, response: t.iter().map(|c| c.0).collect(), se: t.iter().map(|c| c.1).collect() };
            let flat: Vec<f64> = response.iter().enumerate().map(|(i, v)| v / pattern.at(i / cols, i % cols)).collect();
            (p == longest || table(&flat, cols, longest).is_some_and(|rest| !departs(&rest, EXPLAINED))).then_some(pattern)
        })?;
        // (A cell that hardly responds is dead columns or rows, not a channel: they are
        // the defect test's.)
        found.response.iter().all(|&r| r > MIN_CELL_RESPONSE).then_some(found)
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
/// ratio's standard error: the largest of the pixels' (`1.2533 sigma / sqrt(n)`, `sigma`
/// the cell's robust scatter) and the same of the medians of its columns and of its rows
/// (the pixels of a column share its fixed pattern: 5% column noise averaged over 13
/// columns a cell passed for a pattern in 84% of monochrome images with the pixels' alone),
/// the lines' scatter pooled over the cells;
/// `None` where a cell has fewer than [`MIN_CELL_PIXELS`] finite values or the mean is
/// not positive.
fn table(response: &[f64], cols: usize, p: usize) -> Option<Vec<(f64, f64)>> {
    let rows = response.len() / cols.max(1);
    let mut cells: Vec<Vec<f64>> = vec![Vec::new(); p * p];
    for (i, &v) in response.iter().enumerate().filter(|(_, v)| v.is_finite()) {
        cells[((i / cols) % p) * p + (i % cols) % p].push(v);
    }
    if cells.iter().any(|c| c.len() < MIN_CELL_PIXELS) {
        return None;
    }
    let se = |v: &[f64]| 1.2533 * robust(v).1 / (v.len() as f64).sqrt();
    // The medians of the lines of cell (`row mod p`, `column mod p`) = (a, b): its
    // columns (`by_column`) or its rows.
    let lines = |a: usize, b: usize, by_column: bool| -> Vec<f64> {
        let (n, m, first, across) = if by_column { (cols, rows, b, a) } else { (rows, cols, a, b) };
        (first..n)
            .step_by(p)
            .filter_map(|k| {
                let v: Vec<f64> = (across..m).step_by(p).map(|j| if by_column { response[j * cols + k] } else { response[k * cols + j] }).filter(|v| v.is_finite()).collect();
                (!v.is_empty()).then(|| robust(&v).0)
            })
            .collect()
    };
    // The lines' scatter about their cell's median, pooled over the cells (a cell's own
    // 13 lines gave a spread 5 times too small now and then, and one cell in 144 passed).
    let centres: Vec<f64> = cells.iter().map(|c| robust(c).0).collect();
    let lined: Vec<[Vec<f64>; 2]> = (0..p * p).map(|k| [lines(k / p, k % p, true), lines(k / p, k % p, false)]).collect();
    let pooled = |side: usize| {
        let d: Vec<f64> = lined.iter().zip(&centres).flat_map(|(l, c)| l[side].iter().map(move |v| v - c)).collect();
        if d.len() >= 3 { robust(&d).1 } else { 0.0 }
    };
    let (col_sigma, row_sigma) = (pooled(0), pooled(1));
    let stats: Vec<(f64, f64)> = cells
        .iter()
        .zip(&centres)
        .zip(&lined)
        .map(|((c, &centre), l)| {
            let line_se = |sigma: f64, n: usize| if n > 0 { 1.2533 * sigma / (n as f64).sqrt() } else { 0.0 };
            (centre, se(c).max(line_se(col_sigma, l[0].len())).max(line_se(row_sigma, l[1].len())))
        })
        .collect();
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
    /// one, one whose cells differ by 1%, one with every fourth column dead, a 2 x 2
    /// pattern on 13 rows and five draws of 5% column noise have none.
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
        // Every fourth column dead is the defect test's; so is a 2 x 2 pattern on 13 rows
        // (too few periods); 5% column noise is not a pattern.
        let dead: Vec<f64> = base.iter().enumerate().map(|(i, b)| if i % 4 == 0 { 0.0 } else { *b }).collect();
        assert_eq!(CellPattern::find(&dead, cols), None);
        let short: Vec<f64> = base[..13 * cols].iter().enumerate().map(|(i, b)| b * bayer[((i / cols) % 2) * 2 + (i % cols) % 2]).collect();
        assert_eq!(CellPattern::find(&short, cols), None);
        let column = Normal::new(1.0, 0.05).unwrap();
        for _ in 0..5 {
            let gains: Vec<f64> = (0..cols).map(|_| column.sample(&mut rng)).collect();
            let fpn: Vec<f64> = base.iter().enumerate().map(|(i, b)| b * gains[i % cols]).collect();
            assert_eq!(CellPattern::find(&fpn, cols), None);
        }
        let small: Vec<f64> = base.iter().enumerate().map(|(i, b)| b * if (i / cols) % 2 == 0 && i % 2 == 0 { 1.01 } else { 1.0 }).collect();
        assert_eq!(CellPattern::find(&small, cols), None);
    }
}
