//! Where a linearity set's values come from while it is diagnosed: held whole in memory
//! ([`LinearitySet`]) or read from its file a block of rows at a time
//! ([`LinearityRows`]), each thread keeping the block it read last.
//!
//! Every pass of the diagnosis visits the pixels in runs of consecutive pixels (a fixed
//! [`super::TASKS`] tasks, or rayon's splits of a range), so a thread reads each block
//! about once a pass and the memory is a block per thread whatever the sensor: a 2048 x
//! 2048 x 41-level set held as f32 is 1.4 GB, a block of it 8 MiB. The file is read once
//! a pass instead (from the page cache where it fits there); what the passes need of the
//! set is the same either way, value for value, so the diagnosis is the same number for
//! number (tested).

use std::ops::Range;
use std::sync::Mutex;

use rayon::prelude::*;

use crate::formats::fits::{LinearityRows, LinearitySet, Sample};

/// Bytes of values a block of rows holds (both cubes): a few MiB, in cache while its
/// pixels are fitted and small beside any budget.
const BLOCK_BYTES: usize = 8 << 20;

/// Rows a block holds for a set of `[width, height, levels]` read as `T` (`asked`, or
/// as many as fit [`BLOCK_BYTES`] and, all threads' blocks together, `room` bytes; at
/// least 1, at most the height), and the bytes of the blocks every thread may hold at
/// once (one per thread of the pool and one more).
pub fn blocks_of<T>([width, height, levels]: [usize; 3], asked: Option<usize>, room: u64) -> (usize, u64) {
    let row_bytes = (2 * levels * width * std::mem::size_of::<T>()).max(1);
    let slots = (rayon::current_num_threads() + 1) as u64;
    let fitting = (room / slots / row_bytes as u64).min(usize::MAX as u64) as usize;
    let rows = asked.unwrap_or((BLOCK_BYTES / row_bytes).min(fitting)).clamp(1, height.max(1));
    (rows, slots.saturating_mul((rows * row_bytes) as u64))
}

/// A linearity set as the diagnosis reads it: its keys and reference, and its cubes,
/// held or in the file.
pub(super) struct SetView<'a, T: Sample> {
    /// Bits per code of the camera.
    pub bit_depth: u32,
    /// ADCs of the camera; column `c` is read by ADC `c mod n_adc`.
    pub n_adc: usize,
    /// Frames averaged at each level.
    pub n_frames: u32,
    /// Columns per frame.
    pub width: usize,
    /// Rows per frame.
    pub height: usize,
    /// Illumination levels read (those of the file from [`SetView::skip_levels`] on);
    /// level 0 is dark where its reference is zero.
    pub levels: usize,
    /// Reference photodiode voltage of each level in V.
    pub voltage: &'a [f64],
    /// Known bad pixels, 1 = bad.
    pub mask: Option<&'a [u8]>,
    /// What the file says of its pixels beyond their values (a Bayer layout).
    pub keys: crate::formats::fits::SetKeys,
    /// The file's levels left out below level 0 ([`SetView::skip_levels`]).
    skip: usize,
    cubes: Cubes<'a, T>,
}

enum Cubes<'a, T: Sample> {
    Held {
        mean: &'a [T],
        std: &'a [T],
        /// One run of pixels a thread of the pool (and one for any other thread), its
        /// levels side by side ([`Tile`]).
        tiles: Vec<Mutex<Tile<T>>>,
    },
    Rows {
        file: &'a LinearityRows,
        /// Rows per block.
        rows: usize,
        /// One block per thread of the pool, and one for any other thread.
        slots: Vec<Mutex<Block<T>>>,
        /// The first read that failed: its pixels read as NaN (left out of every fit),
        /// and the diagnosis ends with this error ([`SetView::failed`]).
        failed: Mutex<Option<String>>,
    },
}

/// Rows `first..first + rows` of both cubes, level-major.
struct Block<T> {
    first: usize,
    rows: usize,
    mean: Vec<T>,
    std: Vec<T>,
    bytes: Vec<u8>,
}

/// Bytes of a [`Tile`]: a megabyte, in a core's second-level cache on the machines
/// measured while its pixels are fitted.
const TILE_BYTES: usize = 1 << 20;

