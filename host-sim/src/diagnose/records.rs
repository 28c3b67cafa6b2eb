//! Per-pixel records a diagnosis keeps from one pass to the next (each pixel's fits,
//! its held-out score under each model, its quartic through all its levels, the values
//! its population medians select from), held in memory or spilled to a temporary file
//! and read back a block per thread.
//!
//! Held, they were about 300 of the 342 bytes a pixel `diagnose` needed beyond the set
//! (2048 x 2048: 1.4 GB), so a sensor's size set the memory whatever the budget. Spilled,
//! the memory is a 256 KiB block of each kind per thread (its bytes, decoded as they are
//! read) and one per thread being written, and the records go to the disk (about 300
//! bytes a pixel there, in the page cache where it has room; a `TMPDIR` on tmpfs keeps
//! them in memory, outside the budget). The parallel passes read them in runs of
//! consecutive pixels, as they read the set ([`super::cubes`]), so a thread reads a
//! block about once a pass; the sequential ones (the paired tests, the shared curves'
//! choice of pixels, the bad-pixel count) read the file once each on one thread. The
//! records are written and read bit for bit (floats by their bits), so the diagnosis is
//! the same number for number either way (tested).

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

/// Bytes of records a thread holds of one kind while they are spilled.
const BLOCK_BYTES: usize = 256 << 10;

/// Kinds of records alive at once at most: a pixel's fits, the level term's fits, and
/// the scores of up to five models (and one being built).
const KINDS_AT_ONCE: u64 = 8;

/// Bytes a pixel's records take held: its fits on either half of its levels (120), the
/// level term's fits through its levels (72), its scores under up to five models at once
/// (24 each) and a pair of values for the population medians (16). Spilled, they go to
/// the disk (at [`Record::BYTES`] each).
pub const RECORD_BYTES: u64 = 120 + 72 + 5 * 24 + 16;

/// Bytes per pixel that stay in memory however its records are kept: the pixels' and the
/// good pixels' indices (16), each pixel's unsaturated levels and bad-pixel flags (4),
/// and the gains of the pixels a shared curve is fitted on (16 for half of them), with
/// room (2048 x 2048 by rows, records spilled: 183 MB resident in all, 34 bytes a pixel
/// beyond the blocks and the program).
pub const RESIDENT_BYTES: u64 = 40;

/// Bytes the blocks of spilled records of `pixels` pixels take at once: a block of
/// each kind per thread of the pool and one more, and a block per thread being written
/// (no larger than the records).
pub fn spilled_blocks(pixels: u64) -> u64 {
    let block = (BLOCK_BYTES as u64).min(pixels.saturating_mul(120));
    let threads = rayon::current_num_threads() as u64;
    (KINDS_AT_ONCE * (threads + 1) + threads) * block
}

/// A record as its bytes in a spill file: exactly [`Record::BYTES`] of them.
pub(super) trait Record: Copy + Send + Sync {
    /// Bytes a record takes.
    const BYTES: usize;
    /// What a record reads as where its file could not be read or written (the diagnosis
    /// then ends with that failure, [`Keep::failed`]): no fit, no score.
    const LOST: Self;
    /// Appends the record's [`Record::BYTES`] bytes.
    fn put(&self, out: &mut Put<'_>);
    /// The record whose bytes `from` starts with.
    fn take(from: &mut Take<'_>) -> Self;
}

/// Appends values little-endian, floats by their bits.
pub(super) struct Put<'b>(&'b mut Vec<u8>);

impl Put<'_> {
    pub fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub fn f32(&mut self, v: f32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
}

/// Reads back what [`Put`] wrote, in the same order (missing bytes read as zeros).
pub(super) struct Take<'b>(&'b [u8]);

impl Take<'_> {
    fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let mut b = [0u8; N];
        let n = self.0.len().min(N);
        b[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        b
    }
    pub fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.bytes())
    }
    pub fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.bytes())
    }
    pub fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.bytes())
    }
    pub fn u8(&mut self) -> u8 {
        self.bytes::<1>()[0]
    }
}

/// A pair of values a pixel (NaN where it has none).
impl Record for [f64; 2] {
    const BYTES: usize = 16;
    const LOST: [f64; 2] = [f64::NAN; 2];
    fn put(&self, out: &mut Put<'_>) {
        self.iter().for_each(|&v| out.f64(v));
    }
    fn take(from: &mut Take<'_>) -> Self {
        [from.f64(), from.f64()]
    }
}

