//! Exact order statistics of values that are produced, not held: `diagnose` needs medians
//! over millions of pixels per level (the robust centre and spread of each level's
//! residuals) and recomputes each pixel's residuals on demand rather than keep them (4
//! bytes per residual and level was the run's peak). So the values are visited in passes:
//! a radix selection on each value's order-preserving 64-bit key, 8 bits a pass, each
//! pass a histogram per cell of the next digit among the values that share the digits
//! found so far, until the wanted rank's bin holds few enough values to collect and
//! select from (or all 64 bits are fixed: the values are equal). The result is the value
//! a sort would give, whatever the range or the outliers, in at most 8 passes; the memory
//! is a 256-bin histogram per open cell and task, and at most [`COLLECT`] values per cell.

use rayon::prelude::*;

/// Visits the values of item `i`: calls `f(cell, value)` for each (any number per cell).
pub type Visit<'a> = dyn Fn(usize, &mut dyn FnMut(usize, f64)) + Sync + 'a;

/// Bits of the key fixed per pass.
const DIGIT: u32 = 8;
/// A bin with at most this many values is collected and selected from.
const COLLECT: usize = 1 << 14;

/// The order-preserving key of a finite `v`: `a < b` (as `f64::total_cmp`) exactly when
/// `key(a) < key(b)`.
fn key(v: f64) -> u64 {
    let b = v.to_bits();
    if b >> 63 == 1 { !b } else { b | 1 << 63 }
}

/// The value of a key.
fn value(k: u64) -> f64 {
    f64::from_bits(if k >> 63 == 1 { k & !(1 << 63) } else { !k })
}

/// Folds `visit` over items `0..n` in one task per thread, each with its own accumulator
/// from `init`, merged by `merge`.
fn fold_items<A: Send>(n: usize, init: &(dyn Fn() -> A + Sync), step: &(dyn Fn(&mut A, usize, f64) + Sync), merge: &(dyn Fn(&mut A, A) + Sync), visit: &Visit) -> A {
    let t = rayon::current_num_threads().clamp(1, n.max(1));
    (0..t)
        .into_par_iter()
        .map(|k| {
            let mut acc = init();
            for i in (k * n / t)..((k + 1) * n / t) {
                visit(i, &mut |c, v| step(&mut acc, c, v));
            }
            acc
        })
        .reduce_with(|mut a, b| {
            merge(&mut a, b);
            a
        })
        .unwrap_or_else(init)
}

/// Per cell, the `rank(cell, count)`-th smallest (from 0) of its finite values, `count`
/// their number; NaN for a cell without values. Items `0..n` are visited by `visit`,
/// which must give the same values on every pass.
pub fn select(n: usize, cells: usize, rank: &(dyn Fn(usize, usize) -> usize + Sync), visit: &Visit) -> Vec<f64> {
    select_collecting(n, cells, rank, visit, COLLECT).0
}

/// [`select`], collecting a bin of at most `collect` values; also the most values any
/// cell collected.
fn select_collecting(n: usize, cells: usize, rank: &(dyn Fn(usize, usize) -> usize + Sync), visit: &Visit, collect: usize) -> (Vec<f64>, usize) {
    let mut search = Selection::collecting(cells, collect);
    let mut most = 0;
    while !search.done() {
        let counter = search.counter();
        let tally = fold_items(n, &|| counter.tally(), &|t, c, v| counter.add(t, c, v), &|a, b| a.merge(b), visit);
        if let Tally::Values(v) = &tally {
            most = most.max(v.iter().map(Vec::len).max().unwrap_or(0));
        }
        search.advance(tally, rank);
    }
    (search.values(), most)
}

/// Per cell: the key's high `fixed` bits found (`prefix`), the values below them, the
/// rank (known after the first pass's counts), the values sharing the prefix, the count
/// of all.
#[derive(Debug, Clone, Copy)]
struct Search {
    prefix: u64,
    fixed: u32,
    below: usize,
    rank: usize,
    inside: usize,
    count: usize,
    done: Option<f64>,
}

/// A radix selection in progress, driven pass by pass: [`Selection::counter`] says what a
/// pass counts, any number of blocks of the values each [`Counter::add`] theirs to a
/// [`Tally`], the tallies [`Tally::merge`] (in any order: counts and multisets), and
/// [`Selection::advance`] takes the total. The values of one pass may be split over
/// threads, processes or machines; only the counter and the tallies travel.
#[derive(Debug, Clone)]
pub struct Selection {
    cells: Vec<Search>,
    collect: usize,
}

