//! Large floating-point data units read straight from the file, in parallel, with their
//! FITS checksum taken in the same pass.
//!
//! cfitsio reads a data unit on one thread, and verifying its `DATASUM` first
//! (`ffvcks`) reads it once more: on a 1024 x 1024 x 41-level linearity set (689 MB) the
//! two passes were most of the 0.7-1.1 s of reading (the kernel copying the page cache
//! into cfitsio's buffers, then zeroing the destination's fresh pages as they were
//! written). Here each thread reads its chunks of the unit with positioned reads into a
//! buffer it reuses, adds the big-endian words into its part of the checksum, and
//! converts them into its part of the destination.
//!
//! The checksum is the FITS standard's (Appendix J): the 32-bit ones' complement sum of
//! the unit's big-endian 32-bit words, as cfitsio's `ffcsum` computes it (its 16-bit
//! halves with end-around carries are the same adder). A test holds every verdict to
//! cfitsio's on damaged files.

use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;

use rayon::prelude::*;

/// Bytes each thread reads at a time: in cache while it is summed and converted.
const CHUNK: usize = 1 << 20;

/// `a + b` in 32-bit ones' complement arithmetic.
pub(super) fn add(a: u32, b: u32) -> u32 {
    fold(u64::from(a) + u64::from(b))
}

/// Whether a ones' complement sum is zero (either sign, as cfitsio's `ffvcks` takes it):
/// what an HDU whose `CHECKSUM` matches sums to.
pub(super) fn is_zero(sum: u32) -> bool {
    sum == 0 || sum == u32::MAX
}

/// A sum of 32-bit words, carries folded back in (end-around).
fn fold(mut s: u64) -> u32 {
    while s >> 32 != 0 {
        s = (s & 0xFFFF_FFFF) + (s >> 32);
    }
    s as u32
}

/// The ones' complement sum of `bytes` as big-endian 32-bit words (`bytes.len()` a
/// multiple of 4, as every FITS unit is: 2880 bytes a block).
pub(super) fn checksum(bytes: &[u8]) -> u32 {
    // u64 holds 2^32 words of carries: far more than a chunk.
    fold(bytes.chunks_exact(4).map(|w| u64::from(u32::from_be_bytes([w[0], w[1], w[2], w[3]]))).sum())
}

/// The checksum of the `len` bytes at `offset` of `file`, read in parallel.
pub(super) fn checksum_at(file: &File, offset: u64, len: u64) -> io::Result<u32> {
    let chunks = len.div_ceil(CHUNK as u64);
    (0..chunks)
        .into_par_iter()
        .map_init(
            || vec![0u8; CHUNK],
            |buf, k| {
                let at = k * CHUNK as u64;
                let n = (len - at).min(CHUNK as u64) as usize;
                file.read_exact_at(&mut buf[..n], offset + at)?;
                Ok(checksum(&buf[..n]))
            },
        )
        .try_reduce(|| 0, |a, b| Ok(add(a, b)))
}

/// A floating-point type as FITS stores it: IEEE, big-endian.
pub trait BigEndianFloat: Copy + Default + Send + Sync {
    /// The FITS `BITPIX` of the type (-32, -64).
    const BITPIX: i64;
    /// Bytes per value.
    const SIZE: usize;
    /// The value of its big-endian bytes (`SIZE` of them).
    fn from_be(bytes: &[u8]) -> Self;
    /// A stored `f64` as this type: rounded to nearest as C's `(float)` cast, which is
    /// cfitsio's conversion (out of range: infinite; NaN stays NaN).
    fn from_f64(v: f64) -> Self;
    /// A stored `f32` as this type (exact).
    fn from_f32(v: f32) -> Self;
}

impl BigEndianFloat for f32 {
    const BITPIX: i64 = -32;
    const SIZE: usize = 4;
    fn from_be(b: &[u8]) -> Self {
        f32::from_be_bytes([b[0], b[1], b[2], b[3]])
    }
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn from_f32(v: f32) -> Self {
        v
    }
}

impl BigEndianFloat for f64 {
    const BITPIX: i64 = -64;
    const SIZE: usize = 8;
    fn from_be(b: &[u8]) -> Self {
        f64::from_be_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
    }
    fn from_f64(v: f64) -> Self {
        v
    }
    fn from_f32(v: f32) -> Self {
        f64::from(v)
    }
}

/// `n` values stored as `S` from `offset` of `file`, read and converted to `T` by
/// `convert` in parallel, and the checksum of their bytes (the unit's padding is the
/// caller's).
pub(super) fn read_values<S: BigEndianFloat, T: Copy + Default + Send + Sync>(file: &File, offset: u64, n: usize, convert: impl Fn(S) -> T + Sync) -> io::Result<(Vec<T>, u32)> {
    let per_chunk = CHUNK / S::SIZE;
    let mut values = vec![T::default(); n];
    let sum = values
        .par_chunks_mut(per_chunk)
        .enumerate()
        .map_init(
            || vec![0u8; CHUNK],
            |buf, (k, out)| {
                read_into(file, offset + (k * per_chunk * S::SIZE) as u64, out, &convert, buf)?;
                // Every chunk starts on a word: the unit does (a 2880-byte block), and
                // each chunk is a whole number of 4- or 8-byte values.
                Ok::<_, io::Error>(checksum(buf))
            },
        )
        .try_reduce(|| 0, |a, b| Ok(add(a, b)))?;
    Ok((values, sum))
}

/// The first value (in file order) that each of two tests flags: its index and value.
pub(super) type Flagged<T> = [Option<(usize, T)>; 2];

