//! Reading: every access to a file turned into a [`HostError`] naming it; keys read card
//! by card where `fitsio` would panic on legal FITS it does not expect.

use super::direct::BigEndianFloat;
use super::*;

/// What an image HDU's header says about its data.
pub(super) struct ImageHeader {
    /// HDU number, 0 = primary.
    hdu: usize,
    /// How messages name the HDU.
    label: String,
    bitpix: i64,
    /// NAXIS1 (fastest, columns) first.
    pub(super) naxes: Vec<usize>,
    bzero: f64,
    bscale: f64,
    elements: usize,
}

/// Integer pixel values as cfitsio delivers them after BZERO.
pub(super) enum IntegerPixels {
    Signed(Vec<i64>),
    /// BITPIX 64 with BZERO 2^63: the only integer data that does not fit `i64`.
    Unsigned(Vec<u64>),
}

impl IntegerPixels {
    /// Every value as `T`, or the flat index and value of the first that does not fit.
    pub(super) fn convert<T: TryFrom<i128>>(self) -> Result<Vec<T>, (usize, i128)> {
        fn all<T: TryFrom<i128>>(values: impl Iterator<Item = i128>) -> Result<Vec<T>, (usize, i128)> {
            values.enumerate().map(|(i, v)| T::try_from(v).map_err(|_| (i, v))).collect()
        }
        match self {
            IntegerPixels::Signed(v) => all(v.into_iter().map(i128::from)),
            IntegerPixels::Unsigned(v) => all(v.into_iter().map(i128::from)),
        }
    }
}

/// Why a key could not be read.
pub(super) enum KeyError {
    Fits(FitsioError),
    /// A string key whose value is not a quoted string: the card, trimmed.
    NotString(String),
}

/// A key value the readers read: numbers and logicals through fitsio, strings from the
/// card itself ([`string_from_card`]).
pub(super) trait KeyValue: Sized {
    /// Key `name` of HDU `hdu` (0-based), `None` when absent.
    fn read(file: &mut FitsFile, hdu: usize, name: &str) -> Result<Option<Self>, KeyError>;
}

macro_rules! key_through_fitsio {
    ($($t:ty),*) => {$(
        impl KeyValue for $t {
            fn read(file: &mut FitsFile, hdu: usize, name: &str) -> Result<Option<Self>, KeyError> {
                // A hand-made handle: `FitsFile::hdu` would describe the HDU first, which
                // panics inside fitsio on some legal HDUs (see the module documentation).
                let handle = FitsHdu { info: HduInfo::AnyInfo, number: hdu };
                match handle.read_key::<$t>(file, name) {
                    Ok(v) => Ok(Some(v)),
                    Err(FitsioError::Fits(e)) if e.status == KEY_NO_EXIST => Ok(None),
                    Err(e) => Err(KeyError::Fits(e)),
                }
            }
        }
    )*};
}
key_through_fitsio!(f64, bool);

impl KeyValue for String {
    /// The card is read whole (`ffgcrd`, into cfitsio's 81-byte card size) and its quoted
    /// value parsed here. fitsio reads a string key into a 71-byte buffer, and cfitsio
    /// copies an unquoted value of up to 71 characters (a card with no space after `=`)
    /// into it with its terminating NUL: a heap overflow by one byte, found by the
    /// `fits_lut` fuzz target under AddressSanitizer (`EXTNAME =YYYY...` over the whole card).
    fn read(file: &mut FitsFile, hdu: usize, name: &str) -> Result<Option<Self>, KeyError> {
        let fits_error = |status| KeyError::Fits(fitsio::errors::check_status(status).err().unwrap_or(FitsioError::Message("unknown cfitsio error".into())));
        let Ok(key) = std::ffi::CString::new(name) else { return Ok(None) };
        let mut card = [0 as std::ffi::c_char; 81];
        let mut status = 0;
        // SAFETY: `file` is open and `hdu` one of its HDUs (or cfitsio sets a status);
        // `key` is NUL-terminated; `card` holds FLEN_CARD (81) bytes, the most ffgcrd writes.
        unsafe {
            let raw = file.as_raw();
            fitsio::sys::ffmahd(raw, hdu as i32 + 1, std::ptr::null_mut(), &mut status);
            fitsio::sys::ffgcrd(raw, key.as_ptr(), card.as_mut_ptr(), &mut status);
        }
        match status {
            0 => {}
            KEY_NO_EXIST => return Ok(None),
            _ => return Err(fits_error(status)),
        }
        let bytes: Vec<u8> = card.iter().take_while(|&&c| c != 0).map(|&c| c as u8).collect();
        string_from_card(&bytes).map(Some).ok_or_else(|| KeyError::NotString(printable(&bytes)))
    }
}

/// The value of a string card (`KEY     = 'value'  / comment`): the characters between
/// the quotes with `''` read as one quote, trailing spaces dropped (they are not
/// significant in FITS), `None` if the value is not a quoted string.
pub(super) fn string_from_card(card: &[u8]) -> Option<String> {
    let value = card.get(8..)?.strip_prefix(b"=")?;
    let start = value.iter().position(|&b| b != b' ')?;
    let mut bytes = value[start..].strip_prefix(b"'")?.iter().peekable();
    // Bytes up to the closing quote only: the comment after it may hold anything.
    let mut out = Vec::new();
    loop {
        match *bytes.next()? {
            b'\'' if bytes.peek() == Some(&&b'\'') => {
                bytes.next();
                out.push(b'\'');
            }
            b'\'' => return Some(String::from_utf8_lossy(&out).trim_end().to_string()),
            b => out.push(b),
        }
    }
}