/// A value a pixel, where it has one.
impl Record for Option<f64> {
    const BYTES: usize = 9;
    const LOST: Option<f64> = None;
    fn put(&self, out: &mut Put<'_>) {
        out.u8(u8::from(self.is_some()));
        out.f64(self.unwrap_or(f64::NAN));
    }
    fn take(from: &mut Take<'_>) -> Self {
        let some = from.u8() == 1;
        let v = from.f64();
        some.then_some(v)
    }
}

/// Where a diagnosis keeps its records, and the first failure of a spill file (the
/// diagnosis ends with it rather than with a report missing pixels).
#[derive(Debug, Clone, Default)]
pub(super) struct Keep {
    spill: bool,
    failed: Arc<Mutex<Option<String>>>,
}

impl Keep {
    /// Records in memory.
    pub fn held() -> Keep {
        Keep::default()
    }

    /// Records in temporary files.
    pub fn spilled() -> Keep {
        Keep { spill: true, ..Keep::default() }
    }

    /// Whether records go to temporary files.
    pub fn spills(&self) -> bool {
        self.spill
    }

    /// The first failure of a spill file, if any.
    pub fn failed(&self) -> Option<String> {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn fail(&self, message: String) {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(message);
    }
}

/// One record per pixel (by the caller's index), held or spilled.
pub(super) struct Records<R: Record> {
    len: usize,
    keep: Keep,
    store: Store<R>,
}

enum Store<R> {
    Held(Vec<R>),
    Spilled {
        /// `None` where the file could not be made (every record reads as lost).
        file: Option<File>,
        /// One block per thread of the pool, and one for any other thread.
        slots: Vec<Mutex<Cached>>,
        kind: std::marker::PhantomData<R>,
    },
}

/// The bytes of records `first..first + count` of a spilled store, decoded as they are
/// read (a decoded copy beside them doubled a block's memory); `lost` where the read
/// failed.
struct Cached {
    first: usize,
    count: usize,
    bytes: Vec<u8>,
    lost: bool,
}

impl Cached {
    /// Record `j`, one of these.
    fn record<R: Record>(&self, j: usize) -> R {
        match self.bytes.get((j - self.first) * R::BYTES..) {
            Some(b) if !self.lost => R::take(&mut Take(b)),
            _ => R::LOST,
        }
    }
}

impl<R: Record> std::fmt::Debug for Records<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Records").field("len", &self.len).field("spilled", &self.keep.spill).finish()
    }
}

impl<R: Record> Records<R> {
    /// Records per block of a spilled store.
    fn per_block() -> usize {
        (BLOCK_BYTES / R::BYTES.max(1)).max(1)
    }