/// What one pass counts in each cell (see [`Counter::add`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Mode {
    /// Nothing: the cell is done, or waits while others narrow.
    Idle,
    /// The histogram of the next digit of the values that share the prefix.
    Histogram,
    /// The values that share the prefix.
    Collect,
}

/// One pass's instructions: per cell the prefix, its bits and the [`Mode`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Counter {
    cells: Vec<(u64, u32, Mode)>,
}

/// One pass's counts: per cell a histogram of `2^DIGIT` bins (empty when the cell counted
/// nothing), or the values collected.
#[derive(Debug, Clone, PartialEq)]
pub enum Tally {
    Histograms(Vec<Vec<u64>>),
    Values(Vec<Vec<f64>>),
}

impl Tally {
    /// Adds `other`'s counts (histograms bin by bin; values appended).
    pub fn merge(&mut self, other: Tally) {
        match (self, other) {
            (Tally::Histograms(a), Tally::Histograms(b)) => a.iter_mut().zip(b).for_each(|(x, y)| {
                if x.is_empty() {
                    *x = y;
                } else if !y.is_empty() {
                    x.iter_mut().zip(y).for_each(|(p, q)| *p += q);
                }
            }),
            (Tally::Values(a), Tally::Values(b)) => a.iter_mut().zip(b).for_each(|(x, mut y)| x.append(&mut y)),
            // Tallies of one pass are of one kind.
            _ => {}
        }
    }
}

/// Bins of a histogram pass.
pub const BINS: usize = 1 << DIGIT;

impl Counter {
    /// An empty tally of this pass.
    pub fn tally(&self) -> Tally {
        let n = self.cells.len();
        if self.cells.iter().any(|c| c.2 == Mode::Histogram) { Tally::Histograms(vec![Vec::new(); n]) } else { Tally::Values(vec![Vec::new(); n]) }
    }

    /// Counts value `v` of `cell` into `t` (non-finite values are left out).
    pub fn add(&self, t: &mut Tally, cell: usize, v: f64) {
        let Some(&(prefix, fixed, mode)) = self.cells.get(cell) else { return };
        if mode == Mode::Idle || !v.is_finite() {
            return;
        }
        let k = key(v);
        if fixed != 0 && k >> (64 - fixed) != prefix >> (64 - fixed) {
            return;
        }
        match t {
            Tally::Histograms(h) => {
                let h = &mut h[cell];
                if h.is_empty() {
                    h.resize(BINS, 0);
                }
                h[((k >> (64 - fixed - DIGIT)) & (BINS as u64 - 1)) as usize] += 1;
            }
            Tally::Values(v_) => v_[cell].push(v),
        }
    }

    /// The counter as integers, three per cell (prefix, bits, mode 0 idle, 1 histogram,
    /// 2 collect): to send to where the values are.
    pub fn to_words(&self) -> Vec<u64> {
        self.cells.iter().flat_map(|&(p, f, m)| [p, u64::from(f), m as u64]).collect()
    }

    /// The counter of [`Counter::to_words`]; `None` for words it cannot have made.
    pub fn from_words(w: &[u64]) -> Option<Counter> {
        if !w.len().is_multiple_of(3) {
            return None;
        }
        let cells = w
            .chunks(3)
            .map(|c| {
                let mode = match c[2] {
                    0 => Mode::Idle,
                    1 => Mode::Histogram,
                    2 => Mode::Collect,
                    _ => return None,
                };
                // Whole digits fixed, and room for the next one where a histogram counts it.
                let fixed = c[1];
                let fits = fixed % u64::from(DIGIT) == 0 && if mode == Mode::Histogram { fixed + u64::from(DIGIT) <= 64 } else { fixed <= 64 };
                fits.then_some((c[0], fixed as u32, mode))
            })
            .collect::<Option<Vec<_>>>()?;
        // One pass counts one way.
        let has = |m: Mode| cells.iter().any(|c| c.2 == m);
        (!(has(Mode::Histogram) && has(Mode::Collect))).then_some(Counter { cells })
    }
}

impl Selection {
    /// A selection in `cells` cells, collecting bins of at most [`COLLECT`] values.
    pub fn new(cells: usize) -> Self {
        Self::collecting(cells, COLLECT)
    }

