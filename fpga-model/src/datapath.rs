//! The cycle model: input FIFO, BRAM lookup, read-modify-write of the sums.

use std::collections::VecDeque;

use dncal_core::accumulate::{lookup, saturating_sum};
use dncal_core::{AdcMap, Geometry, LutBanks, Mvd1024eLuts};

use crate::{Config, FpgaError};

/// ADCs of the modelled camera (column c is read by ADC c mod 4). With [`CODES`], the
/// core's `Mvd1024eLuts`: the banks below are `LutBanks<ADCS, CODES>` built from it, so
/// the compiler holds the two to the same numbers.
pub const ADCS: usize = 4;
/// Codes per ADC.
pub const CODES: usize = 4096;

/// A pixel in the pipeline: where its sum is, its raw code, the LUT bank it entered with.
#[derive(Debug, Clone, Copy)]
struct Pixel {
    index: usize,
    column: u32,
    raw: u16,
    bank: u64,
}

/// Counters and high-water marks since the model was built (`CLEAR_SUMS` clears the sums
/// and frame counts only).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Pixel clocks run.
    pub cycles: u64,
    /// Pixels accepted into the FIFO.
    pub pixels: u64,
    /// Pixels dropped by a full FIFO.
    pub fifo_overflows: u32,
    /// Largest FIFO occupancy seen, pixels.
    pub fifo_high_water: usize,
    /// Largest number of read-modify-writes in flight.
    pub inflight_high_water: usize,
    /// Codes above the top code (read as the top code).
    pub out_of_range: u32,
    /// Additions clipped at 2^32 - 1.
    pub saturated: u32,
    /// Lines rejected (wrong length, beyond the frame's height, outside a frame).
    pub rejected_lines: u32,
    /// Frames ended.
    pub frames: u32,
    /// Frames ended before all their lines arrived.
    pub incomplete_frames: u32,
    /// LUT bank swaps.
    pub lut_swaps: u32,
    /// Largest cycles from a pixel entering the FIFO to its write-back.
    pub max_latency: u64,
    /// Read-modify-writes issued to a sum whose previous one was still in flight: a
    /// design without forwarding would read a stale sum there (the model's update is
    /// atomic, so its sums stay right; this counts where hardware would need forwarding).
    /// Zero unless frames are shorter than the memory latency.
    pub rmw_hazards: u32,
    /// LUT uploads begun while pixels that entered with the previous tables were still
    /// queued: hardware has two banks, and the upload overwrites the one those pixels
    /// still need (the model keeps a copy, so its sums stay right; this counts where a
    /// design needs an interlock: hold `LUT_BEGIN` until the FIFO has drained).
    pub lut_overwrite_hazards: u32,
}

/// The timing of one frame through the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameTiming {
    /// Cycles of the frame: its vertical blanking (which comes first), then its lines.
    pub cycles: u64,
    /// Cycles with line-valid high.
    pub active_cycles: u64,
}

/// The datapath: configuration, registers, LUT banks, sums and the pipeline.
pub struct Fpga {
    pub(crate) config: Config,
    pub(crate) geometry: Geometry,
    pub(crate) banks: Box<LutBanks<ADCS, CODES>>,
    /// Banks retired by swaps while pixels that entered with them were still queued,
    /// by epoch (a design would hold the swap until they drain; the model keeps them).
    retired: VecDeque<(u64, Box<Mvd1024eLuts>)>,
    /// Bumped at every swap; pixels carry the value they entered with.
    bank_epoch: u64,
    pub(crate) sums: Vec<u32>,
    pub(crate) frames_per_state: Vec<u32>,
    fifo: VecDeque<(Pixel, u64)>,
    looked_up: Vec<(Pixel, dncal_core::LutEntry, u64)>,
    inflight: VecDeque<(u64, usize, dncal_core::LutEntry, u64)>,
    /// Sum indices with a read-modify-write in flight, and how many.
    inflight_at: std::collections::HashMap<usize, u32>,
    tokens: u64,
    pub(crate) stats: Stats,
    pub(crate) frame_open: Option<(u8, u16)>,
    /// The device's side of the SPI link (frame count, hold, open upload).
    pub(crate) link: crate::spi::LinkState,
}

impl Fpga {
    /// A datapath of `config` with geometry `geometry`, ideal LUTs, zero sums.
    pub fn new(config: Config, geometry: Geometry) -> Result<Self, FpgaError> {
        config.validate()?;
        config.holds(&geometry)?;
        Ok(Fpga {
            config,
            geometry,
            banks: Box::new(LutBanks::new(Mvd1024eLuts::ideal())),
            retired: VecDeque::new(),
            bank_epoch: 0,
            sums: vec![0; geometry.sum_len()],
            frames_per_state: vec![0; geometry.states() as usize],
            fifo: VecDeque::new(),
            looked_up: Vec::new(),
            inflight: VecDeque::new(),
            inflight_at: std::collections::HashMap::new(),
            tokens: 0,
            stats: Stats::default(),
            frame_open: None,
            link: Default::default(),
        })
    }

