//! Instructions the firmware executes, counted under QEMU and placed in the source.
//!
//! QEMU runs one guest instruction per translation block (`-singlestep`) and logs each
//! block it executes without chaining blocks (`-d exec,nochain`), so every executed
//! instruction is one `Trace` line on QEMU's stderr, carrying its address. The counts per
//! address are read as the log streams (a 64 x 64 x 32-frame run logs 5 to 7 million
//! lines: nothing is written to disk), and each address is placed by the ELF's DWARF
//! line tables and its chain of inlined frames. Inside the core's stream loop an address
//! counts for the pass the loop called (`core/src/accumulate.rs accumulate_line`: the
//! correction with everything inlined into it, slice iterators and `copy_from_slice`
//! included; `capture_line`; the firmware's line input); elsewhere for the innermost
//! function in the project's sources. A function the pass calls out of line (the core's
//! `retake_out_of_range`, a `memcpy`) counts under its own name, not the pass's. This is what a disassembly cannot give:
//! instructions executed, heads, tails and per-line work included, per pixel.

use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::Path;

use serde::Serialize;

use super::FirmwareFault;
use crate::HostError;

/// The QEMU arguments that log one line per executed instruction on stderr, for QEMU
/// `(major, minor)`: one instruction a translation block is `-singlestep` up to 8.0 and
/// `-accel tcg,one-insn-per-tb=on` from 8.1 (`-singlestep` was removed in 9.0).
pub fn trace_args(version: (u32, u32)) -> &'static [&'static str] {
    if version >= (8, 1) {
        &["-accel", "tcg,one-insn-per-tb=on", "-d", "exec,nochain"]
    } else {
        &["-singlestep", "-d", "exec,nochain"]
    }
}

/// The `(major, minor)` version of the QEMU binary `qemu`, from `qemu --version`
/// (`QEMU emulator version 7.2.22 (Debian ...)`).
pub fn qemu_version(qemu: &str) -> Result<(u32, u32), HostError> {
    let tool = |message: String| HostError::Tool { program: qemu.into(), message };
    let out = std::process::Command::new(qemu).arg("--version").output().map_err(|e| tool(e.to_string()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    parse_version(&text).ok_or_else(|| tool(format!("no version in `{qemu} --version`: {}", text.trim())))
}

fn parse_version(text: &str) -> Option<(u32, u32)> {
    let rest = &text[text.find("version ")? + "version ".len()..];
    let mut parts = rest.split(|c: char| !c.is_ascii_digit());
    Some((parts.next()?.parse().ok()?, parts.next()?.parse().ok()?))
}

/// Most of QEMU's other stderr kept for an error message, bytes.
const OTHER_LIMIT: usize = 64 * 1024;

/// Executed instructions per guest address.
pub type Executed = BTreeMap<u32, u64>;

/// Reads QEMU's stderr to its end (a reader that stopped early would leave QEMU blocked
/// on a full pipe): counts the `Trace` lines per guest address and returns the counts
/// with the other lines (QEMU's own messages, for errors; the first 64 KiB).
pub fn read_trace(mut stderr: impl BufRead) -> (Executed, String) {
    let mut counts = Executed::new();
    let mut other = String::new();
    let mut bytes = Vec::new();
    loop {
        bytes.clear();
        match stderr.read_until(b'\n', &mut bytes) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) => break,
        }
        let line = String::from_utf8_lossy(&bytes);
        match trace_pc(&line) {
            Some(pc) => *counts.entry(pc).or_default() += 1,
            None if other.len() < OTHER_LIMIT => {
                other += line.trim_end_matches('\n');
                other.push('\n');
            }
            None => {}
        }
    }
    (counts, other)
}

