//! One model's held-out scores over the pixels of a linearity set, compact: per pixel what
//! the catalogue's tests read back one pixel at a time (the paired tests, the dispersion
//! over pixels, the departure at the highest held-out level), and per ADC and half of the
//! rows the sums the rest reads ([`Totals`], the RMS by level of the figures). Every
//! selection the catalogue scores is a union of those cells. Each model held every
//! pixel's residuals before (about 300 bytes per pixel and model, six models at once).
//! The per-pixel scores are [`Records`]: held, or spilled where the budget says.

use super::pixel_fit::{Scored, Totals};
use super::records::{Keep, Put, Record, Records, Take};

/// A pixel's held-out score under one model.
#[derive(Debug, Clone, Copy)]
pub(super) struct Score {
    /// Sum of the held-out `z^2`.
    pub sum_sq: f64,
    /// `tr C`, `tr C^2` of the held-out residuals' null covariance ([`Scored`]).
    pub tr: f32,
    pub tr2: f32,
    /// `z` at the pixel's highest held-out level.
    pub last_z: f32,
    /// Held-out residuals.
    pub n: u16,
}

impl Score {
    /// No score (a pixel its model could not fit): `n` past any count of held-out levels
    /// (levels are at most `u16::MAX`, half of them held out). A marker rather than an
    /// `Option`: 24 bytes a pixel and model instead of 32, and up to five models are held
    /// at once.
    const NONE: Score = Score { sum_sq: f64::NAN, tr: f32::NAN, tr2: f32::NAN, last_z: f32::NAN, n: u16::MAX };

    /// The score, unless it is [`Score::NONE`].
    fn scored(self) -> Option<Score> {
        Some(self).filter(|s| s.n != Score::NONE.n)
    }

    fn of(s: &Scored) -> Score {
        Score { sum_sq: s.sum_sq(), tr: s.tr as f32, tr2: s.tr2 as f32, last_z: s.z.last().map_or(f32::NAN, |z| z.z() as f32), n: s.z.len() as u16 }
    }

    pub fn totals(&self) -> Totals {
        Totals { s: self.sum_sq, e: f64::from(self.tr), v: 2.0 * f64::from(self.tr2), n: usize::from(self.n) }
    }
}

impl Record for Score {
    const BYTES: usize = 22;
    const LOST: Score = Score::NONE;
    fn put(&self, out: &mut Put<'_>) {
        out.f64(self.sum_sq);
        out.f32(self.tr);
        out.f32(self.tr2);
        out.f32(self.last_z);
        out.u16(self.n);
    }
    fn take(from: &mut Take<'_>) -> Self {
        Score { sum_sq: from.f64(), tr: from.f32(), tr2: from.f32(), last_z: from.f32(), n: from.u16() }
    }
}

/// Where a pixel's score is summed: its ADC, and whether it lies on an odd row (those
/// score what the even rows estimate).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Cell {
    pub adc: usize,
    pub odd: bool,
}

/// The sums of one cell.
#[derive(Debug, Clone, Default)]
struct Sums {
    totals: Totals,
    /// Per level, the sum of `z^2` and the count.
    by_level: Vec<(f64, usize)>,
}

impl Sums {
    fn new(levels: usize) -> Self {
        Sums { totals: Totals::default(), by_level: vec![(0.0, 0); levels] }
    }

    fn add(&mut self, o: &Sums) {
        self.totals = self.totals.plus(&o.totals);
        self.by_level.iter_mut().zip(&o.by_level).for_each(|(a, b)| (a.0, a.1) = (a.0 + b.0, a.1 + b.1));
    }
}

/// One model's scores: per pixel (by the caller's index) and per [`Cell`].
#[derive(Debug)]
pub(super) struct Scores {
    /// Per pixel, its score or [`Score::NONE`].
    per: Records<Score>,
    cells: Vec<Sums>,
}


