//! Sizing: what the datapath needs for a given camera system, part computed from the
//! design's structure, part measured by running frames through the model.

use dncal_core::Geometry;

use crate::datapath::{ADCS, CODES};
use crate::{Config, Fpga, FpgaError};

/// Bits of one LUT entry in block RAM (12 integer + 11 fractional): the core's entry limit.
pub const ENTRY_BITS: u64 = dncal_core::LUT_ENTRY_LIMIT.trailing_zeros() as u64;

/// The camera system to size for.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct System {
    /// Cameras served by one datapath each (the K-Cor has two).
    pub cameras: u32,
    /// Pixels per line.
    pub width: u16,
    /// Lines per frame.
    pub height: u16,
    /// Frames per second per camera.
    pub frame_rate_hz: f64,
    /// Horizontal blanking as a fraction of a line's active time.
    pub h_blank_fraction: f64,
    /// Vertical blanking as a fraction of a frame's line time (active plus horizontal
    /// blanking).
    pub v_blank_fraction: f64,
}

impl Default for System {
    /// The K-Coronagraph: two 1024 x 1024 cameras at 150 frames/s; 10% horizontal and 5%
    /// vertical blanking (assumed: typical of Camera Link timing, not from the paper).
    fn default() -> Self {
        System { cameras: 2, width: 1024, height: 1024, frame_rate_hz: 150.0, h_blank_fraction: 0.10, v_blank_fraction: 0.05 }
    }
}

/// The sizing at one tap count.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TapSizing {
    /// Pixels per clock.
    pub taps: usize,
    /// Pixel clock needed per camera, MHz: pixels per second over taps, with the blanking.
    pub clock_mhz: f64,
    /// Sum-memory words per clock the row was measured with (2 per tap).
    pub mem_words_per_cycle: u32,
    /// Measured: cycles for one frame, blanking included.
    pub cycles_per_frame: u64,
    /// Measured: pixels summed per clock over the frame.
    pub pixels_per_clock: f64,
    /// Measured: cycles from a pixel's arrival to its write-back, at most.
    pub latency_cycles: u64,
    /// Measured: largest input FIFO occupancy, pixels.
    pub fifo_high_water: usize,
    /// Measured: largest number of read-modify-writes in flight: the queue the design
    /// needs between the sum memory's read and its write-back (about taps x latency).
    pub inflight_high_water: usize,
    /// Measured: pixels dropped (must be 0).
    pub fifo_overflows: u32,
    /// Measured: read-modify-writes that would need forwarding (must be 0).
    pub rmw_hazards: u32,
    /// How the taps reach the per-ADC tables.
    pub lut_access: &'static str,
    /// Block RAM for the LUTs, bits (both banks).
    pub bram_bits: u64,
}

/// The whole sizing report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Sizing {
    /// The system sized for.
    pub system: System,
    /// Pixels per second, all cameras.
    pub pixels_per_s: f64,
    /// Sum-memory bandwidth, bytes per second, all cameras: a 32-bit read and a 32-bit
    /// write per pixel.
    pub sum_bandwidth_bytes_per_s: f64,
    /// Sum memory per camera for `states` modulation states, bytes.
    pub sum_memory_bytes: u64,
    /// Per tap count.
    pub taps: Vec<TapSizing>,
}

/// How `taps` pixels per clock reach the 4 per-ADC tables: aligned to the columns, tap i
/// always meets ADC (first + i) mod 4; otherwise a tap meets every ADC and a crossbar
/// routes each pixel to its ADC's table. No ADC receives more than 2 pixels per clock up
/// to 8 taps, so the two ports of a dual-port block RAM serve every case without
/// replicating a table.
pub fn lut_access(taps: usize) -> &'static str {
    match taps {
        1 => "one port; the tap visits the 4 tables in turn (a 4-way mux)",
        2 => "one port per table; each tap alternates between two tables (a 2-way mux)",
        3 | 5 | 6 | 7 => "crossbar: each tap meets every ADC; dual-port tables (at most 2 pixels per ADC per clock)",
        4 => "one port per table, tap i wired to ADC i (no mux)",
        _ => "both ports of each table, taps i and i + 4 on ADC i (no mux)",
    }
}

