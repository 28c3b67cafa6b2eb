//! Exact order statistics of values that are produced, not held: `diagnose` needs medians
//! over millions of pixels per level (the robust centre and spread of each level's
//! residuals) and recomputes each pixel's residuals on demand rather than keep them (4
//! bytes per residual and level was the run's peak). So the values are visited in passes,
//! and what costs is the number of passes (each one computes every value again, or, on
//! Dask, is a round trip to the workers).
//!
//! The first pass counts each cell's values by the first 8 bits of their order-preserving
//! 64-bit key and keeps a sample of them (each value with a probability `p` from a hash of
//! its place, about `(Z n / 2)^(2/3)` of `n` values: the size that makes the sample and
//! the second pass's values least together). The sample gives each cell a bracket: the
//! two sampled values `Z` standard deviations of the sample's rank either side of the
//! wanted rank. The second pass counts the values below the bracket and at its ends and
//! collects those inside (about `2 Z sqrt(q (1 - q) n / p)` of them), and the rank's value
//! is selected from them. A bracket that missed the rank (about once in 3.5 million
//! for each side), or that held more values than it should (values that changed between
//! passes), costs one pass more: the cell goes on by the radix selection the first pass
//! also began, a histogram of the next 8 bits of the key among the values that share
//! the digits found so far, until the rank's bin holds few enough values to collect and
//! select from (or all 64 bits are fixed: the values are equal). A cell whose sample
//! holds all its values is done after the first pass; one whose first bin already holds
//! at most [`COLLECT`] values collects it. Whatever the sample, the result is the value
//! a sort would give, whatever the range or the outliers: two passes, at most nine.
//!
//! `n` is the count of items a selection is told (a cell's values, where each item gives
//! a cell one value, as every caller's does), the sample at least [`SAMPLE_LEAST`] and at
//! most [`SAMPLE_MOST`] values; a bracket expected to hold more than [`BRACKET_MOST`]
//! is not tried (cells of more than about 13 million values take the radix passes).
//! Memory per cell: a 256-bin histogram and the sample on the first pass (0.35 MiB for a
//! cell of 4 million), then a bracket's values (about 93 000, 0.71 MiB, for the same
//! cell; a task gives up its bracket past twice that, and so does the total), at most
//! [`COLLECT`] values or a histogram after. The miss rate is the median's; for ranks
//! near the ends with small samples the normal approximation is optimistic (a bracket
//! of 64 sampled values at rank 0.999 misses about 5e-5 of the time), which costs
//! passes, never the value.

use rayon::prelude::*;

/// Visits the values of item `i`: calls `f(cell, value)` for each (any number per cell).
pub type Visit<'a> = dyn Fn(usize, &mut dyn FnMut(usize, f64)) + Sync + 'a;

/// Bits of the key fixed per radix pass.
const DIGIT: u32 = 8;
/// A bin with at most this many values is collected and selected from.
const COLLECT: usize = 1 << 14;
/// A bracket's half-width, in standard deviations of the wanted rank's place in the
/// sample (a binomial count): at the median it misses on one side with probability
/// ~2.9e-7 (the normal tail; ~2.3e-7 by the exact hypergeometric one at n = 4 million).
const Z: f64 = 5.0;
/// The fewest sampled values a bracket is drawn from (below, the radix passes go on).
const MIN_SAMPLE: usize = 64;
/// The most values a bracket is expected to hold, or it is not tried (2 MiB a cell: a
/// Dask driver receives every cell's; with the sample's cap, cells of up to about 13
/// million values are bracketed, larger ones take the radix passes).
const BRACKET_MOST: f64 = (1u64 << 18) as f64;
/// The largest sample a selection asks for (0.5 MiB a cell).
const SAMPLE_MOST: f64 = (1u64 << 16) as f64;
/// The least sample a selection asks for: a few thousand values cost nothing beside a
/// pass, and a cell of fewer is done in one.
const SAMPLE_LEAST: f64 = 4096.0;

/// The order-preserving key of a finite `v`: `a < b` (as `f64::total_cmp`) exactly when
/// `key(a) < key(b)`. Finite values never have key 0 or `u64::MAX` (an open bracket's
/// ends).
fn key(v: f64) -> u64 {
    let b = v.to_bits();
    if b >> 63 == 1 { !b } else { b | 1 << 63 }
}

/// The value of a key.
fn value(k: u64) -> f64 {
    f64::from_bits(if k >> 63 == 1 { k & !(1 << 63) } else { !k })
}

/// Whether the `n`-th value a task gave `cell` is sampled, at a rate of `rate / 2^63`:
/// a hash of the place (SplitMix64's finalizer), not of the value, so equal values are
/// sampled independently and the sample does not depend on them.
fn sampled(rate: u64, salt: u64, cell: usize, n: u64) -> bool {
    let mut z = salt.wrapping_add(0x2545_F491_4F6C_DD1D).wrapping_mul(0xD1B5_4A32_D192_ED03) ^ ((cell as u64) << 40).wrapping_add(n).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    z >> 1 < rate
}

/// The sampling rate (in units of 2^-63) for a selection over `items` values a cell:
/// about `(Z n / 2)^(2/3)` of them, at least [`SAMPLE_LEAST`] (all of a small set), at
/// most [`SAMPLE_MOST`].
fn sample_rate(items: usize) -> u64 {
    let n = items.max(1) as f64;
    let m = (Z * n / 2.0).powf(2.0 / 3.0).clamp(SAMPLE_LEAST, SAMPLE_MOST);
    if m >= n { 1 << 63 } else { (m / n * 2f64.powi(63)) as u64 }
}

