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
//! block about once a pass; the sequential ones (the paired tests, the list of good
//! pixels, the bad-pixel count) read the file once each on one thread. The
//! records are written and read bit for bit (floats by their bits), so the diagnosis is
//! the same number for number either way (tested).

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::cell::RefCell;
use std::sync::{Arc, Mutex, Weak};

use rayon::prelude::*;

/// Bytes of records a thread holds of one kind while they are spilled.
const BLOCK_BYTES: usize = 256 << 10;

/// Kinds of records alive at once at most: a pixel's fits, the level term's fits, the
/// scores of up to five models (and one being built), a pair of values for the
/// population medians, and the pixels' unsaturated levels, indices, good pixels' indices
/// and bad-pixel flags.
const KINDS_AT_ONCE: u64 = 13;

/// Bytes a pixel's records take held: its fits on either half of its levels (120), the
/// level term's fits through its levels and its frame variance over them (200), its scores under up to five models at once
/// (24 each), a pair of values for the population medians (16), its unsaturated levels
/// (2), its index and its index among the good pixels (4 each) and its bad-pixel flags
/// (2). Spilled, they go to the disk (at [`Record::BYTES`] each).
pub const RECORD_BYTES: u64 = 120 + 200 + 5 * 24 + 16 + 2 + 4 + 4 + 2;

/// Bytes per pixel that stay in memory however its records are kept: the set's
/// bad-pixel mask where it has one (held beside the blocks when the set is read by rows).
/// Nothing else a diagnosis keeps grows with the sensor once its records are spilled
/// (2048 x 2048 by rows, records spilled: 89 MB resident in all, against 183 MB when
/// the indices, the levels below saturation, the flags and a shared curve's list of
/// pixels stayed, 34 bytes a pixel). The recordings of a pass's values
/// ([`crate::infra::recorded`]) add up to a sixteenth of the budget while a selection or a
/// clipped mean runs, whatever the sensor (64 MiB under `--max-memory 1G`; the 89 MB was
/// measured before them).
pub const RESIDENT_BYTES: u64 = 1;

