//! The LUT device image: how a calibration travels from the host to the datapath.
//!
//! ## Format, version 1 (all integers little-endian)
//! | offset          | size         | field                                                      |
//! |-----------------|--------------|------------------------------------------------------------|
//! | 0               | 4            | magic `DNLT`                                               |
//! | 4               | 2            | version = 1                                                |
//! | 6               | 1            | B, bits per code                                           |
//! | 7               | 1            | N, number of ADCs                                          |
//! | 8               | 1            | fractional bits of an entry = 11                           |
//! | 9               | 3            | reserved, zero                                             |
//! | 12              | 4            | entry count = N x 2^B                                      |
//! | 16              | 4 x count    | entries (u32, units of 2^-11 DN), ADC-major: ADC 0 codes 0..2^B, then ADC 1, ... |
//! | 16 + 4 x count  | 4            | CRC-32 (IEEE 802.3, zlib's `crc32`) of every byte before it |
//!
//! ## Validation
//! The [`ImageLoader`] parses a stream of any chunking without allocation. It checks the
//! header against the LUT set it fills, every entry against 2^23 and its predecessor
//! (monotonicity), the length and the CRC. CRC-32 detects every single-bit error, so any
//! one flipped bit is rejected. The loader writes into the *staging* bank only; the bank
//! becomes activatable only when [`ImageLoader::finish`] succeeds (see [`crate::banks`]).

use crc::{Crc, Digest, CRC_32_ISO_HDLC};

use crate::adc::CodeCount;
use crate::lut::{check_entry, LutEntry};
use crate::{CoreError, LutSet};

/// Magic bytes at the start of every image.
pub const MAGIC: [u8; 4] = *b"DNLT";
/// The only version this core reads and writes.
pub const VERSION: u16 = 1;
/// Header length in bytes.
pub const HEADER_LEN: usize = 16;
const CRC_LEN: usize = 4;

/// The CRC-32 of images (and, for the driver, of nothing else).
pub static CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Length in bytes of the image of a `LutSet<N, CODES>`.
pub const fn image_len<const N: usize, const CODES: usize>() -> usize {
    HEADER_LEN + 4 * N * CODES + CRC_LEN
}

fn header<const N: usize, const CODES: usize>() -> [u8; HEADER_LEN] {
    let mut h = [0u8; HEADER_LEN];
    h[..4].copy_from_slice(&MAGIC);
    h[4..6].copy_from_slice(&VERSION.to_le_bytes());
    h[6] = CodeCount::<CODES>::BITS as u8;
    h[7] = N as u8;
    h[8] = LutSet::<N, CODES>::FRAC_BITS as u8;
    h[12..16].copy_from_slice(&((N * CODES) as u32).to_le_bytes());
    h
}

/// Writes the image of `luts` into `out`; returns the number of bytes written.
pub fn encode_image<const N: usize, const CODES: usize>(luts: &LutSet<N, CODES>, out: &mut [u8]) -> Result<usize, CoreError> {
    let len = image_len::<N, CODES>();
    let Some(out) = out.get_mut(..len) else {
        return Err(CoreError::BufferTooSmall { needed: len as u32, got: out.len() as u32 });
    };
    out[..HEADER_LEN].copy_from_slice(&header::<N, CODES>());
    let entries = luts.tables().iter().flat_map(|t| t.iter());
    for (chunk, e) in out[HEADER_LEN..len - CRC_LEN].chunks_exact_mut(4).zip(entries) {
        chunk.copy_from_slice(&e.to_bits().to_le_bytes());
    }
    let crc = CRC32.checksum(&out[..len - CRC_LEN]);
    out[len - CRC_LEN..].copy_from_slice(&crc.to_le_bytes());
    Ok(len)
}

/// A streaming parser of one image into a set of tables.
pub struct ImageLoader<const N: usize, const CODES: usize> {
    /// Bytes received so far.
    pos: usize,
    header: [u8; HEADER_LEN],
    word: [u8; 4],
    previous: u32,
    crc: Digest<'static, u32>,
    state: LoaderState,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LoaderState {
    Receiving,
    Failed(CoreError),
    Done,
}

impl<const N: usize, const CODES: usize> Default for ImageLoader<N, CODES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const CODES: usize> ImageLoader<N, CODES> {
    const LEN: usize = image_len::<N, CODES>();
    const ENTRIES_END: usize = Self::LEN - CRC_LEN;

    /// A loader waiting for the first byte of an image.
    pub fn new() -> Self {
        ImageLoader { pos: 0, header: [0; HEADER_LEN], word: [0; 4], previous: 0, crc: CRC32.digest(), state: LoaderState::Receiving }
    }

