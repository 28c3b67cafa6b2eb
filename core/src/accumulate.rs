//! Per-modulation-state frame sums of LUT-corrected codes.
//!
//! The acquisition system of the K-Coronagraph sums frames per modulation state before
//! they leave it (de Wijn 2018, section 4). Each pixel adds `lut[adc(column)][code]`, an
//! entry in units of 2^-11 DN, into the `u32` sum of its state.
//!
//! ## Why 512 frames cannot overflow
//! Every entry of a [`LutSet`](crate::LutSet) is below 2^23 (checked when the set is
//! built or loaded, whatever bank is active). Lines arrive in order and each line at
//! most once per frame, so after `f` frames a sum is at most `f (2^23 - 1)`; for
//! `f <= 512 = 2^9` that is below 2^32. While a state has fewer than [`EXACT_FRAMES`]
//! completed frames its sums are added without any check ([`FrameCount::mode`]); the
//! test `five_hundred_twelve_top_code_frames_do_not_overflow` drives the worst case.
//! From frame 513 on the addition saturates at `u32::MAX` and every clipped addition is
//! counted: a sum never wraps silently.

use crate::adc::{count_above_top, AdcMap, Code};
use crate::error::Quantity;
use crate::lut::LutEntry;
use crate::{CoreError, LutBanks, LutSet};

/// Frames per state that sum exactly, without a possible overflow: 2^32 / 2^23.
pub const EXACT_FRAMES: u32 = 1 << (32 - 23);

/// Most modulation states a geometry can have.
pub const MAX_STATES: usize = 8;

/// The region the sums cover: `width` pixels starting at sensor column `first_column`,
/// `height` lines, and `states` modulation states (the K-Coronagraph uses 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Geometry {
    width: u16,
    height: u16,
    states: u8,
    first_column: u16,
}

impl Geometry {
    /// A geometry, or [`CoreError::Geometry`] for a zero size or more than
    /// [`MAX_STATES`] states.
    pub const fn new(width: u16, height: u16, states: u8, first_column: u16) -> Result<Self, CoreError> {
        if width == 0 || height == 0 || states == 0 || states as usize > MAX_STATES {
            return Err(CoreError::Geometry { width, height, states });
        }
        Ok(Geometry { width, height, states, first_column })
    }
    /// Pixels per line.
    pub const fn width(&self) -> u16 {
        self.width
    }
    /// Lines per frame.
    pub const fn height(&self) -> u16 {
        self.height
    }
    /// Modulation states.
    pub const fn states(&self) -> u8 {
        self.states
    }
    /// Sensor column of the first pixel of a line; it decides which ADC reads each pixel.
    pub const fn first_column(&self) -> u16 {
        self.first_column
    }
    /// Pixels of one state's sum image.
    pub const fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
    /// Elements of the whole sum buffer: states x height x width.
    pub const fn sum_len(&self) -> usize {
        self.pixels() * self.states as usize
    }
}

/// How a frame's additions are made, decided by how many frames its state already holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SumMode {
    /// At most 512 frames in the sum: no overflow is possible, plain addition.
    Exact,
    /// Past 512 frames: saturating addition, clipped additions counted.
    Saturating,
}

/// Frames completed in one state's sum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameCount(u32);

impl FrameCount {
    /// Completed frames.
    pub const fn get(self) -> u32 {
        self.0
    }
    /// The mode of the *next* frame: exact while this count is below [`EXACT_FRAMES`].
    pub const fn mode(self) -> SumMode {
        if self.0 < EXACT_FRAMES {
            SumMode::Exact
        } else {
            SumMode::Saturating
        }
    }
}

/// The sum images of all states, in a buffer the caller owns (no allocation here):
/// element `(state * height + row) * width + column`.
#[derive(Debug)]
pub struct SumImages<'a> {
    buf: &'a mut [u32],
    geometry: Geometry,
    /// One count per configured state: the length is the geometry's state count.
    frames: heapless::Vec<FrameCount, MAX_STATES>,
}

impl<'a> SumImages<'a> {
    /// Sums over `buf`, which must hold exactly `geometry.sum_len()` elements; it is
    /// cleared.
    pub fn new(geometry: Geometry, buf: &'a mut [u32]) -> Result<Self, CoreError> {
        if buf.len() != geometry.sum_len() {
            return Err(CoreError::Length {
                what: Quantity::SumBuffer,
                expected: geometry.sum_len() as u32,
                got: buf.len() as u32,
            });
        }
        buf.fill(0);
        Ok(SumImages { buf, geometry, frames: Self::zero_counts(geometry) })
    }
    fn zero_counts(geometry: Geometry) -> heapless::Vec<FrameCount, MAX_STATES> {
        // Geometry::new bounds `states` by MAX_STATES, so every push fits.
        let mut counts = heapless::Vec::new();
        for _ in 0..geometry.states {
            let _ = counts.push(FrameCount::default());
        }
        counts
    }
    /// The geometry.
    pub fn geometry(&self) -> Geometry {
        self.geometry
    }
    /// The sum image of `state`, row-major.
    pub fn state(&self, state: u8) -> Option<&[u32]> {
        let n = self.geometry.pixels();
        (state < self.geometry.states).then(|| &self.buf[state as usize * n..(state as usize + 1) * n])
    }
    /// The whole buffer, state-major.
    pub fn as_slice(&self) -> &[u32] {
        self.buf
    }
    /// Frames completed in `state` since the last clear.
    pub fn frames(&self, state: u8) -> FrameCount {
        self.frames.get(state as usize).copied().unwrap_or_default()
    }
    /// Zeroes every sum and frame count, as after a readout.
    pub fn clear(&mut self) {
        self.buf.fill(0);
        self.frames = Self::zero_counts(self.geometry);
    }
    fn row_mut(&mut self, state: u8, row: u16) -> &mut [u32] {
        self.rows_mut(state, row, 1)
    }
    /// Lines `row..row + count` of `state`, contiguous (the caller keeps them in the frame).
    fn rows_mut(&mut self, state: u8, row: u16, count: usize) -> &mut [u32] {
        let w = self.geometry.width as usize;
        let start = (state as usize * self.geometry.height as usize + row as usize) * w;
        &mut self.buf[start..start + count * w]
    }
}