/// Folds `visit` over items `0..n` in one task per thread, each with its own accumulator
/// from `init(task)`, merged by `merge`.
fn fold_items<A: Send>(n: usize, init: &(dyn Fn(usize) -> A + Sync), step: &(dyn Fn(&mut A, usize, f64) + Sync), merge: &(dyn Fn(&mut A, A) + Sync), visit: &Visit) -> A {
    let t = rayon::current_num_threads().clamp(1, n.max(1));
    (0..t)
        .into_par_iter()
        .map(|k| {
            let mut acc = init(k);
            for i in (k * n / t)..((k + 1) * n / t) {
                visit(i, &mut |c, v| step(&mut acc, c, v));
            }
            acc
        })
        .reduce_with(|mut a, b| {
            merge(&mut a, b);
            a
        })
        .unwrap_or_else(|| init(0))
}

/// Per cell, the `rank(cell, count)`-th smallest (from 0) of its finite values, `count`
/// their number; NaN for a cell without values. Items `0..n` are visited by `visit`,
/// which must give the same values on every pass.
pub fn select(n: usize, cells: usize, rank: &(dyn Fn(usize, usize) -> usize + Sync), visit: &Visit) -> Vec<f64> {
    // Two passes at least (but for a cell sampled whole): the values recorded once, as far
    // as they fit, and every pass reading them back (`super::recorded`; the same values).
    super::recorded::within(n, visit, |v| run(Selection::new(cells, n), n, rank, v).0)
}

/// A selection run to its end over items `0..n`; also the most values any cell held at
/// once (collected, or inside its bracket) and the passes.
fn run(mut search: Selection, n: usize, rank: &(dyn Fn(usize, usize) -> usize + Sync), visit: &Visit) -> (Vec<f64>, usize, usize) {
    let (mut most, mut passes) = (0, 0);
    while !search.done() {
        let counter = search.counter();
        let tally = fold_items(n, &|k| counter.tally(k as u64), &|t, c, v| counter.add(t, c, v), &|a, b| a.merge(b), visit);
        most = most.max(tally.held());
        search.advance(tally, rank);
        passes += 1;
    }
    (search.values(), most, passes)
}

/// A bracket around a cell's rank: the keys of its ends (0 and `u64::MAX` for an open
/// end) and the most values a task may collect inside before it gives up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Bracket {
    lo: u64,
    hi: u64,
    most: u64,
}

/// Per cell: the key's high `fixed` bits found (`prefix`), the values below them, the
/// rank (known after the first pass's counts), the values sharing the prefix, the count
/// of all, and a bracket to count on the next pass.
#[derive(Debug, Clone, Copy)]
struct Search {
    prefix: u64,
    fixed: u32,
    below: usize,
    rank: usize,
    inside: usize,
    count: usize,
    done: Option<f64>,
    bracket: Option<Bracket>,
}

/// A selection in progress, driven pass by pass: [`Selection::counter`] says what a
/// pass counts, any number of blocks of the values each [`Counter::add`] theirs to a
/// [`Tally`], the tallies [`Tally::merge`] (in any order: counts and multisets), and
/// [`Selection::advance`] takes the total. The values of one pass may be split over
/// threads, processes or machines; only the counter and the tallies travel.
#[derive(Debug, Clone)]
pub struct Selection {
    cells: Vec<Search>,
    collect: usize,
    rate: u64,
}

/// What one pass counts in a cell (see [`Counter::add`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ask {
    /// Nothing: the cell is done.
    Idle,
    /// The histogram of the next digit of the values that share the prefix's `fixed`
    /// high bits (and, on the first pass, a sample of the values).
    Histogram { prefix: u64, fixed: u32 },
    /// The values that share the prefix.
    Collect { prefix: u64, fixed: u32 },
    /// The values below, at and between a bracket's ends.
    Bracket(Bracket),
}

/// One pass's instructions: per cell an [`Ask`], and the first pass's sampling rate.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Counter {
    cells: Vec<Ask>,
    rate: u64,
}

/// One cell's counts of one pass.
#[derive(Debug, Clone, PartialEq)]
enum Count {
    Idle,
    /// `2^DIGIT` bins (empty while nothing was counted), the sample, the values seen.
    Histogram { bins: Vec<u64>, sample: Vec<f64>, seen: u64 },
    Values(Vec<f64>),
    /// Counts below and at the ends, the values between them (dropped, `over`, past the
    /// bracket's `most`).
    Bracket { below: u64, at_lo: u64, at_hi: u64, inside: Vec<f64>, over: bool },
    /// Counts of different kinds merged (tallies of different passes): the cell ends
    /// without a value.
    Bad,
}

/// One pass's counts, per cell, made by one task (`salt` makes its sample its own).
#[derive(Debug, Clone, PartialEq)]
pub struct Tally {
    cells: Vec<Count>,
    salt: u64,
}

/// Bins of a histogram pass.
const BINS: usize = 1 << DIGIT;

/// Whether key `k` shares the high `fixed` bits of `prefix`.
fn shares(k: u64, prefix: u64, fixed: u32) -> bool {
    fixed == 0 || k >> (64 - fixed) == prefix >> (64 - fixed)
}