/// A card as a message shows it: bytes outside printable ASCII (a newline would break the
/// one-line error, NULs fill a block cut short) as `?`, trailing spaces dropped.
pub(super) fn printable(card: &[u8]) -> String {
    card.iter().map(|&b| if (0x20..0x7f).contains(&b) { b as char } else { '?' }).collect::<String>().trim_end().to_string()
}

/// A FITS file open for reading, with every access turned into a [`HostError`] naming it.
pub(super) struct FitsReader<'a> {
    file: FitsFile,
    /// Kept while cfitsio has the file open.
    _name: CfitsioName,
    path: &'a Path,
    /// Most data bytes the file can hold: no header may make us allocate more. The file
    /// size; for a gzip file the size it inflates to (counted at open); for a compress-
    /// or zip-compressed file (cfitsio opens those too) the size times 1100, above
    /// deflate's largest ratio of 1032.
    len: u64,
    /// The size a gzip file inflates to, where it is one.
    inflated: Option<u64>,
    /// Bytes cfitsio holds of the file itself: a compressed file inflated into memory at
    /// open (a gzip file's counted size, a zip file's declared size; 0 where a compress-
    /// or pack-compressed file declares none), 0 for a plain file (read through cfitsio's
    /// buffers of a few KiB).
    resident: u64,
    /// The file itself, where it is not compressed: large float images are read from it
    /// directly ([`super::direct`]).
    raw: Option<std::fs::File>,
    /// Large float images whose checksums are verified as their data are read
    /// ([`FitsReader::float_pixels`]) or at [`FitsReader::finish`], not at open.
    pub(super) deferred: Vec<Deferred>,
}

/// Bytes per value of a float image whose stored values are its values (IEEE floats,
/// unscaled), which [`super::direct`] reads; `None` for any other image.
fn stored_width(image: &ImageHeader) -> Option<usize> {
    let bytes = match image.bitpix {
        -32 => 4,
        -64 => 8,
        _ => return None,
    };
    (image.bscale == 1.0 && image.bzero == 0.0).then_some(bytes)
}

/// Whether a file starting with `start` is compressed, by the magic numbers cfitsio
/// recognizes (gzip, compress, pack, LZH, zip).
pub(crate) fn compressed_magic(start: &[u8]) -> bool {
    matches!(start.get(..2), Some([0x1f, 0x8b | 0x9d | 0x1e | 0xa0] | [b'P', b'K']))
}

/// Whether the file at `path` is compressed (a file cfitsio inflates into memory at open).
pub(super) fn is_compressed(path: &Path) -> Result<bool, HostError> {
    let mut start = [0u8; 2];
    let mut file = crate::formats::input::open_regular(path)?;
    Ok(std::io::Read::read_exact(&mut file, &mut start).is_ok() && compressed_magic(&start))
}

/// A float image's values in an uncompressed file: `bytes` (4 or 8) each, big-endian,
/// unscaled, from `offset`; the file opened once more (its own handle).
#[derive(Debug)]
pub(super) struct StoredFloats {
    pub(super) file: std::fs::File,
    pub(super) offset: u64,
    pub(super) bytes: usize,
}

impl StoredFloats {
    /// Values `first..first + out.len()` of the image, converted to `T` as cfitsio
    /// converts (`bytes`: a buffer the caller reuses).
    pub(super) fn read<T: BigEndianFloat>(&self, first: usize, out: &mut [T], bytes: &mut Vec<u8>) -> std::io::Result<()> {
        let at = self.offset + (first * self.bytes) as u64;
        match self.bytes {
            4 => super::direct::read_into::<f32, T>(&self.file, at, out, T::from_f32, bytes),
            _ => super::direct::read_into::<f64, T>(&self.file, at, out, T::from_f64, bytes),
        }
    }
}

/// A data unit of at least [`DEFER_BYTES`] whose checksum verification waits for its
/// data to be read (one pass instead of two).
pub(super) struct Deferred {
    /// HDU number, 0 = primary.
    pub(super) hdu: usize,
    /// Byte offsets of its data unit (padding included) in the file.
    data: (u64, u64),
    /// The ones' complement sum of its header blocks.
    header_sum: u32,
    /// `DATASUM`'s value; `CHECKSUM` is present too, and agrees with the header and
    /// this value.
    datasum: u32,
}

/// Data units this large are verified as they are read, where the caller asks.
const DEFER_BYTES: u64 = 16 << 20;

impl<'a> FitsReader<'a> {
    pub(super) fn open(path: &'a Path) -> Result<Self, HostError> {
        Self::open_with(path, None)
    }

    /// [`FitsReader::open`]; with `defer`, the checksums of large float images in an
    /// uncompressed file are verified as [`FitsReader::float_pixels`] reads them, and the
    /// caller calls [`FitsReader::finish`] to verify any it did not read.
    pub(super) fn open_deferring(path: &'a Path) -> Result<Self, HostError> {
        Self::open_with(path, Some(DEFER_BYTES))
    }