/// Counters of everything the datapath absorbed instead of failing. All saturate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Codes above the top code, read as the top code.
    pub out_of_range_codes: u32,
    /// Additions that clipped at `u32::MAX` (only possible past 512 frames).
    pub saturated_additions: u32,
    /// Lines rejected for their length, order or for arriving outside a frame.
    pub rejected_lines: u32,
    /// Frames ended before all their lines arrived.
    pub incomplete_frames: u32,
    /// Frames completed, all states.
    pub frames: u32,
    /// LUT bank swaps.
    pub lut_swaps: u32,
}

/// What a [`Corrector`] counted, kept between calls by [`SealedSums`]: the geometry,
/// each state's completed frames and the status.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Suspended {
    geometry: Geometry,
    frames: heapless::Vec<FrameCount, MAX_STATES>,
    status: Status,
}

impl Suspended {
    /// The geometry.
    pub fn geometry(&self) -> Geometry {
        self.geometry
    }
    /// Frames completed in `state`.
    pub fn frames(&self, state: u8) -> FrameCount {
        self.frames.get(state as usize).copied().unwrap_or_default()
    }
    /// The counters.
    pub fn status(&self) -> Status {
        self.status
    }
}

/// Sums in a buffer the caller owns (`B`: a `Vec<u32>` on a host, a static slice on a
/// device) but can only read: a host that hands the core frames one call at a time (the
/// Python package) keeps them here between calls, and each call gets a [`Corrector`] that
/// goes on where the last one stopped. Only a corrector writes the buffer, so the frame
/// counts that decide exact addition are always the ones the sums were made with: a run
/// cut into calls is one run, bit for bit, at no cost per call. `B`'s `AsMut` must give
/// the same buffer every time (as `Vec` and slices do).
#[derive(Debug)]
pub struct SealedSums<B> {
    buf: B,
    kept: Suspended,
}

impl<B: AsRef<[u32]> + AsMut<[u32]>> SealedSums<B> {
    /// Sums over `buf` (exactly `geometry.sum_len()` elements; cleared).
    pub fn new(geometry: Geometry, mut buf: B) -> Result<Self, CoreError> {
        SumImages::new(geometry, buf.as_mut())?;
        Ok(SealedSums { buf, kept: Suspended { geometry, frames: SumImages::zero_counts(geometry), status: Status::default() } })
    }
    /// The sums, state-major as [`SumImages`] lays them out.
    pub fn sums(&self) -> &[u32] {
        self.buf.as_ref()
    }
    /// The geometry, frame counts and status so far.
    pub fn kept(&self) -> &Suspended {
        &self.kept
    }
    /// Zeroes the sums, frame counts and status, as after a readout.
    pub fn clear(&mut self) {
        self.buf.as_mut().fill(0);
        self.kept = Suspended { geometry: self.kept.geometry, frames: SumImages::zero_counts(self.kept.geometry), status: Status::default() };
    }
    /// Runs `work` with a corrector over these sums and `banks`, then keeps what it
    /// counted; a frame `work` leaves open is ended (counted incomplete if short).
    pub fn correct<const N: usize, const CODES: usize, R>(&mut self, banks: &mut LutBanks<N, CODES>, work: impl FnOnce(&mut Corrector<'_, N, CODES>) -> R) -> Result<R, CoreError> {
        let geometry = self.kept.geometry;
        let buf = self.buf.as_mut();
        if buf.len() != geometry.sum_len() {
            return Err(CoreError::Length { what: Quantity::SumBuffer, expected: geometry.sum_len() as u32, got: buf.len() as u32 });
        }
        let sums = SumImages { buf, geometry, frames: self.kept.frames.clone() };
        let mut c = Corrector { banks, sums, status: self.kept.status, frame: None };
        let result = work(&mut c);
        let ended = if c.frame.is_some() { c.end_frame() } else { Ok(()) };
        // Kept whatever happened, so the counts always describe the sums.
        self.kept = Suspended { geometry, frames: c.sums.frames.clone(), status: c.status };
        ended.map(|()| result)
    }
}

/// What one accepted line did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LineReport {
    /// Codes of this line above the top code.
    pub out_of_range_codes: u32,
    /// Additions of this line that clipped.
    pub saturated_additions: u32,
}

