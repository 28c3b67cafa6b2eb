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
    /// Cycles from issuing a pixel's read-modify-write to its write-back, at least 1 (a
    /// pixel's whole latency, FIFO entry to write-back, is this plus 2: a cycle in the
    /// FIFO and one in the BRAM).
    pub mem_latency: u32,
    /// Sum-memory bandwidth, 32-bit words per pixel clock (reads plus writes).
    pub mem_words_per_cycle: u32,
    /// Idle cycles between lines (line-valid low).
    pub h_blank: u32,
    /// Idle cycles between frames (frame-valid low).
    pub v_blank: u32,
    /// Size of the sum memory, 32-bit words: a geometry needing more is refused (the model
    /// holds the sums in host memory; a register write must not ask for 500 GB).
    pub sum_words: usize,
}

impl Default for Config {
    /// 4 taps, a 1024-pixel FIFO, 32 cycles of memory latency, 8 words per cycle (enough
    /// for 4 pixels' reads and writes), 64 and 1024 cycles of blanking, 256 MiB of sums
    /// (2^26 words: 8 states of 2048 x 4096).
    fn default() -> Self {
        Config { taps: 4, fifo_depth: 1024, mem_latency: 32, mem_words_per_cycle: 8, h_blank: 64, v_blank: 1024, sum_words: 1 << 26 }
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
        if self.mem_latency == 0 {
            return Err(FpgaError::Config("mem_latency", "must be at least 1 cycle (a write-back lands after its issue)".into()));
        }
        if self.sum_words > 1 << 30 {
            return Err(FpgaError::Config("sum_words", format!("{} words (4 GiB or more) is more than the model holds", self.sum_words)));
        }
        if self.mem_latency > 1_000_000 {
            return Err(FpgaError::Config("mem_latency", format!("{} cycles is not a memory", self.mem_latency)));
        }
        Ok(())
    }

    /// Whether the sums of `geometry` fit the sum memory.
    pub fn holds(&self, geometry: &dncal_core::Geometry) -> Result<(), FpgaError> {
        if geometry.sum_len() > self.sum_words {
            return Err(FpgaError::Config("geometry", format!("needs {} words of sum memory, the design has {}", geometry.sum_len(), self.sum_words)));
        }
        Ok(())
    }
}
