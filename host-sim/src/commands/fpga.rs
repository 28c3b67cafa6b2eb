//! `dncal fpga-size`: the frame-grabber datapath sized for a camera system, measured in
//! the cycle-level model ([`dncal_fpga_model::sizing`]); and the LUTs as `$readmemh`
//! files for an HDL implementation.

use std::path::{Path, PathBuf};

use dncal_core::Mvd1024eLuts;
use dncal_fpga_model::sizing::{readmemh, size, Sizing, System};
use dncal_fpga_model::Config;
use serde::Serialize;

use crate::fits::read_lut;
use crate::outputs::Outputs;
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
    /// `$readmemh` files written.
    pub readmemh: Vec<PathBuf>,
}

/// Sizes for `system` at 1, 2, 4 and 8 taps; with `lut` and `out`, writes one
/// `lut_adc{a}.hex` per ADC of the LUT FITS file into `out` (validated by the core first),
/// all of them or none.
pub fn fpga_size(system: &System, states: u8, config: &Config, lut: Option<&Path>, out: Option<&Path>) -> Result<FpgaSizeReport, HostError> {
    // The LUT first: a bad file is reported at once, not after the sizing's seconds.
    let mut staged = Outputs::new();
    let luts = match (lut, out) {
        (Some(lut), Some(out)) => {
            let luts = load_luts(lut)?;
            staged.create_dir(out)?;
            staged.expect((0..luts.tables().len()).map(|a| out.join(format!("lut_adc{a}.hex"))))?;
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
    Ok(FpgaSizeReport { fifo_depth: config.fifo_depth, mem_latency: config.mem_latency, sizing, readmemh: files })
}

/// The LUT FITS `lut` as the FPGA model's four 12-bit tables, validated by the core.
fn load_luts(lut: &Path) -> Result<Mvd1024eLuts, HostError> {
    let t = read_lut(lut)?;
    let bits: Vec<[u32; 4096]> = t
        .tables
        .iter()
        .map(|v| <[u32; 4096]>::try_from(v.as_slice()).map_err(|_| HostError::Format { path: lut.into(), message: format!("a table of {} entries; the FPGA model is built for 4096", v.len()) }))
        .collect::<Result<_, _>>()?;
    let bits: [[u32; 4096]; 4] = bits.try_into().map_err(|v: Vec<_>| HostError::Format { path: lut.into(), message: format!("{} tables; the FPGA model is built for 4 ADCs", v.len()) })?;
    Mvd1024eLuts::from_bits(&bits).map_err(|e| HostError::core(format!("{}", lut.display()), e))
}
