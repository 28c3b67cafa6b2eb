//! Framing of a recorded line stream and of a run's results, as the firmware reads and
//! writes them over semihosting and the host writes and reads them back. One definition
//! here, so the two sides cannot drift.
//!
//! ## Line stream (`lines.bin`), little-endian
//! | offset | size | field                                          |
//! |--------|------|------------------------------------------------|
//! | 0      | 4    | magic `DNLS`                                   |
//! | 4      | 2    | version = 1                                    |
//! | 6      | 2    | width, pixels per line                         |
//! | 8      | 2    | height, lines per frame                        |
//! | 10     | 1    | modulation states                              |
//! | 11     | 1    | flags: bit 0 = capture the per-ADC histograms; the rest zero |
//! | 12     | 2    | sensor column of a line's first pixel          |
//! | 14     | 4    | frames; frame `f` has modulation state `f mod states` |
//! | 18     | ...  | frames x height x width codes, u16             |
//!
//! ## Results (`status.bin`): [`Status`] as [`STATUS_WORDS`] u32, then the frames of each
//! state, u32. The sums go to `sums.bin` as u32, state-major, row-major.

use crate::{Corrector, CoreError, Geometry, HistogramSet, NoiseEstimator, Roi, Status};

/// Magic of a line stream.
pub const STREAM_MAGIC: [u8; 4] = *b"DNLS";
/// Length of the line-stream header, bytes.
pub const STREAM_HEADER_LEN: usize = 18;
/// Words of an encoded [`Status`].
pub const STATUS_WORDS: usize = 6;

/// The header of a line stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StreamHeader {
    /// Region and states of the stream.
    pub geometry: Geometry,
    /// Frames that follow.
    pub frames: u32,
    /// Whether the device captures the per-ADC code histograms as well (a second pass
    /// over each line, about twice the correction's cost per pixel: asked for when a
    /// calibration is taken, not during science frames).
    pub capture_histograms: bool,
}

impl StreamHeader {
    /// The header's bytes.
    pub fn encode(&self) -> [u8; STREAM_HEADER_LEN] {
        let g = self.geometry;
        let mut h = [0u8; STREAM_HEADER_LEN];
        h[..4].copy_from_slice(&STREAM_MAGIC);
        h[4..6].copy_from_slice(&1u16.to_le_bytes());
        h[6..8].copy_from_slice(&g.width().to_le_bytes());
        h[8..10].copy_from_slice(&g.height().to_le_bytes());
        h[10] = g.states();
        h[11] = self.capture_histograms as u8;
        h[12..14].copy_from_slice(&g.first_column().to_le_bytes());
        h[14..18].copy_from_slice(&self.frames.to_le_bytes());
        h
    }

    /// Parses and validates a header.
    pub fn parse(h: &[u8; STREAM_HEADER_LEN]) -> Result<Self, CoreError> {
        if h[..4] != STREAM_MAGIC || u16::from_le_bytes([h[4], h[5]]) != 1 || h[11] > 1 {
            return Err(CoreError::StreamHeader);
        }
        let u16_at = |i: usize| u16::from_le_bytes([h[i], h[i + 1]]);
        let geometry = Geometry::new(u16_at(6), u16_at(8), h[10], u16_at(12))?;
        Ok(StreamHeader { geometry, frames: u32::from_le_bytes([h[14], h[15], h[16], h[17]]), capture_histograms: h[11] == 1 })
    }
}

impl Status {
    /// The counters in a fixed order: out-of-range codes, saturated additions, rejected
    /// lines, incomplete frames, frames, LUT swaps.
    pub fn to_words(&self) -> [u32; STATUS_WORDS] {
        [self.out_of_range_codes, self.saturated_additions, self.rejected_lines, self.incomplete_frames, self.frames, self.lut_swaps]
    }
    /// The inverse of [`to_words`](Self::to_words).
    pub fn from_words(w: [u32; STATUS_WORDS]) -> Self {
        Status {
            out_of_range_codes: w[0],
            saturated_additions: w[1],
            rejected_lines: w[2],
            incomplete_frames: w[3],
            frames: w[4],
            lut_swaps: w[5],
        }
    }
}

