//! Recorded raw frames, as a DAQ saves them: a 3-D integer cube.

use super::*;

/// Recorded raw frames: `frames` images of `height` x `width` codes, row-major, frame
/// after frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameCube {
    /// Pixels per line.
    pub width: usize,
    /// Lines per frame.
    pub height: usize,
    /// Frames.
    pub frames: usize,
    /// The codes.
    pub codes: Vec<u16>,
}

impl FrameCube {
    /// Frame `f`'s codes.
    pub fn frame(&self, f: usize) -> &[u16] {
        let n = self.width * self.height;
        &self.codes[f * n..(f + 1) * n]
    }
}

/// Reads recorded frames (what a DAQ saves): the primary HDU as a 3-D integer image
/// (NAXIS1 columns, NAXIS2 rows, NAXIS3 frames) or a 2-D one (a single frame) of raw codes
/// 0 to 65535 (BITPIX 16 with BZERO 32768 as astropy writes `uint16`, or any wider
/// integer type). Rejects float or scaled images, other dimensions, empty frames and codes
/// outside 16 bits, naming the first.
pub fn read_frames(path: &Path) -> Result<FrameCube, HostError> {
    let mut r = FitsReader::open(path)?;
    let naxis = r.required_int(0, PRIMARY, "NAXIS")?;
    if naxis != 2 && naxis != 3 {
        return Err(r.error(format!("the {PRIMARY} has NAXIS = {naxis}; recorded frames are a 2-D frame or a 3-D cube (columns, rows, frames)")));
    }
    let image = r.image(0, PRIMARY, naxis as usize)?;
    let (width, height) = (image.naxes[0], image.naxes[1]);
    let frames = image.naxes.get(2).copied().unwrap_or(1);
    if width == 0 || height == 0 || frames == 0 {
        return Err(r.error(format!("the {PRIMARY} has no pixels ({})", shape_text(&image.naxes))));
    }
    let codes: Vec<u16> = r.integer_pixels(&image, "raw codes")?.convert().map_err(|(i, v)| {
        let n = width * height;
        r.error(format!("code {v} at frame {}, row {}, column {} does not fit 16 bits", i / n, i % n / width, i % width))
    })?;
    Ok(FrameCube { width, height, frames, codes })
}