#[derive(Debug, Clone, Copy)]
struct OpenFrame {
    state: u8,
    next_row: u16,
    mode: SumMode,
}

/// The datapath: LUT banks, sum images and status. Frames are bracketed by
/// [`begin_frame`](Self::begin_frame) and [`end_frame`](Self::end_frame); a LUT
/// activation takes effect only between frames.
pub struct Corrector<'a, const N: usize, const CODES: usize> {
    banks: &'a mut LutBanks<N, CODES>,
    sums: SumImages<'a>,
    status: Status,
    frame: Option<OpenFrame>,
}

impl<'a, const N: usize, const CODES: usize> Corrector<'a, N, CODES> {
    /// A corrector over `banks` and `sum_buf` (exactly `geometry.sum_len()` elements,
    /// cleared). Both are borrowed so that a device can keep them in static memory.
    pub fn new(banks: &'a mut LutBanks<N, CODES>, geometry: Geometry, sum_buf: &'a mut [u32]) -> Result<Self, CoreError> {
        Ok(Corrector { banks, sums: SumImages::new(geometry, sum_buf)?, status: Status::default(), frame: None })
    }

    /// Opens a frame of modulation state `state`. A pending LUT activation happens here.
    pub fn begin_frame(&mut self, state: u8) -> Result<SumMode, CoreError> {
        if self.frame.is_some() {
            return Err(CoreError::FrameOpen);
        }
        let states = self.sums.geometry.states;
        if state >= states {
            return Err(CoreError::State { state, states });
        }
        if self.banks.swap_if_pending() {
            self.status.lut_swaps = self.status.lut_swaps.saturating_add(1);
        }
        let mode = self.sums.frames(state).mode();
        self.frame = Some(OpenFrame { state, next_row: 0, mode });
        Ok(mode)
    }

    /// Adds one line of raw codes (line `row` of the open frame) into the sums. A line of
    /// the wrong length, out of order or outside a frame is rejected, counted, and adds
    /// nothing; codes above the top code are read as the top code and counted.
    pub fn accumulate_line(&mut self, row: u16, codes: &[u16]) -> Result<LineReport, CoreError> {
        let result = self.check_line(row, codes.len());
        let frame = match result {
            Ok(frame) => frame,
            Err(e) => {
                self.status.rejected_lines = self.status.rejected_lines.saturating_add(1);
                return Err(e);
            }
        };
        let first_column = self.sums.geometry.first_column as u32;
        let luts = self.banks.active();
        let sums = self.sums.row_mut(frame.state, row);
        let report = match frame.mode {
            SumMode::Exact => add_line::<Exact, N, CODES>(luts, first_column, codes, sums),
            SumMode::Saturating => add_line::<Saturating, N, CODES>(luts, first_column, codes, sums),
        };
        self.status.out_of_range_codes = self.status.out_of_range_codes.saturating_add(report.out_of_range_codes);
        self.status.saturated_additions = self.status.saturated_additions.saturating_add(report.saturated_additions);
        if let Some(f) = self.frame.as_mut() {
            f.next_row += 1;
        }
        Ok(report)
    }

    /// Adds a block of whole lines, `codes.len() / width` of them from line `first_row`
    /// on, exactly as [`accumulate_line`](Self::accumulate_line) would one by one, in one
    /// call: what a DMA transfer of several lines delivers, without the per-line call and
    /// checks. The block is accepted or rejected whole (not a positive multiple of the
    /// width, not starting at the next line, or running past the frame's last line: one
    /// rejected line counted); the report sums its lines'.
    pub fn accumulate_lines(&mut self, first_row: u16, codes: &[u16]) -> Result<LineReport, CoreError> {
        let result = self.check_block(first_row, codes.len());
        let (frame, lines) = match result {
            Ok(x) => x,
            Err(e) => {
                self.status.rejected_lines = self.status.rejected_lines.saturating_add(1);
                return Err(e);
            }
        };
        let width = self.sums.geometry.width as usize;
        let first_column = self.sums.geometry.first_column as u32;
        let luts = self.banks.active();
        let sums = self.sums.rows_mut(frame.state, first_row, lines);
        let mut report = LineReport::default();
        // Where the width is a multiple of N, column `i mod width` of the block goes to
        // the ADC of column `i`, and the block is one line to the loop: no per-line call,
        // and a vector loop runs across the lines' ends (`dncal bench`, checked build,
        // AVX-512: medians 0.99-1.06 of the bench's bare gather loop, 0.99-1.01 line by
        // line).
        let line = if width.is_multiple_of(N) { codes.len() } else { width };
        for (line, line_sums) in codes.chunks_exact(line).zip(sums.chunks_exact_mut(line)) {
            let r = match frame.mode {
                SumMode::Exact => add_line::<Exact, N, CODES>(luts, first_column, line, line_sums),
                SumMode::Saturating => add_line::<Saturating, N, CODES>(luts, first_column, line, line_sums),
            };
            report.out_of_range_codes = report.out_of_range_codes.saturating_add(r.out_of_range_codes);
            report.saturated_additions = report.saturated_additions.saturating_add(r.saturated_additions);
        }
        self.status.out_of_range_codes = self.status.out_of_range_codes.saturating_add(report.out_of_range_codes);
        self.status.saturated_additions = self.status.saturated_additions.saturating_add(report.saturated_additions);
        if let Some(f) = self.frame.as_mut() {
            f.next_row += lines as u16;
        }
        Ok(report)
    }

