//! dncal firmware: the correction core on a Cortex-M4 (QEMU `mps2-an386`).
//!
//! A semihosted run of the datapath, for bit-exactness against the host:
//! 1. load the LUT device image `lut.bin` into the staging bank in 256-byte chunks (as
//!    the SPI upload would), validate it, activate it;
//! 2. stream `lines.bin` line by line through `dncal_core::stream::run_stream`: sums per
//!    modulation state, ADC histograms, a noise estimate;
//! 3. write `sums.bin`, `status.bin` and `hist.bin`, compare the sums with the host's
//!    `expected.bin` and print `firmware bit-exact: OK (N pixels)` or the mismatch count.
//!
//! defmt logs go to `defmt.bin` (see `logger`).
#![no_std]
#![no_main]

mod host_file;
mod logger;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use dncal_core::noise::KCOR_ACCURACY_DN;
use dncal_core::stream::{run_stream, StreamHeader, StreamSinks, STREAM_HEADER_LEN};
use dncal_core::{Corrector, CoreError, HistogramSet, LutBanks, Mvd1024eLuts, NoiseEstimator};
use host_file::{HostFile, IoError};

/// Widest line the firmware takes, pixels.
const MAX_WIDTH: usize = 1024;
/// Largest sum buffer: a 64 x 64 ROI in 4 states.
const MAX_SUMS: usize = 64 * 64 * 4;
/// Largest frame kept for the noise estimate, pixels.
const MAX_NOISE_PIXELS: usize = 64 * 64;

#[derive(Debug, defmt::Format)]
enum FirmwareError {
    Core(CoreError),
    Io(IoError),
    TooLarge,
}
impl From<CoreError> for FirmwareError {
    fn from(e: CoreError) -> Self {
        FirmwareError::Core(e)
    }
}
impl From<IoError> for FirmwareError {
    fn from(e: IoError) -> Self {
        FirmwareError::Io(e)
    }
}

#[entry]
fn main() -> ! {
    let status = match run() {
        Ok(true) => debug::EXIT_SUCCESS,
        Ok(false) => debug::EXIT_FAILURE,
        Err(e) => {
            defmt::error!("run failed: {}", e);
            hprintln!("firmware error: {:?}", e);
            debug::EXIT_FAILURE
        }
    };
    debug::exit(status);
    loop {}
}

/// The run; `Ok(true)` when the sums equal the host's.
fn run() -> Result<bool, FirmwareError> {
    let banks = cortex_m::singleton!(: LutBanks<4, 4096> = LutBanks::new(Mvd1024eLuts::ideal())).ok_or(FirmwareError::TooLarge)?;
    let sums = cortex_m::singleton!(: [u32; MAX_SUMS] = [0; MAX_SUMS]).ok_or(FirmwareError::TooLarge)?;
    let hist = cortex_m::singleton!(: HistogramSet<4, 4096> = HistogramSet::new()).ok_or(FirmwareError::TooLarge)?;
    let first_frame = cortex_m::singleton!(: [u16; MAX_NOISE_PIXELS] = [0; MAX_NOISE_PIXELS]).ok_or(FirmwareError::TooLarge)?;

    // 1. LUT image, chunked as over SPI.
    let mut lut = HostFile::open("lut.bin")?;
    let mut chunk = [0u8; 256];
    banks.begin_upload();
    loop {
        let n = lut.read(&mut chunk)?;
        if n == 0 {
            break;
        }
        banks.upload(&chunk[..n])?;
    }
    banks.finish_upload()?;
    defmt::info!("LUT image validated into staging bank");

    // 2. Lines.
    let mut lines = HostFile::open("lines.bin")?;
    let mut header = [0u8; STREAM_HEADER_LEN];
    lines.read_exact(&mut header)?;
    let header = StreamHeader::parse(&header)?;
    let g = header.geometry;
    if g.width() as usize > MAX_WIDTH || g.sum_len() > MAX_SUMS {
        return Err(FirmwareError::TooLarge);
    }
    let mut corrector = Corrector::new(banks, g, &mut sums[..g.sum_len()])?;
    corrector.request_activation()?;
    defmt::info!("LUT bank {=usize} active; {=u16}x{=u16} lines, {=u8} states, {=u32} frames", corrector.banks().active_index(), g.width(), g.height(), g.states(), header.frames);

    let mut line = [0u16; MAX_WIDTH];
    let mut noise = NoiseEstimator::new(4095);
    // Histogram capture is a pass of its own over each line, run only when the stream
    // asks for it (a calibration), so science frames pay for the correction alone.
    defmt::info!("histogram capture {=bool}", header.capture_histograms);
    let sinks = StreamSinks { histograms: header.capture_histograms.then_some(&mut *hist), noise: &mut noise, first_frame };
    run_stream(&mut corrector, sinks, header.frames, &mut line, |line: &mut [u16]| -> Result<(), FirmwareError> {
        // The line's bytes land in place, as a frame grabber's DMA writes them: no copy.
        // The stream is little-endian; `from_le` is no instruction on this core.
        lines.read_exact(bytemuck::cast_slice_mut(line))?;
        line.iter_mut().for_each(|c| *c = u16::from_le(*c));
        Ok(())
    })?;
    match noise.check(KCOR_ACCURACY_DN) {
        Ok(r) => defmt::info!("noise check: sigma {=f32} DN, worst-case bias {=f32} DN, ok {=bool}", r.sigma_dn, r.worst_bias_dn, r.ok()),
        Err(e) => defmt::warn!("noise check skipped: {}", e),
    }
    let status = corrector.status();
    defmt::info!("status: {}", status);

    // 3. Results and the comparison with the host.
    let mut out = HostFile::create("sums.bin")?;
    for s in corrector.sums().as_slice() {
        out.write_all(&s.to_le_bytes())?;
    }
    let mut out = HostFile::create("status.bin")?;
    for w in status.to_words() {
        out.write_all(&w.to_le_bytes())?;
    }
    for state in 0..g.states() {
        out.write_all(&corrector.sums().frames(state).get().to_le_bytes())?;
    }
    let mut out = HostFile::create("hist.bin")?;
    for adc in 0..4 {
        for c in hist.counts(adc).into_iter().flatten() {
            out.write_all(&c.to_le_bytes())?;
        }
    }
    let mut expected = HostFile::open("expected.bin")?;
    let mut mismatches = 0u32;
    let mut word = [0u8; 4];
    for &s in corrector.sums().as_slice() {
        expected.read_exact(&mut word)?;
        mismatches += (u32::from_le_bytes(word) != s) as u32;
    }
    let pixels = corrector.sums().as_slice().len();
    if mismatches == 0 {
        hprintln!("firmware bit-exact: OK ({} pixels)", pixels);
    } else {
        hprintln!("firmware bit-exact: FAIL ({} of {} pixels differ)", mismatches, pixels);
        defmt::error!("{=u32} sums differ from the host", mismatches);
    }
    Ok(mismatches == 0)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("firmware panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {}
}

#[defmt::panic_handler]
fn defmt_panic() -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {}
}