impl Tally {
    /// Adds `other`'s counts (histograms bin by bin; values and samples appended). Counts
    /// of different kinds, or tallies of different cell counts (not one pass's), make
    /// the cells [`Count::Bad`]: a search ends them without a value, never with a wrong
    /// one.
    pub fn merge(&mut self, other: Tally) {
        if self.cells.len() != other.cells.len() {
            self.cells.iter_mut().for_each(|c| *c = Count::Bad);
            return;
        }
        for (a, b) in self.cells.iter_mut().zip(other.cells) {
            match (a, b) {
                (Count::Histogram { bins: x, sample: s, seen: n }, Count::Histogram { bins: y, sample: mut t, seen: m }) => {
                    if x.is_empty() {
                        *x = y;
                    } else if !y.is_empty() {
                        x.iter_mut().zip(y).for_each(|(p, q)| *p = p.wrapping_add(q));
                    }
                    s.append(&mut t);
                    *n = n.wrapping_add(m);
                }
                (Count::Values(x), Count::Values(mut y)) => x.append(&mut y),
                (Count::Bracket { below, at_lo, at_hi, inside, over }, Count::Bracket { below: b, at_lo: l, at_hi: h, inside: mut i, over: o }) => {
                    *below = below.wrapping_add(b);
                    *at_lo = at_lo.wrapping_add(l);
                    *at_hi = at_hi.wrapping_add(h);
                    *over |= o;
                    if *over {
                        *inside = Vec::new();
                    } else {
                        inside.append(&mut i);
                    }
                }
                (Count::Idle, Count::Idle) => {}
                // Tallies of one pass count a cell one way.
                (a, _) => *a = Count::Bad,
            }
        }
    }

    /// Its number of cells.
    pub fn cells(&self) -> usize {
        self.cells.len()
    }

    /// The most values any cell holds (collected, sampled or inside a bracket).
    fn held(&self) -> usize {
        self.cells
            .iter()
            .map(|c| match c {
                Count::Histogram { sample, .. } => sample.len(),
                Count::Values(v) | Count::Bracket { inside: v, .. } => v.len(),
                Count::Idle | Count::Bad => 0,
            })
            .max()
            .unwrap_or(0)
    }

    /// The tally as integers (values as their bits): to send to where it is merged.
    pub fn to_words(&self) -> Vec<u64> {
        let mut w = vec![self.cells.len() as u64];
        let values = |w: &mut Vec<u64>, v: &[f64]| {
            w.push(v.len() as u64);
            w.extend(v.iter().map(|x| x.to_bits()));
        };
        for c in &self.cells {
            match c {
                Count::Idle => w.push(0),
                Count::Bad => w.push(4),
                Count::Histogram { bins, sample, seen } => {
                    w.extend([1, *seen, bins.len() as u64]);
                    w.extend(bins);
                    values(&mut w, sample);
                }
                Count::Values(v) => {
                    w.push(2);
                    values(&mut w, v);
                }
                Count::Bracket { below, at_lo, at_hi, inside, over } => {
                    w.extend([3, *below, *at_lo, *at_hi, u64::from(*over)]);
                    values(&mut w, inside);
                }
            }
        }
        w
    }

    /// The tally of [`Tally::to_words`]; `None` for words it cannot have made.
    pub fn from_words(w: &[u64]) -> Option<Tally> {
        let mut it = w.iter().copied();
        let mut next = || it.next();
        let cells = usize::try_from(next()?).ok()?;
        // Each cell takes at least one word.
        if cells > w.len() {
            return None;
        }
        let mut out = Vec::with_capacity(cells.min(1 << 12));
        fn take(next: &mut dyn FnMut() -> Option<u64>, n: u64) -> Option<Vec<u64>> {
            (0..n).map(|_| next()).collect()
        }
        for _ in 0..cells {
            out.push(match next()? {
                0 => Count::Idle,
                4 => Count::Bad,
                1 => {
                    let seen = next()?;
                    let nb = next()?;
                    if nb != 0 && nb != BINS as u64 {
                        return None;
                    }
                    let bins = take(&mut next, nb)?;
                    let ns = next()?;
                    let sample = take(&mut next, ns)?.into_iter().map(f64::from_bits).collect();
                    Count::Histogram { bins, sample, seen }
                }
                2 => {
                    let n = next()?;
                    Count::Values(take(&mut next, n)?.into_iter().map(f64::from_bits).collect())
                }
                3 => {
                    let (below, at_lo, at_hi, over) = (next()?, next()?, next()?, next()?);
                    let n = next()?;
                    Count::Bracket { below, at_lo, at_hi, inside: take(&mut next, n)?.into_iter().map(f64::from_bits).collect(), over: over != 0 }
                }
                _ => return None,
            });
        }
        next().is_none().then_some(Tally { cells: out, salt: 0 })
    }
}

impl Counter {
    /// An empty tally of this pass for a task; tasks of one pass take different `salt`s
    /// (their samples are then independent).
    pub fn tally(&self, salt: u64) -> Tally {
        let cells = self
            .cells
            .iter()
            .map(|a| match a {
                Ask::Idle => Count::Idle,
                Ask::Histogram { .. } => Count::Histogram { bins: Vec::new(), sample: Vec::new(), seen: 0 },
                Ask::Collect { .. } => Count::Values(Vec::new()),
                Ask::Bracket(_) => Count::Bracket { below: 0, at_lo: 0, at_hi: 0, inside: Vec::new(), over: false },
            })
            .collect();
        Tally { cells, salt }
    }

    /// Counts value `v` of `cell` into `t` (non-finite values are left out).
    #[inline]
    pub fn add(&self, t: &mut Tally, cell: usize, v: f64) {
        self.add_all(t, cell, std::slice::from_ref(&v));
    }

