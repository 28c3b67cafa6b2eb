//! The firmware-versus-host run: the same LUT image and line stream through the core on
//! the host and on the Cortex-M4 firmware under QEMU, with the firmware's files and
//! defmt log read back for comparison; on request, the instructions it executed
//! ([`instructions`]).

pub mod instructions;
pub mod check;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use dncal_core::error::Quantity;
use dncal_core::noise::KCOR_ACCURACY_DN;
use dncal_core::stream::{run_stream, StreamHeader, StreamSinks, STATUS_WORDS};
use dncal_core::{encode_image, image_len, Corrector, CoreError, Geometry, HistogramSet, LutBanks, Mvd1024eLuts, NoiseEstimator, NoiseReport, Status};

use crate::HostError;

/// What both sides run: a LUT set and frames of raw codes (row-major, frame `f` in state
/// `f mod states`).
#[derive(Clone)]
pub struct RunInputs {
    /// The calibration to load.
    pub luts: Mvd1024eLuts,
    /// Region and states.
    pub geometry: Geometry,
    /// Frames of `width x height` codes.
    pub frames: Vec<Vec<u16>>,
    /// Whether the run captures the per-ADC histograms (the stream header's flag); without
    /// it the histograms stay zero.
    pub capture_histograms: bool,
}

/// What a run produced.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOutputs {
    /// Sums, state-major, row-major.
    pub sums: Vec<u32>,
    /// The datapath's counters.
    pub status: Status,
    /// Completed frames per state.
    pub frames_per_state: Vec<u32>,
    /// Histograms, ADC-major, 4096 codes each.
    pub histograms: Vec<u32>,
}

/// The host's run, with its noise check.
pub struct HostRun {
    /// Outputs, comparable with the firmware's.
    pub outputs: RunOutputs,
    /// The noise check on frames 0 and `states`, if the region allowed it.
    pub noise: Result<NoiseReport, CoreError>,
}

/// A firmware run under QEMU.
pub struct FirmwareRun {
    /// Outputs read back from the files the firmware wrote.
    pub outputs: RunOutputs,
    /// What the firmware printed over semihosting.
    pub stdout: String,
    /// The decoded defmt log, one message per entry.
    pub log: Vec<String>,
    /// Instructions executed per guest address, when the run counted them.
    pub executed: Option<instructions::Executed>,
}

/// Runs `inputs` through the core on the host exactly as the firmware does.
pub fn run_on_host(inputs: &RunInputs) -> Result<HostRun, HostError> {
    let g = inputs.geometry;
    if let Some((i, f)) = inputs.frames.iter().enumerate().find(|(_, f)| f.len() != g.pixels()) {
        let e = CoreError::Length { what: Quantity::LinePixels, expected: g.pixels() as u32, got: f.len() as u32 };
        return Err(HostError::core(format!("frame {i}"), e));
    }
    let mut banks = LutBanks::new(Mvd1024eLuts::ideal());
    banks.stage(&inputs.luts);
    let mut sums = vec![0u32; g.sum_len()];
    let mut corrector = Corrector::new(&mut banks, g, &mut sums).map_err(|e| HostError::core("host corrector", e))?;
    corrector.request_activation().map_err(|e| HostError::core("activate LUT", e))?;
    let mut histograms = Box::new(HistogramSet::<4, 4096>::new());
    let mut noise = NoiseEstimator::new(4095);
    let mut first_frame = vec![0u16; g.pixels()];
    let mut line = vec![0u16; g.width() as usize];
    let mut source = inputs.frames.iter().flat_map(|f| f.chunks_exact(g.width() as usize));
    let sinks = StreamSinks { histograms: inputs.capture_histograms.then_some(&mut *histograms), noise: &mut noise, first_frame: &mut first_frame };
    run_stream(&mut corrector, sinks, inputs.frames.len() as u32, &mut line, |line: &mut [u16]| {
        let next = source.next().ok_or(CoreError::NoFrame)?;
        line.copy_from_slice(next);
        Ok::<(), CoreError>(())
    })
    .map_err(|e| HostError::core("host stream", e))?;
    let status = corrector.status();
    let frames_per_state = (0..g.states()).map(|s| corrector.sums().frames(s).get()).collect();
    let histograms = (0..4).flat_map(|a| histograms.counts(a).into_iter().flatten().copied()).collect();
    Ok(HostRun { outputs: RunOutputs { sums, status, frames_per_state, histograms }, noise: noise.check(KCOR_ACCURACY_DN) })
}

