//! `dncal fpga-size`: the frame-grabber datapath sized for a camera system, measured in
//! the cycle-level model ([`dncal_fpga_model::sizing`]); and the LUTs as `$readmemh`
//! files for an HDL implementation.

use std::path::{Path, PathBuf};

use dncal_core::Mvd1024eLuts;
use dncal_fpga_model::sizing::{readmemh, size, Sizing, System};
use dncal_fpga_model::Config;
use serde::Serialize;

use crate::formats::report::{wrote, Report};
use crate::formats::lut::LutFault;
use crate::formats::outputs::Outputs;
use crate::HostError;

/// The report: the sizing and the files written.
#[derive(Debug, Serialize)]
pub struct FpgaSizeReport {
    /// The model's FIFO depth and memory latency (taps, blanking and memory bandwidth are
    /// set per row).
    pub fifo_depth: usize,
    pub mem_latency: u32,
    /// The sizing.
    #[serde(flatten)]
    pub sizing: Sizing,
    /// Modulation states the sum memory holds.
    pub states: u8,
    /// `$readmemh` files written.
    pub readmemh: Vec<PathBuf>,
}

impl Report for FpgaSizeReport {
    fn text(&self) -> String {
        let s = &self.sizing;
        let mut t = format!(
            "{} camera(s) of {}x{} at {} frames/s: {:.1} Mpixel/s; sum memory {:.2} GB/s (a 32-bit read and write per pixel), {:.1} MiB per camera for {} states\n",
            s.system.cameras,
            s.system.width,
            s.system.height,
            s.system.frame_rate_hz,
            s.pixels_per_s / 1e6,
            s.sum_bandwidth_bytes_per_s / 1e9,
            s.sum_memory_bytes as f64 / 1048576.0,
            self.states
        );
        for row in &s.taps {
            t += &format!(
                "{} taps: clock {:.1} MHz per camera, {} cycles per frame, {:.3} pixels/clock, latency {} cycles, FIFO high water {} ({} dropped), read-modify-writes in flight up to {}, LUT BRAM {} bits; {}\n",
                row.taps, row.clock_mhz, row.cycles_per_frame, row.pixels_per_clock, row.latency_cycles, row.fifo_high_water, row.fifo_overflows, row.inflight_high_water, row.bram_bits, row.lut_access
            );
        }
        t + &wrote(&self.readmemh)
    }
}

/// The request's limits, each said with the `fpga-size` option that sets it: the model
/// holds a square frame's sums in memory (up to 8192 pixels a side) and the core's bound
/// on modulation states.
fn check(system: &System, states: u8, config: &Config) -> Result<(), HostError> {
    config.validate().map_err(|e| HostError::argument("--fifo-depth / --mem-latency", e.to_string()))?;
    if system.cameras == 0 {
        return Err(HostError::argument("--cameras", "must be at least 1"));
    }
    if !(system.frame_rate_hz.is_finite() && system.frame_rate_hz > 0.0) {
        return Err(HostError::argument("--frame-rate", format!("{} Hz must be finite and > 0", system.frame_rate_hz)));
    }
    for side in [system.width, system.height] {
        if side == 0 || side > 8192 {
            return Err(HostError::argument("--size", format!("{side}: 1 to 8192 pixels (the model holds a frame's sums in memory)")));
        }
    }
    if states == 0 || usize::from(states) > dncal_core::MAX_STATES {
        return Err(HostError::argument("--states", format!("{states}: 1 to {} modulation states", dncal_core::MAX_STATES)));
    }
    Ok(())
}

/// Sizes for `system` at 1, 2, 4 and 8 taps; with `lut` and `out`, writes one
/// `lut_adc{a}.hex` per ADC of the LUT FITS file into `out` (validated by the core first),
/// all of them or none.
pub fn fpga_size(system: &System, states: u8, config: &Config, lut: Option<&Path>, out: Option<&Path>) -> Result<FpgaSizeReport, HostError> {
    check(system, states, config)?;
    // The LUT first: a bad file is reported at once, not after the sizing's seconds.
    let mut staged = Outputs::new();
    let luts = match (lut, out) {
        (Some(lut), Some(out)) => {
            let luts = load_luts(lut)?;
            expect_readmemh(&mut staged, out)?;
            Some((luts, out))
        }
        _ => None,
    };
    let sizing = size(system, states, config, &[1, 2, 4, 8]).map_err(|source| HostError::Fpga { source })?;
    let mut files = Vec::new();
    if let Some((luts, out)) = luts {
        for (a, table) in luts.tables().iter().enumerate() {
            let path = out.join(format!("lut_adc{a}.hex"));
            staged.write_bytes(&path, readmemh(a, &table[..]))?;
            files.push(path);
        }
    }
    staged.publish()?;
    Ok(FpgaSizeReport { fifo_depth: config.fifo_depth, mem_latency: config.mem_latency, sizing, states, readmemh: files })
}

/// Creates `dir` and checks the `$readmemh` files [`fpga_size`] writes there, one per table
/// of the FPGA model's four ([`Mvd1024eLuts`]; a LUT of another count is refused), before
/// anything is computed.
pub fn expect_readmemh(files: &mut Outputs, dir: &Path) -> Result<(), HostError> {
    files.create_dir(dir)?;
    files.expect((0..4).map(|a| dir.join(format!("lut_adc{a}.hex"))))
}

/// The LUT `lut` (any format the LUT home reads) as the FPGA model's four 12-bit tables,
/// validated by the core.
fn load_luts(lut: &Path) -> Result<Mvd1024eLuts, HostError> {
    let (_, t) = crate::formats::lut::read(lut)?;
    let bits: Vec<[u32; 4096]> = t
        .tables
        .iter()
        .map(|v| <[u32; 4096]>::try_from(v.as_slice()).map_err(|_| HostError::lut(lut, LutFault::FpgaTableLength { entries: v.len() })))
        .collect::<Result<_, _>>()?;
    let bits: [[u32; 4096]; 4] = bits.try_into().map_err(|v: Vec<_>| HostError::lut(lut, LutFault::FpgaTableCount { tables: v.len() }))?;
    Mvd1024eLuts::from_bits(&bits).map_err(|e| HostError::core(format!("{}", lut.display()), e))
}