impl Scores {
    /// Scores of `n` pixels: `score(j)` fits pixel `j` and scores it, `cell(j)` says where
    /// it is summed; levels below `levels`, ADCs below `n_adc`.
    pub fn collect(keep: &Keep, n: usize, n_adc: usize, levels: usize, cell: &(dyn Fn(usize) -> Cell + Sync), score: &(dyn Fn(usize) -> Option<Scored> + Sync)) -> Scores {
        let n_adc = n_adc.max(1);
        let empty = || vec![Sums::new(levels); 2 * n_adc];
        // A fixed number of tasks, each with its own sums (one set per task, not per few
        // pixels: they are 2 x ADCs x levels), added in task order: the same sums
        // whichever thread did which task, on any machine ([`super::TASKS`]).
        let (per, parts) = Records::build(keep, n, empty, |j, sums| {
            let Some(s) = score(j) else { return Score::NONE };
            let into = &mut sums[Self::key(cell(j), n_adc)];
            into.totals = into.totals.plus(&Score::of(&s).totals());
            for z in &s.z {
                if let Some(b) = into.by_level.get_mut(z.level()) {
                    b.0 += z.z() * z.z();
                    b.1 += 1;
                }
            }
            Score::of(&s)
        });
        let cells = parts.into_iter().fold(empty(), |mut a, b| {
            a.iter_mut().zip(&b).for_each(|(x, y)| x.add(y));
            a
        });
        Scores { per, cells }
    }

    /// The score of pixel `j`, where it has one.
    pub fn get(&self, j: usize) -> Option<Score> {
        self.per.at(j).scored()
    }

    /// Every pixel's score, in the caller's order.
    pub fn iter(&self) -> impl Iterator<Item = Option<Score>> + '_ {
        self.per.iter().map(Score::scored)
    }

    fn key(c: Cell, n_adc: usize) -> usize {
        c.adc.min(n_adc - 1) * 2 + usize::from(c.odd)
    }

    fn cells<'a>(&'a self, sel: &'a dyn Fn(Cell) -> bool) -> impl Iterator<Item = &'a Sums> + 'a {
        self.cells.iter().enumerate().filter(move |(k, _)| sel(Cell { adc: k / 2, odd: k % 2 == 1 })).map(|(_, s)| s)
    }

    /// The sums over the cells `sel`.
    pub fn totals(&self, sel: &dyn Fn(Cell) -> bool) -> Totals {
        self.cells(sel).fold(Totals::default(), |t, s| t.plus(&s.totals))
    }

    /// Per level, the RMS of the held-out `z` over the cells `sel`: the figures.
    pub fn by_level(&self, sel: &dyn Fn(Cell) -> bool) -> Vec<(usize, f64)> {
        let mut acc = Sums::new(self.cells.first().map_or(0, |c| c.by_level.len()));
        self.cells(sel).for_each(|s| acc.add(s));
        acc.by_level.iter().enumerate().filter(|(_, a)| a.1 > 0).map(|(l, a)| (l, (a.0 / a.1 as f64).sqrt())).collect()
    }

    /// Per ADC the scores of `choose(adc)`: pixel `j` read by ADC `adc_of(j)`.
    pub fn per_adc<'a>(choose: &(dyn Fn(usize) -> &'a Scores + Sync), adc_of: &(dyn Fn(usize) -> usize + Sync), n: usize, n_adc: usize) -> Scores {
        let n_adc = n_adc.max(1);
        let per = Records::from_fn(choose(0).per.keep(), n, |j| choose(adc_of(j)).per.at(j));
        let cells = (0..2 * n_adc).map(|k| choose(k / 2).cells.get(k).cloned().unwrap_or_default()).collect();
        Scores { per, cells }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A score spilled and read back is the same, bit for bit, and none stays none.
    #[test]
    fn a_score_reads_back_as_written() {
        let s = Score { sum_sq: 12.5, tr: -0.0, tr2: f32::MIN_POSITIVE, last_z: -2.25, n: 20 };
        let back = super::super::records::round_trip(s);
        assert_eq!((back.sum_sq.to_bits(), back.tr.to_bits(), back.tr2.to_bits(), back.last_z.to_bits(), back.n), (s.sum_sq.to_bits(), s.tr.to_bits(), s.tr2.to_bits(), s.last_z.to_bits(), s.n));
        assert_eq!(super::super::records::round_trip(Score::NONE).n, Score::NONE.n);
    }
}
