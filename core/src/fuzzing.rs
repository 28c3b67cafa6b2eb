//! Entry points of the fuzz targets (`fuzz/`, issue 18), shared with the corpus replay
//! test (`core/tests/fuzz_corpus.rs`) so that both run the same code. Not an API.
//!
//! ## `lut_image_chunks`: what is checked
//! Any bytes, cut into any chunks, uploaded into [`LutBanks`]: the upload never panics,
//! and `finish_upload` succeeds exactly when the bytes are a valid image by an
//! independent whole-image parse ([`reference_entries`]: the header byte by byte, every
//! entry below 2^23 and not below its predecessor, the CRC-32 by the textbook bitwise
//! algorithm). After a successful upload and a frame boundary the active tables hold the
//! image's entries, bit for bit; after a failed one the active tables are untouched and
//! activation is refused. Whole-image loading ([`LutBanks::load_image`]) must agree with
//! the chunked upload.
//!
//! ## Input layout
//! Byte 0: bit 0 selects the layout (0: 2 ADCs of 16 codes, a 148-byte image the fuzzer
//! can explore by itself; 1: the camera's 4 ADCs of 4096 codes), bits 1-3 the largest
//! chunk (2^0 to 2^7 bytes), bit 4 whether empty chunks occur. Bytes 1-2 seed the chunk
//! lengths (xorshift). The rest is the image stream.

use crate::image::{image_len, HEADER_LEN, MAGIC, VERSION};
use crate::lut::LUT_ENTRY_LIMIT;
use crate::{CoreError, LutBanks, LutSet, StagingState};

/// Bytes before the image stream in a `lut_image_chunks` input.
pub const LUT_IMAGE_PREFIX: usize = 3;

/// The `lut_image_chunks` target: panics only if an invariant of the module documentation
/// breaks.
pub fn lut_image_chunks(data: &[u8]) {
    if data.len() < LUT_IMAGE_PREFIX {
        return;
    }
    let (control, seed, image) = (data[0], u16::from_le_bytes([data[1], data[2]]), &data[LUT_IMAGE_PREFIX..]);
    if control & 1 == 0 {
        upload_in_chunks::<2, 16>(control, seed, image);
    } else {
        upload_in_chunks::<4, 4096>(control, seed, image);
    }
}

/// A `lut_image_chunks` input that uploads `image` in chunks of at most `2^max_chunk_log2`
/// bytes into the layout `camera` (4 x 4096) or the small one (2 x 16).
pub fn lut_image_input(camera: bool, max_chunk_log2: u8, seed: u16, image: &[u8], out: &mut [u8]) -> Option<usize> {
    let len = LUT_IMAGE_PREFIX + image.len();
    let out = out.get_mut(..len)?;
    out[0] = camera as u8 | (max_chunk_log2 & 7) << 1;
    out[1..3].copy_from_slice(&seed.to_le_bytes());
    out[LUT_IMAGE_PREFIX..].copy_from_slice(image);
    Some(len)
}

fn upload_in_chunks<const N: usize, const CODES: usize>(control: u8, seed: u16, image: &[u8]) {
    let max_chunk = 1usize << ((control >> 1) & 7);
    let empty_chunks = control & 0x10 != 0;
    // Every entry differs from the ideal tables', so a stale or half-written bank shows.
    let initial = LutSet::<N, CODES>::ideal();
    let mut banks = LutBanks::new(initial.clone());
    banks.begin_upload();
    let mut state = u32::from(seed) | 1 << 16;
    let mut rest = image;
    let mut first_error = None;
    loop {
        // xorshift32: any seed but 0, which the high bit excludes.
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let len = if empty_chunks && state % 8 == 0 { 0 } else { 1 + (state >> 3) as usize % max_chunk };
        let (chunk, after) = rest.split_at(len.min(rest.len()));
        let result = banks.upload(chunk);
        match (first_error, result) {
            (None, Err(e)) => first_error = Some(e),
            // The first error ends the upload: every later chunk is refused.
            (Some(_), r) => assert!(r.is_err(), "an upload continued after its error"),
            (None, Ok(())) => {}
        }
        rest = after;
        if rest.is_empty() {
            break;
        }
    }
    let finished = banks.finish_upload();
    let reference = reference_entries::<N, CODES>(image);
    match (&finished, &reference) {
        (Ok(()), Ok(())) => {
            assert_eq!(first_error, None);
            assert_eq!(banks.staging_state(), StagingState::Valid);
            assert_eq!(banks.active(), &initial, "the active bank changed before activation");
            banks.request_activation().expect("a valid staging bank activates");
            assert!(banks.swap_if_pending());
            for (i, entry) in banks.active().tables().iter().flatten().enumerate() {
                assert_eq!(entry.to_bits(), entry_at(image, i), "active entry {i} differs from the image");
            }
        }
        (Err(e), Err(why)) => {
            assert!(first_error.is_none_or(|f| f == *e), "finish_upload did not report the upload's first error");
            assert!(matches!(banks.staging_state(), StagingState::Failed(f) if f == *e));
            assert_eq!(banks.request_activation(), Err(CoreError::StagingNotValid), "{why}");
            assert!(!banks.swap_if_pending());
            assert_eq!(banks.active(), &initial, "a refused upload ({e}) changed the active bank");
        }
        (Ok(()), Err(why)) => panic!("the loader accepted an invalid image: {why}"),
        (Err(e), Ok(())) => panic!("the loader refused a valid image: {e}"),
    }
    // The same bytes in one piece: the same verdict.
    let mut whole = LutBanks::new(initial);
    assert_eq!(whole.load_image(image).is_ok(), finished.is_ok(), "chunked and whole uploads disagree");
}