/// Where a streamed run's side products go.
pub struct StreamSinks<'a, const N: usize, const CODES: usize> {
    /// Per-ADC histograms over the whole region, when asked for: a separate pass over
    /// each line after its correction, so the correction's loop carries no capture.
    pub histograms: Option<&'a mut HistogramSet<N, CODES>>,
    /// Noise estimate from frame 0 and frame `states` (the first two frames of state 0).
    pub noise: &'a mut NoiseEstimator,
    /// Keeps frame 0 for the noise pair; needs `geometry.pixels()` codes, or the noise
    /// estimate is skipped.
    pub first_frame: &'a mut [u16],
}

/// Runs `frames` frames through `corrector`, frame `f` in state `f mod states`, each
/// line fetched by `next_line` into a buffer of the geometry's width. The one loop both
/// the firmware (lines from a file) and the host (lines from memory) drive.
pub fn run_stream<const N: usize, const CODES: usize, E: From<CoreError>>(
    corrector: &mut Corrector<'_, N, CODES>,
    sinks: StreamSinks<'_, N, CODES>,
    frames: u32,
    line: &mut [u16],
    mut next_line: impl FnMut(&mut [u16]) -> Result<(), E>,
) -> Result<(), E> {
    let g = corrector.sums().geometry();
    let width = g.width() as usize;
    let Some(line) = line.get_mut(..width) else {
        return Err(CoreError::Length { what: crate::error::Quantity::LinePixels, expected: width as u32, got: line.len() as u32 }.into());
    };
    let roi = Roi::new((0, g.height()), (g.first_column(), g.first_column().saturating_add(g.width())), g)?;
    let StreamSinks { mut histograms, noise, first_frame } = sinks;
    let keep = first_frame.len() >= g.pixels();
    for frame in 0..frames {
        corrector.begin_frame((frame % g.states() as u32) as u8)?;
        for row in 0..g.height() {
            next_line(line)?;
            corrector.accumulate_line(row, line)?;
            if let Some(h) = histograms.as_deref_mut() {
                h.capture_line(&roi, row, g.first_column(), line);
            }
            let start = row as usize * width;
            if let Some(saved) = first_frame.get_mut(start..start + width).filter(|_| keep) {
                if frame == 0 {
                    saved.copy_from_slice(line);
                } else if frame == g.states() as u32 {
                    noise.add_pair(saved, line)?;
                }
            }
        }
        corrector.end_frame()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips_and_rejects_garbage() {
        let h = StreamHeader { geometry: Geometry::new(64, 32, 4, 3).unwrap(), frames: 40, capture_histograms: false };
        let bytes = h.encode();
        assert_eq!(&bytes[..6], b"DNLS\x01\x00");
        assert_eq!(StreamHeader::parse(&bytes), Ok(h));
        // The capture flag is bit 0 of byte 11; any other bit there is refused.
        let c = StreamHeader { capture_histograms: true, ..h };
        assert_eq!(c.encode()[11], 1);
        assert_eq!(StreamHeader::parse(&c.encode()), Ok(c));
        for flags in [2u8, 3, 0x80] {
            let mut f = bytes;
            f[11] = flags;
            assert_eq!(StreamHeader::parse(&f), Err(CoreError::StreamHeader), "flags {flags:#x}");
        }
        let mut bad = bytes;
        bad[10] = 0;
        assert!(matches!(StreamHeader::parse(&bad), Err(CoreError::Geometry { states: 0, .. })));
        bad = bytes;
        bad[0] = b'X';
        assert_eq!(StreamHeader::parse(&bad), Err(CoreError::StreamHeader));
        let s = Status { out_of_range_codes: 1, saturated_additions: 2, rejected_lines: 3, incomplete_frames: 4, frames: 5, lut_swaps: 6 };
        assert_eq!(Status::from_words(s.to_words()), s);
    }
}
