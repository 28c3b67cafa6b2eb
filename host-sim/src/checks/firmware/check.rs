//! `dncal firmware-check`: the same LUTs and frames through the core on the host and
//! through the firmware under QEMU ([`crate::checks::firmware`]), compared sum by sum.

use std::time::Duration;

use dncal_core::{Geometry, Mvd1024eLuts};
use serde::Serialize;

use crate::formats::report::Report;
use crate::checks::firmware::instructions::{attribute, InstructionCounts};
use crate::checks::firmware::{build_firmware, repo_root, run_firmware, run_on_host, RunInputs};
use crate::model::synth::{dn_error_weights, synthetic_frames, Rng};
use crate::HostError;

/// What `firmware-check` asks for.
#[derive(Debug, Clone, Copy)]
pub struct CheckParams {
    /// Frames per modulation state.
    pub frames_per_state: u32,
    /// Modulation states.
    pub states: u8,
    /// Side of the square frames, pixels.
    pub size: u16,
    /// Seed of the LUTs' DN error and the frames.
    pub seed: u64,
    /// Also count the instructions the firmware executes, by place in the source (QEMU
    /// runs one instruction a block: seconds instead of a fraction of one).
    pub count_instructions: bool,
}

/// The comparison.
#[derive(Debug, Serialize)]
pub struct CheckReport {
    /// Sums compared (pixels x states).
    pub pixels: usize,
    /// Frames streamed.
    pub frames: usize,
    /// Sums that differ, plus any difference in their count.
    pub mismatches: usize,
    /// Whether the status counters and frames per state agree.
    pub status_equal: bool,
    /// Whether the captured histograms agree.
    pub histograms_equal: bool,
    /// The host core's noise estimate, DN, where the region allowed one.
    pub noise_sigma_dn: Option<f32>,
    /// The firmware's decoded defmt log.
    pub firmware_log: Vec<String>,
    /// Instructions the firmware executed, by place in the source, when asked for.
    pub instructions: Option<InstructionCounts>,
    /// All three agree.
    pub ok: bool,
    /// What the firmware printed over semihosting.
    #[serde(skip)]
    pub firmware_stdout: String,
    /// The request.
    #[serde(skip)]
    pub params: CheckParams,
}

impl Report for CheckReport {
    fn text(&self) -> String {
        let mut t = self.firmware_stdout.clone();
        let p = &self.params;
        t += &format!("host: {} frames of {}x{} in {} states, {} sums\n", self.frames, p.size, p.size, p.states, self.pixels);
        t += &format!("firmware vs host: {} sum mismatches, status equal: {}, histograms equal: {}\n", self.mismatches, self.status_equal, self.histograms_equal);
        for line in &self.firmware_log {
            t += &format!("firmware log: {line}\n");
        }
        if let Some(counts) = &self.instructions {
            t += &counts.table(0.01);
        }
        t
    }
}

/// Builds the firmware (`scripts/firmware.sh build`), runs `p`'s synthetic frames with
/// LUTs of random DN error through it under QEMU and through the core here, histogram
/// capture on, and compares the outputs. With `count_instructions`, QEMU also counts the
/// instructions the run executes, and they are placed in the source.
pub fn firmware_check(p: CheckParams) -> Result<CheckReport, HostError> {
    let geometry = Geometry::new(p.size, p.size, p.states, 130).map_err(|e| HostError::core("geometry from --size/--states", e))?;
    let mut rng = Rng::new(p.seed);
    let weights: Vec<_> = (0..4).map(|_| dn_error_weights(&mut rng, 4096)).collect();
    let luts = Mvd1024eLuts::from_weights(&[&weights[0], &weights[1], &weights[2], &weights[3]]).map_err(|e| HostError::core("LUTs from weights", e))?;
    let frames = synthetic_frames(&mut rng, geometry, p.frames_per_state * p.states as u32, 1.5, 4096);
    let inputs = RunInputs { luts, geometry, frames, capture_histograms: true };
    let host = run_on_host(&inputs)?;
    let elf = build_firmware()?;
    let fw = run_firmware(&elf, &inputs, &host.outputs.sums, Duration::from_secs(if p.count_instructions { 1200 } else { 600 }), p.count_instructions)?;
    let pixels = (inputs.frames.len() * geometry.pixels()) as u64;
    let instructions = fw.executed.as_ref().map(|executed| attribute(&elf, executed, &repo_root(), pixels)).transpose()?;
    let (ours, theirs) = (&host.outputs, &fw.outputs);
    let mismatches = theirs.sums.iter().zip(&ours.sums).filter(|(a, b)| a != b).count() + theirs.sums.len().abs_diff(ours.sums.len());
    let status_equal = theirs.status == ours.status && theirs.frames_per_state == ours.frames_per_state;
    let histograms_equal = theirs.histograms == ours.histograms;
    Ok(CheckReport {
        pixels: ours.sums.len(),
        frames: inputs.frames.len(),
        mismatches,
        status_equal,
        histograms_equal,
        noise_sigma_dn: host.noise.as_ref().ok().map(|r| r.sigma_dn),
        firmware_log: fw.log,
        instructions,
        ok: mismatches == 0 && status_equal && histograms_equal,
        firmware_stdout: fw.stdout,
        params: p,
    })
}