/// Entry `i` (ADC-major) of an image whose length was checked.
fn entry_at(image: &[u8], i: usize) -> u32 {
    let at = HEADER_LEN + 4 * i;
    u32::from_le_bytes([image[at], image[at + 1], image[at + 2], image[at + 3]])
}

/// Whether `image` is a valid image of a `LutSet<N, CODES>`, checked on the whole image
/// and independently of [`crate::ImageLoader`]; `Err` says what is wrong.
pub fn reference_entries<const N: usize, const CODES: usize>(image: &[u8]) -> Result<(), &'static str> {
    if image.len() != image_len::<N, CODES>() {
        return Err("length");
    }
    let count = (N * CODES) as u32;
    let bits = CODES.trailing_zeros() as u8;
    let mut header = [0u8; HEADER_LEN];
    header[..4].copy_from_slice(&MAGIC);
    header[4..6].copy_from_slice(&VERSION.to_le_bytes());
    // Written out here rather than asked of the core: 23-bit entries, 11 fractional bits
    // up to 12-bit codes and the rest of the 23 above.
    let frac = if bits <= 12 { 11 } else { 23 - bits };
    header[6..9].copy_from_slice(&[bits, N as u8, frac]);
    header[12..].copy_from_slice(&count.to_le_bytes());
    if image[..HEADER_LEN] != header {
        return Err("header");
    }
    for adc in 0..N {
        let mut previous = 0;
        for code in 0..CODES {
            let e = entry_at(image, adc * CODES + code);
            if e >= LUT_ENTRY_LIMIT {
                return Err("entry at or above 2^23");
            }
            if e < previous {
                return Err("decreasing entry");
            }
            previous = e;
        }
    }
    let body = &image[..image.len() - 4];
    let mut crc = 0xFFFF_FFFFu32;
    for &b in body {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    if entry_at(image, N * CODES).to_le_bytes() != (!crc).to_le_bytes() {
        return Err("CRC");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encode_image;

    #[test]
    fn the_reference_parse_accepts_encoded_images_and_rejects_flipped_bits() {
        let set = LutSet::<2, 16>::from_bits(&[[3; 16], core::array::from_fn(|k| 100 * k as u32)]).unwrap();
        let mut image = [0u8; image_len::<2, 16>()];
        encode_image(&set, &mut image).unwrap();
        assert_eq!(reference_entries::<2, 16>(&image), Ok(()));
        assert_eq!(reference_entries::<4, 16>(&image), Err("length"));
        for bit in [0, 8 * 7, 8 * 20, 8 * (image.len() - 1) + 7] {
            let mut bad = image;
            bad[bit / 8] ^= 1 << (bit % 8);
            assert!(reference_entries::<2, 16>(&bad).is_err(), "bit {bit}");
        }
        // And the target agrees with it for any chunking of the valid image.
        let mut input = [0u8; LUT_IMAGE_PREFIX + image_len::<2, 16>()];
        for (log2, seed) in [(0, 1), (3, 7), (7, 65535)] {
            let n = lut_image_input(false, log2, seed, &image, &mut input).unwrap();
            lut_image_chunks(&input[..n]);
        }
    }
}