/// The repository root, where `scripts/firmware.sh` lives.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_default()
}

/// Builds the firmware (installing the cross toolchain if missing) and returns its ELF.
pub fn build_firmware() -> Result<PathBuf, HostError> {
    let script = repo_root().join("scripts/firmware.sh");
    let out = Command::new(&script)
        .arg("build")
        .stderr(Stdio::inherit())
        .output()
        .map_err(|e| HostError::Tool { program: script.display().to_string(), message: e.to_string() })?;
    if !out.status.success() {
        return Err(HostError::Tool { program: script.display().to_string(), message: format!("firmware build failed ({})", out.status) });
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let elf = PathBuf::from(stdout.lines().last().unwrap_or_default().trim());
    if elf.is_file() {
        Ok(elf)
    } else {
        Err(HostError::Tool { program: script.display().to_string(), message: format!("no ELF at {}", elf.display()) })
    }
}

/// What is wrong with the firmware's ELF or an output file of its run;
/// `HostError::Firmware` wraps it with the file. The causes from other crates (defmt's
/// decoder, addr2line) come as their text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FirmwareFault {
    /// An output file of u32 words with bytes left over.
    #[error("{bytes} bytes is not a whole number of u32")]
    PartialWord {
        /// The file's size.
        bytes: usize,
    },
    /// The status file's length is not the counters' and the states'.
    #[error("{words} words, expected {expected}")]
    StatusWords {
        /// Words read.
        words: usize,
        /// Words the geometry gives.
        expected: usize,
    },
    /// The ELF's defmt table cannot be parsed.
    #[error("{0}")]
    DefmtTable(String),
    /// An ELF without a defmt table.
    #[error("no defmt table")]
    NoDefmtTable,
    /// A defmt log that the ELF's table does not decode.
    #[error("malformed defmt log: {0}")]
    DefmtLog(String),
    /// The ELF's DWARF cannot be read.
    #[error("reading DWARF: {0}")]
    Dwarf(String),
    /// No source place for an executed address.
    #[error("DWARF at {pc:#x}: {cause}")]
    DwarfAt {
        /// The address.
        pc: u32,
        /// addr2line's reason.
        cause: String,
    },
}

fn write(path: PathBuf, bytes: &[u8]) -> Result<(), HostError> {
    std::fs::write(&path, bytes).map_err(|e| HostError::io(path, e))
}