    /// `n` records kept as `keep` says: record `j` is `each(j, state)`, in a fixed
    /// [`super::TASKS`] tasks of consecutive records, each with its own `state` from
    /// `init`, returned in task order (sums added in that order are the same whichever
    /// thread ran which task, and whether the records are held or spilled).
    pub fn build<S: Send>(keep: &Keep, n: usize, init: impl Fn() -> S + Sync, each: impl Fn(usize, &mut S) -> R + Sync) -> (Self, Vec<S>) {
        let chunk = n.div_ceil(super::TASKS).max(1);
        let keep = keep.clone();
        if !keep.spill {
            let mut all = vec![R::LOST; n];
            let states = all
                .par_chunks_mut(chunk)
                .enumerate()
                .map(|(c, out)| {
                    let mut state = init();
                    out.iter_mut().enumerate().for_each(|(k, slot)| *slot = each(c * chunk + k, &mut state));
                    state
                })
                .collect();
            return (Records { len: n, keep, store: Store::Held(all) }, states);
        }
        let empty = || Mutex::new(Cached { first: 0, count: 0, bytes: Vec::new(), lost: false });
        let slots = (0..=rayon::current_num_threads()).map(|_| empty()).collect();
        // After a failure nothing more is computed: the diagnosis ends with it.
        let file = match keep.failed() {
            Some(_) => None,
            None => tempfile::tempfile().map_err(|e| keep.fail(format!("creating a temporary file for the per-pixel records in {}: {e}", std::env::temp_dir().display()))).ok(),
        };
        let Some(file) = file else {
            let states = (0..n.div_ceil(chunk)).map(|_| init()).collect();
            return (Records { len: n, keep, store: Store::Spilled { file: None, slots, kind: std::marker::PhantomData } }, states);
        };
        let per_block = Self::per_block();
        let states = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let mut state = init();
                let mut bytes = Vec::with_capacity(per_block * R::BYTES);
                let mut first = c * chunk;
                for j in c * chunk..((c + 1) * chunk).min(n) {
                    each(j, &mut state).put(&mut Put(&mut bytes));
                    if bytes.len() != (j + 1 - first) * R::BYTES {
                        // A `put` that disagrees with `BYTES` would shift every record after.
                        keep.fail(format!("a per-pixel record wrote {} bytes, not {}", bytes.len() - (j - first) * R::BYTES, R::BYTES));
                        bytes.resize((j + 1 - first) * R::BYTES, 0);
                    }
                    if bytes.len() >= per_block * R::BYTES || j + 1 == ((c + 1) * chunk).min(n) {
                        if let Err(e) = file.write_all_at(&bytes, (first * R::BYTES) as u64) {
                            keep.fail(format!("writing the per-pixel records to a temporary file in {}: {e}", std::env::temp_dir().display()));
                        }
                        bytes.clear();
                        first = j + 1;
                        if keep.failed().is_some() {
                            break;
                        }
                    }
                }
                state
            })
            .collect();
        (Records { len: n, keep, store: Store::Spilled { file: Some(file), slots, kind: std::marker::PhantomData } }, states)
    }

    /// `n` records, record `j` being `f(j)` ([`Records::build`] without a state).
    pub fn from_fn(keep: &Keep, n: usize, f: impl Fn(usize) -> R + Sync) -> Self {
        Self::build(keep, n, || (), |j, _| f(j)).0
    }

    /// How these records are kept.
    pub fn keep(&self) -> &Keep {
        &self.keep
    }

    /// Record `j` ([`Record::LOST`] past the end, or where its file failed).
    pub fn at(&self, j: usize) -> R {
        if j >= self.len {
            return R::LOST;
        }
        let (file, slots) = match &self.store {
            Store::Held(all) => return all[j],
            Store::Spilled { file: Some(file), slots, .. } => (file, slots),
            Store::Spilled { file: None, .. } => return R::LOST,
        };
        let slot = rayon::current_thread_index().unwrap_or(slots.len() - 1) % slots.len();
        let mut cached = match slots[slot].try_lock() {
            Ok(c) => c,
            Err(std::sync::TryLockError::Poisoned(e)) => e.into_inner(),
            // A thread outside the pool while another holds the spare slot: the record alone.
            Err(std::sync::TryLockError::WouldBlock) => {
                let mut one = Cached { first: 0, count: 0, bytes: Vec::new(), lost: false };
                self.read(file, j..j + 1, &mut one);
                return one.record(j);
            }
        };
        if !(cached.first..cached.first + cached.count).contains(&j) {
            let first = j - j % Self::per_block();
            self.read(file, first..(first + Self::per_block()).min(self.len), &mut cached);
        }
        cached.record(j)
    }

    /// Records `span` into `into` (lost, and the failure recorded, where the read fails).
    fn read(&self, file: &File, span: std::ops::Range<usize>, into: &mut Cached) {
        into.bytes.resize(span.len() * R::BYTES, 0);
        (into.first, into.count) = (span.start, span.len());
        into.lost = match file.read_exact_at(&mut into.bytes, (span.start * R::BYTES) as u64) {
            Ok(()) => false,
            Err(e) => {
                self.keep.fail(format!("reading the per-pixel records back from their temporary file: {e}"));
                true
            }
        };
    }

    /// Every record, in order.
    pub fn iter(&self) -> impl Iterator<Item = R> + '_ {
        (0..self.len).map(|j| self.at(j))
    }
}