    /// Counts `values` of `cell` into `t` (as [`Counter::add`] each, the cell's ask looked
    /// up once: a block's values of one cell in a tight loop).
    #[inline]
    pub fn add_all(&self, t: &mut Tally, cell: usize, values: &[f64]) {
        let (Some(&ask), salt) = (self.cells.get(cell), t.salt) else { return };
        let Some(count) = t.cells.get_mut(cell) else { return };
        let finite = values.iter().copied().filter(|v| v.is_finite());
        match (ask, count) {
            (Ask::Histogram { prefix, fixed }, Count::Histogram { bins, sample, seen }) => {
                if bins.is_empty() {
                    bins.resize(BINS, 0);
                }
                for v in finite {
                    let k = key(v);
                    if !shares(k, prefix, fixed) {
                        continue;
                    }
                    bins[((k >> (64 - fixed - DIGIT)) & (BINS as u64 - 1)) as usize] += 1;
                    if fixed == 0 && sampled(self.rate, salt, cell, *seen) {
                        sample.push(v);
                    }
                    *seen += 1;
                }
            }
            (Ask::Collect { prefix, fixed }, Count::Values(held)) => held.extend(finite.filter(|&v| shares(key(v), prefix, fixed))),
            (Ask::Bracket(b), Count::Bracket { below, at_lo, at_hi, inside, over }) => {
                // The counts without a branch (a value is below or above a narrow bracket
                // about as often: a branch on it is mispredicted half the time).
                let (mut n_below, mut n_lo, mut n_hi) = (0, 0, 0);
                // Strictly inside: one unsigned comparison (0 when the ends are equal).
                let (first, width) = (b.lo.wrapping_add(1), b.hi.saturating_sub(b.lo).saturating_sub(1));
                let hi = if b.hi == b.lo { None } else { Some(b.hi) };
                for v in finite {
                    let k = key(v);
                    n_below += u64::from(k < b.lo);
                    n_lo += u64::from(k == b.lo);
                    n_hi += u64::from(Some(k) == hi);
                    if k.wrapping_sub(first) < width && !*over {
                        inside.push(v);
                        if inside.len() as u64 > b.most {
                            *over = true;
                            *inside = Vec::new();
                        }
                    }
                }
                *below += n_below;
                *at_lo += n_lo;
                *at_hi += n_hi;
            }
            _ => {}
        }
    }

    /// The counter as integers, the sampling rate then four per cell (idle `0, 0, 0, 0`;
    /// histogram `prefix, bits, 0, 1`; collect `prefix, bits, 0, 2`; bracket `lo, hi,
    /// most, 3`): to send to where the values are.
    pub fn to_words(&self) -> Vec<u64> {
        let mut w = vec![self.rate];
        for a in &self.cells {
            w.extend(match *a {
                Ask::Idle => [0, 0, 0, 0],
                Ask::Histogram { prefix, fixed } => [prefix, u64::from(fixed), 0, 1],
                Ask::Collect { prefix, fixed } => [prefix, u64::from(fixed), 0, 2],
                Ask::Bracket(b) => [b.lo, b.hi, b.most, 3],
            });
        }
        w
    }

    /// The counter of [`Counter::to_words`]; `None` for words it cannot have made.
    pub fn from_words(w: &[u64]) -> Option<Counter> {
        let (&rate, rest) = w.split_first()?;
        if !rest.len().is_multiple_of(4) || rate > 1 << 63 {
            return None;
        }
        let cells = rest
            .chunks(4)
            .map(|c| {
                // Whole digits fixed, and room for the next one where a histogram counts it.
                let digits = |most: u64| (c[1] % u64::from(DIGIT) == 0 && c[1] <= most).then_some(c[1] as u32);
                match c[3] {
                    0 => Some(Ask::Idle),
                    1 => Some(Ask::Histogram { prefix: c[0], fixed: digits(64 - u64::from(DIGIT))? }),
                    2 => Some(Ask::Collect { prefix: c[0], fixed: digits(64)? }),
                    3 => (c[0] <= c[1]).then_some(Ask::Bracket(Bracket { lo: c[0], hi: c[1], most: c[2] })),
                    _ => None,
                }
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Counter { cells, rate })
    }
}

impl Selection {
    /// A selection in `cells` cells of about `items` values each (the sample's size is
    /// chosen for it; any count gives the exact result).
    pub fn new(cells: usize, items: usize) -> Self {
        Self::with(cells, COLLECT, sample_rate(items))
    }

    /// A selection collecting bins of at most `collect` values, sampling at `rate` /
    /// 2^63 (0: no sample, the radix passes alone).
    fn with(cells: usize, collect: usize, rate: u64) -> Self {
        Selection { cells: vec![Search { prefix: 0, fixed: 0, below: 0, rank: 0, inside: usize::MAX, count: 0, done: None, bracket: None }; cells], collect, rate }
    }

    /// Whether every cell has its value.
    pub fn done(&self) -> bool {
        self.cells.iter().all(|s| s.done.is_some())
    }

    /// What the next pass asks of cell `s`.
    fn ask(&self, s: &Search) -> Ask {
        match (s.done, s.bracket) {
            (Some(_), _) => Ask::Idle,
            (None, Some(b)) => Ask::Bracket(b),
            (None, None) if s.inside <= self.collect => Ask::Collect { prefix: s.prefix, fixed: s.fixed },
            (None, None) => Ask::Histogram { prefix: s.prefix, fixed: s.fixed },
        }
    }

    /// What the next pass counts: in each cell a bracket's values, a bin's values (when
    /// it holds few enough) or the histogram of the next digit.
    pub fn counter(&self) -> Counter {
        Counter { cells: self.cells.iter().map(|s| self.ask(s)).collect(), rate: self.rate }
    }

