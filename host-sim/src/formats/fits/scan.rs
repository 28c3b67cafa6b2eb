//! Checks on a file's bytes before cfitsio reads it: a gzip file's inflated size, HDUs
//! that declare more bytes than the file has, malformed binary tables.

use super::*;

/// The size cfitsio allocates at once to uncompress `file` (of `size` bytes) into memory,
/// as it reads it from the header (`mem_compress_open` in cfitsio's `drvrmem.c`): gzip's
/// `ISIZE`, the last 4 bytes, plus 2^32 until above the file's size if the file has more
/// than 10 000 bytes; zip's uncompressed size at byte 22 (a file too short to hold it
/// leaves cfitsio with stale bytes: counted as 2^32, refused). `None` for a file that is
/// not gzip or zip: cfitsio estimates other methods at 3 x the file's size (issue 18: an
/// 11-byte file starting `PK` made every FITS reader allocate 4 GB).
pub(super) fn declared_uncompressed_size(file: &mut std::fs::File, size: u64) -> std::io::Result<Option<u64>> {
    use std::io::{Read, Seek, SeekFrom};
    let le = |b: [u8; 4]| u64::from(u32::from_le_bytes(b));
    let mut magic = [0u8; 2];
    file.seek(SeekFrom::Start(0))?;
    if size < 2 {
        return Ok(None);
    }
    file.read_exact(&mut magic)?;
    let mut field = [0u8; 4];
    match &magic {
        b"\x1f\x8b" if size >= 4 => {
            file.seek(SeekFrom::End(-4))?;
            file.read_exact(&mut field)?;
            let mut declared = le(field);
            if size > 10_000 {
                while declared < size {
                    declared += 1 << 32;
                }
            }
            Ok(Some(declared))
        }
        b"PK" if size >= 26 => {
            file.seek(SeekFrom::Start(22))?;
            file.read_exact(&mut field)?;
            Ok(Some(le(field)))
        }
        b"\x1f\x8b" | b"PK" => Ok(Some(1 << 32)),
        _ => Ok(None),
    }
}

/// Refuses a gzip file that inflates to more than `limit` bytes. cfitsio decompresses a
/// gzip file whole into memory, growing its buffer past the size the trailer declares
/// (which is the size modulo 2^32: a 5 GiB file declares 1 GiB), so the only bound is the
/// inflated size itself: counted here by inflating into nothing, stopping one byte past
/// the limit (issue 18: a 5 MB file reached 3 GB in cfitsio before it gave up).
pub(super) fn check_gzip_inflates_within(file: &mut std::fs::File, path: &Path, limit: u64) -> Result<u64, HostError> {
    use std::io::{Read, Seek, SeekFrom};
    file.seek(SeekFrom::Start(0)).map_err(|e| HostError::io(path, e))?;
    let mut inflated = flate2::read::MultiGzDecoder::new(std::io::BufReader::new(&mut *file)).take(limit.saturating_add(1));
    // A corrupt stream is cfitsio's to report (with its own message); only the size is
    // ours, counted up to where the stream breaks.
    let (mut n, mut buf) = (0u64, vec![0u8; 1 << 16]);
    while let Ok(k) = inflated.read(&mut buf) {
        if k == 0 {
            break;
        }
        n += k as u64;
    }
    if n > limit {
        return Err(format_error(path, format!(
            "inflates to more than {} (gzip), more than {}",
            crate::infra::budget::human(limit),
            if limit == crate::infra::budget::limit() { "the memory budget (--max-memory)" } else { "1100 times its size, above deflate's largest ratio" }
        )));
    }
    Ok(n)
}

