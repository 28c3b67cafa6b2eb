//! Writing: one FITS file at a temporary path, with provenance (DATE, CREATOR, ORIGIN,
//! the command line and its parameters) and CHECKSUM/DATASUM on every HDU.

use super::*;

/// The parameters of the command being run, every one with the value it took (defaults
/// included), as `main` reads them from the command line: written as a `HISTORY` record
/// into every FITS file the process writes, beside the command line itself.
pub(super) static PARAMETERS: std::sync::OnceLock<String> = std::sync::OnceLock::new();

/// Records `text` as the run's parameters for [`PARAMETERS`] (once; later calls are
/// ignored).
pub fn record_parameters(text: String) {
    let _ = PARAMETERS.set(text);
}

/// A FITS file being written at a temporary path; errors name the final `path`.
pub(super) struct FitsWriter<'a> {
    file: FitsFile,
    /// Kept while cfitsio has the file open.
    _name: CfitsioName,
    path: &'a Path,
    /// The HDU that keys and data go to.
    hdu: FitsHdu,
}

impl<'a> FitsWriter<'a> {
    /// Creates `tmp` (replacing it) with a primary image of `dims` (slowest axis first).
    pub(super) fn create(tmp: &Path, path: &'a Path, data_type: ImageType, dims: &[usize]) -> Result<Self, HostError> {
        let name = CfitsioName::for_writing(tmp, path)?;
        let description = ImageDescription { data_type, dimensions: dims };
        let mut file = FitsFile::create(&name.name)
            .with_custom_primary(&description)
            .overwrite()
            .open()
            .map_err(|e| fits_error(path, "creating the file", &e))?;
        let hdu = file.primary_hdu().map_err(|e| fits_error(path, "creating the primary HDU", &e))?;
        // fitsio names a custom primary HDU "_PRIMARY"; a primary HDU has no name in FITS
        // practice (astropy calls it PRIMARY), so the key goes.
        let mut status = 0;
        // SAFETY: `file` is open and its current HDU is the primary (moved to just above);
        // the key name is a NUL-terminated literal.
        unsafe { fitsio::sys::ffdkey(file.as_raw(), c"EXTNAME".as_ptr(), &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(path, "removing fitsio's EXTNAME", &e))?;
        let mut writer = FitsWriter { file, _name: name, path, hdu };
        writer.provenance()?;
        Ok(writer)
    }

    /// Where the file comes from, in the primary HDU: `DATE` (UTC, when written),
    /// `CREATOR` (dncal and its version), `ORIGIN`, and as `HISTORY` cards (cfitsio
    /// continues a long line on further cards) the command line that made it and every
    /// parameter it ran with, defaults included ([`record_parameters`]).
    fn provenance(&mut self) -> Result<(), HostError> {
        let path = self.path;
        let mut status = 0;
        // SAFETY: `self.file` is open with the primary HDU current; ffpdat writes one key.
        unsafe { fitsio::sys::ffpdat(self.file.as_raw(), &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(path, "writing key DATE", &e))?;
        self.key("CREATOR", (format!("dncal {}", env!("CARGO_PKG_VERSION")), "software that wrote this file"))?;
        self.key("ORIGIN", ("dncal", "camera detector correction and characterization"))?;
        // (`args_os`: `args` panics on an argument that is not Unicode, such as a path.)
        let args: Vec<String> = std::env::args_os().map(|a| a.to_string_lossy().into_owned()).collect();
        self.history(&format!("command: {}", args.join(" ")))?;
        match PARAMETERS.get() {
            Some(p) => self.history(&format!("parameters: {p}")),
            None => Ok(()),
        }
    }

    /// One `HISTORY` record of `text`: printable ASCII only (a FITS header holds nothing
    /// else, the rest becomes `?`), at most 4 KB of it.
    fn history(&mut self, text: &str) -> Result<(), HostError> {
        let text: String = text.chars().map(|c| if (' '..='~').contains(&c) { c } else { '?' }).take(4096).collect();
        let Ok(text) = std::ffi::CString::new(text) else { return Ok(()) };
        let mut status = 0;
        // SAFETY: `self.file` is open with the primary HDU current; `text` is NUL-terminated.
        unsafe { fitsio::sys::ffphis(self.file.as_raw(), text.as_ptr(), &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, "writing HISTORY", &e))
    }

    /// Writes `value` (a value or a (value, comment) pair) as key `name` of the current HDU.
    pub(super) fn key<T: WritesKey>(&mut self, name: &str, value: T) -> Result<(), HostError> {
        let path = self.path;
        self.hdu
            .write_key(&mut self.file, name, value)
            .map_err(|e| fits_error(path, &format!("writing key {name}"), &e))
    }

    /// The keys every format carries: `BITDEPTH`, `NADC`, `ADCMAP`.
    pub(super) fn adc_keys(&mut self, bit_depth: u32, n_adc: usize) -> Result<(), HostError> {
        self.key("BITDEPTH", (i64::from(bit_depth), "bits per ADC code"))?;
        let n_adc = i64::try_from(n_adc).map_err(|_| format_error(self.path, "NADC exceeds the key's range"))?;
        self.key("NADC", (n_adc, "ADCs; column c is read by ADC c mod NADC"))?;
        self.key("ADCMAP", (ADCMAP_COLMOD, "ADC of column c is c mod NADC"))
    }

    /// Writes the whole data array of the current image HDU.
    pub(super) fn image<T: WriteImage>(&mut self, data: &[T]) -> Result<(), HostError> {
        let path = self.path;
        self.hdu.write_image(&mut self.file, data).map_err(|e| fits_error(path, "writing image data", &e))
    }

    /// Appends image extension `extname` of `dims` and makes it current.
    pub(super) fn add_image(&mut self, extname: &str, data_type: ImageType, dims: &[usize]) -> Result<(), HostError> {
        let description = ImageDescription { data_type, dimensions: dims };
        self.hdu = self
            .file
            .create_image(extname, &description)
            .map_err(|e| fits_error(self.path, &format!("creating extension {extname}"), &e))?;
        Ok(())
    }

    /// Appends binary table `extname` with the single float64 column `column` in `unit`.
    pub(super) fn add_table(&mut self, extname: &str, column: &str, unit: &str, values: &[f64]) -> Result<(), HostError> {
        let path = self.path;
        let context = format!("writing table {extname}");
        let described = ColumnDescription::new(column).with_type(ColumnDataType::Double).create();
        let description = described.map_err(|e| fits_error(path, &context, &e))?;
        self.hdu = self.file.create_table(extname, &[description]).map_err(|e| fits_error(path, &context, &e))?;
        self.hdu.write_col(&mut self.file, column, values).map_err(|e| fits_error(path, &context, &e))?;
        self.key("TUNIT1", unit)
    }

    /// Flushes everything to disk, so that a full disk is an error here and not a silently
    /// short file when `Drop` closes it (fitsio ignores errors on close).
    /// Every HDU also gets the standard `DATASUM` and `CHECKSUM` keys (the FITS checksum
    /// convention, which astropy verifies), computed last, over the final header and data.
    pub(super) fn finish(mut self) -> Result<(), HostError> {
        let (mut status, mut count) = (0, 0);
        // SAFETY: `self.file` is open; ffthdu counts its HDUs, ffmahd moves among them,
        // ffpcks writes the two keys of the current HDU, ffflus only writes its buffers.
        unsafe {
            let raw = self.file.as_raw();
            fitsio::sys::ffthdu(raw, &mut count, &mut status);
            for hdu in 1..=count {
                fitsio::sys::ffmahd(raw, hdu, std::ptr::null_mut(), &mut status);
                fitsio::sys::ffpcks(raw, &mut status);
            }
            fitsio::sys::ffflus(raw, &mut status);
        }
        fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, "writing checksums and flushing to disk", &e))
    }
}

// ---------------------------------------------------------------------------------------
// Reading
