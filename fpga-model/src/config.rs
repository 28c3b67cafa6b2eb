//! The datapath's build-time parameters (what an HDL design would fix as generics).

use crate::FpgaError;

/// Build-time parameters of the datapath.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Config {
    /// Pixels delivered per pixel clock, 1 to 8 (Camera Link base to deca: 1 to 10 taps;
    /// we model up to 8).
    pub taps: usize,
    /// Input FIFO depth, pixels.
    pub fifo_depth: usize,
    /// Cycles from issuing a pixel's read-modify-write to its write-back.
    pub mem_latency: u32,
    /// Sum-memory bandwidth, 32-bit words per pixel clock (reads plus writes).
    pub mem_words_per_cycle: u32,
    /// Idle cycles between lines (line-valid low).
    pub h_blank: u32,
    /// Idle cycles between frames (frame-valid low).
    pub v_blank: u32,
}

impl Default for Config {
    /// 4 taps, a 1024-pixel FIFO, 32 cycles of memory latency, 8 words per cycle (enough
    /// for 4 pixels' reads and writes), 64 and 1024 cycles of blanking.
    fn default() -> Self {
        Config { taps: 4, fifo_depth: 1024, mem_latency: 32, mem_words_per_cycle: 8, h_blank: 64, v_blank: 1024 }
    }
}

impl Config {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), FpgaError> {
        if !(1..=8).contains(&self.taps) {
            return Err(FpgaError::Config("taps", format!("must be 1 to 8, got {}", self.taps)));
        }
        if self.fifo_depth < self.taps {
            return Err(FpgaError::Config("fifo_depth", format!("must hold one beat of {} pixels, got {}", self.taps, self.fifo_depth)));
        }
        if self.mem_words_per_cycle == 0 {
            return Err(FpgaError::Config("mem_words_per_cycle", "must be at least 1".into()));
        }
        if self.mem_latency > 1_000_000 {
            return Err(FpgaError::Config("mem_latency", format!("{} cycles is not a memory", self.mem_latency)));
        }
        Ok(())
    }
}