/// The guest address of a QEMU `exec` log line,
/// `Trace 0: 0x7f0c68071dc0 [00800408/00000aac/00000010/ff000201] symbol`:
/// the second field in brackets (QEMU 7.2 to 9: cs_base/pc/flags/cflags).
fn trace_pc(line: &str) -> Option<u32> {
    let rest = line.strip_prefix("Trace ")?;
    let fields = &rest[rest.find('[')? + 1..];
    let pc = fields.split(['/', ']']).nth(1)?;
    u32::from_str_radix(pc, 16).ok()
}

/// Instructions executed at one place of the source.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Place {
    /// Source file, relative to the repository (or as DWARF has it, outside it).
    pub file: String,
    /// Function, without its path and generic arguments (`add_indexed`,
    /// `run::{closure#0}`).
    pub function: String,
    /// Instructions executed there.
    pub instructions: u64,
    /// The same per pixel streamed.
    pub per_pixel: f64,
}

/// A run's executed instructions by place, most first.
#[derive(Debug, Clone, Serialize)]
pub struct InstructionCounts {
    /// Pixels streamed (frames x width x height).
    pub pixels: u64,
    /// Instructions executed in the whole run, boot and file I/O included.
    pub total: u64,
    /// Places, most instructions first; their instructions add up to `total`.
    pub places: Vec<Place>,
}

impl InstructionCounts {
    /// Instructions executed at places whose function is `function`.
    pub fn instructions_in(&self, function: &str) -> u64 {
        self.places.iter().filter(|p| p.function == function).map(|p| p.instructions).sum()
    }

    /// The same per pixel.
    pub fn per_pixel_in(&self, function: &str) -> f64 {
        self.instructions_in(function) as f64 / self.pixels.max(1) as f64
    }

    /// The places above `min_per_pixel` as a table.
    pub fn table(&self, min_per_pixel: f64) -> String {
        let mut t = format!("instructions executed (QEMU, one a translation block): {} in all, {:.2} a pixel over {} pixels\n", self.total, self.total as f64 / self.pixels.max(1) as f64, self.pixels);
        for p in self.places.iter().filter(|p| p.per_pixel >= min_per_pixel) {
            t += &format!("  {:>8.3} a pixel  {:>10}  {} {}\n", p.per_pixel, p.instructions, p.file, p.function);
        }
        t
    }
}

/// Places `executed` in `elf`'s source (DWARF), files relative to `root`; `pixels` is
/// what the per-pixel figures divide by.
pub fn attribute(elf: &Path, executed: &Executed, root: &Path, pixels: u64) -> Result<InstructionCounts, HostError> {
    let fault = |fault| HostError::Firmware { path: elf.to_path_buf(), fault };
    let loader = addr2line::Loader::new(elf).map_err(|e| fault(FirmwareFault::Dwarf(e.to_string())))?;
    let root = root.to_string_lossy().into_owned() + "/";
    let mut by_place: BTreeMap<(String, String), u64> = BTreeMap::new();
    for (&pc, &n) in executed {
        let place = place_of(&loader, pc as u64, &root).map_err(|e| fault(FirmwareFault::DwarfAt { pc, cause: e.to_string() }))?;
        *by_place.entry(place).or_default() += n;
    }
    let mut places: Vec<Place> = by_place
        .into_iter()
        .map(|((file, function), instructions)| Place { file, function, instructions, per_pixel: instructions as f64 / pixels.max(1) as f64 })
        .collect();
    places.sort_by(|a, b| b.instructions.cmp(&a.instructions).then_with(|| a.file.cmp(&b.file)));
    Ok(InstructionCounts { pixels, total: executed.values().sum(), places })
}