    /// Bytes cfitsio holds of the file itself while it is open (a compressed file's
    /// inflated size; 0 for a plain file): a part of what a command reading it needs.
    pub(super) fn resident(&self) -> u64 {
        self.resident
    }

    /// Opens `path`; with `defer`, float images of at least that many data bytes are
    /// verified as they are read ([`FitsReader::open_deferring`]).
    pub(super) fn open_with(path: &'a Path, defer: Option<u64>) -> Result<Self, HostError> {
        // A device or FIFO never reaches cfitsio, which would read or wait for ever.
        let mut plain_file = crate::formats::input::open_regular(path)?;
        let size = plain_file.metadata().map_err(|e| HostError::io(path, e))?.len();
        let mut start = [0u8; 9];
        // Compressed by the magic numbers cfitsio recognizes (gzip, compress, pack, LZH,
        // zip); anything else is read as it is. (Deciding "plain" by an exact `SIMPLE  =`
        // let a file with `SIMPLE   =`, which cfitsio reads, skip the table check: found by
        // `fits_linearity`.)
        let read = std::io::Read::read_exact(&mut plain_file, &mut start).is_ok();
        let compressed = read && compressed_magic(&start);
        let plain = !compressed;
        let mut len = if plain { size } else { size.saturating_mul(1100) };
        // (`Some` exactly for a gzip file: inflated, counted, its true size.)
        let mut inflated = None;
        let mut resident = 0;
        if let Some(declared) = declared_uncompressed_size(&mut plain_file, size).map_err(|e| HostError::io(path, e))? {
            resident = declared;
            if declared > len {
                return Err(format_error(path, format!(
                    "a compressed file of {size} bytes whose header declares {declared} bytes uncompressed, more than it can hold; cfitsio would allocate them at once"
                )));
            }
            crate::infra::budget::check(path, "decompressing it (the size its header declares)", declared)?;
            if start[..2] == [0x1f, 0x8b] {
                // Counted in chunks into nothing, never held: the size the headers'
                // declarations are then held to (issue 43: a 1.2 MB file declaring 9.6 GB
                // of counts was allocated from that declaration).
                let n = check_gzip_inflates_within(&mut plain_file, path, len.min(crate::infra::budget::limit()))?;
                (len, inflated, resident) = (n, Some(n), n);
            }
        }
        if plain {
            if let Some((at, card)) = malformed_table(&mut plain_file, size).map_err(|e| HostError::io(path, e))? {
                return Err(format_error(path, format!(
                    "the table header at byte {at} has \"{card}\"; a table header opens with BITPIX, NAXIS, NAXIS1, NAXIS2, PCOUNT, GCOUNT and TFIELDS (0 to 999), integers in range (cfitsio would take it for valid)"
                )));
            }
        }
        let name = CfitsioName::for_reading(path)?;
        let file = FitsFile::open(&name.name).map_err(|e| fits_error(path, "not a readable FITS file", &e))?;
        let raw = plain.then_some(plain_file);
        let resident = if plain { 0 } else { resident };
        let mut reader = FitsReader { file, _name: name, path, len, inflated, resident, raw, deferred: Vec::new() };
        reader.check_declared_sizes(plain)?;
        reader.verify_checksums(defer)?;
        Ok(reader)
    }