/// The first table header of the plain FITS file `file` whose mandatory keywords cfitsio
/// mis-checks: its byte offset and the card. `ffgttb` compares the status where it means
/// to set it (`return(*status == BAD_TFIELDS)`), so a table with `TFIELDS` above 999 or a
/// negative `NAXIS1` or `NAXIS2` passes as valid, with `TFIELDS` as written or never read;
/// cfitsio then allocates a column descriptor for every field as soon as it walks past the
/// HDU, which counting HDUs does (issue 18, found by `fits_linearity`: an allocation of
/// 2^54 bytes; a third input reached the same allocation with a garbled `GCOUNT` card). So
/// a table header must open with the cards the standard fixes in place, `BITPIX`, `NAXIS`,
/// `NAXIS1`, `NAXIS2`, `PCOUNT`, `GCOUNT`, `TFIELDS`, each a plain integer in range
/// (`TFIELDS` at most 999).
/// The walk reads the headers only, skipping each data unit by the size its header
/// declares; past a header it cannot follow (cfitsio reads some values this parse does
/// not) it checks every following 2880-byte block that starts like a table header.
///
/// About 115 lines: one walk over the file's blocks with its position as the state; the
/// card parsing it needs is local helpers.
pub(super) fn malformed_table(file: &mut std::fs::File, size: u64) -> std::io::Result<Option<(u64, String)>> {
    use std::io::{Read, Seek, SeekFrom};
    const BLOCK: u64 = 2880;
    // The value as cfitsio reads it, before the comment (found by `fits_linearity`: an
    // image's `NAXIS2` with a byte 0xDF in its comment had sent the walk to the wrong
    // block, past the table after it; `ffpsvc`, then `ffc2jj`): the token from the first
    // non-blank after the `= ` up to the next blank or `/`, its leading whitespace skipped
    // by `strtoll` (a tab or a form feed), then digits to the token's end. Rust's `trim`
    // had dropped the form feed of `NAXIS1 =      \x0c             8` and read 8 where
    // cfitsio reads an empty token and fails (found by `fits_linearity`: `ffgttb` passed
    // that failure on unnoticed, and `ffbinit` allocated descriptors for a `TFIELDS` it
    // never read).
    let integer = |card: &[u8]| -> Option<i64> {
        let value = &card[10..];
        let token = &value[value.iter().position(|&b| b != b' ')?..];
        let token = &token[..token.iter().position(|&b| b == b' ' || b == b'/').unwrap_or(token.len())];
        let digits = &token[token.iter().position(|b| !b"\t\n\x0b\x0c\r".contains(b)).unwrap_or(token.len())..];
        std::str::from_utf8(digits).ok()?.parse::<i64>().ok()
    };
    // The keyword's name as cfitsio's `ffgknm` reads it: up to the first blank, `=` or NUL
    // (found by `fits_linearity`: an image's `END    q` ends its header for cfitsio, and a
    // walk that did not see it missed the table after it).
    fn keyword(card: &[u8]) -> &str {
        let end = card.iter().position(|&b| b == b' ' || b == b'=' || b == 0).unwrap_or(card.len());
        std::str::from_utf8(&card[..end]).unwrap_or("")
    }
    let (mut start, mut lost) = (0u64, false);
    let mut block = [0u8; BLOCK as usize];
    // A last block cut short is read too (the rest as zeros): cfitsio parses what a
    // truncated file holds of a header (found by `fits_linearity`: a table header cut
    // after its `PCOUNT` card made cfitsio allocate 2^54 bytes).
    while start < size {
        file.seek(SeekFrom::Start(start))?;
        block.fill(0);
        let n = (size - start).min(BLOCK) as usize;
        file.read_exact(&mut block[..n])?;
        let card = |n: usize| &block[80 * (n - 1)..80 * n];
        if &card(1)[..10] == b"XTENSION= " {
            // The quoted string, as cfitsio reads it, whatever follows it before the comment.
            let xtension = String::from_utf8_lossy(&card(1)[10..]);
            let xtension = xtension.trim_start().strip_prefix('\'').and_then(|v| v.split('\'').next()).unwrap_or("").trim();
            if ["TABLE", "BINTABLE", "A3DTABLE", "3DTABLE"].contains(&xtension) {
                let mandatory = [
                    (2, "BITPIX", i64::MIN, i64::MAX),
                    (3, "NAXIS", 0, 999),
                    (4, "NAXIS1", 0, i64::MAX),
                    (5, "NAXIS2", 0, i64::MAX),
                    (6, "PCOUNT", 0, i64::MAX),
                    (7, "GCOUNT", 0, i64::MAX),
                    (8, "TFIELDS", 0, 999),
                ];
                for (n, key, min, max) in mandatory {
                    let c = card(n);
                    if &c[..10] != format!("{key:<8}= ").as_bytes() || !integer(c).is_some_and(|v| (min..=max).contains(&v)) {
                        return Ok(Some((start, printable(c))));
                    }
                }
            }
        }
        // An extension must start where the one before ended; a walk that lands elsewhere
        // has misread a size, and from there checks every block instead.
        if start > 0 && &block[..9] != b"XTENSION=" {
            lost = true;
        }
        if lost {
            start += BLOCK;
            continue;
        }
        let (mut bitpix, mut naxis, mut pcount, mut gcount) = (None, None, 0i64, 1i64);
        let mut axes: Vec<i64> = Vec::new();
        let mut at = start + BLOCK;
        let ended = 'header: loop {
            for card in block.chunks_exact(80) {
                let key = keyword(card);
                if key == "END" {
                    break 'header true;
                }
                if &card[8..10] != b"= " {
                    continue;
                }
                let Some(value) = integer(card) else { continue };
                match key {
                    "BITPIX" => bitpix = Some(value),
                    "NAXIS" => naxis = Some(value),
                    "PCOUNT" => pcount = value,
                    "GCOUNT" => gcount = value,
                    k if k.starts_with("NAXIS") => {
                        if let Some(n) = k[5..].parse::<usize>().ok().filter(|n| (1..=999).contains(n)) {
                            axes.resize(axes.len().max(n), 0);
                            axes[n - 1] = value;
                        }
                    }
                    _ => {}
                }
            }
            if at + BLOCK > size {
                break false;
            }
            file.read_exact(&mut block)?;
            at += BLOCK;
        };
        if !ended {
            // No END: cfitsio refuses the header itself.
            return Ok(None);
        }
        let axes = naxis.and_then(|n| axes.get(..usize::try_from(n).ok()?));
        let bytes = match (bitpix, naxis, axes) {
            (Some(_), Some(0), _) => Some(0),
            (Some(bitpix), Some(_), Some(axes)) => {
                // Random groups (primary NAXIS1 = 0) leave out the first axis, as cfitsio does.
                let counted = if start == 0 && axes.first() == Some(&0) && axes.len() > 1 { &axes[1..] } else { axes };
                counted
                    .iter()
                    .try_fold(1i64, |p, &n| p.checked_mul(n))
                    .and_then(|p| p.checked_add(pcount))
                    .and_then(|p| p.checked_mul(gcount))
                    .and_then(|p| p.checked_mul(bitpix.abs() / 8))
                    .and_then(|b| u64::try_from(b).ok())
            }
            _ => None,
        };
        match bytes {
            Some(bytes) => start = at.saturating_add(bytes.div_ceil(BLOCK).saturating_mul(BLOCK)),
            None => {
                lost = true;
                start += BLOCK;
            }
        }
    }
    Ok(None)
}
