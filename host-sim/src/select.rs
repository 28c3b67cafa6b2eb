//! Exact order statistics of values that are produced, not held: `diagnose` needs medians
//! over millions of pixels per level (the robust centre and spread of each level's
//! residuals) and recomputes each pixel's residuals on demand rather than keep them (4
//! bytes per residual and level was the run's peak). So the values are visited in passes:
//! one for each cell's count and range, then histograms of each cell's remaining range
//! that narrow it to the bin holding the wanted rank, until that bin holds few enough
//! values to collect and select from. The result is the value a sort would give; the
//! memory is a histogram per cell, whatever the number of values.

use rayon::prelude::*;

/// Visits the values of item `i`: calls `f(cell, value)` for each (any number per cell).
pub type Visit<'a> = dyn Fn(usize, &mut dyn FnMut(usize, f64)) + Sync + 'a;

/// Bins per cell and pass.
const BINS: usize = 1024;
/// A bin with at most this many values is collected and selected from.
const COLLECT: usize = 1 << 14;
/// Narrowing passes before the wanted bin is collected whatever it holds (values equal
/// to within the spacing of f64 cannot be told apart by a histogram).
const MAX_PASSES: usize = 8;

/// Items per task: the accumulators (a histogram per cell) are per task.
fn tasks(n: usize) -> usize {
    (4 * rayon::current_num_threads()).clamp(1, n.max(1))
}

/// Folds `visit` over items `0..n` in a few tasks, each with its own accumulator from
/// `init`, merged by `merge`.
fn fold_items<A: Send>(n: usize, init: &(dyn Fn() -> A + Sync), step: &(dyn Fn(&mut A, usize, f64) + Sync), merge: &(dyn Fn(&mut A, A) + Sync), visit: &Visit) -> A {
    let t = tasks(n);
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
    select_collecting(n, cells, rank, visit, COLLECT)
}

/// [`select`], collecting a bin of at most `collect` values.
fn select_collecting(n: usize, cells: usize, rank: &(dyn Fn(usize, usize) -> usize + Sync), visit: &Visit, collect: usize) -> Vec<f64> {
    // Count and range.
    let init = || vec![(0usize, f64::INFINITY, f64::NEG_INFINITY); cells];
    let range = fold_items(
        n,
        &init,
        &|a, c, v| {
            if v.is_finite() {
                let x = &mut a[c];
                *x = (x.0 + 1, x.1.min(v), x.2.max(v));
            }
        },
        &|a, b| a.iter_mut().zip(b).for_each(|(x, y)| *x = (x.0 + y.0, x.1.min(y.1), x.2.max(y.2))),
        visit,
    );
    // Per cell: the range `[lo, hi]` still searched, the values below it, the rank.
    #[derive(Clone, Copy)]
    struct Search {
        lo: f64,
        hi: f64,
        below: usize,
        inside: usize,
        rank: usize,
        done: Option<f64>,
    }
    let mut s: Vec<Search> = range
        .iter()
        .enumerate()
        .map(|(c, &(count, lo, hi))| {
            let r = rank(c, count).min(count.saturating_sub(1));
            let done = if count == 0 { Some(f64::NAN) } else if lo == hi { Some(lo) } else { None };
            Search { lo, hi, below: 0, inside: count, rank: r, done }
        })
        .collect();
    let open = |s: &Search| s.done.is_none() && s.inside > collect;
    // The bin of `v` in `[lo, hi]`: the last edge `lo + j w` at or below it (the edges
    // compared directly, so that a value's bin is the same in every use).
    let bin = |s: &Search, v: f64| -> usize {
        let w = width(s.lo, s.hi);
        let mut j = (((v - s.lo) / w) as usize).min(BINS - 1);
        while j > 0 && edge(s.lo, w, j) > v {
            j -= 1;
        }
        while j + 1 < BINS && edge(s.lo, w, j + 1) <= v {
            j += 1;
        }
        j
    };
    for _ in 0..MAX_PASSES {
        if !s.iter().any(open) {
            break;
        }
        let hist = fold_items(
            n,
            &|| vec![Vec::new(); cells],
            &|a: &mut Vec<Vec<usize>>, c, v| {
                let x = &s[c];
                if open(x) && v.is_finite() && v >= x.lo && v <= x.hi {
                    let h = &mut a[c];
                    if h.is_empty() {
                        h.resize(BINS, 0);
                    }
                    h[bin(x, v)] += 1;
                }
            },
            &|a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| {
                    if x.is_empty() {
                        *x = y;
                    } else if !y.is_empty() {
                        x.iter_mut().zip(y).for_each(|(p, q)| *p += q);
                    }
                })
            },
            visit,
        );
        for (x, h) in s.iter_mut().zip(hist) {
            if !open(x) || h.is_empty() {
                continue;
            }
            // The bin holding the rank within the range.
            let mut want = x.rank - x.below;
            let w = width(x.lo, x.hi);
            for (j, &k) in h.iter().enumerate() {
                if want < k {
                    // Bin `j` holds `edge_j <= v < edge_(j+1)`, the last bin up to `hi`
                    // itself: the next range is `[edge_j, edge_(j+1))`, closed.
                    let lo = edge(x.lo, w, j);
                    let hi = if j + 1 == BINS { x.hi } else { prev_float(edge(x.lo, w, j + 1)) };
                    x.below = x.rank - want;
                    x.inside = k;
                    (x.lo, x.hi) = (lo, hi.max(lo));
                    if x.lo == x.hi {
                        x.done = Some(x.lo);
                    }
                    break;
                }
                want -= k;
            }
        }
    }
    // Collect what each open range holds and select.
    let need: Vec<bool> = s.iter().map(|x| x.done.is_none()).collect();
    if need.iter().any(|&b| b) {
        let held = fold_items(
            n,
            &|| vec![Vec::new(); cells],
            &|a: &mut Vec<Vec<f64>>, c, v| {
                let x = &s[c];
                if need[c] && v.is_finite() && v >= x.lo && v <= x.hi {
                    a[c].push(v);
                }
            },
            &|a, b| a.iter_mut().zip(b).for_each(|(x, mut y)| x.append(&mut y)),
            visit,
        );
        for ((x, mut v), need) in s.iter_mut().zip(held).zip(need) {
            if need {
                let k = x.rank - x.below;
                x.done = (k < v.len()).then(|| *v.select_nth_unstable_by(k, f64::total_cmp).1).or(Some(f64::NAN));
            }
        }
    }
    s.iter().map(|x| x.done.unwrap_or(f64::NAN)).collect()
}