/// `record` written and read back: the same bits where `same` compares them, and
/// exactly [`Record::BYTES`] bytes (for the records' own tests).
#[cfg(test)]
pub(super) fn round_trip<R: Record>(record: R) -> R {
    let mut bytes = Vec::new();
    record.put(&mut Put(&mut bytes));
    assert_eq!(bytes.len(), R::BYTES);
    R::take(&mut Take(&bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, Copy, PartialEq)]
    struct Pair(f64, u16);

    impl Record for Pair {
        const BYTES: usize = 10;
        const LOST: Pair = Pair(f64::NAN, u16::MAX);
        fn put(&self, out: &mut Put<'_>) {
            out.f64(self.0);
            out.u16(self.1);
        }
        fn take(from: &mut Take<'_>) -> Self {
            Pair(from.f64(), from.u16())
        }
    }

    fn pair(j: usize) -> Pair {
        // Values whose bits matter: negative zero, subnormals, NaN payloads.
        let v = match j % 5 {
            0 => -0.0,
            1 => f64::from_bits(j as u64),
            2 => f64::from_bits(0x7ff8_0000_0000_0000 | j as u64),
            _ => (j as f64).sqrt() * if j % 2 == 0 { 1.0 } else { -1.0 },
        };
        Pair(v, (j % 65_536) as u16)
    }

    /// Spilled records read back bit for bit, in order, from the pool (rayon's splits),
    /// from outside it, and in a reversed order that misses the cache every block; the
    /// task states are the same as held, in task order; past the end reads as lost.
    #[test]
    fn spilled_records_read_back_as_held_ones() {
        let n = 3 * Records::<Pair>::per_block() + 17;
        let sum = |j: usize, s: &mut (usize, f64)| {
            s.0 += 1;
            s.1 += j as f64;
            pair(j)
        };
        let (held, hs) = Records::build(&Keep::held(), n, || (0, 0.0), sum);
        let (spilled, ss) = Records::build(&Keep::spilled(), n, || (0, 0.0), sum);
        assert_eq!(hs, ss);
        assert_eq!(hs.len(), n.div_ceil(n.div_ceil(super::super::TASKS)));
        assert_eq!(hs.iter().map(|s| s.0).sum::<usize>(), n);
        let bits = |p: Pair| (p.0.to_bits(), p.1);
        assert!(held.iter().map(bits).eq((0..n).map(|j| bits(pair(j)))));
        assert!(spilled.iter().map(bits).eq((0..n).map(|j| bits(pair(j)))));
        let par: Vec<_> = (0..n).into_par_iter().map(|j| bits(spilled.at(j))).collect();
        assert!(par.into_iter().eq((0..n).map(|j| bits(pair(j)))));
        assert!((0..n).rev().all(|j| bits(spilled.at(j)) == bits(pair(j))));
        assert_eq!(bits(spilled.at(n)), bits(Pair::LOST));
        assert_eq!(spilled.keep().failed(), None);
        assert_eq!(Records::<Pair>::from_fn(&Keep::spilled(), 0, pair).iter().count(), 0);
    }

    /// The blocks' size and what the budget counts for them, against their closed form: a
    /// block of each of 8 kinds per thread and one more, and one per writing thread, each
    /// 256 KiB or the records of a small set (120 bytes a pixel at most).
    #[test]
    fn the_spilled_blocks_are_counted_as_they_are_held() {
        assert_eq!(Records::<Pair>::per_block(), (256 << 10) / 10);
        let t = rayon::current_num_threads() as u64;
        assert_eq!(spilled_blocks(1 << 20), (8 * (t + 1) + t) * (256 << 10));
        assert_eq!(spilled_blocks(100), (8 * (t + 1) + t) * 12_000);
        assert_eq!(spilled_blocks(0), 0);
    }

    /// A nested read from inside the pool while the thread's slot is held (an `at` in
    /// the closure of another record's use) cannot happen with copies; a thread outside
    /// the pool whose spare slot is busy reads the record alone.
    #[test]
    fn a_busy_spare_slot_reads_the_record_alone() {
        let n = 2 * Records::<Pair>::per_block();
        let spilled = Records::from_fn(&Keep::spilled(), n, pair);
        let Store::Spilled { slots, .. } = &spilled.store else { panic!("not spilled") };
        let _busy = slots.last().unwrap().lock().unwrap();
        assert!(std::thread::scope(|s| s.spawn(|| (0..n).all(|j| spilled.at(j).0.to_bits() == pair(j).0.to_bits())).join().unwrap()));
    }
}