/// Consecutive pixels of a held set with each pixel's levels side by side (the cubes are
/// level-major): a pass that visits a pixel's levels one after another read them a frame
/// apart, and at a frame of a power of two bytes (128 x 128 pixels, 2048 x 2048) all of
/// them fell in the same sets of the caches, a load that stalled a fifth of a
/// diagnosis. Copied level by level from the cubes, where the reads are consecutive.
struct Tile<T> {
    first: usize,
    pixels: usize,
    mean: Vec<T>,
    std: Vec<T>,
}

/// Bytes the tiles of a held set's diagnosis take, every thread's.
pub fn tile_bytes() -> u64 {
    ((rayon::current_num_threads() + 1) * TILE_BYTES) as u64
}

/// The calling thread's slot of `slots` (one a thread of the pool, the last for any other
/// thread), locked; `None` where it is in use (by an enclosing call on the same thread, or
/// by another thread outside the pool). A slot poisoned by a panic is taken: its holder
/// marks it empty while it fills it.
fn thread_slot<S>(slots: &[Mutex<S>]) -> Option<std::sync::MutexGuard<'_, S>> {
    let slot = rayon::current_thread_index().unwrap_or(slots.len() - 1) % slots.len();
    match slots[slot].try_lock() {
        Ok(s) => Some(s),
        Err(std::sync::TryLockError::Poisoned(e)) => Some(e.into_inner()),
        Err(std::sync::TryLockError::WouldBlock) => None,
    }
}

/// The levels of one pixel: level `l` at `(skip + l) * stride + at` of each cube.
#[derive(Clone, Copy)]
pub(super) struct Levels<'b, T> {
    mean: &'b [T],
    std: &'b [T],
    stride: usize,
    at: usize,
    skip: usize,
}

impl<T: Sample> Levels<'_, T> {
    /// The mean at `level`, DN.
    pub fn mean(&self, level: usize) -> f64 {
        self.mean[(self.skip + level) * self.stride + self.at].into()
    }

    /// The frames' standard deviation at `level`, DN.
    pub fn std(&self, level: usize) -> f64 {
        self.std[(self.skip + level) * self.stride + self.at].into()
    }
}

/// Some rows of a set: pixel `p` of the frame (in `rows`) at `level` is at
/// `(skip + level) * stride + p - offset` of each cube.
pub(super) struct Rows<'b, T> {
    pub rows: Range<usize>,
    mean: &'b [T],
    std: &'b [T],
    stride: usize,
    offset: usize,
    skip: usize,
}

impl<T: Sample> Rows<'_, T> {
    /// The levels of pixel `p` of the frame, a pixel of these rows.
    pub fn pixel(&self, p: usize) -> Levels<'_, T> {
        Levels { mean: self.mean, std: self.std, stride: self.stride, at: p - self.offset, skip: self.skip }
    }
}

impl<'a, T: Sample> SetView<'a, T> {
    /// A set held whole.
    pub fn held(set: &'a LinearitySet<T>) -> Self {
        SetView {
            bit_depth: set.bit_depth,
            n_adc: set.n_adc,
            n_frames: set.n_frames,
            width: set.width,
            height: set.height,
            levels: set.levels,
            voltage: &set.voltage,
            mask: set.mask.as_deref(),
            keys: set.keys,
            skip: 0,
            cubes: Cubes::Held { mean: &set.mean, std: &set.std, tiles: (0..=rayon::current_num_threads()).map(|_| Mutex::new(Tile { first: usize::MAX, pixels: 0, mean: Vec::new(), std: Vec::new() })).collect() },
        }
    }

    /// A set read from its file `rows` rows at a time (`None`: as many as fit
    /// [`BLOCK_BYTES`]; see [`blocks_of`]).
    pub fn rows(file: &'a LinearityRows, rows: Option<usize>) -> Self {
        let (rows, _) = blocks_of::<T>([file.width, file.height, file.levels], rows, u64::MAX);
        let empty = || Mutex::new(Block { first: usize::MAX, rows: 0, mean: Vec::new(), std: Vec::new(), bytes: Vec::new() });
        SetView {
            bit_depth: file.bit_depth,
            n_adc: file.n_adc,
            n_frames: file.n_frames,
            width: file.width,
            height: file.height,
            levels: file.levels,
            voltage: &file.voltage,
            mask: file.mask.as_deref(),
            keys: file.keys,
            skip: 0,
            cubes: Cubes::Rows { file, rows, slots: (0..=rayon::current_num_threads()).map(|_| empty()).collect(), failed: Mutex::new(None) },
        }
    }