    fn collecting(cells: usize, collect: usize) -> Self {
        Selection { cells: vec![Search { prefix: 0, fixed: 0, below: 0, rank: 0, inside: usize::MAX, count: 0, done: None }; cells], collect }
    }

    /// Whether a cell still narrows by histograms.
    fn open(&self, s: &Search) -> bool {
        s.done.is_none() && s.inside > self.collect
    }

    /// Whether every cell has its value.
    pub fn done(&self) -> bool {
        self.cells.iter().all(|s| s.done.is_some())
    }

    /// What the next pass counts: histograms while any cell's bin holds more than can be
    /// collected, then the values of the bins.
    pub fn counter(&self) -> Counter {
        let narrowing = self.cells.iter().any(|s| self.open(s));
        let cells = self
            .cells
            .iter()
            .map(|s| {
                let mode = match (s.done, narrowing, self.open(s)) {
                    (Some(_), _, _) => Mode::Idle,
                    (None, true, true) => Mode::Histogram,
                    (None, true, false) => Mode::Idle,
                    (None, false, _) => Mode::Collect,
                };
                (s.prefix, s.fixed, mode)
            })
            .collect();
        Counter { cells }
    }

    /// Takes a pass's total tally: each cell's rank (`rank(cell, count)`, from 0, of its
    /// `count` finite values) narrowed to the next digit, or found among the values
    /// collected.
    pub fn advance(&mut self, tally: Tally, rank: &(dyn Fn(usize, usize) -> usize + Sync)) {
        let collect = self.collect;
        match tally {
            Tally::Histograms(hist) => {
                for (c, (x, h)) in self.cells.iter_mut().zip(hist).enumerate() {
                    if !(x.done.is_none() && x.inside > collect) {
                        continue;
                    }
                    if x.fixed == 0 {
                        let count: usize = h.iter().sum::<u64>() as usize;
                        x.count = count;
                        if count == 0 {
                            x.done = Some(f64::NAN);
                            continue;
                        }
                        x.rank = rank(c, count).min(count - 1);
                    }
                    // The digit holding the rank among the values that share the prefix.
                    let mut want = x.rank - x.below;
                    let mut found = false;
                    for (j, &k) in h.iter().enumerate() {
                        let k = k as usize;
                        if want < k {
                            x.fixed += DIGIT;
                            x.prefix |= (j as u64) << (64 - x.fixed);
                            x.below = x.rank - want;
                            x.inside = k;
                            if x.fixed == 64 {
                                x.done = Some(value(x.prefix));
                            }
                            found = true;
                            break;
                        }
                        want -= k;
                    }
                    if !found {
                        // A tally that does not hold the rank (not this pass's total, or
                        // values that changed between passes): no value, rather than
                        // the same pass again forever.
                        x.done = Some(f64::NAN);
                    }
                }
            }
            Tally::Values(held) => {
                for (x, mut v) in self.cells.iter_mut().zip(held) {
                    if x.done.is_none() {
                        let k = x.rank - x.below;
                        x.done = Some(if k < v.len() { *v.select_nth_unstable_by(k, f64::total_cmp).1 } else { f64::NAN });
                    }
                }
            }
        }
    }

    /// Each cell's value (NaN for a cell without finite values, or not done).
    pub fn values(&self) -> Vec<f64> {
        self.cells.iter().map(|x| x.done.unwrap_or(f64::NAN)).collect()
    }

    /// Each cell's count of finite values (known after the first pass).
    pub fn counts(&self) -> Vec<usize> {
        self.cells.iter().map(|x| x.count).collect()
    }
}

/// The median of each of `queries` sets of values as [`crate::infra::stats::median`]
/// gives it (the mean of the two middle values of an even count), by a [`Selection`] of
/// two cells per set: cell `2q` holds set `q`'s lower middle, `2q + 1` its upper.
pub fn median_rank(cell: usize, count: usize) -> usize {
    if cell.is_multiple_of(2) { (count - 1) / 2 } else { count / 2 }
}

/// The medians of a [`Selection`] run with [`median_rank`] over `2 q` cells, with each
/// set's count of finite values.
pub fn medians_of(search: &Selection) -> Vec<(f64, usize)> {
    let (v, n) = (search.values(), search.counts());
    (0..v.len() / 2)
        .map(|q| {
            let (lo, hi, count) = (v[2 * q], v[2 * q + 1], n[2 * q]);
            (if count % 2 == 1 { hi } else { 0.5 * (lo + hi) }, count)
        })
        .collect()
}

