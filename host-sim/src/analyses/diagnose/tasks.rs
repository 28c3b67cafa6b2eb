//! Fixed task splits of items a pass picks from, without the list of those picked.
//!
//! A shared curve is summed over the good pixels of even rows that a group takes, in
//! [`super::TASKS`] tasks of consecutive picks (so that its sums are the same on every
//! run). The list of picks was 16 bytes for every other pixel, the last per-pixel state a
//! spilled diagnosis held; [`picked_tasks`] finds the same tasks by counting instead.

use rayon::prelude::*;

/// `task` of each of [`super::TASKS`] runs of the items `0..n` that `pick` takes, in
/// order: exactly `(0..n).filter_map(pick).collect::<Vec<_>>().par_chunks(m.div_ceil(TASKS).max(1)).map(task)`
/// for `m` picks, without the `Vec`. `pick` is called about three times an item (a count,
/// the skip to a task's first pick, the task's own).
pub(super) fn picked_tasks<X, S: Send>(n: usize, pick: impl Fn(usize) -> Option<X> + Sync, task: impl Fn(&mut dyn Iterator<Item = X>) -> S + Sync) -> Vec<S> {
    let tasks = super::TASKS;
    // Picks per run of the items, in the same fixed split.
    let run = n.div_ceil(tasks).max(1);
    let counts: Vec<usize> = (0..n.div_ceil(run)).into_par_iter().map(|r| (r * run..((r + 1) * run).min(n)).filter(|&j| pick(j).is_some()).count()).collect();
    // `before[r]`: picks before run `r`.
    let before: Vec<usize> = counts.iter().scan(0, |acc, &c| Some(std::mem::replace(acc, *acc + c))).collect();
    let m: usize = counts.iter().sum();
    let chunk = m.div_ceil(tasks).max(1);
    (0..m.div_ceil(chunk))
        .into_par_iter()
        .map(|t| {
            let (from, to) = (t * chunk, ((t + 1) * chunk).min(m));
            // The run holding pick `from`: the last whose first pick is at or before it.
            let r = before.partition_point(|&b| b <= from) - 1;
            let mut picks = (r * run..n).filter_map(&pick).skip(from - before[r]).take(to - from);
            task(&mut picks)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The tasks are those of the picks' list cut in chunks: same items, same order,
        /// same split (a float sum per task, compared bit for bit, shows both).
        #[test]
        fn the_tasks_are_the_chunks_of_the_picked_list(n in 0usize..3000, every in 1usize..9, seed in 0u64..1000) {
            let pick = |j: usize| (j as u64 * 2_654_435_761 + seed).is_multiple_of(every as u64).then(|| (j as f64).sqrt() * 1e-3 + j as f64);
            let list: Vec<f64> = (0..n).filter_map(pick).collect();
            let naive: Vec<(Vec<f64>, u64)> = list.par_chunks(list.len().div_ceil(crate::analyses::diagnose::TASKS).max(1)).map(|c| (c.to_vec(), c.iter().sum::<f64>().to_bits())).collect();
            let ours = picked_tasks(n, pick, |it| {
                let v: Vec<f64> = it.collect();
                let s = v.iter().sum::<f64>().to_bits();
                (v, s)
            });
            prop_assert_eq!(ours, naive);
        }
    }

    /// None picked: no task, as the chunks of an empty list.
    #[test]
    fn nothing_picked_is_no_task() {
        assert!(picked_tasks(100, |_| None::<f64>, |it| it.count()).is_empty());
        assert!(picked_tasks(0, Some, |it| it.count()).is_empty());
        assert_eq!(picked_tasks(5, Some, |it| it.count()), vec![1; 5]);
    }
}