/// Bytes the blocks of spilled records of `pixels` pixels take at once: a block of
/// each kind per thread of the pool and one more (a thread outside it), and a block
/// being written per thread of the pool and one more (no larger than the records).
pub fn spilled_blocks(pixels: u64) -> u64 {
    let block = (BLOCK_BYTES as u64).min(pixels.saturating_mul(120));
    let threads = rayon::current_num_threads() as u64;
    (KINDS_AT_ONCE + 1) * (threads + 1) * block
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
    pub fn u32(&mut self, v: u32) {
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
    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
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

/// A count a pixel (its levels below saturation); lost, none.
impl Record for u16 {
    const BYTES: usize = 2;
    const LOST: u16 = 0;
    fn put(&self, out: &mut Put<'_>) {
        out.u16(*self);
    }
    fn take(from: &mut Take<'_>) -> Self {
        from.u16()
    }
}

/// An index of a pixel (sets of up to `u32::MAX` pixels, checked by the diagnosis's
/// `prepare`);
/// lost, pixel 0 (a valid index, so that nothing reads out of bounds before the
/// diagnosis ends with the failure).
impl Record for u32 {
    const BYTES: usize = 4;
    const LOST: u32 = 0;
    fn put(&self, out: &mut Put<'_>) {
        out.u32(*self);
    }
    fn take(from: &mut Take<'_>) -> Self {
        from.u32()
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
        /// The store's identity in the threads' caches ([`BLOCKS`]), which keep a `Weak`
        /// of it: whether the store is still there (a block of a dropped store is the
        /// first to make room), and while one is kept, no other store's address.
        alive: Arc<()>,
        kind: std::marker::PhantomData<R>,
    },
}

thread_local! {
    /// This thread's blocks of spilled records: a block per store at most, and at most
    /// [`KINDS_AT_ONCE`] in all, in the order they were loaded. A new store's block takes
    /// the place of a dropped store's, else of the one loaded longest ago. A thread
    /// reads its own without a lock (the mutex a store kept per thread cost 8% of a
    /// diagnosis's time at 512 x 512).
    static BLOCKS: RefCell<Vec<Cached>> = const { RefCell::new(Vec::new()) };
}

/// The bytes of records `first..first + count` of the spilled store `store` is of,
/// decoded as they are read (a decoded copy beside them doubled a block's memory); `lost`
/// where the read failed.
struct Cached {
    store: Weak<()>,
    first: usize,
    count: usize,
    bytes: Vec<u8>,
    lost: bool,
}

impl Cached {
    fn empty() -> Self {
        Cached { store: Weak::new(), first: 0, count: 0, bytes: Vec::new(), lost: false }
    }

    /// Whether these are of the store `alive` identifies.
    fn of(&self, alive: &Arc<()>) -> bool {
        std::ptr::eq(self.store.as_ptr(), Arc::as_ptr(alive))
    }

    /// Whether record `j` of that store is one of these.
    fn holds(&self, alive: &Arc<()>, j: usize) -> bool {
        self.of(alive) && (self.first..self.first + self.count).contains(&j)
    }

    /// Record `j`, one of these.
    fn record<R: Record>(&self, j: usize) -> R {
        match self.bytes.get((j - self.first) * R::BYTES..) {
            Some(b) if !self.lost => R::take(&mut Take(b)),
            _ => R::LOST,
        }
    }
}

/// A spilled store's block on this thread goes with it (other threads' make room for
/// the next stores they read).
impl<R: Record> Drop for Records<R> {
    fn drop(&mut self) {
        if let Store::Spilled { alive, .. } = &self.store {
            let _ = BLOCKS.try_with(|blocks| blocks.try_borrow_mut().map(|mut b| b.retain(|c| !c.of(alive))));
        }
    }
}

/// Frees every thread's blocks of dropped stores (at the end of a spilled diagnosis:
/// else they stay until a thread reads another store).
pub(super) fn release() {
    let free = || {
        let _ = BLOCKS.try_with(|blocks| blocks.try_borrow_mut().map(|mut b| b.retain(|c| c.store.strong_count() > 0)));
    };
    rayon::broadcast(|_| free());
    free();
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
        let out = Writer::new(keep, n);
        let states = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let mut state = init();
                let span = c * chunk..((c + 1) * chunk).min(n);
                out.gather(span.start, span.map(|j| each(j, &mut state)));
                state
            })
            .collect();
        (out.finish(), states)
    }

    /// The records of `items` in order, written as they come (on this thread): for
    /// lists whose length is known only at their end, such as the good pixels.
    pub fn collect(keep: &Keep, items: impl Iterator<Item = R>) -> Self {
        if !keep.spill {
            let all: Vec<R> = items.collect();
            return Records { len: all.len(), keep: keep.clone(), store: Store::Held(all) };
        }
        // (As many as come: the length is checked against none.)
        let out = Writer { len: usize::MAX, ..Writer::new(keep, 0) };
        let n = out.gather(0, items);
        out.into_records(n)
    }

    /// `n` records, record `j` being `f(j)` ([`Records::build`] without a state).
    pub fn from_fn(keep: &Keep, n: usize, f: impl Fn(usize) -> R + Sync) -> Self {
        Self::build(keep, n, || (), |j, _| f(j)).0
    }

    /// Records kept.
    pub fn len(&self) -> usize {
        self.len
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
        let (file, alive) = match &self.store {
            Store::Held(all) => return all[j],
            Store::Spilled { file: Some(file), alive, .. } => (file, alive),
            Store::Spilled { file: None, .. } => return R::LOST,
        };
        let block = |first: usize| first..(first + Self::per_block()).min(self.len);
        let cached = BLOCKS.try_with(|blocks| {
            // (Never borrowed already: nothing reads a record while this one is read.)
            let mut blocks = blocks.try_borrow_mut().ok()?;
            if let Some(c) = blocks.iter().rev().find(|c| c.holds(alive, j)) {
                return Some(c.record(j));
            }
            // This store's block, else a dropped store's, else (as many as kinds) the one
            // loaded longest ago, else a new one; it goes last.
            let dead = || blocks.iter().position(|c| c.store.strong_count() == 0);
            let k = blocks.iter().position(|c| c.of(alive)).or_else(dead).or((blocks.len() >= KINDS_AT_ONCE as usize).then_some(0));
            let mut c = k.map_or_else(Cached::empty, |k| blocks.remove(k));
            c.store = Arc::downgrade(alive);
            self.read(file, block(j - j % Self::per_block()), &mut c);
            let r = c.record(j);
            blocks.push(c);
            Some(r)
        });
        // A thread whose cache is gone (it is ending): the record alone.
        cached.ok().flatten().unwrap_or_else(|| {
            let mut one = Cached::empty();
            self.read(file, j..j + 1, &mut one);
            one.record(j)
        })
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

impl Records<u32> {
    /// Index `j` of a list of indices.
    pub fn index(&self, j: usize) -> usize {
        self.at(j) as usize
    }
}

/// Records written by spans, from any thread, then read as [`Records`].
pub(super) struct Writer<R: Record> {
    len: usize,
    keep: Keep,
    sink: Sink<R>,
}

enum Sink<R> {
    Held(Mutex<Vec<R>>),
    /// `None` where the file could not be made.
    Spilled(Option<File>),
}

impl<R: Record> Writer<R> {
    /// `len` records to come, kept as `keep` says (each [`Record::LOST`] until written).
    pub fn new(keep: &Keep, len: usize) -> Self {
        let keep = keep.clone();
        let sink = if !keep.spill {
            Sink::Held(Mutex::new(vec![R::LOST; len]))
        } else if keep.failed().is_some() {
            Sink::Spilled(None)
        } else {
            Sink::Spilled(tempfile::tempfile().map_err(|e| keep.fail(format!("creating a temporary file for the per-pixel records in {}: {e}", std::env::temp_dir().display()))).ok())
        };
        Writer { len, keep, sink }
    }

    /// Whether a spill file has failed (what is computed after is in vain).
    pub fn failed(&self) -> bool {
        self.keep.failed().is_some()
    }

    /// Records [`Writer::gather`] takes before it writes them: a block with their bytes
    /// ([`Writer::put`] encodes them into a buffer of its own).
    fn per_write() -> usize {
        (BLOCK_BYTES / (R::BYTES + std::mem::size_of::<R>()).max(1)).max(1)
    }

    /// Writes `items` as records `first..`, a block at a time, and says how many there
    /// were. After a failure it stops taking them: nothing more is computed, the
    /// diagnosis ends with it.
    pub fn gather(&self, first: usize, mut items: impl Iterator<Item = R>) -> usize {
        let mut block = Vec::with_capacity(Self::per_write().min(items.size_hint().1.unwrap_or(usize::MAX)));
        let mut at = first;
        while !self.failed() {
            block.extend(items.by_ref().take(Self::per_write()));
            if block.is_empty() {
                break;
            }
            self.put(at, &block);
            at += block.len();
            block.clear();
        }
        at - first
    }

    /// Writes records `first..first + records.len()` (past the writer's length, none:
    /// the failure is recorded).
    pub fn put(&self, first: usize, records: &[R]) {
        if first.checked_add(records.len()).is_none_or(|end| end > self.len) {
            self.keep.fail(format!("per-pixel records {first}.. ({}) written past their {}", records.len(), self.len));
            return;
        }
        match &self.sink {
            Sink::Held(all) => {
                if let Some(to) = all.lock().unwrap_or_else(|e| e.into_inner()).get_mut(first..first + records.len()) {
                    to.copy_from_slice(records);
                }
            }
            Sink::Spilled(None) => {}
            Sink::Spilled(Some(file)) => {
                let mut bytes = Vec::with_capacity(records.len() * R::BYTES);
                for (k, r) in records.iter().enumerate() {
                    r.put(&mut Put(&mut bytes));
                    if bytes.len() != (k + 1) * R::BYTES {
                        // A `put` that disagrees with `BYTES` would shift every record after.
                        self.keep.fail(format!("a per-pixel record wrote {} bytes, not {}", bytes.len() - k * R::BYTES, R::BYTES));
                        bytes.resize((k + 1) * R::BYTES, 0);
                    }
                }
                if let Err(e) = file.write_all_at(&bytes, (first * R::BYTES) as u64) {
                    self.keep.fail(format!("writing the per-pixel records to a temporary file in {}: {e}", std::env::temp_dir().display()));
                }
            }
        }
    }

    /// The records written. Each must have been: held, one never written reads as
    /// lost; spilled, as zero bytes decoded, or a failed read past the file's end.
    pub fn finish(self) -> Records<R> {
        let len = self.len;
        self.into_records(len)
    }

    fn into_records(self, len: usize) -> Records<R> {
        let (len, store) = match self.sink {
            Sink::Held(all) => {
                let all = all.into_inner().unwrap_or_else(|e| e.into_inner());
                (all.len(), Store::Held(all))
            }
            Sink::Spilled(file) => (len, Store::Spilled { file, alive: Arc::new(()), kind: std::marker::PhantomData }),
        };
        Records { len, keep: self.keep, store }
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

    #[test]
    fn every_value_put_is_taken_back_bit_for_bit_in_order() {
        // Each width with values whose bytes all differ, a NaN payload and a negative
        // zero among the floats; then a read past the end gives zeros.
        let mut bytes = Vec::new();
        let mut put = Put(&mut bytes);
        let nan = f64::from_bits(0x7ff8_0000_dead_beef);
        put.f64(-0.0);
        put.f64(nan);
        put.f32(1.5e-30);
        put.f32(-7.25);
        put.u32(0x0102_0304);
        put.u16(0xa1b2);
        put.u8(0xc3);
        assert_eq!(bytes.len(), 2 * 8 + 2 * 4 + 4 + 2 + 1);
        let mut take = Take(&bytes);
        assert_eq!(take.f64().to_bits(), (-0.0f64).to_bits());
        assert_eq!(take.f64().to_bits(), nan.to_bits());
        assert_eq!(take.f32().to_bits(), 1.5e-30f32.to_bits());
        assert_eq!(take.f32().to_bits(), (-7.25f32).to_bits());
        assert_eq!(take.u32(), 0x0102_0304);
        assert_eq!(take.u16(), 0xa1b2);
        assert_eq!(take.u8(), 0xc3);
        assert_eq!((take.u32(), take.u8()), (0, 0));
    }

    #[test]
    fn the_small_records_take_their_stated_bytes_and_read_back_bit_for_bit() {
        let nan = f64::from_bits(0x7ff8_0000_0bad_f00d);
        let [a, b] = round_trip([-0.0, nan]);
        assert_eq!((a.to_bits(), b.to_bits()), ((-0.0f64).to_bits(), nan.to_bits()));
        assert_eq!(round_trip([1.25e300, -3.5]), [1.25e300, -3.5]);
        assert_eq!(round_trip(Some(2.5f64)), Some(2.5));
        assert_eq!(round_trip(Some(-0.0f64)).map(f64::to_bits), Some((-0.0f64).to_bits()));
        assert_eq!(round_trip(Some(nan)).map(f64::to_bits), Some(nan.to_bits()));
        assert_eq!(round_trip(None::<f64>), None);
        assert_eq!(round_trip(0xbeefu16), 0xbeef);
        assert_eq!(round_trip(0xdead_beefu32), 0xdead_beef);
    }

    /// A spilled store whose file ends before its length: the read past the end fails,
    /// every record of that block reads as lost (not as the zeros the buffer was filled
    /// with), and the failure is kept for the diagnosis to end with.
    #[test]
    fn a_read_past_the_spill_file_reads_as_lost_and_is_a_failure() {
        let w = Writer::<Pair>::new(&Keep::spilled(), 10);
        w.put(0, &(0..4).map(pair).collect::<Vec<_>>());
        let r = w.finish();
        let bits = |p: Pair| (p.0.to_bits(), p.1);
        assert_eq!(bits(r.at(7)), bits(Pair::LOST));
        assert_eq!(bits(r.at(2)), bits(Pair::LOST));
        assert!(r.keep().failed().is_some_and(|m| m.contains("reading the per-pixel records back")), "{:?}", r.keep().failed());
    }

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

    /// A record whose `put` writes one byte short when its value is odd: a faulty
    /// `Record` impl.
    #[derive(Clone, Copy, Debug, PartialEq)]
    struct Short(u32);
    impl Record for Short {
        const BYTES: usize = 4;
        const LOST: Short = Short(u32::MAX);
        fn put(&self, out: &mut Put<'_>) {
            out.u16(self.0 as u16);
            out.u8((self.0 >> 16) as u8);
            if self.0.is_multiple_of(2) {
                out.u8((self.0 >> 24) as u8);
            }
        }
        fn take(from: &mut Take<'_>) -> Self {
            Short(from.u16() as u32 | (from.u8() as u32) << 16 | (from.u8() as u32) << 24)
        }
    }

    /// A record that writes fewer bytes than it states fails the spill, and is padded to
    /// its size, so that the records after it stay where they are; gather says how many it
    /// took from any first index.
    #[test]
    fn a_record_short_of_its_bytes_fails_the_spill_and_shifts_nothing() {
        let out = Writer::<Short>::new(&Keep::spilled(), 9);
        let written: Vec<Short> = (0..9u32).map(|j| Short(0x0403_0200 + 2 * j + (j == 3) as u32)).collect();
        out.put(0, &written);
        assert!(out.failed(), "the odd record wrote 3 bytes of 4");
        assert_eq!(out.gather(5, [Short(0x1000_0002), Short(0x2000_0004)].into_iter()), 0, "nothing is taken after a failure");
        let r = out.finish();
        assert_eq!(r.at(3), Short(0x0003_0207), "padded with a zero byte");
        assert!((0..9).filter(|&j| j != 3).all(|j| r.at(j) == written[j]), "the records around the short one in their places");
        let good = Writer::<Short>::new(&Keep::spilled(), 9);
        assert_eq!(good.gather(0, (0..5).map(|j| Short(2 * j)).collect::<Vec<_>>().into_iter()), 5);
        assert_eq!(good.gather(5, [Short(0x1000_0002), Short(0x2000_0004), Short(6), Short(8)].into_iter()), 4);
        assert!(!good.failed());
        let r = good.finish();
        assert_eq!((r.at(5), r.at(6), r.at(7)), (Short(0x1000_0002), Short(0x2000_0004), Short(6)));
    }

    fn pair(j: usize) -> Pair {
        // Values whose bits matter: negative zero, subnormals, NaN payloads.
        let v = match j % 5 {
            0 => -0.0,
            1 => f64::from_bits(j as u64),
            2 => f64::from_bits(0x7ff8_0000_0000_0000 | j as u64),
            _ => (j as f64).sqrt() * if j.is_multiple_of(2) { 1.0 } else { -1.0 },
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
        // What the diagnosis reports as `records_spilled`.
        assert!(spilled.keep().spills() && !held.keep().spills());
        assert_eq!(Records::<Pair>::from_fn(&Keep::spilled(), 0, pair).iter().count(), 0);
    }

    /// The blocks' size and what the budget counts for them, against their closed form: a
    /// block of each of 13 kinds per thread and one more, and one being written by each, each
    /// 256 KiB or the records of a small set (120 bytes a pixel at most).
    #[test]
    fn the_spilled_blocks_are_counted_as_they_are_held() {
        assert_eq!(Records::<Pair>::per_block(), (256 << 10) / 10);
        let t = rayon::current_num_threads() as u64;
        assert_eq!(spilled_blocks(1 << 20), 14 * (t + 1) * (256 << 10));
        assert_eq!(spilled_blocks(100), 14 * (t + 1) * 12_000);
        assert_eq!(spilled_blocks(0), 0);
    }

    /// A list of indices collected as they come, across blocks: the same held and
    /// spilled; a writer's spans put out of order from the pool read back in place, and
    /// a span past its end is refused (the failure recorded, nothing written).
    #[test]
    fn collected_lists_and_spans_read_back_in_place() {
        let n = 2 * Records::<u32>::per_block() + 5;
        let items = || (0..3 * n as u32).filter(|v| v % 3 != 1);
        let held = Records::collect(&Keep::held(), items());
        let spilled = Records::collect(&Keep::spilled(), items());
        assert_eq!((held.len(), spilled.len()), (2 * n, 2 * n));
        assert!(held.iter().eq(items()) && spilled.iter().eq(items()));
        assert_eq!(spilled.index(2 * n - 1), 3 * n - 1);
        for keep in [Keep::held(), Keep::spilled()] {
            let out = Writer::<Pair>::new(&keep, n);
            let spans: Vec<usize> = (0..n).step_by(1000).collect();
            spans.par_iter().rev().for_each(|&a| out.put(a, &(a..(a + 1000).min(n)).map(pair).collect::<Vec<_>>()));
            assert!(!out.failed());
            out.put(n - 1, &[pair(0), pair(1)]);
            assert!(out.failed());
            let r = out.finish();
            assert!(r.iter().map(|p| (p.0.to_bits(), p.1)).eq((0..n).map(|j| (pair(j).0.to_bits(), pair(j).1))));
        }
    }

    /// A read while the thread's cache is taken (it cannot be, as records are copies;
    /// and a thread whose cache is gone) reads the record alone.
    #[test]
    fn a_read_without_the_cache_reads_the_record_alone() {
        let n = 2 * Records::<Pair>::per_block();
        let spilled = Records::from_fn(&Keep::spilled(), n, pair);
        BLOCKS.with(|b| {
            let _taken = b.borrow_mut();
            assert!((0..n).step_by(331).all(|j| spilled.at(j).0.to_bits() == pair(j).0.to_bits()));
        });
    }

    /// A store read on every thread of the pool and dropped: `release` leaves no thread a
    /// block of it (the dropping thread's goes with the drop, the others' only here), and
    /// keeps the blocks of a store still alive.
    #[test]
    fn release_frees_every_threads_blocks_of_dropped_stores_only() {
        let n = 4 * Records::<Pair>::per_block();
        let (gone, kept) = (Records::from_fn(&Keep::spilled(), n, pair), Records::from_fn(&Keep::spilled(), n, pair));
        let id = |r: &Records<Pair>| match &r.store {
            Store::Spilled { alive, .. } => Arc::downgrade(alive),
            Store::Held(_) => unreachable!("spilled"),
        };
        let (gone_id, kept_id) = (id(&gone), id(&kept));
        // Every pool thread reads a record of each (the blocks they load stay theirs).
        rayon::broadcast(|_| {
            gone.at(1);
            kept.at(1);
        });
        let held_of = |w: &std::sync::Weak<()>| {
            let w = w.clone();
            let count = move || BLOCKS.with(|b| b.borrow().iter().filter(|c| c.store.ptr_eq(&w)).count());
            rayon::broadcast(|_| count()).into_iter().sum::<usize>() + count()
        };
        assert!(held_of(&gone_id) >= 1, "the pool's threads hold blocks of the store");
        drop(gone);
        release();
        assert_eq!(held_of(&gone_id), 0, "blocks of a dropped store left after release");
        assert!(held_of(&kept_id) >= 1, "release freed a live store's blocks");
        drop(kept);
    }

    /// More stores than a thread keeps blocks of, read in turn on one thread (each read
    /// evicts another's block): every record right, and at most a block per kind held;
    /// a dropped store's block goes with it.
    #[test]
    fn more_stores_than_kinds_read_back_in_turn() {
        let n = 2 * Records::<Pair>::per_block() + 3;
        let stores: Vec<Records<Pair>> = (0..KINDS_AT_ONCE as usize + 3).map(|_| Records::from_fn(&Keep::spilled(), n, pair)).collect();
        let held = || BLOCKS.with(|b| b.borrow().len());
        std::thread::scope(|s| {
            s.spawn(|| {
                for j in (0..n).step_by(97).chain([n - 1]) {
                    for st in &stores {
                        assert_eq!(st.at(j).0.to_bits(), pair(j).0.to_bits());
                    }
                }
                assert_eq!(held(), KINDS_AT_ONCE as usize);
                let one = Records::from_fn(&Keep::spilled(), n, pair);
                assert_eq!(one.at(5).1, 5);
                assert_eq!(held(), KINDS_AT_ONCE as usize);
                drop(one);
                assert_eq!(held(), KINDS_AT_ONCE as usize - 1);
            })
            .join()
            .unwrap()
        });
    }
}