/// A pass over the `n` values stored as `S` at `offset` of `file` that holds none of
/// them: each converted by `convert`, the first in file order that each of `bad` flags,
/// and the checksum of their bytes. What a set read by blocks of rows checks once before
/// its passes ([`super::linearity::LinearityRows`]).
pub(super) fn scan_values<S: BigEndianFloat, T: Copy + Send>(file: &File, offset: u64, n: usize, convert: impl Fn(S) -> T + Sync, bad: [&(dyn Fn(T) -> bool + Sync); 2]) -> io::Result<(Flagged<T>, u32)> {
    let per_chunk = CHUNK / S::SIZE;
    let earlier = |a: Option<(usize, T)>, b: Option<(usize, T)>| match (a, b) {
        (Some(a), Some(b)) => Some(if a.0 <= b.0 { a } else { b }),
        (a, b) => a.or(b),
    };
    let first = |a: Flagged<T>, b: Flagged<T>| [earlier(a[0], b[0]), earlier(a[1], b[1])];
    (0..n.div_ceil(per_chunk))
        .into_par_iter()
        .map_init(
            || vec![0u8; CHUNK],
            |buf, k| {
                let count = (n - k * per_chunk).min(per_chunk);
                let bytes = &mut buf[..count * S::SIZE];
                file.read_exact_at(bytes, offset + (k * per_chunk * S::SIZE) as u64)?;
                let mut flagged = [None, None];
                for (i, v) in bytes.chunks_exact(S::SIZE).map(|b| convert(S::from_be(b))).enumerate() {
                    for (f, bad) in flagged.iter_mut().zip(bad) {
                        if f.is_none() && bad(v) {
                            *f = Some((k * per_chunk + i, v));
                        }
                    }
                }
                Ok::<_, io::Error>((flagged, checksum(bytes)))
            },
        )
        .try_reduce(|| ([None, None], 0), |a, b| Ok((first(a.0, b.0), add(a.1, b.1))))
}

/// The `out.len()` values stored as `S` at `offset` of `file`, converted by `convert`,
/// on the calling thread (`bytes`: a buffer it reuses).
pub(super) fn read_into<S: BigEndianFloat, T>(file: &File, offset: u64, out: &mut [T], convert: impl Fn(S) -> T, bytes: &mut Vec<u8>) -> io::Result<()> {
    bytes.resize(out.len() * S::SIZE, 0);
    file.read_exact_at(bytes, offset)?;
    for (v, b) in out.iter_mut().zip(bytes.chunks_exact(S::SIZE)) {
        *v = convert(S::from_be(b));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// The textbook adder: 16-bit halves, carries crossing over (cfitsio's `ffcsum`,
    /// written again from the standard's description).
    fn seaman(bytes: &[u8]) -> u32 {
        let (mut hi, mut lo) = (0u64, 0u64);
        for w in bytes.chunks_exact(4) {
            hi += u64::from(u16::from_be_bytes([w[0], w[1]]));
            lo += u64::from(u16::from_be_bytes([w[2], w[3]]));
            while (hi >> 16) | (lo >> 16) != 0 {
                let (hc, lc) = (hi >> 16, lo >> 16);
                hi = (hi & 0xFFFF) + lc;
                lo = (lo & 0xFFFF) + hc;
            }
        }
        ((hi << 16) + lo) as u32
    }

    #[test]
    fn the_checksum_is_the_ones_complement_sum_and_splits_anywhere() {
        assert_eq!(checksum(&[0; 2880]), 0);
        // 0xFFFFFFFF + 1 wraps to 1 (end-around carry), not 0.
        assert_eq!(checksum(&[0xFF, 0xFF, 0xFF, 0xFF, 0, 0, 0, 1]), 1);
        let mut x = 0x1234_5678_9abc_def0u64;
        let bytes: Vec<u8> = (0..40_000)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 24) as u8
            })
            .collect();
        assert_eq!(checksum(&bytes), seaman(&bytes));
        for cut in [0, 4, 2880, 39_996] {
            assert_eq!(add(checksum(&bytes[..cut]), checksum(&bytes[cut..])), checksum(&bytes), "split at {cut}");
        }
    }

    #[test]
    fn values_read_in_parallel_are_the_file_s_and_so_is_their_sum() {
        let values: Vec<f64> = (0..(CHUNK / 8) * 3 + 17).map(|i| (i as f64).sqrt() - 100.0).collect();
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let mut file = tempfile::tempfile().unwrap();
        file.write_all(b"0123456789ab").unwrap();
        file.write_all(&bytes).unwrap();
        let (got, sum) = read_values::<f64, f64>(&file, 12, values.len(), f64::from_f64).unwrap();
        assert_eq!(got, values);
        assert_eq!(sum, seaman(&bytes));
        assert_eq!(checksum_at(&file, 12, bytes.len() as u64).unwrap(), sum);
        let (got32, _) = read_values::<f32, f32>(&file, 12, 5, f32::from_f32).unwrap();
        let want32: Vec<f32> = bytes[..20].chunks_exact(4).map(|b| f32::from_be_bytes([b[0], b[1], b[2], b[3]])).collect();
        assert_eq!(got32, want32);
        // Past the end: an error, not a short read taken for data.
        // Narrowed as it is read: the f64 values rounded to f32.
        let (narrow, narrow_sum) = read_values::<f64, f32>(&file, 12, values.len(), f32::from_f64).unwrap();
        assert_eq!(narrow, values.iter().map(|&v| v as f32).collect::<Vec<_>>());
        assert_eq!(narrow_sum, sum, "the checksum is of the stored bytes");
        assert_eq!(read_values::<f64, f64>(&file, 12, values.len() + 1, f64::from_f64).unwrap_err().kind(), io::ErrorKind::UnexpectedEof);
    }
}