    fn check_block(&self, first_row: u16, len: usize) -> Result<(OpenFrame, usize), CoreError> {
        let frame = self.frame.ok_or(CoreError::NoFrame)?;
        let width = self.sums.geometry.width as usize;
        if len == 0 || !len.is_multiple_of(width) {
            return Err(CoreError::Length { what: Quantity::BlockPixels, expected: width as u32, got: len as u32 });
        }
        let lines = len / width;
        if first_row != frame.next_row || first_row as usize + lines > self.sums.geometry.height as usize {
            return Err(CoreError::LineOrder { expected: frame.next_row, got: first_row });
        }
        Ok((frame, lines))
    }

    fn check_line(&self, row: u16, len: usize) -> Result<OpenFrame, CoreError> {
        let frame = self.frame.ok_or(CoreError::NoFrame)?;
        let width = self.sums.geometry.width;
        if len != width as usize {
            return Err(CoreError::Length { what: Quantity::LinePixels, expected: width as u32, got: len as u32 });
        }
        if row != frame.next_row || row >= self.sums.geometry.height {
            return Err(CoreError::LineOrder { expected: frame.next_row, got: row });
        }
        Ok(frame)
    }

    /// Closes the open frame and counts it in its state. A frame closed before all its
    /// lines arrived is still counted (its lines are in the sums) and flagged in
    /// [`Status::incomplete_frames`]. A LUT activation requested during the frame
    /// happens here.
    pub fn end_frame(&mut self) -> Result<(), CoreError> {
        let frame = self.frame.take().ok_or(CoreError::NoFrame)?;
        if frame.next_row != self.sums.geometry.height {
            self.status.incomplete_frames = self.status.incomplete_frames.saturating_add(1);
        }
        if let Some(count) = self.sums.frames.get_mut(frame.state as usize) {
            count.0 = count.0.saturating_add(1);
        }
        self.status.frames = self.status.frames.saturating_add(1);
        if self.banks.swap_if_pending() {
            self.status.lut_swaps = self.status.lut_swaps.saturating_add(1);
        }
        Ok(())
    }

    /// Asks for the validated staging bank to become active: now if no frame is open,
    /// otherwise when the open frame ends.
    pub fn request_activation(&mut self) -> Result<(), CoreError> {
        self.banks.request_activation()?;
        if self.frame.is_none() && self.banks.swap_if_pending() {
            self.status.lut_swaps = self.status.lut_swaps.saturating_add(1);
        }
        Ok(())
    }

    /// The LUT banks, to load a staging image.
    pub fn banks_mut(&mut self) -> &mut LutBanks<N, CODES> {
        self.banks
    }
    /// The LUT banks.
    pub fn banks(&self) -> &LutBanks<N, CODES> {
        self.banks
    }
    /// The sums.
    pub fn sums(&self) -> &SumImages<'a> {
        &self.sums
    }
    /// Zeroes the sums and frame counts after a readout. Refused while a frame is open.
    pub fn clear_sums(&mut self) -> Result<(), CoreError> {
        if self.frame.is_some() {
            return Err(CoreError::FrameOpen);
        }
        self.sums.clear();
        Ok(())
    }
    /// The counters.
    pub fn status(&self) -> Status {
        self.status
    }
    /// Whether a frame is open.
    pub fn frame_open(&self) -> bool {
        self.frame.is_some()
    }
}

/// How one sum takes one entry; a type per [`SumMode`] so the exact loop carries no
/// overflow check at all.
trait Add {
    /// Whether an addition can be taken back exactly afterwards (wrapping arithmetic).
    const UNDOABLE: bool;
    fn add(sum: &mut u32, entry: LutEntry, saturated: &mut u32);
}
struct Exact;
struct Saturating;

impl Add for Exact {
    const UNDOABLE: bool = true;
    #[inline(always)]
    fn add(sum: &mut u32, entry: LutEntry, _: &mut u32) {
        // Cannot wrap: at most 512 entries below 2^23 (module documentation).
        *sum = sum.wrapping_add(entry.to_bits());
    }
}
impl Add for Saturating {
    const UNDOABLE: bool = false;
    #[inline(always)]
    fn add(sum: &mut u32, entry: LutEntry, saturated: &mut u32) {
        let (s, overflow) = saturating_sum(*sum, entry);
        *sum = s;
        *saturated += overflow as u32;
    }
}

/// The datapath's addition: `sum + entry`, clipped at `2^32 - 1`, and whether it clipped.
/// Below 513 frames per state it never clips (module documentation), so a datapath that
/// always adds this way (the FPGA model) is bit-exact with the exact mode.
#[inline(always)]
pub fn saturating_sum(sum: u32, entry: LutEntry) -> (u32, bool) {
    let (s, overflow) = sum.overflowing_add(entry.to_bits());
    (if overflow { u32::MAX } else { s }, overflow)
}