/// The place of `pc` as (file relative to `root`, short function name): inside the
/// stream loop, the function [`STREAM_LOOP`] calls there (the pass: `accumulate_line`,
/// `capture_line`, the line input closure) or the loop itself; elsewhere the innermost
/// frame in the project's sources, else the innermost frame; `("?", "?")` without line
/// data.
fn place_of(loader: &addr2line::Loader, pc: u64, root: &str) -> Result<(String, String), Box<dyn std::error::Error>> {
    let mut frames = loader.find_frames(pc)?;
    let mut own = Vec::new();
    let mut first = None;
    while let Some(frame) = frames.next()? {
        let file = frame.location.as_ref().and_then(|l| l.file).unwrap_or("?").to_string();
        let function = frame.function.as_ref().and_then(|f| f.demangle().ok()).map(|f| short_name(&f)).unwrap_or_else(|| "?".into());
        match file.strip_prefix(root) {
            Some(path) => own.push((path.to_string(), function)),
            None => {
                first.get_or_insert((file, function));
            }
        }
    }
    let place = match own.iter().rposition(|(_, f)| f == STREAM_LOOP) {
        Some(at) => own.swap_remove(at.saturating_sub(1)),
        None if !own.is_empty() => own.swap_remove(0),
        None => first.unwrap_or_else(|| ("?".into(), "?".into())),
    };
    Ok(place)
}

/// The core's stream loop (`dncal_core::stream::run_stream`), whose callees are the
/// passes a line goes through.
pub const STREAM_LOOP: &str = "run_stream";

/// The exact-mode correction's cost on the firmware, executed instructions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CorrectionCost {
    /// Per pixel: the loop's part.
    pub per_pixel: f64,
    /// Per line beyond its pixels: the line's checks, its head and tail of two columns
    /// each, the loop's set-up.
    pub per_line: f64,
    /// The 16-pixel lines' count against the prediction of the two wider ones, relative.
    pub misfit: f64,
}

/// Measures the exact-mode correction on the firmware `elf`: QEMU counts the
/// instructions executed in `accumulate_line` (the correction with all it inlines) on
/// 8 frames of 16, 32 and 64 lines of as many pixels, first column 130 (two columns of
/// head and two of tail on every line), all codes in range (no retake). The count on
/// `w`-pixel lines is `frames * w * (per_line + w * per_pixel)`: the 32- and 64-pixel
/// lines give both parts and the 16-pixel lines check that the count is that line.
/// Each run is also checked bit for bit against the host.
pub fn correction_cost(elf: &Path) -> Result<CorrectionCost, HostError> {
    use super::{repo_root, run_firmware, run_on_host, RunInputs};
    use crate::model::synth::{dn_error_weights, synthetic_frames, Rng};
    use dncal_core::{Geometry, Mvd1024eLuts};
    let mut rng = Rng::new(7);
    let weights: Vec<Vec<_>> = (0..4).map(|_| dn_error_weights(&mut rng, 4096)).collect();
    let luts = Mvd1024eLuts::from_weights(&[&weights[0], &weights[1], &weights[2], &weights[3]]).map_err(|e| HostError::core("LUTs from weights", e))?;
    let frames = 8u32;
    let mut count = |side: u16| -> Result<f64, HostError> {
        let geometry = Geometry::new(side, side, 4, 130).map_err(|e| HostError::core("geometry", e))?;
        let mut codes = synthetic_frames(&mut rng, geometry, frames, 1.5, 4096);
        // The planted codes above the top would send a line through the retake.
        codes.iter_mut().flatten().for_each(|c| *c = (*c).min(4095));
        let inputs = RunInputs { luts: luts.clone(), geometry, frames: codes, capture_histograms: false };
        let host = run_on_host(&inputs)?;
        let run = run_firmware(elf, &inputs, &host.outputs.sums, std::time::Duration::from_secs(600), true)?;
        if run.outputs != host.outputs {
            return Err(HostError::Tool { program: "qemu-system-arm".into(), message: format!("the traced firmware's outputs differ from the host's on {side}-pixel lines") });
        }
        let pixels = (frames as usize * geometry.pixels()) as u64;
        let counts = attribute(elf, run.executed.as_ref().unwrap_or(&Executed::new()), &repo_root(), pixels)?;
        Ok(counts.instructions_in("accumulate_line") as f64)
    };
    let (a16, a32, a64) = (count(16)?, count(32)?, count(64)?);
    let per_line_pixel = |a: f64, w: f64| a / (frames as f64 * w);
    let per_pixel = (per_line_pixel(a64, 64.0) - per_line_pixel(a32, 32.0)) / 32.0;
    let per_line = per_line_pixel(a32, 32.0) - 32.0 * per_pixel;
    let predicted16 = frames as f64 * 16.0 * (per_line + 16.0 * per_pixel);
    Ok(CorrectionCost { per_pixel, per_line, misfit: (a16 - predicted16) / a16.max(1.0) })
}