/// The bin width of `[lo, hi]` (finite ends; no overflow for the widest range).
fn width(lo: f64, hi: f64) -> f64 {
    hi / BINS as f64 - lo / BINS as f64
}

/// The lower edge of bin `j` (every use computes it alike, so a value's bin is the same
/// in every pass).
fn edge(lo: f64, w: f64, j: usize) -> f64 {
    lo + j as f64 * w
}

/// The largest f64 below `x` (finite `x`).
fn prev_float(x: f64) -> f64 {
    if x > 0.0 {
        f64::from_bits(x.to_bits() - 1)
    } else if x == 0.0 {
        -f64::from_bits(1)
    } else {
        f64::from_bits(x.to_bits() + 1)
    }
}

/// Per cell, the upper median of its finite values ([`crate::stats::upper_median`]).
pub fn upper_medians(n: usize, cells: usize, visit: &Visit) -> Vec<f64> {
    select(n, cells, &|_, count| count / 2, visit)
}

/// Per cell, [`crate::stats::robust`]: the upper median and 1.4826 times the upper median
/// of the absolute deviations from it.
pub fn robust(n: usize, cells: usize, visit: &Visit) -> Vec<(f64, f64)> {
    let m = upper_medians(n, cells, visit);
    let mad = upper_medians(n, cells, &|i, f| visit(i, &mut |c, v| f(c, (v - m[c]).abs())));
    m.into_iter().zip(mad).map(|(m, d)| (m, 1.4826 * d)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats;
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

    #[test]
    fn an_empty_cell_is_nan_and_one_value_is_itself() {
        let table = vec![vec![(1, 2.5)], vec![(1, f64::NAN)]];
        let (m, _) = run(&table, 3);
        assert!(m[0].is_nan() && m[2].is_nan());
        assert_eq!(m[1], 2.5);
    }

    proptest! {
        #[test]
        fn any_values_give_the_sorted_rank(values in prop::collection::vec((0usize..4, prop::num::f64::ANY), 0..3000), rank_frac in 0.0f64..1.0) {
            let table: Vec<Vec<(usize, f64)>> = values.chunks(3).map(|c| c.to_vec()).collect();
            let visit = |i: usize, f: &mut dyn FnMut(usize, f64)| table[i].iter().for_each(|&(c, v)| f(c, v));
            let rank = |_: usize, count: usize| (rank_frac * count as f64) as usize;
            // Narrowed down to bins of 2 values: every pass's edges are exercised.
            let got = select_collecting(table.len(), 4, &rank, &visit, 2);
            for c in 0..4 {
                let mut v: Vec<f64> = values.iter().filter(|(k, x)| *k == c && x.is_finite()).map(|(_, x)| *x).collect();
                v.sort_by(f64::total_cmp);
                let want = if v.is_empty() { f64::NAN } else { v[rank(c, v.len()).min(v.len() - 1)] };
                prop_assert!(same(got[c], want), "cell {}: {} vs {}", c, got[c], want);
            }
        }
    }
}