    /// Refuses an HDU whose `CHECKSUM` or `DATASUM` (where present: files of other tools
    /// often have none) does not match its bytes: the file changed after it was written.
    fn verify_checksums(&mut self, defer: Option<u64>) -> Result<(), HostError> {
        let (mut status, mut count) = (0, 0);
        // SAFETY: `self.file` is open; ffthdu counts its HDUs.
        unsafe { fitsio::sys::ffthdu(self.file.as_raw(), &mut count, &mut status) };
        for hdu in 1..=count {
            // cfitsio's ffvcks reads both keys into 71-byte buffers that an unquoted value
            // filling the card overruns (see `String::read`): each must be absent or a
            // quoted string, read safely first.
            let label = if hdu == 1 { PRIMARY.to_string() } else { format!("HDU {}", hdu - 1) };
            let mut keys = [None, None];
            for (k, key) in keys.iter_mut().zip(["CHECKSUM", "DATASUM"]) {
                *k = self.key::<String>(hdu as usize - 1, &label, key)?;
            }
            if let Some(min) = defer {
                if let Some(d) = self.deferrable(hdu as usize - 1, &label, &keys, min)? {
                    self.deferred.push(d);
                    continue;
                }
            }
            let (mut data_ok, mut hdu_ok) = (0, 0);
            // SAFETY: as above; ffvcks reads the current HDU and writes the two flags
            // (1 verified, 0 no key, -1 wrong).
            unsafe {
                let raw = self.file.as_raw();
                fitsio::sys::ffmahd(raw, hdu, std::ptr::null_mut(), &mut status);
                fitsio::sys::ffvcks(raw, &mut data_ok, &mut hdu_ok, &mut status);
            }
            fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, &format!("verifying the checksums of HDU {}", hdu - 1), &e))?;
            if data_ok < 0 || hdu_ok < 0 {
                return Err(self.checksum_failure(hdu as usize - 1, data_ok < 0));
            }
        }
        Ok(())
    }

    /// The HDU `hdu` as a [`Deferred`] where its verification can wait for its data: an
    /// uncompressed file, an image (primary or IMAGE extension) of floats, a data unit of
    /// at least `min` bytes, both checksum keys, a header that agrees with them. `keys`:
    /// its `CHECKSUM` and `DATASUM`, read safely.
    fn deferrable(&mut self, hdu: usize, label: &str, keys: &[Option<String>; 2], min: u64) -> Result<Option<Deferred>, HostError> {
        if self.raw.is_none() {
            return Ok(None);
        }
        let (head, start, end) = self.offsets(hdu)?;
        if end.saturating_sub(start) < min.max(1) {
            return Ok(None);
        }
        // A header this cannot read is left to cfitsio's verification (and to the errors
        // of whatever reads it next).
        let image = hdu == 0 || self.key::<String>(hdu, label, "XTENSION").ok().flatten().is_some_and(|x| x.trim() == "IMAGE");
        if !image || !matches!(self.required_int(hdu, label, "BITPIX").ok(), Some(-32 | -64)) {
            return Ok(None);
        }
        // Both keys, DATASUM a plain 32-bit sum (anything else, and a file without keys,
        // which ffvcks passes without reading, is left to ffvcks).
        let given = |v: &Option<String>| v.as_deref().map(str::trim).filter(|v| !v.is_empty()).map(str::to_string);
        let (Some(_), Some(datasum)) = (given(&keys[0]), given(&keys[1]).and_then(|v| v.parse::<u32>().ok())) else {
            return Ok(None);
        };
        let Some(raw) = &self.raw else { return Ok(None) };
        let header_sum = super::direct::checksum_at(raw, head, start - head).map_err(|e| HostError::io(self.path, e))?;
        // The header must agree with CHECKSUM given the data sum DATASUM states: a header
        // changed since (or read with another layout than it was written with, as a
        // damaged END card makes cfitsio do) is judged now, by ffvcks, so its error is
        // the checksum's and comes before anything that reads the header.
        if !super::direct::is_zero(super::direct::add(header_sum, datasum)) {
            return Ok(None);
        }
        Ok(Some(Deferred { hdu, data: (start, end), header_sum, datasum }))
    }

    /// Byte offsets of HDU `hdu` in the file: its header, its data unit, its end.
    fn offsets(&mut self, hdu: usize) -> Result<(u64, u64, u64), HostError> {
        let (mut status, mut head, mut start, mut end) = (0, 0, 0, 0);
        // SAFETY: `self.file` is open and `hdu` below its HDU count; ffghadll writes the
        // three offsets.
        unsafe {
            let f = self.file.as_raw();
            fitsio::sys::ffmahd(f, hdu as i32 + 1, std::ptr::null_mut(), &mut status);
            fitsio::sys::ffghadll(f, &mut head, &mut start, &mut end, &mut status);
        }
        fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, &format!("reading the header of HDU {hdu}"), &e))?;
        Ok((head as u64, start as u64, end as u64))
    }

    /// The verdict on a deferred HDU whose data unit sums to `data_sum`, as ffvcks gives
    /// it: DATASUM equal to the sum, the header and data summing to zero (either sign).
    fn check_deferred(&self, d: &Deferred, data_sum: u32) -> Result<(), HostError> {
        let data_ok = d.datasum == data_sum;
        if data_ok && super::direct::is_zero(super::direct::add(d.header_sum, data_sum)) {
            return Ok(());
        }
        Err(self.checksum_failure(d.hdu, !data_ok))
    }

    /// The verdict on a deferred HDU whose values, up to `values_end` in `file`, summed to
    /// `sum` as they were read: the unit's padding after them added, as ffvcks sums it.
    fn check_read(&self, d: &Deferred, file: &std::fs::File, values_end: u64, sum: u32) -> Result<(), HostError> {
        let padding = super::direct::checksum_at(file, values_end, d.data.1 - values_end).map_err(|e| HostError::io(self.path, e))?;
        self.check_deferred(d, super::direct::add(sum, padding))
    }

    /// HDU `hdu` (0 = primary) fails its checksum: its data (`data`) or else its header.
    fn checksum_failure(&self, hdu: usize, data: bool) -> HostError {
        let label = if hdu == 0 { PRIMARY.to_string() } else { format!("HDU {hdu}") };
        let which = if data { "its data do not match DATASUM" } else { "its header and data do not match CHECKSUM" };
        self.error(format!(
            "the {label} fails its checksum: {which} (the file was changed or damaged after it was written; a tool that edited it kept the old keys: have it write new ones, astropy's writeto(..., checksum=True), or delete CHECKSUM and DATASUM)"
        ))
    }

    /// Verifies the deferred HDU `hdu`, if it is one, by reading its data unit (for a
    /// caller that reads its data otherwise, or not at all).
    pub(super) fn verify_deferred(&mut self, hdu: usize) -> Result<(), HostError> {
        let Some(i) = self.deferred.iter().position(|d| d.hdu == hdu) else { return Ok(()) };
        let d = self.deferred.remove(i);
        // (Only an uncompressed file, which `raw` is, defers.)
        let Some(raw) = &self.raw else { return Err(self.error("a deferred checksum without the file to read it from")) };
        let sum = super::direct::checksum_at(raw, d.data.0, d.data.1 - d.data.0).map_err(|e| HostError::io(self.path, e))?;
        self.check_deferred(&d, sum)
    }

    /// Verifies every deferred HDU not yet read: a reader opened with
    /// [`FitsReader::open_deferring`] ends with this (on its way to `Ok`: an error
    /// returned before it refuses the file anyway).
    pub(super) fn finish(mut self) -> Result<(), HostError> {
        while let Some(hdu) = self.deferred.first().map(|d| d.hdu) {
            self.verify_deferred(hdu)?;
        }
        Ok(())
    }

    /// Refuses a file whose HDUs declare more bytes than it has: each HDU's header, data
    /// and heap (`PCOUNT`), in 2880-byte blocks, as cfitsio lays them out. cfitsio itself
    /// checks only what is read, so a binary table declaring a 2 GB heap would pass.
    fn check_declared_sizes(&mut self, plain: bool) -> Result<(), HostError> {
        let count = self.file.num_hdus().map_err(|e| fits_error(self.path, "counting HDUs", &e))?;
        for hdu in 0..count {
            let (mut status, mut end) = (0, 0);
            // SAFETY: `self.file` is open and `hdu` below its HDU count; cfitsio skips the
            // null outputs (HDU type, header and data start) and writes only `end`.
            unsafe {
                let raw = self.file.as_raw();
                fitsio::sys::ffmahd(raw, hdu as i32 + 1, std::ptr::null_mut(), &mut status);
                fitsio::sys::ffghadll(raw, std::ptr::null_mut(), std::ptr::null_mut(), &mut end, &mut status);
            }
            fitsio::errors::check_status(status)
                .map_err(|e| fits_error(self.path, &format!("reading the header of HDU {hdu}"), &e))?;
            if end as u64 > self.len {
                let label = match (hdu, self.key::<String>(hdu, "HDU", "EXTNAME")?) {
                    (0, _) => PRIMARY.to_string(),
                    (_, Some(name)) => format!("HDU {hdu} ({})", name.trim()),
                    (_, None) => format!("HDU {hdu}"),
                };
                let has = match (plain, self.inflated) {
                    (true, _) => format!("the file has {} bytes", self.len),
                    (false, Some(n)) => format!("the file inflates to {n} bytes"),
                    (false, None) => "more than the compressed file can hold".into(),
                };
                return Err(self.error(format!(
                    "the {label} declares its header, data and heap (PCOUNT) to end at byte {end}; {has} (truncated?)"
                )));
            }
        }
        Ok(())
    }

    /// The file read.
    pub(super) fn path(&self) -> &'a Path {
        self.path
    }

    pub(super) fn error(&self, message: impl Into<String>) -> HostError {
        format_error(self.path, message)
    }

    /// A fault of the file read.
    pub(super) fn fault(&self, source: Fault) -> HostError {
        fault(self.path)(source)
    }

    /// Key `name` of HDU `hdu`, `None` when absent.
    pub(super) fn key<T: KeyValue>(&mut self, hdu: usize, label: &str, name: &str) -> Result<Option<T>, HostError> {
        match T::read(&mut self.file, hdu, name) {
            Ok(v) => Ok(v),
            Err(KeyError::Fits(e)) => Err(fits_error(self.path, &format!("key {name} of the {label}"), &e)),
            Err(KeyError::NotString(card)) => Err(self.error(format!("key {name} of the {label} is not a quoted string: \"{card}\""))),
        }
    }

    fn required<T: KeyValue>(&mut self, hdu: usize, label: &str, name: &str) -> Result<T, HostError> {
        self.key(hdu, label, name)?.ok_or_else(|| self.error(format!("missing key {name} in the {label}")))
    }

    /// An integer-valued key (read as a float so that `4.5` is an error, not 4).
    pub(super) fn int_key(&mut self, hdu: usize, label: &str, name: &str) -> Result<Option<i64>, HostError> {
        match self.key::<f64>(hdu, label, name)? {
            None => Ok(None),
            Some(v) if v.fract() == 0.0 && v.abs() <= 9.007_199_254_740_992e15 => Ok(Some(v as i64)),
            Some(v) => Err(self.error(format!("key {name} of the {label} is {v}, not an integer"))),
        }
    }

    pub(super) fn required_int(&mut self, hdu: usize, label: &str, name: &str) -> Result<i64, HostError> {
        self.int_key(hdu, label, name)?.ok_or_else(|| self.error(format!("missing key {name} in the {label}")))
    }

    /// The kind of dncal file the primary HDU announces by the keys its writer puts there
    /// (`FRACBITS`: a LUT; `NFRAMES`: a linearity set; `BITDEPTH` on a 2-D image without
    /// either: a histogram set), `None` for anything else.
    fn kind(&mut self) -> Result<Option<FileKind>, HostError> {
        if self.key::<f64>(0, PRIMARY, "FRACBITS")?.is_some() {
            return Ok(Some(FileKind::Lut));
        }
        if self.key::<f64>(0, PRIMARY, "NFRAMES")?.is_some() {
            return Ok(Some(FileKind::Linearity));
        }
        let two_d = self.key::<f64>(0, PRIMARY, "NAXIS")? == Some(2.0);
        Ok((two_d && self.key::<f64>(0, PRIMARY, "BITDEPTH")?.is_some()).then_some(FileKind::Histograms))
    }

    /// Refuses a dncal file of another kind than `want`, naming what it is and which
    /// command reads it (rather than the first key it lacks).
    /// Whether the file is of kind `kind` by its keys.
    pub(super) fn is_kind(&mut self, kind: FileKind) -> bool {
        self.kind().ok().flatten() == Some(kind)
    }

    pub(super) fn expect_kind(&mut self, want: FileKind) -> Result<(), HostError> {
        match self.kind()? {
            Some(found) if found != want => Err(self.error(format!("this is {}, not {}", found.describe(), want.name()))),
            _ => Ok(()),
        }
    }

    /// `BITDEPTH`, `NADC` and `ADCMAP` of the primary HDU: (bits, ADCs, codes).
    pub(super) fn adc_keys(&mut self) -> Result<(u32, usize, usize), HostError> {
        let bits = self.required_int(0, PRIMARY, "BITDEPTH")?;
        let bit_depth = u32::try_from(bits).unwrap_or(0);
        let codes =
            codes_for(bit_depth).map_err(|_| self.error(format!("BITDEPTH = {bits}, must be 1 to {MAX_BIT_DEPTH}")))?;
        let n = self.required_int(0, PRIMARY, "NADC")?;
        let n_adc = usize::try_from(n)
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| self.error(format!("NADC = {n}, must be at least 1")))?;
        let map: String = self.required(0, PRIMARY, "ADCMAP")?;
        if map.trim() != ADCMAP_COLMOD {
            return Err(self.error(format!(
                "ADCMAP = '{map}'; only '{ADCMAP_COLMOD}' (column c read by ADC c mod NADC) is defined"
            )));
        }
        Ok((bit_depth, n_adc, codes))
    }

    /// The first extension named `name` (case-insensitive), if any.
    pub(super) fn extension(&mut self, name: &str) -> Result<Option<usize>, HostError> {
        let count = self.file.num_hdus().map_err(|e| fits_error(self.path, "counting HDUs", &e))?;
        for hdu in 1..count {
            let label = format!("HDU {hdu}");
            if let Some(extname) = self.key::<String>(hdu, &label, "EXTNAME")? {
                if extname.trim().eq_ignore_ascii_case(name) {
                    return Ok(Some(hdu));
                }
            }
        }
        Ok(None)
    }

    pub(super) fn require_extension(&mut self, name: &str, holding: &str) -> Result<usize, HostError> {
        match self.extension(name)? {
            Some(hdu) => Ok(hdu),
            None => {
                let count = self.file.num_hdus().unwrap_or(0);
                Err(self.error(format!("missing extension {name} ({holding}); the file has {count} HDUs")))
            }
        }
    }

    /// The header of image HDU `hdu`, which must have `naxis` axes.
    pub(super) fn image(&mut self, hdu: usize, label: &str, naxis: usize) -> Result<ImageHeader, HostError> {
        if hdu > 0 {
            let xtension: String = self.required(hdu, label, "XTENSION")?;
            if xtension.trim() != "IMAGE" {
                let hint = match self.key::<bool>(hdu, label, "ZIMAGE") {
                    Ok(Some(true)) => " (a tile-compressed image: write it uncompressed)",
                    _ => "",
                };
                return Err(self.error(format!("the {label} is a {} extension, not an image{hint}", xtension.trim())));
            }
        }
        let bitpix = self.required_int(hdu, label, "BITPIX")?;
        if ![8, 16, 32, 64, -32, -64].contains(&bitpix) {
            return Err(self.error(format!("the {label} has BITPIX = {bitpix}, not a FITS data type")));
        }
        let found = self.required_int(hdu, label, "NAXIS")?;
        if found != naxis as i64 {
            return Err(self.error(format!("the {label} has NAXIS = {found}, expected {naxis} axes")));
        }
        let mut naxes = Vec::with_capacity(naxis);
        for axis in 1..=naxis {
            let key = format!("NAXIS{axis}");
            let n = self.required_int(hdu, label, &key)?;
            naxes.push(usize::try_from(n).map_err(|_| self.error(format!("{key} = {n} in the {label}")))?);
        }
        // An image has no group parameters: with PCOUNT = 2 on an IMAGE extension cfitsio
        // read its pixels two values late (the direct read did not), found by the
        // `fits_linearity` target's comparison of the two readers.
        let (pcount, gcount) = (self.int_key(hdu, label, "PCOUNT")?.unwrap_or(0), self.int_key(hdu, label, "GCOUNT")?.unwrap_or(1));
        if (pcount, gcount) != (0, 1) {
            return Err(self.error(format!("the {label} has PCOUNT = {pcount} and GCOUNT = {gcount}; an image has 0 and 1 (random groups are not read)")));
        }
        let bzero = self.key::<f64>(hdu, label, "BZERO")?.unwrap_or(0.0);
        let bscale = self.key::<f64>(hdu, label, "BSCALE")?.unwrap_or(1.0);
        let elements = naxes.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
        let bytes = elements.and_then(|n| n.checked_mul(bitpix.unsigned_abs() as usize / 8));
        match (elements, bytes) {
            (Some(elements), Some(bytes)) if bytes as u64 <= self.len => {
                Ok(ImageHeader { hdu, label: label.into(), bitpix, naxes, bzero, bscale, elements })
            }
            _ => Err(self.error(format!(
                "the {label} declares {} pixels of BITPIX {bitpix}, more than the file can hold (truncated?)",
                shape_text(&naxes)
            ))),
        }
    }

    /// Checks a per-ADC table image: NAXIS1 = codes, NAXIS2 = ADCs.
    pub(super) fn check_adc_image_shape(
        &self,
        image: &ImageHeader,
        codes: usize,
        n_adc: usize,
        bits: u32,
    ) -> Result<(), HostError> {
        if image.naxes[0] != codes {
            return Err(self.error(format!(
                "the {} has NAXIS1 = {} codes, BITDEPTH = {bits} needs 2^{bits} = {codes}",
                image.label, image.naxes[0]
            )));
        }
        if image.naxes[1] != n_adc {
            return Err(self.error(format!("the {} has NAXIS2 = {} rows, NADC = {n_adc}", image.label, image.naxes[1])));
        }
        Ok(())
    }

    /// All pixels of an image as `T` (cfitsio converts), if they fit the memory budget.
    pub(super) fn pixels<T>(&mut self, image: &ImageHeader) -> Result<Vec<T>, HostError>
    where
        Vec<T>: ReadImage,
    {
        let what = format!("the {} ({} pixels as {}-byte values)", image.label, shape_text(&image.naxes), std::mem::size_of::<T>());
        crate::infra::budget::check(self.path, &what, crate::infra::budget::bytes_of(image.elements as u64, std::mem::size_of::<T>() as u64))?;
        let shape = image.naxes.iter().rev().copied().collect();
        let handle = FitsHdu { info: HduInfo::ImageInfo { shape, image_type: ImageType::Double }, number: image.hdu };
        handle
            .read_section(&mut self.file, 0, image.elements)
            .map_err(|e| fits_error(self.path, &format!("reading the data of the {}", image.label), &e))
    }

    /// [`FitsReader::pixels`] of a float image: a deferred one (unscaled floats) read
    /// directly, converted to `T` as cfitsio converts, and verified in the same pass
    /// ([`super::direct`]); any other through cfitsio, a deferred one verified first.
    pub(super) fn float_pixels<T: BigEndianFloat>(&mut self, image: &ImageHeader) -> Result<Vec<T>, HostError>
    where
        Vec<T>: ReadImage,
    {
        let i = self.deferred.iter().position(|d| d.hdu == image.hdu);
        let (Some(i), Some(raw), Some(stored)) = (i, &self.raw, stored_width(image)) else {
            self.verify_deferred(image.hdu)?;
            return self.pixels(image);
        };
        let what = format!("the {} ({} pixels as {}-byte values)", image.label, shape_text(&image.naxes), T::SIZE);
        crate::infra::budget::check(self.path, &what, crate::infra::budget::bytes_of(image.elements as u64, T::SIZE as u64))?;
        let d = self.deferred.remove(i);
        let io = |e| HostError::io(self.path, e);
        let values_end = d.data.0 + (image.elements * stored) as u64;
        if values_end > d.data.1 {
            return Err(self.error(format!("the {} declares more data than its unit holds", image.label)));
        }
        let (values, sum) = match stored {
            4 => super::direct::read_values::<f32, T>(raw, d.data.0, image.elements, T::from_f32),
            _ => super::direct::read_values::<f64, T>(raw, d.data.0, image.elements, T::from_f64),
        }
        .map_err(io)?;
        self.check_read(&d, raw, values_end, sum)?;
        Ok(values)
    }

    /// Where a float image's values can be read directly, as [`super::direct`] reads
    /// them: an uncompressed file, unscaled IEEE floats, all of them inside their data
    /// unit and the file. `None` for any other image: one whose values the file or its
    /// unit cuts short is left to cfitsio, whose error names the HDU (both found by the
    /// `fits_linearity` target's comparison of the two readers).
    pub(super) fn stored_floats(&mut self, image: &ImageHeader) -> Result<Option<StoredFloats>, HostError> {
        let (Some(bytes), Some(raw)) = (stored_width(image), &self.raw) else { return Ok(None) };
        let file = raw.try_clone().map_err(|e| HostError::io(self.path, e))?;
        let (_, start, end) = self.offsets(image.hdu)?;
        let values_end = start + (image.elements * bytes) as u64;
        if values_end > end || values_end > self.len {
            return Ok(None);
        }
        Ok(Some(StoredFloats { file, offset: start, bytes }))
    }

    /// One pass over a float image read directly ([`FitsReader::stored_floats`]), holding
    /// none of it: its values converted to `T`, the first that each of `bad` flags, and
    /// its checksum verified where it was deferred (else cfitsio verified it at open).
    pub(super) fn scan_floats<T: BigEndianFloat>(&mut self, image: &ImageHeader, at: &StoredFloats, bad: [&(dyn Fn(T) -> bool + Sync); 2]) -> Result<super::direct::Flagged<T>, HostError> {
        let io = |e| HostError::io(self.path, e);
        let (flagged, sum) = match at.bytes {
            4 => super::direct::scan_values::<f32, T>(&at.file, at.offset, image.elements, T::from_f32, bad),
            _ => super::direct::scan_values::<f64, T>(&at.file, at.offset, image.elements, T::from_f64, bad),
        }
        .map_err(io)?;
        if let Some(i) = self.deferred.iter().position(|d| d.hdu == image.hdu) {
            let d = self.deferred.remove(i);
            self.check_read(&d, &at.file, at.offset + (image.elements * at.bytes) as u64, sum)?;
        }
        Ok(flagged)
    }

    /// All pixels of an integer image, physical values (BZERO applied).
    pub(super) fn integer_pixels(&mut self, image: &ImageHeader, what: &str) -> Result<IntegerPixels, HostError> {
        if image.bitpix < 0 {
            return Err(self.error(format!(
                "the {} is a floating-point image (BITPIX = {}); {what} must be integers",
                image.label, image.bitpix
            )));
        }
        if image.bscale != 1.0 || image.bzero.fract() != 0.0 {
            return Err(self.error(format!(
                "the {} is scaled (BSCALE = {}, BZERO = {}); {what} must be unscaled integers",
                image.label, image.bscale, image.bzero
            )));
        }
        if image.bitpix == 64 && image.bzero == 9_223_372_036_854_775_808.0 {
            Ok(IntegerPixels::Unsigned(self.pixels(image)?))
        } else {
            Ok(IntegerPixels::Signed(self.pixels(image)?))
        }
    }

    /// Scalar numeric column `column` (case-insensitive) of binary table `hdu`.
    pub(super) fn column_f64(&mut self, hdu: usize, label: &str, column: &str) -> Result<Vec<f64>, HostError> {
        let xtension: String = self.required(hdu, label, "XTENSION")?;
        if xtension.trim() != "BINTABLE" {
            return Err(self.error(format!("the {label} is a {} extension, not a binary table", xtension.trim())));
        }
        let row_bytes = self.required_int(hdu, label, "NAXIS1")?;
        let rows = self.required_int(hdu, label, "NAXIS2")?;
        if row_bytes.checked_mul(rows).is_none_or(|b| b < 0 || b as u64 > self.len) {
            return Err(
                self.error(format!("the {label} declares {rows} rows of {row_bytes} bytes, more than the file holds"))
            );
        }
        let fields = self.required_int(hdu, label, "TFIELDS")?;
        let mut found = None;
        for n in 1..=fields {
            let tform: String = self.required(hdu, label, &format!("TFORM{n}"))?;
            let (repeat, letter) = split_tform(&tform);
            // fitsio describes every column when reading any, and panics on the types it
            // cannot describe: variable-length (P, Q) and complex (C, M) columns.
            if !matches!(letter, Some('L' | 'X' | 'B' | 'I' | 'J' | 'K' | 'E' | 'D' | 'A')) {
                return Err(self.error(format!(
                    "column {n} of the {label} has TFORM{n} = '{tform}'; variable-length and complex columns are not supported"
                )));
            }
            let name: Option<String> = self.key(hdu, label, &format!("TTYPE{n}"))?;
            if let Some(name) = name.filter(|t| t.trim().eq_ignore_ascii_case(column)) {
                found = Some((name, tform.clone(), repeat, letter));
            }
        }
        let (name, tform, repeat, letter) =
            found.ok_or_else(|| self.error(format!("the {label} has no column {column}")))?;
        if repeat != Some(1) || !matches!(letter, Some('B' | 'I' | 'J' | 'K' | 'E' | 'D')) {
            return Err(self.error(format!(
                "column {column} of the {label} has TFORM '{tform}'; it must hold one number per row (e.g. 'D')"
            )));
        }
        // fitsio panics where cfitsio takes the HDU for another kind than its XTENSION
        // key says (a header damaged past what the key reader sees; found by
        // `fits_linearity`): cfitsio's own verdict first.
        let (mut status, mut kind) = (0, 0);
        // SAFETY: `self.file` is open and `hdu` below its HDU count; ffmahd writes the
        // HDU's type.
        unsafe { fitsio::sys::ffmahd(self.file.as_raw(), hdu as i32 + 1, &mut kind, &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, &format!("reading the header of the {label}"), &e))?;
        if kind != fitsio::sys::BINARY_TBL as i32 {
            return Err(self.error(format!("the {label} says XTENSION = 'BINTABLE' but its header does not read as a binary table (damaged)")));
        }
        let handle = FitsHdu { info: HduInfo::AnyInfo, number: hdu };
        handle
            .read_col::<f64>(&mut self.file, &name)
            .map_err(|e| fits_error(self.path, &format!("reading column {column} of the {label}"), &e))
    }
}

/// The repeat count (`None` if unreadable) and type letter of a binary-table TFORM such as
/// `1D`, `D` or `10A`.
pub(super) fn split_tform(tform: &str) -> (Option<usize>, Option<char>) {
    let tform = tform.trim();
    let digits = tform.len() - tform.trim_start_matches(|c: char| c.is_ascii_digit()).len();
    let repeat = if digits == 0 { Some(1) } else { tform[..digits].parse().ok() };
    (repeat, tform[digits..].chars().next().map(|c| c.to_ascii_uppercase()))
}

// ---------------------------------------------------------------------------------------
// Validation shared by writers and readers