/// Sizes the datapath for `system` with `states` modulation states, measuring one frame
/// per tap count in the model built from `base` (its taps, blanking and memory bandwidth
/// are replaced: 2 words per tap per clock).
pub fn size(system: &System, states: u8, base: &Config, tap_counts: &[usize]) -> Result<Sizing, FpgaError> {
    let fraction = |what: &'static str, f: f64| if f.is_finite() && (0.0..=1.0).contains(&f) { Ok(()) } else { Err(FpgaError::Config(what, format!("must be a fraction from 0 to 1, got {f}"))) };
    fraction("h_blank_fraction", system.h_blank_fraction)?;
    fraction("v_blank_fraction", system.v_blank_fraction)?;
    if !(system.frame_rate_hz.is_finite() && system.frame_rate_hz > 0.0) {
        return Err(FpgaError::Config("frame_rate_hz", format!("must be positive, got {}", system.frame_rate_hz)));
    }
    if let Some(&t) = tap_counts.iter().find(|t| !(1..=8).contains(*t)) {
        return Err(FpgaError::Config("taps", format!("must be 1 to 8, got {t}")));
    }
    let pixels_per_frame = f64::from(system.width) * f64::from(system.height);
    let pixels_per_s = pixels_per_frame * system.frame_rate_hz * f64::from(system.cameras);
    let geometry = Geometry::new(system.width, system.height, states, 0)?;
    let mut rows = Vec::new();
    for &taps in tap_counts {
        let active_line = u32::from(system.width).div_ceil(taps as u32);
        let h_blank = (f64::from(active_line) * system.h_blank_fraction).round() as u32;
        let v_blank = ((f64::from(active_line + h_blank) * f64::from(system.height)) * system.v_blank_fraction).round() as u32;
        // The sum memory sized to the taps: a read and a write per pixel per clock.
        let config = Config { taps, h_blank, v_blank, mem_words_per_cycle: 2 * taps as u32, ..base.clone() };
        let mut model = Fpga::new(config, geometry)?;
        // Timing does not depend on the codes: a ramp.
        let lines: Vec<Vec<u16>> = (0..system.height).map(|r| (0..system.width).map(|c| r.wrapping_add(c) % 4096).collect()).collect();
        let refs: Vec<&[u16]> = lines.iter().map(|l| l.as_slice()).collect();
        let timing = model.stream_frame(0, &refs)?;
        model.drain();
        let st = model.stats();
        let cycles_per_s = timing.cycles as f64 * system.frame_rate_hz;
        rows.push(TapSizing {
            taps,
            clock_mhz: cycles_per_s / 1e6,
            mem_words_per_cycle: 2 * taps as u32,
            cycles_per_frame: timing.cycles,
            pixels_per_clock: st.pixels as f64 / timing.cycles as f64,
            latency_cycles: st.max_latency,
            fifo_high_water: st.fifo_high_water,
            inflight_high_water: st.inflight_high_water,
            fifo_overflows: st.fifo_overflows,
            rmw_hazards: st.rmw_hazards,
            lut_access: lut_access(taps),
            bram_bits: 2 * ADCS as u64 * CODES as u64 * ENTRY_BITS,
        });
    }
    Ok(Sizing {
        system: system.clone(),
        pixels_per_s,
        sum_bandwidth_bytes_per_s: pixels_per_s * 8.0,
        sum_memory_bytes: u64::from(states) * pixels_per_frame as u64 * 4,
        taps: rows,
    })
}

/// A table as `$readmemh` reads it: one entry per line, 6 hex digits (23 bits), code 0
/// first, with a comment header.
pub fn readmemh(adc: usize, table: &[dncal_core::LutEntry]) -> String {
    let mut s = format!("// dncal LUT, ADC {adc}: {} entries of {ENTRY_BITS} bits (12.11 fixed point, DN), code 0 first\n", table.len());
    for e in table {
        s += &format!("{:06x}\n", e.to_bits());
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clock_is_the_pixel_rate_over_the_taps_plus_blanking() {
        let system = System { cameras: 1, width: 64, height: 16, frame_rate_hz: 100.0, h_blank_fraction: 0.25, v_blank_fraction: 0.0 };
        let s = size(&system, 1, &Config { mem_words_per_cycle: 16, ..Config::default() }, &[1, 4]).unwrap();
        // 1 tap: 64 active + 16 blank cycles per line, 16 lines: 1280 cycles per frame.
        assert_eq!(s.taps[0].cycles_per_frame, 1280);
        assert!((s.taps[0].clock_mhz - 1280.0 * 100.0 / 1e6).abs() < 1e-12);
        // 4 taps: 16 + 4 per line.
        assert_eq!(s.taps[1].cycles_per_frame, 320);
        assert_eq!(s.taps[1].fifo_overflows, 0);
        assert_eq!(s.taps[0].bram_bits, 2 * 4 * 4096 * 23);
        assert!((s.sum_bandwidth_bytes_per_s - 64.0 * 16.0 * 100.0 * 8.0).abs() < 1e-9);
    }

    #[test]
    fn readmemh_writes_every_entry_as_six_hex_digits() {
        let luts = dncal_core::Mvd1024eLuts::ideal();
        let text = readmemh(2, &luts.tables()[2][..]);
        let lines: Vec<&str> = text.lines().skip(1).collect();
        assert_eq!(lines.len(), 4096);
        // Code k of an ideal ADC reads k + 1/2 DN: (2k + 1) 2^10.
        assert_eq!(lines[0], "000400");
        assert_eq!(lines[4095], format!("{:06x}", (2 * 4095 + 1) << 10));
    }

    /// Bad systems and tap counts are errors, never a panic, a wrap or NaN clocks.
    #[test]
    fn bad_systems_are_refused() {
        let ok = System::default();
        let base = Config::default();
        assert!(size(&ok, 1, &base, &[0]).is_err());
        assert!(size(&ok, 1, &base, &[1 << 31]).is_err());
        assert!(size(&System { h_blank_fraction: 1e30, ..ok.clone() }, 1, &base, &[1]).is_err());
        assert!(size(&System { v_blank_fraction: f64::NAN, ..ok.clone() }, 1, &base, &[1]).is_err());
        assert!(size(&System { frame_rate_hz: f64::NAN, ..ok.clone() }, 1, &base, &[1]).is_err());
        assert!(size(&System { frame_rate_hz: -1.0, ..ok }, 1, &base, &[1]).is_err());
    }

}