/// The datapath's lookup: the entry of raw code `raw` in `table`, a code above the top
/// read as the top code, and whether it was above.
#[inline(always)]
pub fn lookup<const CODES: usize>(table: &[LutEntry; CODES], raw: u16) -> (LutEntry, bool) {
    let (code, clipped) = Code::<CODES>::clamped(raw);
    (table[code.index()], clipped)
}

/// Adds `lut[adc(first_column + i)][codes[i]]` to `sums[i]`. `codes` and `sums` have the
/// same length (checked by the caller).
///
/// A camera's lines are in range, so the loop is written for them: the index is the
/// code masked to `CODES - 1` (`CODES` is a power of two), one instruction (or none,
/// folded into the load) that lets the compiler drop the bounds check, and the identity
/// on a code in range. Whether every code was in range is learnt from the bitwise OR of
/// the line, which no code exceeds.
/// - Exact mode (wrapping addition, which can be taken back exactly): the OR is taken in
///   the loop itself, of the code words it loads anyway (two codes a word where N is
///   even: half an instruction a pixel on a Cortex-M4; one a code where N is odd; and
///   no pass over the line before the loop). A line whose OR is above the top code then
///   has the entries of its out-of-range codes taken back and the top code's added in
///   their place ([`lookup`]'s rule), and those codes counted.
/// - Saturating mode (a clipped addition cannot be taken back): the OR is a pass of its
///   own before the loop ([`or_of`]). A line that may hold codes above the top goes
///   through the same loop with the index clamped to the top and its out-of-range codes
///   counted.
///
/// Measured 2026-11-26 (x86, `dncal bench`, nine alternating invocations each): the
/// frame as a block at 0.94-1.02 of the plain LUT loop (median 0.99) with the OR in the
/// loop, against 0.85-0.94 (median 0.90) with the pass before it. On the Cortex-M4 the
/// exact loop is 6.25 instructions a pixel (7.25 while LLVM unrolled it four groups
/// deep), against 7.0 plus 1.0 for the pass before (docs/firmware.md).
fn add_line<A: Add, const N: usize, const CODES: usize>(
    luts: &LutSet<N, CODES>,
    first_column: u32,
    codes: &[u16],
    sums: &mut [u32],
) -> LineReport {
    let top = Code::<CODES>::MAX.index();
    // `top` is `CODES - 1`, all ones: the mask is the identity on codes in range.
    let masked = |raw: u16| raw as usize & top;
    if A::UNDOABLE {
        let mut or = 0u32;
        let mut report = match gathered(luts, first_column, codes, sums) {
            Some(all) => {
                or = all;
                LineReport::default()
            }
            None => add_indexed::<A, N, CODES>(luts, first_column, codes, sums, |word| or |= word, masked),
        };
        if ((or as u16 | (or >> 16) as u16) as usize) > top {
            report.out_of_range_codes = retake_out_of_range(luts, first_column, codes, sums);
        }
        report
    } else if (or_of(codes) as usize) <= top {
        add_indexed::<A, N, CODES>(luts, first_column, codes, sums, |_| (), masked)
    } else {
        let mut report = add_indexed::<A, N, CODES>(luts, first_column, codes, sums, |_| (), |raw| Code::<CODES>::clamped(raw).0.index());
        report.out_of_range_codes = count_above_top::<CODES>(codes);
        report
    }
}

/// The exact loop as a vector gather where the host has one ([`crate::simd`]): the OR of
/// the codes, having added their masked entries; `None`, having added nothing, where it
/// does not apply.
#[cfg(all(feature = "simd", target_arch = "x86_64"))]
#[inline(always)]
fn gathered<const N: usize, const CODES: usize>(luts: &LutSet<N, CODES>, first_column: u32, codes: &[u16], sums: &mut [u32]) -> Option<u32> {
    crate::simd::add_exact(crate::simd::Kernel::detected(), luts.tables(), first_column, codes, sums)
}
#[cfg(not(all(feature = "simd", target_arch = "x86_64")))]
#[inline(always)]
fn gathered<const N: usize, const CODES: usize>(_: &LutSet<N, CODES>, _: u32, _: &[u16], _: &mut [u32]) -> Option<u32> {
    None
}

/// Takes back the masked entry each out-of-range code of a line added and adds the one
/// [`lookup`] gives it (the top code's) in its place; the count of such codes. Exact only after wrapping additions
/// (the exact mode), where `sum - a + b` is the sum that `b` alone would have made.
/// Out of line: a camera's lines never come here.
#[inline(never)]
fn retake_out_of_range<const N: usize, const CODES: usize>(luts: &LutSet<N, CODES>, first_column: u32, codes: &[u16], sums: &mut [u32]) -> u32 {
    let top = Code::<CODES>::MAX.index();
    let tables = luts.tables();
    let mut count = 0;
    for (i, (&raw, sum)) in codes.iter().zip(sums).enumerate() {
        let table = &tables[AdcMap::<N>::adc(first_column + i as u32)];
        if let (entry, true) = lookup(table, raw) {
            *sum = sum.wrapping_sub(table[raw as usize & top].to_bits()).wrapping_add(entry.to_bits());
            count += 1;
        }
    }
    count
}

