//! `dncal`: the command people run. Library code returns `HostError`; this file turns it
//! into a message on stderr and a nonzero exit.

use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use dncal_core::{Geometry, Mvd1024eLuts};
use dncal_host::firmware::{build_firmware, run_firmware, run_on_host, RunInputs};
use dncal_host::synth::{dn_error_weights, synthetic_frames, Rng};
use dncal_host::HostError;

#[derive(Parser)]
#[command(name = "dncal", version, about = "Real-time correction and characterization of scientific camera detectors")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run the correction core on the Cortex-M4 firmware in QEMU and on the host, and
    /// compare the per-state sums bit for bit.
    FirmwareCheck {
        /// Frames per modulation state.
        #[arg(long, default_value_t = 8)]
        frames_per_state: u32,
        /// Modulation states.
        #[arg(long, default_value_t = 4)]
        states: u8,
        /// Line width and frame height, pixels (the firmware takes at most 64 x 64 x 4 sums).
        #[arg(long, default_value_t = 64)]
        size: u16,
        /// Seed of the synthetic LUTs and lines.
        #[arg(long, default_value_t = 2018)]
        seed: u64,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("dncal: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode, HostError> {
    match cli.command {
        Cmd::FirmwareCheck { frames_per_state, states, size, seed, json } => firmware_check(frames_per_state, states, size, seed, json),
    }
}

fn firmware_check(frames_per_state: u32, states: u8, size: u16, seed: u64, json: bool) -> Result<ExitCode, HostError> {
    let geometry = Geometry::new(size, size, states, 130).map_err(|e| HostError::core("geometry from --size/--states", e))?;
    let mut rng = Rng::new(seed);
    let weights: Vec<_> = (0..4).map(|_| dn_error_weights(&mut rng, 4096)).collect();
    let luts = Mvd1024eLuts::from_weights(&[&weights[0], &weights[1], &weights[2], &weights[3]]).map_err(|e| HostError::core("LUTs from weights", e))?;
    let frames = synthetic_frames(&mut rng, geometry, frames_per_state * states as u32, 1.5, 4096);
    let inputs = RunInputs { luts, geometry, frames };
    let host = run_on_host(&inputs)?;
    let elf = build_firmware()?;
    let fw = run_firmware(&elf, &inputs, &host.outputs.sums, Duration::from_secs(600))?;
    let mismatches = fw.outputs.sums.iter().zip(&host.outputs.sums).filter(|(a, b)| a != b).count()
        + fw.outputs.sums.len().abs_diff(host.outputs.sums.len());
    let same_status = fw.outputs.status == host.outputs.status && fw.outputs.frames_per_state == host.outputs.frames_per_state;
    let same_hist = fw.outputs.histograms == host.outputs.histograms;
    let ok = mismatches == 0 && same_status && same_hist;
    if json {
        let summary = serde_json::json!({
            "pixels": host.outputs.sums.len(),
            "frames": inputs.frames.len(),
            "mismatches": mismatches,
            "status_equal": same_status,
            "histograms_equal": same_hist,
            "noise_sigma_dn": host.noise.as_ref().ok().map(|r| r.sigma_dn),
            "firmware_log": fw.log,
            "ok": ok,
        });
        println!("{summary:#}");
    } else {
        print!("{}", fw.stdout);
        println!("host: {} frames of {}x{} in {} states, {} sums", inputs.frames.len(), size, size, states, host.outputs.sums.len());
        println!("firmware vs host: {mismatches} sum mismatches, status equal: {same_status}, histograms equal: {same_hist}");
        for line in &fw.log {
            println!("firmware log: {line}");
        }
    }
    Ok(if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
