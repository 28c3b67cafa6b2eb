//! A visit's values recorded once, for the passes over them that follow.
//!
//! The exact order statistics ([`super::select`]) and `diagnose`'s clipped means pass over
//! the same values several times: a median two passes, a median and its absolute deviation
//! four, a clipped mean six. Where an item's values are computed (a pixel's points: its
//! levels read a frame apart, its noise, the terms taken out), computing them again is
//! most of each pass. Recorded, every pass reads them from memory instead.
//!
//! The items are split in one run of consecutive items a thread; each run records its
//! items in order until its share of [`most_bytes`] is full, and a pass replays the items
//! recorded and visits the rest. So nothing recorded is lost where the values do not all
//! fit (a 2048 x 2048 set's: the first few percent are replayed), and each item's values
//! come in the order the visit gave them: whatever is computed from them (a tally, a sum
//! added in item order) is the same bit for bit with or without the recording.
//!
//! A recording is beyond what a command's memory plan counts ([`super::budget`]): at most
//! a sixteenth of the budget, "somewhat more than it checked".

use rayon::prelude::*;

/// The most a recording holds: 256 MiB, or a sixteenth of the memory budget
/// ([`super::budget::limit`]) where that is less. A cell and a value take 12 bytes (20 for
/// a pair of values) and an item 4 more, so 256 MiB holds a 256 x 256 set's 41 levels in
/// two cells each twice over, about two thirds of a 512 x 512 set's clipped-mean
/// residuals and 3% of a 2048 x 2048 set's.
pub fn most_bytes() -> usize {
    let budget = usize::try_from(super::budget::limit() / 16).unwrap_or(usize::MAX);
    budget.min(256 << 20)
}

/// Items `first..first + ends.len()` of a run, recorded: item `first + j`'s values are
/// `values[ends[j - 1]..ends[j]]` (from 0 for `j = 0`), each with its cell. The run's
/// items from `first + ends.len()` to `last` are not recorded.
struct Chunk<V> {
    first: usize,
    last: usize,
    ends: Vec<u32>,
    cells: Vec<u32>,
    values: Vec<V>,
}

/// The values a visit gave items `0..n`, in runs of consecutive items (one a thread),
/// each recorded from its start as far as its share allowed.
pub struct Recorded<V> {
    chunks: Vec<Chunk<V>>,
}

/// A visit of values of type `V`: `f(cell, value)` for each of item `i`'s.
pub type VisitOf<'a, V> = dyn Fn(usize, &mut dyn FnMut(usize, V)) + Sync + 'a;

impl<V: Copy + Send + Sync> Recorded<V> {
    /// The values `visit` gives items `0..n`, recorded in one parallel pass, at most
    /// `most` bytes (by capacity, items' ends included): each run stops at the first item
    /// whose values would pass its share (that item and the rest are not recorded).
    pub fn of(n: usize, visit: &VisitOf<'_, V>, most: usize) -> Self {
        let t = rayon::current_num_threads().clamp(1, n.max(1));
        let each = size_of::<V>() + size_of::<u32>();
        let chunks = (0..t)
            .into_par_iter()
            .map(|k| {
                let (first, last) = (k * n / t, (k + 1) * n / t);
                // The run's share less its items' ends, in values.
                let share = (most / t).saturating_sub((last - first) * size_of::<u32>());
                let per = (share / each).min(u32::MAX as usize);
                let mut c = Chunk { first, last, ends: Vec::with_capacity(if per > 0 { last - first } else { 0 }), cells: Vec::new(), values: Vec::new() };
                for i in first..last {
                    let mut over = false;
                    visit(i, &mut |cell, v| {
                        if over {
                            return;
                        }
                        if c.values.len() == c.values.capacity() {
                            // Grown by hand, never past the share.
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
                    if over {
                        // This item's values in part: dropped, and the run ends here.
                        let kept = c.ends.last().map_or(0, |&e| e as usize);
                        c.values.truncate(kept);
                        c.cells.truncate(kept);
                        break;
                    }
                    c.ends.push(c.values.len() as u32);
                }
                c
            })
            .collect();
        Recorded { chunks }
    }

    /// Items recorded, of all.
    pub fn items(&self) -> usize {
        self.chunks.iter().map(|c| c.ends.len()).sum()
    }

    /// Item `i`'s values, in the order the visit gave them: replayed where recorded, else
    /// from `visit` (the visit recorded from).
    pub fn visit(&self, i: usize, f: &mut dyn FnMut(usize, V), visit: &VisitOf<'_, V>) {
        // Runs start at strictly rising items (each holds one at least, but for n = 0).
        let k = self.chunks.partition_point(|c| c.first <= i);
        let Some(c) = k.checked_sub(1).map(|k| &self.chunks[k]).filter(|c| i < c.last) else { return };
        let j = i - c.first;
        let Some(&end) = c.ends.get(j) else { return visit(i, f) };
        let start = if j == 0 { 0 } else { c.ends[j - 1] };
        for v in start as usize..end as usize {
            f(c.cells[v] as usize, c.values[v]);
        }
    }
}

/// `then` of a visit that gives what `visit` gives items `0..n`, with the values recorded
/// as far as [`most_bytes`] allows (none recorded: `visit` itself).
pub fn within<V: Copy + Send + Sync, R>(n: usize, visit: &VisitOf<'_, V>, then: impl FnOnce(&VisitOf<'_, V>) -> R) -> R {
    let rec = Recorded::of(n, visit, most_bytes());
    if rec.items() == 0 {
        drop(rec);
        return then(visit);
    }
    then(&|i, f| rec.visit(i, f, visit))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

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
            let rec = Recorded::of(n, &visit, 1 << 20);
            assert_eq!(rec.items(), n, "{n} items, all recorded");
            // A replay that never visits: every item's values from the recording.
            let never = |_: usize, _: &mut dyn FnMut(usize, (f64, f64))| panic!("visited");
            assert_eq!(all(n, &|i, f| rec.visit(i, f, &never)), all(n, &visit), "{n} items");
            // Past the end: nothing.
            let mut none = 0;
            rec.visit(n, &mut |_, _| none += 1, &visit);
            assert_eq!(none, 0);
        }
    }

    /// 1000 items give 2000 values of 20 bytes and 4 bytes an item: 44 000 bytes.
    #[test]
    fn a_recording_short_of_room_replays_what_it_holds_and_visits_the_rest() {
        for most in [0, 100, 16_000, 43_000] {
            let rec = Recorded::of(1000, &visit, most);
            assert!(rec.items() < 1000, "{most} bytes");
            if most >= 16_000 {
                assert!(rec.items() > 0, "{most} bytes: some recorded");
            }
            let visits = AtomicUsize::new(0);
            let counted = |i: usize, f: &mut dyn FnMut(usize, (f64, f64))| {
                visits.fetch_add(1, Ordering::Relaxed);
                visit(i, f)
            };
            assert_eq!(all(1000, &|i, f| rec.visit(i, f, &counted)), all(1000, &visit), "{most} bytes");
            assert_eq!(visits.load(Ordering::Relaxed), 1000 - rec.items(), "{most} bytes: only the items not recorded visited");
        }
        assert_eq!(Recorded::of(1000, &visit, 44_000 * 2).items(), 1000);
        let got = within(1000, &visit, |v| all(1000, v));
        assert_eq!(got, all(1000, &visit));
    }
}