/// The bitwise OR of `codes`. Pairs of codes are joined into 32-bit words, which the
/// compiler turns into one word load per two codes (half the loads and ORs of a plain
/// fold on a Cortex-M4). Each run of 32 codes is folded on its own: on the Cortex-M4
/// that is 16 word loads and ORs unrolled, on x86 four vector loads and ORs with one
/// reduction a run. (A running OR across the runs, 8 codes at a time, had x86 reduce
/// every 8 codes: 6-9% of the core's time on a 1024-pixel line against 3-5% now,
/// measured beside a loop without the pass.)
#[inline(always)]
pub(crate) fn or_of(codes: &[u16]) -> u16 {
    let mut runs = codes.chunks_exact(32);
    let mut acc = 0u32;
    for run in &mut runs {
        acc |= run.chunks_exact(2).fold(0u32, |a, pair| a | pair[0] as u32 | (pair[1] as u32) << 16);
    }
    let rest = runs.remainder().iter().fold(0u16, |a, &c| a | c);
    (acc as u16) | ((acc >> 16) as u16) | rest
}

/// The loop of [`add_line`] with its index rule `index` (a value below `CODES`). Every
/// code also passes through `see` once, as part of a 32-bit word: two codes joined (low
/// half the first) inside a group of N columns when N is even, else one code alone. The
/// line is split into a head up to the next multiple of N columns, whole groups of N in
/// ADC order 0..N (no index arithmetic per pixel), and a tail.
///
/// A group's codes and sums are copied into arrays and its sums written back whole:
/// LLVM then loads the codes as words (two per word on a Cortex-M4, where the halves
/// come out with the mask folded in: `bfc` and `ubfx`, and `see` takes the word as it
/// was loaded) and pairs the sums' loads and stores (`ldrd`, `strd`).
#[inline(always)]
fn add_indexed<A: Add, const N: usize, const CODES: usize>(
    luts: &LutSet<N, CODES>,
    first_column: u32,
    codes: &[u16],
    sums: &mut [u32],
    mut see: impl FnMut(u32),
    index: impl Fn(u16) -> usize,
) -> LineReport {
    let tables = luts.tables();
    let mut report = LineReport::default();
    let mut add = |table: &[LutEntry; CODES], raw: u16, sum: &mut u32| A::add(sum, table[index(raw)], &mut report.saturated_additions);
    let head = AdcMap::<N>::head(first_column, codes.len());
    let (head_codes, body_codes) = codes.split_at(head);
    let (head_sums, body_sums) = sums.split_at_mut(head);
    for (i, (&raw, sum)) in head_codes.iter().zip(head_sums).enumerate() {
        see(raw as u32);
        add(&tables[AdcMap::<N>::adc(first_column + i as u32)], raw, sum);
    }
    let whole = body_codes.len() / N * N;
    let (body_codes, tail_codes) = body_codes.split_at(whole);
    let (body_sums, tail_sums) = body_sums.split_at_mut(whole);
    for (cs, ss) in body_codes.chunks_exact(N).zip(body_sums.chunks_exact_mut(N)) {
        let mut c = [0u16; N];
        c.copy_from_slice(cs);
        let mut s = [0u32; N];
        s.copy_from_slice(ss);
        for j in 0..N {
            if N % 2 == 1 {
                see(c[j] as u32);
            } else if j % 2 == 0 {
                see(c[j] as u32 | (c[j + 1] as u32) << 16);
            }
            add(&tables[j], c[j], &mut s[j]);
        }
        ss.copy_from_slice(&s);
    }
    for ((table, &raw), sum) in tables.iter().zip(tail_codes).zip(tail_sums) {
        see(raw as u32);
        add(table, raw, sum);
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lut::LUT_ENTRY_LIMIT;

    fn top_luts() -> LutSet<4, 4096> {
        LutSet::from_bits(&[[LUT_ENTRY_LIMIT - 1; 4096]; 4]).unwrap()
    }

    #[test]
    fn the_or_of_a_line_is_the_plain_fold() {
        // Every length around the 32-code runs (two of them and a remainder), one bit set
        // at each position in turn, odd and even, either half of a joined word.
        for len in 0..100usize {
            for at in 0..len {
                for bit in [0u16, 5, 12, 15] {
                    let mut codes = [0u16; 100];
                    codes[at] = 1 << bit;
                    codes[(at * 7) % len] |= 3;
                    let want = codes[..len].iter().fold(0, |a, &c| a | c);
                    assert_eq!(or_of(&codes[..len]), want, "len {len}, at {at}, bit {bit}");
                }
            }
        }
    }

    #[test]
    fn a_bad_block_is_rejected_whole_and_counted() {
        let g = Geometry::new(4, 3, 1, 0).unwrap();
        let mut buf = [0u32; 12];
        let mut banks = LutBanks::new(top_luts());
        let mut c = Corrector::new(&mut banks, g, &mut buf).unwrap();
        assert_eq!(c.accumulate_lines(0, &[1; 4]), Err(CoreError::NoFrame));
        c.begin_frame(0).unwrap();
        // Not whole lines, empty, not the next line, past the last line.
        assert!(matches!(c.accumulate_lines(0, &[1; 6]), Err(CoreError::Length { what: Quantity::BlockPixels, expected: 4, got: 6 })));
        assert!(matches!(c.accumulate_lines(0, &[]), Err(CoreError::Length { .. })));
        assert_eq!(c.accumulate_lines(1, &[1; 4]), Err(CoreError::LineOrder { expected: 0, got: 1 }));
        assert_eq!(c.accumulate_lines(0, &[1; 16]), Err(CoreError::LineOrder { expected: 0, got: 0 }));
        assert_eq!(c.status().rejected_lines, 5);
        assert!(c.sums().state(0).unwrap().iter().all(|&s| s == 0), "a rejected block adds nothing");
        // Two lines, then the last one: the frame is complete; codes above the top count.
        assert_eq!(c.accumulate_lines(0, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap().out_of_range_codes, 0);
        assert_eq!(c.accumulate_lines(2, &[4095, 4096, 9000, 0]).unwrap().out_of_range_codes, 2);
        c.end_frame().unwrap();
        assert_eq!(c.status().incomplete_frames, 0);
        assert_eq!(c.status().out_of_range_codes, 2);
        assert!(c.sums().state(0).unwrap().iter().all(|&s| s == LUT_ENTRY_LIMIT - 1));
    }

    #[test]
    fn sealed_sums_cut_at_every_frame_are_one_uninterrupted_run() {
        // 520 frames, mostly top codes with some codes above the top: state 0 gets 515
        // of them and so crosses 512 into saturating addition, state 1 the last 5.
        // One call a frame through SealedSums: the sums, counts and status equal those
        // of one corrector that ran them all.
        let g = Geometry::new(8, 2, 2, 3).unwrap();
        let frame = |f: u32| -> [u16; 16] { core::array::from_fn(|i| if f.is_multiple_of(7) { (i as u16 * 517 + f as u16) % 5000 } else { 4095 }) };
        let state = |f: u32| if f < 515 { 0 } else { 1 };
        let (mut once_buf, mut banks_once) = ([0u32; 32], LutBanks::new(top_luts()));
        let mut once = Corrector::new(&mut banks_once, g, &mut once_buf).unwrap();
        let mut banks = LutBanks::new(top_luts());
        let mut sealed = SealedSums::new(g, [7u32; 32]).unwrap();
        assert!(sealed.sums().iter().all(|&s| s == 0), "cleared");
        for f in 0..520 {
            once.begin_frame(state(f)).unwrap();
            once.accumulate_lines(0, &frame(f)).unwrap();
            once.end_frame().unwrap();
            sealed
                .correct(&mut banks, |c| {
                    c.begin_frame(state(f)).unwrap();
                    c.accumulate_lines(0, &frame(f)).unwrap();
                    c.end_frame().unwrap();
                })
                .unwrap();
        }
        let kept = sealed.kept();
        assert_eq!(kept.status(), once.status());
        assert!(once.status().saturated_additions > 0 && once.status().out_of_range_codes > 0);
        assert_eq!((kept.frames(0).get(), kept.frames(1).get()), (515, 5));
        assert_eq!(kept.frames(0), once.sums().frames(0));
        assert_eq!(kept.geometry(), g);
        assert_eq!(sealed.sums(), once.sums().as_slice());
        sealed.clear();
        assert!(sealed.sums().iter().all(|&s| s == 0));
        assert_eq!((sealed.kept().frames(0).get(), sealed.kept().status()), (0, Status::default()));
    }

    #[test]
    fn a_frame_left_open_is_ended_and_a_buffer_of_another_size_refused() {
        let g = Geometry::new(4, 2, 1, 0).unwrap();
        let mut banks = LutBanks::new(top_luts());
        let mut sealed = SealedSums::new(g, [0u32; 8]).unwrap();
        sealed
            .correct(&mut banks, |c| {
                c.begin_frame(0).unwrap();
                c.accumulate_line(0, &[4095; 4]).unwrap();
            })
            .unwrap();
        assert_eq!((sealed.kept().frames(0).get(), sealed.kept().status().incomplete_frames), (1, 1));
        assert_eq!(sealed.sums(), &[LUT_ENTRY_LIMIT - 1, LUT_ENTRY_LIMIT - 1, LUT_ENTRY_LIMIT - 1, LUT_ENTRY_LIMIT - 1, 0, 0, 0, 0]);
        assert!(matches!(SealedSums::new(g, [0u32; 7]).err(), Some(CoreError::Length { what: Quantity::SumBuffer, .. })));
    }

    #[test]
    fn five_hundred_twelve_top_code_frames_do_not_overflow() {
        // The worst case: every entry at 2^23 - 1, every code at the top code.
        let g = Geometry::new(8, 1, 1, 0).unwrap();
        let mut buf = [0u32; 8];
        let mut banks = LutBanks::new(top_luts());
        let mut c = Corrector::new(&mut banks, g, &mut buf).unwrap();
        for _ in 0..EXACT_FRAMES {
            assert_eq!(c.begin_frame(0).unwrap(), SumMode::Exact);
            c.accumulate_line(0, &[4095; 8]).unwrap();
            c.end_frame().unwrap();
        }
        let expected = 512u64 * (LUT_ENTRY_LIMIT as u64 - 1);
        assert!(expected < 1 << 32);
        assert!(c.sums().state(0).unwrap().iter().all(|&s| s as u64 == expected));
        assert_eq!(c.status().saturated_additions, 0);
        // Frame 513 switches to saturating; one more top entry still fits (2^32 - 512 +
        // 2^23 - 1 overflows, so it clips).
        assert_eq!(c.begin_frame(0).unwrap(), SumMode::Saturating);
        c.accumulate_line(0, &[4095; 8]).unwrap();
        c.end_frame().unwrap();
        assert!(c.sums().state(0).unwrap().iter().all(|&s| s == u32::MAX));
        assert_eq!(c.status().saturated_additions, 8);
    }

    #[test]
    fn out_of_range_codes_that_would_cancel_under_xor_are_all_read_as_the_top() {
        // Equal codes above the top in one word of two codes, and in two words: an OR
        // that cancelled them (an XOR) would skip the take-back and the count.
        let g = Geometry::new(4, 2, 1, 0).unwrap();
        let mut buf = [0u32; 8];
        let mut banks = LutBanks::new(LutSet::<4, 4096>::ideal());
        let mut c = Corrector::new(&mut banks, g, &mut buf).unwrap();
        c.begin_frame(0).unwrap();
        assert_eq!(c.accumulate_line(0, &[4096, 4096, 0, 0]).unwrap().out_of_range_codes, 2);
        assert_eq!(c.accumulate_line(1, &[4096, 0, 4096, 0]).unwrap().out_of_range_codes, 2);
        c.end_frame().unwrap();
        let (top, zero) = (LutEntry::ideal::<4096>(4095).to_bits(), LutEntry::ideal::<4096>(0).to_bits());
        assert_eq!(c.sums().state(0).unwrap(), [top, top, zero, zero, top, zero, top, zero]);
    }

    #[test]
    fn bad_lines_are_rejected_and_add_nothing() {
        let g = Geometry::new(4, 2, 2, 1).unwrap();
        let mut buf = [0u32; 16];
        let mut banks = LutBanks::new(LutSet::<4, 4096>::ideal());
        let mut c = Corrector::new(&mut banks, g, &mut buf).unwrap();
        assert_eq!(c.accumulate_line(0, &[1; 4]), Err(CoreError::NoFrame));
        assert_eq!(c.begin_frame(2), Err(CoreError::State { state: 2, states: 2 }));
        c.begin_frame(1).unwrap();
        assert_eq!(c.begin_frame(1), Err(CoreError::FrameOpen));
        assert!(matches!(c.accumulate_line(0, &[1; 5]), Err(CoreError::Length { expected: 4, got: 5, .. })));
        assert_eq!(c.accumulate_line(1, &[1; 4]), Err(CoreError::LineOrder { expected: 0, got: 1 }));
        let r = c.accumulate_line(0, &[0, 4095, 4096, 65535]).unwrap();
        assert_eq!(r.out_of_range_codes, 2);
        c.end_frame().unwrap();
        assert_eq!(c.status().rejected_lines, 3);
        assert_eq!(c.status().incomplete_frames, 1);
        assert_eq!(c.status().out_of_range_codes, 2);
        let top = LutEntry::ideal::<4096>(4095).to_bits();
        assert_eq!(c.sums().state(1).unwrap()[..4], [LutEntry::ideal::<4096>(0).to_bits(), top, top, top]);
        assert!(c.sums().state(0).unwrap().iter().all(|&s| s == 0));
        assert_eq!(c.sums().frames(1).get(), 1);
    }

    #[test]
    fn geometry_and_buffer_are_validated() {
        assert!(Geometry::new(0, 1, 1, 0).is_err());
        assert!(Geometry::new(1, 1, 9, 0).is_err());
        let g = Geometry::new(3, 3, 2, 0).unwrap();
        let mut buf = [0u32; 17];
        assert!(matches!(SumImages::new(g, &mut buf), Err(CoreError::Length { expected: 18, got: 17, .. })));
    }

    /// The readout cycle: a frame is open between begin and end (and clearing is refused
    /// then), clearing zeroes every sum and frame count, and there is no state beyond the
    /// last.
    #[test]
    fn clearing_after_a_readout_zeroes_sums_and_frame_counts() {
        let g = Geometry::new(4, 1, 2, 0).unwrap();
        let mut buf = [0u32; 8];
        let mut banks = LutBanks::new(LutSet::<4, 4096>::ideal());
        let mut c = Corrector::new(&mut banks, g, &mut buf).unwrap();
        assert!(!c.frame_open());
        c.begin_frame(1).unwrap();
        assert!(c.frame_open());
        assert_eq!(c.clear_sums(), Err(CoreError::FrameOpen));
        c.accumulate_line(0, &[0, 1, 2, 3]).unwrap();
        c.end_frame().unwrap();
        assert!(!c.frame_open());
        // Ideal entries: code k reads (k + 1/2) 2^11 units.
        assert_eq!(c.sums().state(1).unwrap(), &[1024, 3072, 5120, 7168]);
        assert_eq!(c.sums().frames(1).get(), 1);
        assert_eq!(c.sums().state(2), None, "two states: 0 and 1");
        c.clear_sums().unwrap();
        assert_eq!(c.sums().state(1).unwrap(), &[0; 4]);
        assert_eq!((c.sums().frames(0).get(), c.sums().frames(1).get()), (0, 0));
    }
}