/// A demangled Rust path without generic arguments and leading modules:
/// `<dncal_core::histogram::HistogramSet<4, 4096>>::count_indexed::<F>` is
/// `count_indexed`, `dncal_firmware::run::{closure#0}` is `run::{closure#0}`.
fn short_name(demangled: &str) -> String {
    let mut depth = 0usize;
    let mut plain = String::new();
    for c in demangled.chars() {
        match c {
            '<' => depth += 1,
            '>' => depth = depth.saturating_sub(1),
            _ if depth == 0 => plain.push(c),
            _ => {}
        }
    }
    let segments: Vec<&str> = plain.split("::").filter(|s| !s.is_empty()).collect();
    let keep = if segments.last().is_some_and(|s| s.starts_with('{')) { 2 } else { 1 };
    segments[segments.len().saturating_sub(keep)..].join("::")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trace_line_gives_its_guest_address_and_other_lines_are_kept() {
        let log = "Trace 0: 0x7f0c68071dc0 [00800408/00000aac/00000010/ff000201] run_stream\n\
                   qemu-system-arm: warning: something\n\
                   Trace 0: 0x7f0c68071f40 [00800408/00000ab0/00000010/ff000201] run_stream\n\
                   Trace 0: 0x7f0c68071dc0 [00800408/00000aac/00000010/ff000201] run_stream\n\
                   Trace 0: 0x7f0c68071dc0 [garbled\n";
        let (counts, other) = read_trace(log.as_bytes());
        assert_eq!(counts, Executed::from([(0xaac, 2), (0xab0, 1)]));
        assert_eq!(other, "qemu-system-arm: warning: something\nTrace 0: 0x7f0c68071dc0 [garbled\n");
        let (counts, other) = read_trace(&b"Trace 0: 0x1 [0/00000aac/0/0] x\n\xff\xfe not utf-8\nTrace 0: 0x1 [0/00000aac/0/0] x"[..]);
        assert_eq!(counts, Executed::from([(0xaac, 2)]), "reads on past a line that is not UTF-8, and a last line without newline");
        assert_eq!(other, "\u{fffd}\u{fffd} not utf-8\n");
    }

    #[test]
    fn the_trace_flag_follows_the_qemu_version() {
        assert_eq!(parse_version("QEMU emulator version 7.2.22 (Debian 1:7.2+dfsg-7+deb12u18+b3)\nCopyright"), Some((7, 2)));
        assert_eq!(parse_version("QEMU emulator version 10.0.2"), Some((10, 0)));
        assert_eq!(parse_version("qemu"), None);
        assert_eq!(trace_args((7, 2))[0], "-singlestep");
        assert_eq!(trace_args((8, 1))[..2], ["-accel", "tcg,one-insn-per-tb=on"]);
        assert_eq!(trace_args((10, 0))[0], "-accel");
    }

    #[test]
    fn short_names_drop_generics_and_modules_and_keep_a_closures_owner() {
        assert_eq!(short_name("<dncal_core::histogram::HistogramSet<4, 4096>>::count_indexed::<<dncal_core::histogram::HistogramSet<4, 4096>>::capture_line::{closure#0}>"), "count_indexed");
        assert_eq!(short_name("dncal_core::accumulate::add_indexed::<dncal_core::accumulate::Exact, 4, 4096>"), "add_indexed");
        assert_eq!(short_name("dncal_firmware::run::{closure#0}"), "run::{closure#0}");
        assert_eq!(short_name("main"), "main");
    }
}