    /// Takes the next bytes of the image and writes validated entries into `tables`. The
    /// first error ends the upload: later calls return it again.
    pub fn feed(&mut self, tables: &mut [[LutEntry; CODES]; N], bytes: &[u8]) -> Result<(), CoreError> {
        match self.state {
            LoaderState::Receiving => {}
            LoaderState::Failed(e) => return Err(e),
            LoaderState::Done => return Err(CoreError::LoaderState),
        }
        let result = self.feed_bytes(tables, bytes);
        if let Err(e) = result {
            self.state = LoaderState::Failed(e);
        }
        result
    }

    fn feed_bytes(&mut self, tables: &mut [[LutEntry; CODES]; N], bytes: &[u8]) -> Result<(), CoreError> {
        if self.pos + bytes.len() > Self::LEN {
            return Err(CoreError::ImageLength { expected: Self::LEN as u32, got: (self.pos + bytes.len()) as u32 });
        }
        let covered = Self::ENTRIES_END.saturating_sub(self.pos).min(bytes.len());
        self.crc.update(&bytes[..covered]);
        for &b in bytes {
            let pos = self.pos;
            self.pos += 1;
            if pos < HEADER_LEN {
                self.header[pos] = b;
                if pos == HEADER_LEN - 1 {
                    self.check_header()?;
                }
                continue;
            }
            self.word[(pos - HEADER_LEN) % 4] = b;
            if (pos - HEADER_LEN) % 4 != 3 {
                continue;
            }
            let value = u32::from_le_bytes(self.word);
            if pos < Self::ENTRIES_END {
                let index = (pos - HEADER_LEN) / 4;
                let (adc, code) = (index / CODES, index % CODES);
                let entry = check_entry(adc, code, self.previous, value)?;
                if let Some(slot) = tables.get_mut(adc).and_then(|t| t.get_mut(code)) {
                    *slot = entry;
                }
                self.previous = value;
            } else {
                let computed = self.crc.clone().finalize();
                if computed != value {
                    return Err(CoreError::ImageCrc { stored: value, computed });
                }
                self.state = LoaderState::Done;
            }
        }
        Ok(())
    }

    fn check_header(&self) -> Result<(), CoreError> {
        let h = &self.header;
        if h[..4] != MAGIC {
            return Err(CoreError::ImageMagic);
        }
        let version = u16::from_le_bytes([h[4], h[5]]);
        if version != VERSION {
            return Err(CoreError::ImageVersion { version });
        }
        if h[6] as u32 != CodeCount::<CODES>::BITS || h[7] as usize != N || h[8] as u32 != LutSet::<N, CODES>::FRAC_BITS {
            return Err(CoreError::ImageLayout { bits: h[6], adcs: h[7], frac_bits: h[8] });
        }
        if h[9..12] != [0, 0, 0] {
            return Err(CoreError::ImageReserved);
        }
        let count = u32::from_le_bytes([h[12], h[13], h[14], h[15]]);
        if count as usize != N * CODES {
            let declared = (HEADER_LEN as u64 + 4 * count as u64 + CRC_LEN as u64).min(u32::MAX as u64) as u32;
            return Err(CoreError::ImageLength { expected: declared, got: Self::LEN as u32 });
        }
        Ok(())
    }