/// Per cell, the upper median of its finite values ([`crate::infra::stats::upper_median`]).
pub fn upper_medians(n: usize, cells: usize, visit: &Visit) -> Vec<f64> {
    select(n, cells, &|_, count| count / 2, visit)
}

/// Per cell, [`crate::infra::stats::robust`]: the upper median and 1.4826 times the upper median
/// of the absolute deviations from it.
pub fn robust(n: usize, cells: usize, visit: &Visit) -> Vec<(f64, f64)> {
    let m = upper_medians(n, cells, visit);
    let mad = upper_medians(n, cells, &|i, f| visit(i, &mut |c, v| f(c, (v - m[c]).abs())));
    m.into_iter().zip(mad).map(|(m, d)| (m, 1.4826 * d)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::infra::stats;
    use proptest::prelude::*;

    /// Values of `cells` cells from a table: item `i` gives `table[i]`.
    fn run(table: &[Vec<(usize, f64)>], cells: usize) -> (Vec<f64>, Vec<(f64, f64)>) {
        let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| table[i].iter().for_each(|&(c, v)| f(c, v));
        (upper_medians(table.len(), cells, &visit), robust(table.len(), cells, &visit))
    }

    fn naive(table: &[Vec<(usize, f64)>], cells: usize) -> (Vec<f64>, Vec<(f64, f64)>) {
        let per: Vec<Vec<f64>> = (0..cells).map(|c| table.iter().flatten().filter(|(k, _)| *k == c).map(|(_, v)| *v).collect()).collect();
        (per.iter().map(|v| stats::upper_median(v.iter().copied())).collect(), per.iter().map(|v| stats::robust(v)).collect())
    }

    fn same(a: f64, b: f64) -> bool {
        a == b || (a.is_nan() && b.is_nan())
    }

    #[test]
    fn medians_of_many_values_with_outliers_ties_and_nans_are_the_sorted_ones() {
        // 200 000 values in 3 cells: a narrow bulk (most in one bin of the first pass,
        // so the search narrows several times), far outliers, many exact ties, NaN and
        // infinities (left out, as the naive median leaves them).
        let mut table = Vec::new();
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for i in 0..200_000usize {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let u = (x >> 11) as f64 / (1u64 << 53) as f64;
            let v = match i % 50 {
                0 => 1e12 * (u - 0.5),
                1 => f64::NAN,
                2 => f64::INFINITY,
                3..=12 => 3.0,
                _ => 3.0 + 1e-9 * (u - 0.5),
            };
            table.push(vec![(i % 3, v), (2, -v)]);
        }
        let (m, r) = run(&table, 3);
        let (nm, nr) = naive(&table, 3);
        for c in 0..3 {
            assert!(same(m[c], nm[c]), "cell {c}: {} vs sorted {}", m[c], nm[c]);
            assert!(same(r[c].0, nr[c].0) && same(r[c].1, nr[c].1), "cell {c}: {:?} vs sorted {:?}", r[c], nr[c]);
        }
    }

    /// What the module is for: a million values of a narrow bulk with ties, beside one
    /// far outlier or between adjacent subnormals, never held: the bin collected holds at
    /// most `COLLECT` values, and the median is the sorted one.
    #[test]
    fn far_outliers_and_tiny_ranges_are_narrowed_not_collected() {
        let tiny = f64::from_bits(3);
        for outlier in [-1e300, 1e30, -3e38, tiny] {
            let table: Vec<Vec<(usize, f64)>> = (0..1_000_000usize)
                .map(|i| {
                    let v = if i == 0 { outlier } else if outlier == tiny { f64::from_bits(1 + (i % 3) as u64) } else { 5.0 + (i % 1000) as f64 * 1e-9 };
                    vec![(0, v)]
                })
                .collect();
            let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| table[i].iter().for_each(|&(c, v)| f(c, v));
            let (got, most) = select_collecting(table.len(), 1, &|_, count| count / 2, &visit, COLLECT);
            let (want, _) = naive(&table, 1);
            assert!(same(got[0], want[0]), "outlier {outlier:e}: {} vs {}", got[0], want[0]);
            assert!(most <= COLLECT, "outlier {outlier:e}: {most} values collected");
        }
    }

    #[test]
    fn an_empty_cell_is_nan_and_one_value_is_itself() {
        let table = vec![vec![(1, 2.5)], vec![(1, f64::NAN)]];
        let (m, _) = run(&table, 3);
        assert!(m[0].is_nan() && m[2].is_nan());
        assert_eq!(m[1], 2.5);
    }

    #[test]
    fn a_tally_without_the_rank_ends_the_search_and_bad_words_are_refused() {
        // A second pass whose total holds no value at all (the values changed between
        // passes): the cell ends without a value instead of asking for the pass again.
        let mut search = Selection::collecting(2, 1);
        let counter = search.counter();
        let mut t = counter.tally();
        for v in [1.0, 2.0, 3.0] {
            counter.add(&mut t, 0, v);
            counter.add(&mut t, 1, v);
        }
        search.advance(t, &median_rank);
        assert!(!search.done());
        search.advance(Tally::Histograms(vec![vec![0; BINS]; 2]), &median_rank);
        assert!(search.done() && search.values().iter().all(|v| v.is_nan()));
        // Words a search cannot make: a histogram without room for its digit, part of a
        // digit fixed, an unknown mode, both kinds of count in one pass.
        for words in [vec![0, 64, 1], vec![0, 60, 1], vec![0, 4, 2], vec![0, 8, 3], vec![0, 8, 1, 0, 8, 2], vec![0, 8]] {
            assert!(Counter::from_words(&words).is_none(), "{words:?}");
        }
        assert!(Counter::from_words(&[5 << 56, 8, 1, 0, 64, 0]).is_some());
    }

    proptest! {
        /// The pass-by-pass protocol over blocks (a Dask reduction's view): any split of
        /// the values, the counter sent as words, the tallies merged in reverse, gives
        /// `stats::median` of each set bit for bit.
        #[test]
        fn medians_over_blocks_are_the_in_memory_ones(values in prop::collection::vec((0usize..3, prop::num::f64::ANY), 0..2000), narrow in prop::collection::vec(-1e-9f64..1e-9, 0..2000), blocks in 1usize..6) {
            let mut values = values;
            // A narrow bulk, so that the search narrows over several passes.
            values.extend(narrow.iter().enumerate().map(|(i, d)| (i % 3, 7.0 + d)));
            let mut search = Selection::collecting(6, 4);
            let chunk = values.len().div_ceil(blocks).max(1);
            while !search.done() {
                let words = search.counter().to_words();
                let mut tallies: Vec<Tally> = values.chunks(chunk).map(|part| {
                    let counter = Counter::from_words(&words).unwrap();
                    let mut t = counter.tally();
                    for &(q, v) in part {
                        counter.add(&mut t, 2 * q, v);
                        counter.add(&mut t, 2 * q + 1, v);
                    }
                    t
                }).collect();
                let mut total = tallies.pop().unwrap_or_else(|| search.counter().tally());
                while let Some(t) = tallies.pop() {
                    total.merge(t);
                }
                search.advance(total, &median_rank);
            }
            let got = medians_of(&search);
            for (q, &(median, count)) in got.iter().enumerate() {
                let want = stats::median(values.iter().filter(|v| v.0 == q).map(|v| v.1));
                prop_assert!(same(median, want) && (want.is_nan() || median.to_bits() == want.to_bits()), "set {}: {} vs {}", q, median, want);
                prop_assert_eq!(count, values.iter().filter(|v| v.0 == q && v.1.is_finite()).count());
            }
        }

        #[test]
        fn any_values_give_the_sorted_rank(values in prop::collection::vec((0usize..4, prop::num::f64::ANY), 0..3000), rank_frac in 0.0f64..1.0) {
            let table: Vec<Vec<(usize, f64)>> = values.chunks(3).map(|c| c.to_vec()).collect();
            let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| table[i].iter().for_each(|&(c, v)| f(c, v));
            let rank = |_: usize, count: usize| (rank_frac * count as f64) as usize;
            // Narrowed down to bins of 2 values: every pass's edges are exercised.
            let (got, most) = select_collecting(table.len(), 4, &rank, &visit, 2);
            prop_assert!(most <= 2, "{} values collected", most);
            for c in 0..4 {
                let mut v: Vec<f64> = values.iter().filter(|(k, x)| *k == c && x.is_finite()).map(|(_, x)| *x).collect();
                v.sort_by(f64::total_cmp);
                let want = if v.is_empty() { f64::NAN } else { v[rank(c, v.len()).min(v.len() - 1)] };
                prop_assert!(same(got[c], want), "cell {}: {} vs {}", c, got[c], want);
            }
        }
    }
}