    /// The build-time configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The geometry the registers set.
    pub fn geometry(&self) -> Geometry {
        self.geometry
    }

    /// The sums of modulation state `state`, row-major (valid once [`Self::drain`] ran).
    pub fn sums(&self, state: u8) -> Option<&[u32]> {
        let n = self.geometry.width() as usize * self.geometry.height() as usize;
        self.sums.get(state as usize * n..(state as usize + 1) * n)
    }

    /// Frames summed in `state`.
    pub fn frames(&self, state: u8) -> u32 {
        self.frames_per_state.get(state as usize).copied().unwrap_or(0)
    }

    /// Counters and high-water marks.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// The LUT banks (the staging bank is what an SPI upload fills).
    pub fn banks(&self) -> &LutBanks<ADCS, CODES> {
        &self.banks
    }

    /// Changes the geometry (the `WIDTH`, `HEIGHT`, `STATES`, `FIRST_COLUMN` registers):
    /// clears the sums; refused while a frame is open.
    pub(crate) fn set_geometry(&mut self, geometry: Geometry) -> Result<(), FpgaError> {
        if self.frame_open.is_some() {
            return Err(FpgaError::Config("geometry", "cannot change while a frame is open".into()));
        }
        self.config.holds(&geometry)?;
        self.drain();
        self.geometry = geometry;
        self.clear_sums();
        Ok(())
    }

    /// Zeroes the sums and the frame counts once the pipeline has drained.
    pub(crate) fn clear_sums(&mut self) {
        self.drain();
        self.sums = vec![0; self.geometry.sum_len()];
        self.frames_per_state = vec![0; self.geometry.states() as usize];
    }

    fn swap_if_pending(&mut self) {
        if !self.banks.activation_pending() {
            return;
        }
        let old = Box::new(self.banks.active().clone());
        if self.banks.swap_if_pending() {
            if !self.fifo.is_empty() {
                self.retired.push_back((self.bank_epoch, old));
            }
            self.bank_epoch += 1;
            self.stats.lut_swaps = self.stats.lut_swaps.saturating_add(1);
        }
    }

    /// A `LUT_BEGIN`: the staging bank is overwritten from here on (see
    /// [`Stats::lut_overwrite_hazards`]).
    pub(crate) fn begin_upload(&mut self) {
        if self.fifo.front().is_some_and(|(p, _)| p.bank < self.bank_epoch) {
            self.stats.lut_overwrite_hazards = self.stats.lut_overwrite_hazards.saturating_add(1);
        }
        self.banks.begin_upload();
    }

    /// The frame-boundary action of a `LUT_COMMIT` (as the core's corrector: at once if
    /// no frame is open, otherwise when the open frame ends). Register traffic takes no
    /// cycles in the model and frames are streamed whole, so over SPI no frame is ever
    /// open here: the swap happens at once; the frame-boundary path is the core's.
    pub(crate) fn activation_requested(&mut self) {
        if self.frame_open.is_none() {
            self.swap_if_pending();
        }
    }

