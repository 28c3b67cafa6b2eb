//! The device image: the LUT set as the co-processor's staging bank loads it, in the
//! core's encoding ([`dncal_core::image`]: a 16-byte header with `DNLT`, bit depth and ADC
//! count, the entries, a CRC). The host never encodes or parses it by hand: both ways go
//! through the core, so what the host writes is what the device accepts.

use std::path::Path;

use dncal_core::{encode_image, image_len, LutSet};

use super::LutFault;
use crate::{HostError, Origin};

/// The first bytes of every device image.
pub const MAGIC: &[u8] = &dncal_core::image::MAGIC;

/// The largest device image the core loads (4 ADCs of 16 bits); a longer file is not
/// read whole.
const DEVICE_IMAGE_LIMIT: crate::formats::input::SizeLimit = crate::formats::input::SizeLimit { what: "device image", bytes: image_len::<4, 65536>() as u64 };

/// Reads the device image `path`: the core validates it (header, CRC, every entry) as it
/// loads it into a staging bank and activates it, and the tables are the active bank's.
pub fn read(path: &Path) -> Result<Vec<Vec<u32>>, HostError> {
    let bytes = crate::formats::input::read_regular(path, DEVICE_IMAGE_LIMIT)?;
    if bytes.len() < 16 {
        return Err(HostError::lut(path, LutFault::ImageShort));
    }
    let (bits, n) = (bytes[6] as u32, bytes[7] as usize);
    if !(1..=16).contains(&bits) {
        return Err(HostError::lut(path, LutFault::ImageBits { bits }));
    }
    crate::dispatch_lut_dims!(n, 1usize << bits, path, parse(&bytes, path))
}

fn parse<const N: usize, const CODES: usize>(bytes: &[u8], path: &Path) -> Result<Vec<Vec<u32>>, HostError> {
    let err = |e| HostError::core(path.display().to_string(), e);
    let mut banks = Box::new(dncal_core::LutBanks::new(LutSet::<N, CODES>::ideal()));
    banks.load_image(bytes).map_err(err)?;
    // With no frame open the activation swaps the validated staging bank in at once.
    let g = dncal_core::Geometry::new(1, 1, 1, 0).map_err(err)?;
    let mut sums = [0u32; 1];
    let mut c = dncal_core::Corrector::new(&mut banks, g, &mut sums).map_err(err)?;
    c.request_activation().map_err(err)?;
    Ok(c.banks().active().tables().iter().map(|t| t.iter().map(|e| e.to_bits()).collect()).collect())
}

/// The device image of a LUT set.
pub fn encode_set<const N: usize, const CODES: usize>(set: &LutSet<N, CODES>) -> Result<Vec<u8>, HostError> {
    let mut image = vec![0u8; image_len::<N, CODES>()];
    encode_image(set, &mut image).map_err(|e| HostError::core("encode device image", e))?;
    Ok(image)
}

/// The device image of per-ADC `tables` (entries, LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits`), which the core
/// validates first; `source` names the input in errors.
pub fn encode(tables: &[Vec<u32>], source: impl Into<Origin>) -> Result<Vec<u8>, HostError> {
    let source = source.into();
    let (n, codes) = (tables.len(), tables.first().map_or(0, Vec::len));
    crate::dispatch_lut_dims!(n, codes, source.clone(), encode_tables(tables, &source))
}

fn encode_tables<const N: usize, const CODES: usize>(tables: &[Vec<u32>], source: &Origin) -> Result<Vec<u8>, HostError> {
    encode_set(&*crate::infra::dims::lut_set::<N, CODES>(tables, source)?)
}
