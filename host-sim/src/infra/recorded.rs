//! A visit's values recorded once, for the passes over them that follow.
//!
//! The exact order statistics ([`super::select`]) and `diagnose`'s clipped means pass over
//! the same values several times: a median two passes, a median and its absolute deviation
//! four, a clipped mean six. Where an item's values are computed (a pixel's points: its
//! levels read a frame apart, its noise, the terms taken out), computing them again is
//! most of each pass. Recorded, each pass after the first reads them from memory.
//!
//! The replay gives each item's values in the order the visit gave them, so whatever is
//! computed from them (a tally, a sum added in item order) is the same bit for bit with
//! or without the recording. A recording holds at most [`most_bytes`]; a visit that gives
//! more is used as it is, pass after pass.

use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

/// The most a recording holds: 256 MiB, or a sixteenth of the memory budget
/// ([`super::budget::limit`]) where that is less. A cell and a value take 12 bytes (20 for
/// a pair of values), so 256 MiB holds a 256 x 256 set's 41 levels in two cells each
/// twice over; a 2048 x 2048 set's 344 million are visited as before, after a recording
/// that stopped at 256 MiB (a few percent of one pass).
pub fn most_bytes() -> usize {
    let budget = usize::try_from(super::budget::limit() / 16).unwrap_or(usize::MAX);
    budget.min(256 << 20)
}

/// Items `first..first + ends.len()` of a recording: item `first + j`'s values are
/// `values[ends[j - 1]..ends[j]]` (from 0 for `j = 0`), each with its cell.
struct Chunk<V> {
    first: usize,
    ends: Vec<u32>,
    cells: Vec<u32>,
    values: Vec<V>,
}

/// The values a visit gave items `0..n`, in chunks of consecutive items (one a thread).
pub struct Recorded<V> {
    chunks: Vec<Chunk<V>>,
}

/// A visit of values of type `V`: `f(cell, value)` for each of item `i`'s.
pub type VisitOf<'a, V> = dyn Fn(usize, &mut dyn FnMut(usize, V)) + Sync + 'a;

impl<V: Copy + Send + Sync> Recorded<V> {
    /// The values `visit` gives items `0..n`, recorded in one parallel pass; `None` where
    /// they come to more than `most` bytes (or a cell or count past `u32`).
    pub fn of(n: usize, visit: &VisitOf<'_, V>, most: usize) -> Option<Self> {
        let t = rayon::current_num_threads().clamp(1, n.max(1));
        // Each chunk's share of `most`, by capacity: grown by hand, never past it.
        let each = size_of::<V>() + size_of::<u32>();
        let per = (most / t / each).min(u32::MAX as usize);
        // Set by the first chunk past its share: the others stop at their next item.
        let stop = AtomicBool::new(false);
        let chunks: Option<Vec<Chunk<V>>> = (0..t)
            .into_par_iter()
            .map(|k| {
                let (first, last) = (k * n / t, (k + 1) * n / t);
                let mut c = Chunk { first, ends: Vec::with_capacity(last - first), cells: Vec::new(), values: Vec::new() };
                let mut over = false;
                for i in first..last {
                    visit(i, &mut |cell, v| {
                        if c.values.len() == c.values.capacity() {
                            let more = c.values.capacity().max(4096).min(per - c.values.len());
                            c.values.reserve_exact(more);
                            c.cells.reserve_exact(more);
                        }
                        match u32::try_from(cell) {
                            Ok(cell) if c.values.len() < per => {
                                c.cells.push(cell);
                                c.values.push(v);
                            }
                            _ => over = true,
                        }
                    });
                    if over || stop.load(Ordering::Relaxed) {
                        stop.store(true, Ordering::Relaxed);
                        return None;
                    }
                    c.ends.push(c.values.len() as u32);
                }
                Some(c)
            })
            .collect();
        chunks.map(|chunks| Recorded { chunks })
    }

    /// Item `i`'s values, in the order the visit gave them.
    pub fn visit(&self, i: usize, f: &mut dyn FnMut(usize, V)) {
        // Chunks start at strictly rising items (each holds one at least, but for n = 0).
        let k = self.chunks.partition_point(|c| c.first <= i);
        let Some(c) = k.checked_sub(1).map(|k| &self.chunks[k]) else { return };
        let j = i - c.first;
        let Some(&end) = c.ends.get(j) else { return };
        let start = if j == 0 { 0 } else { c.ends[j - 1] };
        for v in start as usize..end as usize {
            f(c.cells[v] as usize, c.values[v]);
        }
    }
}

/// `then` of a visit that gives what `visit` gives items `0..n`: its values recorded
/// where they fit [`most_bytes`], else `visit` itself.
pub fn within<V: Copy + Send + Sync, R>(n: usize, visit: &VisitOf<'_, V>, then: impl FnOnce(&VisitOf<'_, V>) -> R) -> R {
    match Recorded::of(n, visit, most_bytes()) {
        Some(rec) => then(&|i, f| rec.visit(i, f)),
        None => then(visit),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Item `i` gives `i % 5` values, cells and values from `i`.
    fn visit(i: usize, f: &mut dyn FnMut(usize, (f64, f64))) {
        for k in 0..i % 5 {
            f((i * 7 + k) % 13, (i as f64 + 0.5 * k as f64, -(k as f64)));
        }
    }

    fn all(n: usize, v: &VisitOf<'_, (f64, f64)>) -> Vec<(usize, usize, (f64, f64))> {
        let mut out = Vec::new();
        for i in 0..n {
            v(i, &mut |c, x| out.push((i, c, x)));
        }
        out
    }

    #[test]
    fn a_replay_gives_each_items_values_in_order() {
        for n in [0, 1, 2, 3, 17, 1000] {
            let rec = Recorded::of(n, &visit, 1 << 20).expect("fits");
            assert_eq!(all(n, &|i, f| rec.visit(i, f)), all(n, &visit), "{n} items");
            // Past the end: nothing.
            let mut none = 0;
            rec.visit(n, &mut |_, _| none += 1);
            assert_eq!(none, 0);
        }
    }

    #[test]
    fn too_many_values_are_not_recorded_and_within_still_gives_them() {
        // 1000 items give 2000 values of 20 bytes (40 000 bytes): 16 000 bytes is short,
        // 39 000 too (by the last item's values, on any number of threads).
        assert!(Recorded::of(1000, &visit, 16_000).is_none());
        assert!(Recorded::of(1000, &visit, 39_000).is_none());
        assert!(Recorded::of(1000, &visit, 1 << 20).is_some());
        let got = within(1000, &visit, |v| all(1000, v));
        assert_eq!(got, all(1000, &visit));
    }
}