    /// Takes a pass's total tally: each cell's rank (`rank(cell, count)`, from 0, of its
    /// `count` finite values) bracketed or narrowed to the next digit, or found among the
    /// values collected. A cell whose count is not of the kind asked for, or does not
    /// hold the rank (not this pass's total, or values that changed between passes),
    /// ends without a value rather than ask for the same pass again forever.
    pub fn advance(&mut self, tally: Tally, rank: &(dyn Fn(usize, usize) -> usize + Sync)) {
        for (c, count) in tally.cells.into_iter().enumerate() {
            let Some(&x) = self.cells.get(c) else { break };
            let asked = self.ask(&x);
            let x = &mut self.cells[c];
            match (asked, count) {
                (Ask::Idle, _) => {}
                (Ask::Histogram { .. }, Count::Histogram { bins, sample, .. }) => {
                    let first = x.fixed == 0;
                    narrow(x, &bins, c, rank);
                    if first && x.done.is_none() {
                        x.bracket = bracket(x, sample, self.collect);
                    }
                }
                (Ask::Collect { .. }, Count::Values(mut v)) => {
                    let k = x.rank - x.below;
                    x.done = Some(if k < v.len() { *v.select_nth_unstable_by(k, f64::total_cmp).1 } else { f64::NAN });
                }
                (Ask::Bracket(b), Count::Bracket { below, at_lo, at_hi, inside, over }) => {
                    x.bracket = None;
                    if !over && inside.len() as u64 <= b.most {
                        // Otherwise the radix passes go on from the first pass's digit.
                        x.done = within(x.rank, b, [below, at_lo, at_hi], inside);
                    }
                }
                _ => x.done = Some(f64::NAN),
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

/// Narrows cell `x` (cell `c`) by a histogram of its next digit (`bins`, empty for none
/// counted); on the first pass, its count and rank.
fn narrow(x: &mut Search, bins: &[u64], c: usize, rank: &(dyn Fn(usize, usize) -> usize + Sync)) {
    if x.fixed == 0 {
        let count = bins.iter().fold(0u64, |a, &b| a.wrapping_add(b)) as usize;
        x.count = count;
        if count == 0 {
            x.done = Some(f64::NAN);
            return;
        }
        x.rank = rank(c, count).min(count - 1);
    }
    // The digit holding the rank among the values that share the prefix.
    let mut want = x.rank - x.below;
    for (j, &k) in bins.iter().enumerate() {
        let k = k as usize;
        if want < k {
            x.fixed += DIGIT;
            x.prefix |= (j as u64) << (64 - x.fixed);
            x.below = x.rank - want;
            x.inside = k;
            if x.fixed == 64 {
                x.done = Some(value(x.prefix));
            }
            return;
        }
        want -= k;
    }
    x.done = Some(f64::NAN);
}

/// A bracket for cell `x` from its first pass's `sample`: `None` where the cell is done by
/// the sample itself (it holds every value), where the first digit's bin can be
/// collected as it is, or where the sample is too small or the bracket too wide.
fn bracket(x: &mut Search, mut sample: Vec<f64>, collect: usize) -> Option<Bracket> {
    let m = sample.len();
    if m == x.count {
        x.done = Some(*sample.select_nth_unstable_by(x.rank, f64::total_cmp).1);
        return None;
    }
    if x.inside <= collect || m < MIN_SAMPLE {
        return None;
    }
    // The rank's place in the sample: binomial about q m.
    let (n, mf) = (x.count as f64, m as f64);
    let q = (x.rank as f64 + 0.5) / n;
    let half = Z * (mf * q * (1.0 - q)).sqrt() + 1.0;
    let (lo, hi) = ((q * mf - half).floor(), (q * mf + half).ceil());
    let expect = n * (hi.min(mf) - lo.max(-1.0)) / mf;
    if expect > BRACKET_MOST {
        return None;
    }
    // Two order statistics of the sample (linear time each, not a sort).
    let mut at = |i: f64| key(*sample.select_nth_unstable_by(i as usize, f64::total_cmp).1);
    let lo = if lo < 0.0 { 0 } else { at(lo) };
    let hi = if hi >= mf { u64::MAX } else { at(hi) };
    Some(Bracket { lo, hi, most: (2.0 * expect) as u64 + collect as u64 })
}

/// The `rank`-th value given the counts below bracket `b` and at its ends and the values
/// inside; `None` where the rank is outside the bracket.
fn within(rank: usize, b: Bracket, [below, at_lo, at_hi]: [u64; 3], mut inside: Vec<f64>) -> Option<f64> {
    let mut r = (rank as u64).checked_sub(below)?;
    if r < at_lo {
        return Some(value(b.lo));
    }
    r -= at_lo;
    if r < inside.len() as u64 {
        return Some(*inside.select_nth_unstable_by(r as usize, f64::total_cmp).1);
    }
    r -= inside.len() as u64;
    (r < at_hi).then(|| value(b.hi))
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

/// The rank of the upper median of `count` values ([`crate::infra::stats::upper_median`]),
/// whatever the cell.
fn upper_rank(_: usize, count: usize) -> usize {
    count / 2
}

/// Per cell, the upper median of its finite values ([`crate::infra::stats::upper_median`]).
pub fn upper_medians(n: usize, cells: usize, visit: &Visit) -> Vec<f64> {
    select(n, cells, &upper_rank, visit)
}

/// Per cell, [`crate::infra::stats::robust`]: the upper median and 1.4826 times the upper median
/// of the absolute deviations from it.
pub fn robust(n: usize, cells: usize, visit: &Visit) -> Vec<(f64, f64)> {
    super::recorded::within(n, visit, |v| robust_replayed(n, cells, v))
}

/// [`robust`] of a visit that is cheap to repeat (values already recorded,
/// [`super::recorded`]): its four passes read `visit` itself.
pub fn robust_replayed(n: usize, cells: usize, visit: &Visit) -> Vec<(f64, f64)> {
    let m = run(Selection::new(cells, n), n, &upper_rank, visit).0;
    let mad = run(Selection::new(cells, n), n, &upper_rank, &|i, f| visit(i, &mut |c, v| f(c, (v - m[c]).abs()))).0;
    m.into_iter().zip(mad).map(|(m, d)| (m, 1.4826 * d)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::infra::stats;
    use proptest::prelude::*;

    /// Values of `cells` cells from a table: item `i` gives `table[i]`.
    fn medians(table: &[Vec<(usize, f64)>], cells: usize) -> (Vec<f64>, Vec<(f64, f64)>) {
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

    /// A xorshift's uniforms in [0, 1).
    fn uniforms(seed: u64) -> impl FnMut() -> f64 {
        let mut x = seed;
        move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The sorted `rank`-th finite value of each cell of `values`.
    fn sorted_rank(values: &[(usize, f64)], cells: usize, rank: &dyn Fn(usize, usize) -> usize) -> Vec<f64> {
        (0..cells)
            .map(|c| {
                let mut v: Vec<f64> = values.iter().filter(|(k, x)| *k == c && x.is_finite()).map(|(_, x)| *x).collect();
                v.sort_by(f64::total_cmp);
                if v.is_empty() { f64::NAN } else { v[rank(c, v.len()).min(v.len() - 1)] }
            })
            .collect()
    }

    #[test]
    fn medians_of_many_values_with_outliers_ties_and_nans_are_the_sorted_ones() {
        // 200 000 values in 3 cells: a narrow bulk (most in one bin of the first pass,
        // so the search narrows several times), far outliers, many exact ties, NaN and
        // infinities (left out, as the naive median leaves them).
        let mut table = Vec::new();
        let mut u = uniforms(0x2545_f491_4f6c_dd1d);
        for i in 0..200_000usize {
            let u = u();
            let v = match i % 50 {
                0 => 1e12 * (u - 0.5),
                1 => f64::NAN,
                2 => f64::INFINITY,
                3..=12 => 3.0,
                _ => 3.0 + 1e-9 * (u - 0.5),
            };
            table.push(vec![(i % 3, v), (2, -v)]);
        }
        let (m, r) = medians(&table, 3);
        let (nm, nr) = naive(&table, 3);
        for c in 0..3 {
            assert!(same(m[c], nm[c]), "cell {c}: {} vs sorted {}", m[c], nm[c]);
            assert!(same(r[c].0, nr[c].0) && same(r[c].1, nr[c].1), "cell {c}: {:?} vs sorted {:?}", r[c], nr[c]);
        }
    }

    /// What the module is for: a million values of a narrow bulk with ties, beside one
    /// far outlier or between adjacent subnormals, never held: by the radix passes alone
    /// the bin collected holds at most `COLLECT` values; with the sample, two passes and
    /// a bracket of a few percent of the values (Z n / sqrt(m) with m about 18 000).
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
            let (want, _) = naive(&table, 1);
            let rank = |_: usize, count: usize| count / 2;
            let (got, most, _) = run(Selection::with(1, COLLECT, 0), table.len(), &rank, &visit);
            assert!(same(got[0], want[0]), "outlier {outlier:e}, radix: {} vs {}", got[0], want[0]);
            assert!(most <= COLLECT, "outlier {outlier:e}, radix: {most} values collected");
            let (got, most, passes) = run(Selection::new(1, table.len()), table.len(), &rank, &visit);
            assert!(same(got[0], want[0]), "outlier {outlier:e}, bracket: {} vs {}", got[0], want[0]);
            assert!(most <= 60_000 && passes == 2, "outlier {outlier:e}, bracket: {most} values held, {passes} passes");
        }
    }

    /// The bracket's margin, against what it is for: 400 cells of 20 000 normal values
    /// (a sample of about 4 100 each, the least a selection takes) and 1 000 of 2 000
    /// sampled at 15% (about 300 each), every rank from 0.001 to 0.999, each found in two
    /// passes (a margin of 1 standard deviation instead of 5 misses about a third),
    /// holding no more than the sample or the bracket the module comment gives (within
    /// 1.5x: a bracket left open would hold all); and cells of 2 000 at the selection's own
    /// rate, sampled whole, found in one pass. (Bins of over 64 values are bracketed, not
    /// collected.)
    #[test]
    fn brackets_hold_their_ranks_in_two_passes() {
        let rate = |m: f64, per: usize| (m / per as f64 * 2f64.powi(63)) as u64;
        for (cells, per, rate, passes) in [(400usize, 20_000usize, sample_rate(20_000), 2), (1000, 2_000, rate(300.0, 2_000), 2), (100, 2_000, sample_rate(2_000), 1)] {
            let mut u = uniforms(0x9e37_79b9_7f4a_7c15 ^ rate);
            let values: Vec<(usize, f64)> = (0..cells * per)
                .map(|i| {
                    let (a, b) = (u().max(1e-300), u());
                    (i % cells, 100.0 + (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos())
                })
                .collect();
            let table: Vec<Vec<(usize, f64)>> = values.chunks(cells).map(<[_]>::to_vec).collect();
            let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| table[i].iter().for_each(|&(c, v)| f(c, v));
            let rank = |c: usize, count: usize| ((0.001 + 0.998 * c as f64 / cells as f64) * count as f64) as usize;
            let (got, most, took) = run(Selection::with(cells, 64, rate), table.len(), &rank, &visit);
            assert_eq!(got, sorted_rank(&values, cells, &rank), "{cells} cells of {per}");
            assert_eq!(took, passes, "{cells} cells of {per}");
            let m = rate as f64 / 2f64.powi(63) * per as f64;
            let width = 2.0 * Z * 0.5 * per as f64 / m.sqrt();
            assert!((most as f64) < 1.5 * width.max(m), "{cells} cells of {per}: {most} values held, {width:.0} in a bracket and {m:.0} in a sample expected");
        }
    }

    /// A bracket that misses its rank (below it, above it) or holds more than its `most`
    /// (values that changed) costs a pass or more, never the value: the radix passes go on
    /// from the first pass's digit.
    #[test]
    fn a_missed_or_overfull_bracket_falls_back_to_the_radix_passes() {
        let mut u = uniforms(7);
        let values: Vec<(usize, f64)> = (0..400_000).map(|i| (i % 4, 10.0 + u())).collect();
        let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| f(values[i].0, values[i].1);
        let rank = |_: usize, count: usize| count / 2;
        let mut search = Selection::with(4, 64, 1 << 56);
        let pass = |search: &mut Selection| {
            let counter = search.counter();
            let tally = fold_items(values.len(), &|k| counter.tally(k as u64), &|t, c, v| counter.add(t, c, v), &|a, b| a.merge(b), &visit);
            search.advance(tally, &rank);
        };
        pass(&mut search);
        assert!(search.cells.iter().all(|x| x.bracket.is_some()), "{:?}", search.cells);
        // Cell 0 bracketed below its rank, 1 above, 2 with room for no value, 3 as drawn.
        let (k, mid) = (key, 10.5);
        search.cells[0].bracket = Some(Bracket { lo: k(10.0), hi: k(10.25), most: 1 << 20 });
        search.cells[1].bracket = Some(Bracket { lo: k(10.75), hi: k(11.0), most: 1 << 20 });
        search.cells[2].bracket = Some(Bracket { lo: k(mid - 0.1), hi: k(mid + 0.1), most: 0 });
        pass(&mut search);
        assert!(search.cells[..3].iter().all(|x| x.done.is_none() && x.fixed == 8) && search.cells[3].done.is_some());
        let mut passes = 2;
        while !search.done() {
            pass(&mut search);
            passes += 1;
        }
        assert_eq!(search.values(), sorted_rank(&values, 4, &rank));
        // The radix passes went on from the first pass's digit: one pass more than the
        // radix search alone takes.
        let (want, _, radix) = run(Selection::with(4, 64, 0), values.len(), &rank, &visit);
        assert_eq!((search.values(), passes), (want, radix + 1));
    }

    /// The rank's value at each place a bracket can hold it, counted as a pass would: on
    /// its low end, inside, on its high end, and missed below and above; a bracket with
    /// equal ends; open ends.
    #[test]
    fn a_bracket_gives_the_rank_at_its_ends_and_inside() {
        let values = [1.0, 2.0, 2.0, 3.0, 4.0, 4.0, 4.0, 5.0, -0.0, 0.0];
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        for (lo, hi) in [(2.0, 4.0), (0.0, 4.0), (-0.0, 0.0), (4.0, 4.0), (1.0, 5.0)] {
            for open in [(false, false), (true, false), (false, true), (true, true)] {
                let b = Bracket { lo: if open.0 { 0 } else { key(lo) }, hi: if open.1 { u64::MAX } else { key(hi) }, most: 100 };
                let counter = Counter { cells: vec![Ask::Bracket(b)], rate: 0 };
                let mut t = counter.tally(0);
                counter.add_all(&mut t, 0, &values);
                let Count::Bracket { below, at_lo, at_hi, inside, .. } = t.cells[0].clone() else { unreachable!() };
                for (rank, &want) in sorted.iter().enumerate() {
                    let got = within(rank, b, [below, at_lo, at_hi], inside.clone());
                    let (l, h) = (if open.0 { f64::NEG_INFINITY } else { lo }, if open.1 { f64::INFINITY } else { hi });
                    let held = want.total_cmp(&l).is_ge() && want.total_cmp(&h).is_le();
                    assert_eq!(got.map(f64::to_bits), held.then(|| want.to_bits()), "rank {rank} in [{lo}, {hi}], open {open:?}");
                }
            }
        }
    }

    /// Merging: a task over its bracket's `most` makes the total over (its values were
    /// dropped, its counts kept), and counts of different kinds or cell counts (tallies
    /// of different passes) end the cells without a value.
    #[test]
    fn merged_tallies_keep_an_overflow_and_refuse_mixed_passes() {
        let b = Bracket { lo: key(1.0), hi: key(9.0), most: 3 };
        let counter = Counter { cells: vec![Ask::Bracket(b)], rate: 0 };
        let (mut few, mut many) = (counter.tally(0), counter.tally(1));
        counter.add_all(&mut few, 0, &[2.0, 3.0]);
        counter.add_all(&mut many, 0, &[2.0, 3.0, 4.0, 5.0]);
        for (mut a, b_) in [(few.clone(), many.clone()), (many, few)] {
            a.merge(b_);
            assert!(matches!(&a.cells[0], Count::Bracket { inside, over: true, .. } if inside.is_empty()), "{a:?}");
        }
        let mut search = Selection::with(1, 1, 0);
        let first = search.counter();
        let mut t = counter.tally(0);
        counter.add_all(&mut t, 0, &[1.0]);
        let mut h = first.tally(1);
        first.add_all(&mut h, 0, &[1.0, 2.0, 3.0]);
        h.merge(t);
        assert_eq!(h.cells[0], Count::Bad);
        search.advance(h, &median_rank);
        assert!(search.done() && search.values()[0].is_nan());
        let mut two = Counter { cells: vec![Ask::Idle; 2], rate: 0 }.tally(0);
        two.merge(first.tally(0));
        assert!(two.cells.iter().all(|c| *c == Count::Bad));
        assert_eq!(Tally::from_words(&two.to_words()), Some(Tally { cells: vec![Count::Bad; 2], salt: 0 }));
    }

    #[test]
    fn an_empty_cell_is_nan_and_one_value_is_itself() {
        let table = vec![vec![(1, 2.5)], vec![(1, f64::NAN)]];
        let (m, _) = medians(&table, 3);
        assert!(m[0].is_nan() && m[2].is_nan());
        assert_eq!(m[1], 2.5);
    }

    #[test]
    fn a_tally_without_the_rank_ends_the_search_and_bad_words_are_refused() {
        // A second pass whose total holds no value at all (the values changed between
        // passes): the cell ends without a value instead of asking for the pass again.
        let mut search = Selection::with(2, 1, 0);
        let counter = search.counter();
        let mut t = counter.tally(0);
        for v in [1.0, 2.0, 3.0] {
            counter.add(&mut t, 0, v);
            counter.add(&mut t, 1, v);
        }
        search.advance(t, &median_rank);
        assert!(!search.done());
        search.advance(search.counter().tally(0), &median_rank);
        assert!(search.done() && search.values().iter().all(|v| v.is_nan()));
        // A count of another kind than asked for ends the cell too.
        let mut search = Selection::with(1, 1, 0);
        search.advance(Tally { cells: vec![Count::Values(vec![1.0])], salt: 0 }, &median_rank);
        assert!(search.done() && search.values()[0].is_nan());
        // Counters a search cannot make: no rate, a rate over 1, a histogram without room
        // for its digit, part of a digit fixed, an unknown ask, a bracket upside down,
        // words not of whole cells.
        let h = 1u64 << 63;
        for words in [vec![], vec![h + 1, 0, 8, 0, 1], vec![0, 0, 64, 0, 1], vec![0, 0, 60, 0, 1], vec![0, 0, 4, 0, 2], vec![0, 0, 8, 0, 4], vec![0, 5, 3, 0, 3], vec![0, 0, 8]] {
            assert!(Counter::from_words(&words).is_none(), "{words:?}");
        }
        assert!(Counter::from_words(&[h, 5 << 56, 8, 0, 1, 0, 64, 0, 2, 3, 3, 9, 3, 0, 0, 0, 0]).is_some());
        // Tallies a counter cannot make: more cells than words (a count past the guard,
        // one within it), a histogram of 3 bins, an unknown count, words left over,
        // values cut short.
        for words in [vec![u64::MAX], vec![1 << 40, 0], vec![2, 0], vec![1, 1, 0, 3, 1, 2, 3, 0], vec![1, 5], vec![1, 0, 0], vec![1, 2, 3, 0]] {
            assert!(Tally::from_words(&words).is_none(), "{words:?}");
        }
    }

    proptest! {
        /// The pass-by-pass protocol over blocks (a Dask reduction's view): any split of
        /// the values, counted one at a time or a set at once (`add_all`), the counter
        /// and the tallies sent as words, the tallies merged in reverse, with no sample, a small one or all values sampled, gives
        /// `stats::median` of each set bit for bit.
        #[test]
        fn medians_over_blocks_are_the_in_memory_ones(values in prop::collection::vec((0usize..3, prop::num::f64::ANY), 0..2000), narrow in prop::collection::vec(-1e-9f64..1e-9, 0..2000), blocks in 1usize..6, rate in prop::sample::select(vec![0u64, 1 << 59, 1 << 61, 1 << 63])) {
            let mut values = values;
            // A narrow bulk, so that the search narrows over several passes.
            values.extend(narrow.iter().enumerate().map(|(i, d)| (i % 3, 7.0 + d)));
            let mut search = Selection::with(6, 4, rate);
            let chunk = values.len().div_ceil(blocks).max(1);
            while !search.done() {
                let words = search.counter().to_words();
                let mut tallies: Vec<Tally> = values.chunks(chunk).enumerate().map(|(b, part)| {
                    let counter = Counter::from_words(&words).unwrap();
                    let mut t = counter.tally(b as u64);
                    if b % 2 == 0 {
                        for &(q, v) in part {
                            counter.add(&mut t, 2 * q, v);
                            counter.add(&mut t, 2 * q + 1, v);
                        }
                    } else {
                        // A set's values at once, in their order.
                        for q in 0..3 {
                            let v: Vec<f64> = part.iter().filter(|x| x.0 == q).map(|x| x.1).collect();
                            counter.add_all(&mut t, 2 * q, &v);
                            counter.add_all(&mut t, 2 * q + 1, &v);
                        }
                    }
                    Tally::from_words(&t.to_words()).unwrap()
                }).collect();
                let mut total = tallies.pop().unwrap_or_else(|| search.counter().tally(0));
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
        fn any_values_give_the_sorted_rank(values in prop::collection::vec((0usize..4, prop::num::f64::ANY), 0..3000), rank_frac in 0.0f64..1.0, rate in prop::sample::select(vec![0u64, 1 << 57, 1 << 60, 1 << 63])) {
            let table: Vec<Vec<(usize, f64)>> = values.chunks(3).map(|c| c.to_vec()).collect();
            let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| table[i].iter().for_each(|&(c, v)| f(c, v));
            let rank = |_: usize, count: usize| (rank_frac * count as f64) as usize;
            // Narrowed down to bins of 2 values: every pass's edges are exercised.
            let (got, most, _) = run(Selection::with(4, 2, rate), table.len(), &rank, &visit);
            if rate == 0 {
                prop_assert!(most <= 2, "{} values collected", most);
            }
            let want = sorted_rank(&values, 4, &rank);
            for c in 0..4 {
                prop_assert!(same(got[c], want[c]), "cell {}: {} vs {}", c, got[c], want[c]);
            }
        }
    }
}