    /// Ends the upload: `Ok` only if the whole image arrived and validated.
    pub fn finish(&mut self) -> Result<(), CoreError> {
        match self.state {
            LoaderState::Done => Ok(()),
            LoaderState::Failed(e) => Err(e),
            LoaderState::Receiving => {
                let e = CoreError::ImageLength { expected: Self::LEN as u32, got: self.pos as u32 };
                self.state = LoaderState::Failed(e);
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_layout_is_as_documented() {
        let luts = LutSet::<4, 16>::ideal();
        let mut buf = [0u8; image_len::<4, 16>()];
        assert_eq!(encode_image(&luts, &mut buf), Ok(16 + 4 * 64 + 4));
        assert_eq!(&buf[..16], b"DNLT\x01\x00\x04\x04\x0b\x00\x00\x00\x40\x00\x00\x00");
        // Entry 1 of ADC 0: 1.5 DN = 3072.
        assert_eq!(&buf[20..24], &3072u32.to_le_bytes());
        // zlib's crc32 of the same bytes, computed by the textbook bitwise algorithm.
        let mut crc = 0xFFFF_FFFFu32;
        for &b in &buf[..buf.len() - 4] {
            crc ^= b as u32;
            for _ in 0..8 {
                crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
            }
        }
        assert_eq!(&buf[buf.len() - 4..], &(!crc).to_le_bytes());
        let mut small = [0u8; 10];
        assert!(matches!(encode_image(&luts, &mut small), Err(CoreError::BufferTooSmall { .. })));
    }

    /// Every 2-bit error in an image shorter than 2^32 - 1 bits changes its CRC-32 (with
    /// every burst of up to 32 bits, what the SPI link relies on for LUT payloads): the
    /// error x^i (1 + x^d) is a multiple of the generator G only if x^d = 1 modulo G, and
    /// the order of x modulo G is 2^32 - 1, checked here against its prime factors.
    #[test]
    fn the_image_crc_catches_every_two_bit_error() {
        const G: u64 = 1 << 32 | 0x04C1_1DB7;
        let mul = |mut a: u64, mut b: u64| {
            let mut r = 0u64;
            while b != 0 {
                if b & 1 == 1 {
                    r ^= a;
                }
                b >>= 1;
                a <<= 1;
                if a >> 32 & 1 == 1 {
                    a ^= G;
                }
            }
            r
        };
        let x_to = |mut e: u64| {
            let (mut r, mut base) = (1u64, 2u64);
            while e != 0 {
                if e & 1 == 1 {
                    r = mul(r, base);
                }
                base = mul(base, base);
                e >>= 1;
            }
            r
        };
        let order = (1u64 << 32) - 1;
        assert_eq!(x_to(order), 1);
        for p in [3, 5, 17, 257, 65537] {
            assert_ne!(x_to(order / p), 1, "x^((2^32-1)/{p})");
        }
    }

    #[test]
    fn round_trip_in_odd_chunks() {
        let luts = LutSet::<2, 8>::from_bits(&[[0, 1, 2, 3, 4, 5, 6, 7], [9, 9, 9, 10, 11, 200, 300, 8_000_000]]).unwrap();
        let mut buf = [0u8; image_len::<2, 8>()];
        encode_image(&luts, &mut buf).unwrap();
        let mut tables = LutSet::<2, 8>::ideal();
        let mut loader = ImageLoader::<2, 8>::new();
        for chunk in buf.chunks(7) {
            loader.feed(tables.tables_mut(), chunk).unwrap();
        }
        loader.finish().unwrap();
        assert_eq!(tables, luts);
        assert_eq!(loader.feed(tables.tables_mut(), &[0]), Err(CoreError::LoaderState));
    }

    #[test]
    fn truncated_and_overlong_images_are_rejected() {
        let mut buf = [0u8; image_len::<1, 4>() + 1];
        encode_image(&LutSet::<1, 4>::ideal(), &mut buf).unwrap();
        let mut t = LutSet::<1, 4>::ideal();
        let mut loader = ImageLoader::<1, 4>::new();
        loader.feed(t.tables_mut(), &buf[..20]).unwrap();
        assert_eq!(loader.finish(), Err(CoreError::ImageLength { expected: 36, got: 20 }));
        let mut loader = ImageLoader::<1, 4>::new();
        assert_eq!(loader.feed(t.tables_mut(), &buf), Err(CoreError::ImageLength { expected: 36, got: 37 }));
        let mut wrong = buf;
        wrong[7] = 2;
        let mut loader = ImageLoader::<1, 4>::new();
        assert_eq!(loader.feed(t.tables_mut(), &wrong[..36]), Err(CoreError::ImageLayout { bits: 2, adcs: 2, frac_bits: 11 }));
    }

    /// A header declaring another entry count is refused with the length it declares
    /// (16 header bytes, 4 per entry, 4 of CRC: 3 entries declare 32 bytes) against the
    /// length this layout needs (4 entries: 36).
    #[test]
    fn a_wrong_entry_count_is_refused_with_the_length_it_declares() {
        let mut buf = [0u8; image_len::<1, 4>()];
        encode_image(&LutSet::<1, 4>::ideal(), &mut buf).unwrap();
        buf[12] = 3;
        let mut t = LutSet::<1, 4>::ideal();
        let mut loader = ImageLoader::<1, 4>::new();
        assert_eq!(loader.feed(t.tables_mut(), &buf[..16]), Err(CoreError::ImageLength { expected: 32, got: 36 }));
        buf[12] = 200;
        let mut loader = ImageLoader::<1, 4>::new();
        assert_eq!(loader.feed(t.tables_mut(), &buf[..16]), Err(CoreError::ImageLength { expected: 16 + 800 + 4, got: 36 }));
    }
}
