//! The firmware in QEMU against the host, bit for bit.
//!
//! A LUT set with DN error and 8 frames x 4 modulation states of 64 x 64 synthetic
//! lines go through the core on the host and through the firmware (thumbv7em-none-eabihf
//! on QEMU mps2-an386), which writes its sums, status and histograms back over
//! semihosting. Both must equal each other and the naive reference of `dncal_tests`.
//! The firmware's defmt log is decoded with its ELF.
//!
//! Needs the cross toolchain: `scripts/firmware.sh install` (the README's test command
//! runs it). Without it this test fails; it does not skip.

use std::time::Duration;

use dncal_core::{Geometry, LutSet, Mvd1024eLuts};
use dncal_host::checks::firmware::instructions::{attribute, correction_cost};
use dncal_host::checks::firmware::{build_firmware, repo_root, run_firmware, run_on_host, RunInputs};
use dncal_host::model::synth::{dn_error_weights, synthetic_frames, Rng};
use dncal_tests::{lut_bits, naive_histograms, naive_sums};

const FRAMES: u32 = 32;

#[test]
fn firmware_sums_are_bit_exact_with_the_host() {
    let elf = build_firmware().expect("firmware build (scripts/firmware.sh install installs the toolchain)");
    let mut rng = Rng::new(0x5EED_2018);
    let weights: Vec<Vec<_>> = (0..4).map(|_| dn_error_weights(&mut rng, 4096)).collect();
    let luts = Mvd1024eLuts::from_weights(&[&weights[0], &weights[1], &weights[2], &weights[3]]).unwrap();
    assert_ne!(luts, LutSet::ideal(), "the test LUT must differ from the boot LUT");
    let g = Geometry::new(64, 64, 4, 130).unwrap();
    let frames = synthetic_frames(&mut rng, g, FRAMES, 1.5, 4096);
    let inputs = RunInputs { luts: luts.clone(), geometry: g, frames: frames.clone(), capture_histograms: true };

    let host = run_on_host(&inputs).unwrap();
    let naive = naive_sums(&lut_bits(&luts), g, &frames);
    assert!(naive.iter().all(|&s| s < 1 << 32));
    assert_eq!(host.outputs.sums.iter().map(|&s| s as u64).collect::<Vec<_>>(), naive, "host core vs naive reference");

    let fw = run_firmware(&elf, &inputs, &host.outputs.sums, Duration::from_secs(600), true).unwrap();
    println!("{}\ndefmt log:\n{}", fw.stdout, fw.log.join("\n"));
    let pixels = g.sum_len();
    assert!(fw.stdout.contains(&format!("firmware bit-exact: OK ({pixels} pixels)")), "{}", fw.stdout);
    assert_eq!(fw.outputs.sums, host.outputs.sums, "firmware sums vs host sums");
    assert_eq!(fw.outputs.status, host.outputs.status);
    assert_eq!(fw.outputs.status.lut_swaps, 1, "one swap from the boot LUT to the uploaded one");
    assert_eq!(fw.outputs.status.out_of_range_codes, 2 * FRAMES, "two planted codes above the top per frame");
    assert_eq!(fw.outputs.frames_per_state, vec![FRAMES / 4; 4]);
    let naive_hist = naive_histograms(g, &frames, 4, 4096);
    assert_eq!(fw.outputs.histograms, naive_hist, "firmware histograms vs naive count");
    assert_eq!(host.outputs.histograms, naive_hist);

    assert!(fw.log.iter().any(|l| l.contains("LUT image validated")), "{:?}", fw.log);
    let noise_line = fw.log.iter().find(|l| l.starts_with("noise check: sigma")).expect("noise check logged");
    let sigma: f32 = noise_line.split_whitespace().nth(3).unwrap().parse().unwrap();
    let host_noise = host.noise.unwrap();
    assert_eq!(sigma, host_noise.sigma_dn, "device noise estimate (micromath on the M4) vs host: {noise_line}");
    assert!((host_noise.sigma_dn - 1.5).abs() < 0.15, "planted noise 1.5 DN, estimated {}", host_noise.sigma_dn);

    // Without the capture flag the device runs the correction alone: the same sums and
    // status, histograms untouched (all zero), and it says so in its log.
    let science = RunInputs { capture_histograms: false, ..inputs };
    let host_science = run_on_host(&science).unwrap();
    assert_eq!(host_science.outputs.sums, host.outputs.sums);
    assert!(host_science.outputs.histograms.iter().all(|&c| c == 0));
    let fw_science = run_firmware(&elf, &science, &host.outputs.sums, Duration::from_secs(600), true).unwrap();
    assert_eq!(fw_science.outputs.sums, host.outputs.sums, "firmware sums without capture");
    assert_eq!(fw_science.outputs.status, host.outputs.status);
    assert!(fw_science.outputs.histograms.iter().all(|&c| c == 0), "no capture asked, none done");
    assert!(fw_science.log.iter().any(|l| l == "histogram capture false"), "{:?}", fw_science.log);
    assert!(fw.log.iter().any(|l| l == "histogram capture true"), "{:?}", fw.log);

    // Counted by QEMU, instruction by instruction: the capture pass runs on every pixel
    // when asked for and not one instruction of it runs otherwise.
    let pixels = (FRAMES as usize * g.pixels()) as u64;
    let counted = |run: &dncal_host::checks::firmware::FirmwareRun| attribute(&elf, run.executed.as_ref().unwrap(), &repo_root(), pixels).unwrap();
    let (with, without) = (counted(&fw), counted(&fw_science));
    println!("with capture:\n{}without:\n{}", with.table(0.5), without.table(0.5));
    assert!(with.per_pixel_in("capture_line") >= 3.0, "a count is at least a code load, a count load and a store:\n{}", with.table(0.0));
    assert_eq!(without.per_pixel_in("capture_line"), 0.0, "{}", without.table(0.0));
    assert!(without.per_pixel_in("accumulate_line") >= 3.0, "the correction is where the counts place it:\n{}", without.table(0.0));
}

/// The correction's cost per pixel, measured: QEMU counts the instructions the firmware
/// executes in `accumulate_line` on lines of 16, 32 and 64 pixels, split into a per-line
/// and a per-pixel part ([`correction_cost`]). Issue 17's target for the exact-mode
/// loop: at most 7 a pixel. The disassembly says 25 instructions per 4 pixels.
#[test]
fn the_exact_mode_correction_costs_at_most_seven_instructions_a_pixel_under_qemu() {
    let elf = build_firmware().expect("firmware build (scripts/firmware.sh install installs the toolchain)");
    let cost = correction_cost(&elf).unwrap();
    println!("accumulate_line: {:.3} instructions a pixel + {:.1} a line; the 16-pixel lines {:+.4} off the fit", cost.per_pixel, cost.per_line, cost.misfit);
    assert!(cost.misfit.abs() <= 1e-3, "the count is not a per-line plus a per-pixel part: {cost:?}");
    assert!(cost.per_pixel >= 4.0, "a LUT correction needs at least the index, the entry's load, the add and part of a load and store: {cost:?}");
    assert!(cost.per_pixel <= 7.0, "issue 17: at most 7 instructions a pixel in the exact-mode loop: {cost:?}");
}