    /// The view from the file's level `k` on (its levels below left out: levels the
    /// camera clipped at code 0, [`super::linearity::clip`]); level `l` of the view is
    /// the file's `k + l`. Levels already left out count: `k` is the view's.
    pub fn skip_levels(&mut self, k: usize) {
        let k = k.min(self.levels);
        self.skip += k;
        self.levels -= k;
        self.voltage = &self.voltage[k..];
    }

    /// Pixels per frame.
    pub fn frame(&self) -> usize {
        self.width * self.height
    }

    /// `f` of the levels of pixel `p` of the frame. (Where its thread's block is in use,
    /// `f` running for another pixel of the same thread, the pixel alone is read.)
    pub fn with_pixel<R>(&self, p: usize, f: impl FnOnce(Levels<'_, T>) -> R) -> R {
        let (file, failed) = match &self.cubes {
            Cubes::Held { mean, std, tiles } => return self.with_tile(mean, std, tiles, p, f),
            Cubes::Rows { file, failed, .. } => (file, failed),
        };
        let row = p / self.width;
        let mut f = Some(f);
        let held = self.with_block(row, |b| f.take().map(|f| f(Levels { mean: &b.mean, std: &b.std, stride: b.rows * self.width, at: p - b.first * self.width, skip: self.skip })));
        if let Some(Some(r)) = held {
            return r;
        }
        let mut one = Block { first: row, rows: 1, mean: Vec::new(), std: Vec::new(), bytes: Vec::new() };
        if let Err(e) = file.read_pixel(p, &mut one.mean, &mut one.std, &mut one.bytes) {
            Self::fail(failed, &mut one, self.skip + self.levels, format!("reading pixel {p} of the set: {e}"));
        }
        let f = f.take().expect("with_block did not call f: it returned None");
        f(Levels { mean: &one.mean, std: &one.std, stride: 1, at: 0, skip: self.skip })
    }

    /// `f` of the levels of pixel `p` of a held set, from the calling thread's tile
    /// (filled with the run of pixels holding `p` where it holds another); from the cubes
    /// where that tile is in use (by `f` of an enclosing call on the same thread).
    fn with_tile<R>(&self, mean: &[T], std: &[T], tiles: &[Mutex<Tile<T>>], p: usize, f: impl FnOnce(Levels<'_, T>) -> R) -> R {
        let frame = self.frame();
        let Some(mut tile) = thread_slot(tiles) else { return f(Levels { mean, std, stride: frame, at: p, skip: self.skip }) };
        // Every level of the file, the skipped ones too (`skip` counts in the index).
        let levels = (mean.len() / frame.max(1)).max(1);
        if !(tile.first..tile.first.saturating_add(tile.pixels)).contains(&p) {
            let run = (TILE_BYTES / (2 * levels * std::mem::size_of::<T>())).max(1);
            let first = p - p % run;
            let pixels = run.min(frame - first);
            let t = &mut *tile;
            (t.first, t.pixels) = (usize::MAX, 0);
            for (to, from) in [(&mut t.mean, mean), (&mut t.std, std)] {
                to.clear();
                to.resize(pixels * levels, T::from_f64(0.0));
                // Runs of 64 pixels, every level of a run before the next: what is written
                // stays in the first cache while it is, each level's run read whole.
                for start in (0..pixels).step_by(64) {
                    let n = 64.min(pixels - start);
                    let into = &mut to[start * levels..][..n * levels];
                    for l in 0..levels {
                        for (k, v) in from[l * frame + first + start..][..n].iter().enumerate() {
                            into[k * levels + l] = *v;
                        }
                    }
                }
            }
            (t.first, t.pixels) = (first, pixels);
        }
        f(Levels { mean: &tile.mean, std: &tile.std, stride: 1, at: (p - tile.first) * levels, skip: self.skip })
    }

    /// `f` of the block holding `row`, read into the calling thread's slot; `None` where
    /// that slot is in use (by `f` of an enclosing call on the same thread, or by another
    /// thread outside the pool). Only for a set read by rows.
    fn with_block<R>(&self, row: usize, f: impl FnOnce(&Block<T>) -> R) -> Option<R> {
        let Cubes::Rows { file, rows, slots, failed } = &self.cubes else { return None };
        let mut block = thread_slot(slots)?;
        if !(block.first..block.first + block.rows).contains(&row) {
            let first = row - row % rows;
            let span = first..(first + rows).min(self.height);
            let b = &mut *block;
            // Marked empty while it is read: a panic in between leaves no block that
            // claims rows it does not hold.
            (b.first, b.rows) = (usize::MAX, 0);
            self.read_block(file, failed, span.clone(), b);
            (b.first, b.rows) = (span.start, span.len());
        }
        Some(f(&block))
    }

    /// Rows `span` of both cubes into `block`'s buffers; where the read fails, NaN
    /// (which every fit leaves out) and the first failure recorded.
    fn read_block(&self, file: &LinearityRows, failed: &Mutex<Option<String>>, span: Range<usize>, block: &mut Block<T>) {
        if let Err(e) = file.read_rows(span.clone(), &mut block.mean, &mut block.std, &mut block.bytes) {
            Self::fail(failed, block, (self.skip + self.levels) * self.width * span.len(), format!("reading rows {} to {} of the set: {e}", span.start, span.end - 1));
        }
    }

    /// Records the first failed read and fills `block` with `n` NaN a cube.
    fn fail(failed: &Mutex<Option<String>>, block: &mut Block<T>, n: usize, message: String) {
        failed.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(message);
        block.mean = vec![T::from_f64(f64::NAN); n];
        block.std = vec![T::from_f64(f64::NAN); n];
    }

    /// `f` of each block of rows, in parallel, the results in row order: the passes that
    /// go level by level over the pixels of a block (the cubes are level-major).
    pub fn blocks<R: Send>(&self, f: impl Fn(&Rows<'_, T>) -> R + Sync) -> Vec<R> {
        let rows = match &self.cubes {
            Cubes::Held { .. } => self.height.div_ceil(super::TASKS).max(1),
            Cubes::Rows { rows, .. } => *rows,
        };
        (0..self.height.div_ceil(rows))
            .into_par_iter()
            .map(|b| {
                let span = b * rows..((b + 1) * rows).min(self.height);
                let of = |b: &Block<T>| f(&Rows { rows: span.clone(), mean: &b.mean, std: &b.std, stride: b.rows * self.width, offset: b.first * self.width, skip: self.skip });
                match &self.cubes {
                    Cubes::Held { mean, std, .. } => f(&Rows { rows: span.clone(), mean, std, stride: self.frame(), offset: 0, skip: self.skip }),
                    // The block holding the span's first row is the span (spans are
                    // blocks); where the thread's slot is in use, a block of its own.
                    Cubes::Rows { file, failed, .. } => self.with_block(span.start, of).unwrap_or_else(|| {
                        let mut own = Block { first: span.start, rows: span.len(), mean: Vec::new(), std: Vec::new(), bytes: Vec::new() };
                        self.read_block(file, failed, span.clone(), &mut own);
                        of(&own)
                    }),
                }
            })
            .collect()
    }

    /// Rows a block, for a set read by rows.
    pub fn block_rows(&self) -> Option<usize> {
        match &self.cubes {
            Cubes::Held { .. } => None,
            Cubes::Rows { rows, .. } => Some(*rows),
        }
    }

    /// Why reading the set failed, if it did.
    pub fn failed(&self) -> Option<String> {
        match &self.cubes {
            Cubes::Held { .. } => None,
            Cubes::Rows { failed, .. } => failed.lock().unwrap_or_else(|e| e.into_inner()).clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::fits::{open_linearity_rows, read_linearity_as, write_linearity};
    use crate::model::hidden::{linearity_set, Plant};

    /// Blocks of 8 MiB, fewer rows where the budget left is smaller (all threads' blocks
    /// within it), at least one row and at most the frame; the bytes they take.
    #[test]
    fn blocks_fill_8_mib_or_the_room_left() {
        let slots = (rayon::current_num_threads() + 1) as u64;
        // 2048 x 41 levels as f32, two cubes: 671,744 bytes a row, 12 rows in 8 MiB.
        let row = 2 * 41 * 2048 * 4;
        assert_eq!(blocks_of::<f32>([2048, 2048, 41], None, u64::MAX), (12, slots * 12 * row));
        assert_eq!(blocks_of::<f64>([2048, 2048, 41], None, u64::MAX).0, 6);
        assert_eq!(blocks_of::<f32>([2048, 2048, 41], None, slots * 5 * row + 1).0, 5);
        assert_eq!(blocks_of::<f32>([2048, 2048, 41], None, 0).0, 1, "at least a row");
        assert_eq!(blocks_of::<f32>([64, 10, 41], None, u64::MAX).0, 10, "at most the frame");
        assert_eq!(blocks_of::<f32>([2048, 2048, 41], Some(100), 0), (100, slots * 100 * row), "asked: taken, and counted");
    }

    /// A held set's pixels through the threads' runs of pixels are the cubes' values, in
    /// order and out of it, across runs, nested (the inner call reads the cubes), and
    /// with levels skipped.
    #[test]
    fn a_held_sets_runs_of_pixels_are_its_values() {
        let set = linearity_set(&Plant { width: 100, height: 70, levels: 11, ..Plant::default() }, &[], 3);
        let np = 100 * 70;
        // (f64, 11 levels: runs of 5957 pixels, two in the frame.)
        assert!(TILE_BYTES / (2 * 11 * 8) < np);
        let direct = |p: usize, skip: usize| (skip..11).map(|l| (set.mean[l * np + p], set.std[l * np + p])).collect::<Vec<_>>();
        let mut view = SetView::held(&set);
        let all = |v: &SetView<f64>, p: usize| v.with_pixel(p, |a| (0..v.levels).map(|l| (a.mean(l), a.std(l))).collect::<Vec<_>>());
        for p in [0, 1, 5956, 5957, 6999, 3, 6500, 0] {
            assert_eq!(all(&view, p), direct(p, 0), "pixel {p}");
            let q = np - 1 - p;
            let (outer, inner) = view.with_pixel(p, |a| ((0..11).map(|l| (a.mean(l), a.std(l))).collect::<Vec<_>>(), all(&view, q)));
            assert_eq!((outer, inner), (direct(p, 0), direct(q, 0)), "pixels {p} and {q}");
        }
        assert!((0..np).into_par_iter().all(|p| all(&view, p) == direct(p, 0)));
        view.skip_levels(2);
        assert!((0..np).into_par_iter().all(|p| all(&view, p) == direct(p, 2)));
    }

    /// Every value read by rows is the held set's: through a thread's block, through the
    /// one-pixel read a nested call falls back to, and through `blocks`.
    #[test]
    fn values_read_by_rows_are_the_held_values_however_they_are_reached() {
        let set = linearity_set(&Plant { width: 24, height: 10, levels: 11, ..Plant::default() }, &[], 2);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("set.fits");
        write_linearity(&path, &set).unwrap();
        let held_set = read_linearity_as::<f32>(&path).unwrap();
        let rows = open_linearity_rows(&path).unwrap().unwrap().check::<f32>().unwrap();
        let (held, by_rows) = (SetView::held(&held_set), SetView::<f32>::rows(&rows, Some(3)));
        let all = |v: &SetView<f32>, p: usize| v.with_pixel(p, |a| (0..11).map(|l| (a.mean(l), a.std(l))).collect::<Vec<_>>());
        for p in [0, 23, 24, 100, 239] {
            let want = all(&held, p);
            assert_eq!(all(&by_rows, p), want, "pixel {p}");
            // Nested: the inner call finds the thread's block in use and reads the pixel.
            let q = 239 - p;
            let (outer, inner) = by_rows.with_pixel(p, |a| ((0..11).map(|l| (a.mean(l), a.std(l))).collect::<Vec<_>>(), all(&by_rows, q)));
            assert_eq!((outer, inner), (want, all(&held, q)), "pixels {p} and {q}");
        }
        let sums = |v: &SetView<f32>| v.blocks(|b| b.rows.clone().flat_map(|r| (0..24).map(move |c| r * 24 + c)).map(|p| (0..11).map(|l| b.pixel(p).mean(l) + 2.0 * b.pixel(p).std(l)).sum::<f64>()).collect::<Vec<_>>()).concat();
        assert_eq!(sums(&by_rows), sums(&held));
        assert_eq!(sums(&held).len(), 240);
        assert!(by_rows.failed().is_none());
    }
}