    /// One pixel clock. `beat` holds the pixels delivered in it (line-valid high), each as
    /// (index into the sums, sensor column, raw code).
    fn tick(&mut self, beat: &[(usize, u32, u16)]) {
        let cycle = self.stats.cycles;
        // Write-backs due this cycle.
        while let Some(&(ready, index, entry, entered)) = self.inflight.front() {
            if ready > cycle {
                break;
            }
            self.inflight.pop_front();
            if let Some(n) = self.inflight_at.get_mut(&index) {
                *n -= 1;
                if *n == 0 {
                    self.inflight_at.remove(&index);
                }
            }
            let (sum, clipped) = saturating_sum(self.sums[index], entry);
            self.sums[index] = sum;
            self.stats.saturated = self.stats.saturated.saturating_add(clipped as u32);
            self.stats.max_latency = self.stats.max_latency.max(cycle - entered);
        }
        // Last cycle's BRAM outputs issue their read-modify-writes.
        for (p, entry, entered) in self.looked_up.drain(..) {
            let n = self.inflight_at.entry(p.index).or_insert(0);
            if *n > 0 {
                self.stats.rmw_hazards = self.stats.rmw_hazards.saturating_add(1);
            }
            *n += 1;
            self.inflight.push_back((cycle + u64::from(self.config.mem_latency), p.index, entry, entered));
        }
        self.stats.inflight_high_water = self.stats.inflight_high_water.max(self.inflight.len());
        // Lookups: as many pixels as taps and the memory bandwidth allow (2 words each).
        // The bucket holds one cycle's words (two when a cycle brings one, so that a pixel
        // can issue every other cycle; one more when it brings an odd number, so that the
        // half pixel left over is not lost): no burst above the memory's bandwidth (the
        // first version held four cycles' words and issued 4 pixels in a cycle on a
        // 2-word memory after a blanking).
        let words = u64::from(self.config.mem_words_per_cycle);
        self.tokens = (self.tokens + words).min(words.max(2) + words % 2);
        let mut issued = 0;
        while issued < self.config.taps && self.tokens >= 2 {
            let Some((p, entered)) = self.fifo.pop_front() else { break };
            while self.retired.front().is_some_and(|(e, _)| *e < p.bank) {
                self.retired.pop_front();
            }
            let luts = match self.retired.iter().find(|(e, _)| *e == p.bank) {
                Some((_, l)) => l.as_ref(),
                None => self.banks.active(),
            };
            let table = &luts.tables()[AdcMap::<ADCS>::adc(p.column)];
            let (entry, clipped) = lookup(table, p.raw);
            self.stats.out_of_range = self.stats.out_of_range.saturating_add(clipped as u32);
            self.looked_up.push((p, entry, entered));
            self.tokens -= 2;
            issued += 1;
        }
        // Input.
        for &(index, column, raw) in beat {
            if self.fifo.len() >= self.config.fifo_depth {
                self.stats.fifo_overflows = self.stats.fifo_overflows.saturating_add(1);
            } else {
                self.fifo.push_back((Pixel { index, column, raw, bank: self.bank_epoch }, cycle));
                self.stats.pixels += 1;
            }
        }
        self.stats.fifo_high_water = self.stats.fifo_high_water.max(self.fifo.len());
        self.stats.cycles += 1;
    }

    /// Runs clocks without input until the pipeline is empty.
    pub fn drain(&mut self) {
        while !(self.fifo.is_empty() && self.looked_up.is_empty() && self.inflight.is_empty()) {
            self.tick(&[]);
        }
    }

    /// Streams one frame of modulation state `state`: vertical blanking, then each line
    /// (line-valid for `ceil(width / taps)` cycles, then horizontal blanking). Lines of the
    /// wrong length or beyond the frame's height are rejected and counted (their cycles
    /// still pass: the camera sends them); a frame with fewer lines is counted incomplete.
    /// A pending LUT activation happens at the frame's start and end, as in the core.
    pub fn stream_frame(&mut self, state: u8, lines: &[&[u16]]) -> Result<FrameTiming, FpgaError> {
        if state >= self.geometry.states() {
            return Err(FpgaError::Core(dncal_core::CoreError::State { state, states: self.geometry.states() }));
        }
        let start = self.stats.cycles;
        for _ in 0..self.config.v_blank {
            self.tick(&[]);
        }
        self.swap_if_pending();
        self.frame_open = Some((state, 0));
        let (w, h) = (self.geometry.width() as usize, self.geometry.height() as usize);
        let first = u32::from(self.geometry.first_column());
        let mut active = 0u64;
        let mut beat = Vec::with_capacity(self.config.taps);
        let mut next_row = 0usize;
        for (row, line) in lines.iter().enumerate() {
            // As the core: a line must have the frame's width and be the next one; after
            // a rejected line the row count does not advance, so the rest of the frame is
            // rejected too.
            let ok = line.len() == w && row == next_row && row < h;
            if !ok {
                self.stats.rejected_lines = self.stats.rejected_lines.saturating_add(1);
            }
            for (k, chunk) in line.chunks(self.config.taps).enumerate() {
                beat.clear();
                if ok {
                    let base = (state as usize * h + row) * w;
                    let col0 = k * self.config.taps;
                    beat.extend(chunk.iter().enumerate().map(|(i, &raw)| (base + col0 + i, first + (col0 + i) as u32, raw)));
                }
                self.tick(&beat);
                active += 1;
            }
            for _ in 0..self.config.h_blank {
                self.tick(&[]);
            }
            if ok {
                next_row += 1;
                self.frame_open = Some((state, next_row as u16));
            }
        }
        let received = self.frame_open.map_or(0, |f| f.1);
        if (received as usize) < h {
            self.stats.incomplete_frames = self.stats.incomplete_frames.saturating_add(1);
        }
        self.frame_open = None;
        if let Some(c) = self.frames_per_state.get_mut(state as usize) {
            *c = c.saturating_add(1);
        }
        self.stats.frames = self.stats.frames.saturating_add(1);
        self.swap_if_pending();
        Ok(FrameTiming { cycles: self.stats.cycles - start, active_cycles: active })
    }
}