fn read_words(path: PathBuf) -> Result<Vec<u32>, HostError> {
    let bytes = std::fs::read(&path).map_err(|e| HostError::io(&path, e))?;
    if bytes.len() % 4 != 0 {
        return Err(HostError::Firmware { path, fault: FirmwareFault::PartialWord { bytes: bytes.len() } });
    }
    Ok(bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
}

/// Decodes a defmt log with the ELF that wrote it.
pub fn decode_defmt(elf: &Path, log: &[u8]) -> Result<Vec<String>, HostError> {
    let bytes = std::fs::read(elf).map_err(|e| HostError::io(elf, e))?;
    let fault = |fault| HostError::Firmware { path: elf.to_path_buf(), fault };
    let table = defmt_decoder::Table::parse(&bytes).map_err(|e| fault(FirmwareFault::DefmtTable(e.to_string())))?.ok_or_else(|| fault(FirmwareFault::NoDefmtTable))?;
    let mut decoder = table.new_stream_decoder();
    decoder.received(log);
    let mut out = Vec::new();
    loop {
        match decoder.decode() {
            Ok(frame) => out.push(frame.display_message().to_string()),
            Err(defmt_decoder::DecodeError::UnexpectedEof) => return Ok(out),
            Err(e) => return Err(fault(FirmwareFault::DefmtLog(format!("{e:?}")))),
        }
    }
}

/// Runs the firmware `elf` in QEMU on `inputs`, with `expected` (the host's sums) for
/// its own comparison, in a fresh temporary directory; gives up after `timeout`. With
/// `count_instructions` QEMU runs one instruction a block and logs each one executed
/// (the check's 64 x 64 x 32-frame run: 6-8 s against 0.3-1 s), and the run returns
/// the counts per address.
pub fn run_firmware(elf: &Path, inputs: &RunInputs, expected: &[u32], timeout: Duration, count_instructions: bool) -> Result<FirmwareRun, HostError> {
    let g = inputs.geometry;
    let dir = tempfile::tempdir().map_err(|e| HostError::io(std::env::temp_dir(), e))?;
    let at = |name: &str| dir.path().join(name);
    let mut image = vec![0u8; image_len::<4, 4096>()];
    encode_image(&inputs.luts, &mut image).map_err(|e| HostError::core("encode LUT image", e))?;
    write(at("lut.bin"), &image)?;
    let mut stream = StreamHeader { geometry: g, frames: inputs.frames.len() as u32, capture_histograms: inputs.capture_histograms }.encode().to_vec();
    stream.extend(inputs.frames.iter().flatten().flat_map(|c| c.to_le_bytes()));
    write(at("lines.bin"), &stream)?;
    write(at("expected.bin"), &expected.iter().flat_map(|s| s.to_le_bytes()).collect::<Vec<u8>>())?;

    let qemu = "qemu-system-arm";
    let tool = |message: String| HostError::Tool { program: qemu.into(), message };
    let mut child = Command::new(qemu)
        .args(["-cpu", "cortex-m4", "-machine", "mps2-an386", "-nographic", "-semihosting-config", "enable=on,target=native", "-kernel"])
        .arg(elf)
        .args(if count_instructions { instructions::trace_args(instructions::qemu_version(qemu)?) } else { &[] })
        .current_dir(dir.path())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| tool(e.to_string()))?;
    // QEMU's stderr is read as it comes: with the trace it is millions of lines.
    let stderr = child.stderr.take().map(|e| std::thread::spawn(move || instructions::read_trace(std::io::BufReader::new(e))));
    let start = Instant::now();
    while child.try_wait().map_err(|e| tool(e.to_string()))?.is_none() {
        if start.elapsed() > timeout {
            child.kill().ok();
            return Err(tool(format!("firmware did not finish in {} s", timeout.as_secs())));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().map_err(|e| tool(e.to_string()))?;
    let (executed, stderr) = match stderr {
        Some(reader) => reader.join().map_err(|_| tool("the reader of QEMU's stderr failed".into()))?,
        None => Default::default(),
    };
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let log = std::fs::read(at("defmt.bin")).map_err(|e| HostError::io(at("defmt.bin"), e)).and_then(|bytes| decode_defmt(elf, &bytes));
    if !out.status.success() && !stdout.contains("firmware bit-exact") {
        let log = log.map_or_else(|e| format!("none ({e})"), |l| l.join(" | "));
        return Err(tool(format!("firmware failed ({}): {}{}; log: {}", out.status, stdout, stderr, log)));
    }
    let log = log?;
    if count_instructions && executed.is_empty() {
        return Err(tool(format!("QEMU logged no executed instruction (has its `-d exec` log format changed?); its stderr: {stderr}")));
    }
    let sums = read_words(at("sums.bin"))?;
    let words = read_words(at("status.bin"))?;
    if words.len() != STATUS_WORDS + g.states() as usize {
        return Err(HostError::Firmware { path: at("status.bin"), fault: FirmwareFault::StatusWords { words: words.len(), expected: STATUS_WORDS + g.states() as usize } });
    }
    let mut status = [0u32; STATUS_WORDS];
    status.copy_from_slice(&words[..STATUS_WORDS]);
    let outputs = RunOutputs { sums, status: Status::from_words(status), frames_per_state: words[STATUS_WORDS..].to_vec(), histograms: read_words(at("hist.bin"))? };
    Ok(FirmwareRun { outputs, stdout, log, executed: count_instructions.then_some(executed) })
}
