//! Linearity sets and what `linearity` writes of them: the pixel-wise correction and the
//! corrected cube (`docs/formats.md`, section 2).

use super::*;

/// The value type a linearity set's cubes are held in: `f64` (the default, every
/// command that writes from them) or `f32` (`diagnose`, which holds the cubes through the
/// whole run: half the memory, each value to 2^-24 of itself).
pub trait Sample: Copy + Into<f64> + Send + Sync + std::fmt::Display + std::fmt::LowerExp + super::direct::BigEndianFloat + 'static {
    /// A bound on the variance the type's rounding adds to a value `v`: `(v 2^-24)^2 / 3`
    /// for `f32` (an error uniform within half a last place taken at its widest relative
    /// size; up to 4 times the true variance, negligible beside a mean's noise either
    /// way), 0 for `f64`.
    fn rounding_var(v: f64) -> f64;
}

impl Sample for f64 {
    fn rounding_var(_: f64) -> f64 {
        0.0
    }
}

impl Sample for f32 {
    fn rounding_var(v: f64) -> f64 {
        (v * 2.0f64.powi(-24)).powi(2) / 3.0
    }
}

/// A linearity measurement: frames averaged at illumination levels of known reference
/// voltage.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearitySet<T: Sample = f64> {
    /// Bits per code of the camera.
    pub bit_depth: u32,
    /// ADCs of the camera; column `c` is read by ADC `c mod n_adc`.
    pub n_adc: usize,
    /// Frames averaged at each level.
    pub n_frames: u32,
    /// Columns per frame.
    pub width: usize,
    /// Rows per frame.
    pub height: usize,
    /// Illumination levels; level 0 is dark.
    pub levels: usize,
    /// Mean frames in DN, level-major, then row, then column:
    /// `mean[(level * height + row) * width + column]`.
    pub mean: Vec<T>,
    /// Per-pixel standard deviation of the frames in DN, laid out as `mean`.
    pub std: Vec<T>,
    /// Reference photodiode voltage of each level in V.
    pub voltage: Vec<f64>,
    /// Known bad pixels, `mask[row * width + column]`, 1 = bad, 0 = good.
    pub mask: Option<Vec<u8>>,
    /// What the file says of its pixels beyond their values (optional keys).
    pub keys: SetKeys,
}

/// What a linearity set says of itself beyond its shape and values: optional keys, each
/// a label the analyses report and carry, none of them changing a number measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SetKeys {
    /// The Bayer layout of a colour sensor's pixels from the set's first stored pixel
    /// (`BAYERPAT`, with `XBAYROFF`, `YBAYROFF` and `ROWORDER` applied as read:
    /// [`crate::formats::bayer`]).
    pub bayer: Option<crate::formats::bayer::Bayer>,
    /// Whether the file declares a colour layout this does not read as a 2 x 2 one (an
    /// X-Trans filter's 36 letters, an unknown `ROWORDER`): not an error, the keys are
    /// labels; `bayer` is then `None` and `diagnose` says the colours are not named.
    pub bayer_unread: bool,
    /// What the reference column measures ([`Reference`]).
    pub reference: Reference,
}

/// What a linearity set's reference measures: the light each level received, up to a
/// scale no analysis of a linearity set uses (the fits take `x = reference / its
/// largest`), so either kind gives the same numbers; what differs is what the reference
/// can be wrong by, which the reports say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reference {
    /// A reference photodiode's voltage beside the sensor (column `VOLTAGE`, V): it sees
    /// the light itself, so it follows a source that drifts (the paper's bench).
    #[default]
    Photodiode,
    /// A relative exposure (column `EXPOSURE`, s: exposure time over the f-number
    /// squared, `t / N^2`), what a camera's own series gives: right only as far as the
    /// shutter and the aperture keep their marked values and the light stays put, so
    /// level errors of a few percent are the rule (issue 58), and it says nothing of the
    /// photons a pixel received (no absolute quantum efficiency).
    Exposure,
}

impl Reference {
    /// Its column in extension `REFERENCE`.
    pub fn column(self) -> &'static str {
        match self {
            Reference::Photodiode => "VOLTAGE",
            Reference::Exposure => "EXPOSURE",
        }
    }

    /// Its column's unit (`TUNIT1`).
    pub fn unit(self) -> &'static str {
        match self {
            Reference::Photodiode => "V",
            Reference::Exposure => "s",
        }
    }
}

/// A linearity set borrowed: what the analysis and the checks read, from a
/// [`LinearitySet`] or from arrays another owner holds (a numpy array, one block of a
/// Dask array), without a copy. Fields as [`LinearitySet`]'s.
#[derive(Debug, Clone, Copy)]
pub struct SetView<'a, T: Sample = f64> {
    pub bit_depth: u32,
    pub n_adc: usize,
    pub n_frames: u32,
    pub width: usize,
    pub height: usize,
    pub levels: usize,
    pub mean: &'a [T],
    pub std: &'a [T],
    pub voltage: &'a [f64],
    pub mask: Option<&'a [u8]>,
    pub keys: SetKeys,
}

impl<T: Sample> LinearitySet<T> {
    /// The set, borrowed.
    pub fn view(&self) -> SetView<'_, T> {
        SetView {
            bit_depth: self.bit_depth,
            n_adc: self.n_adc,
            n_frames: self.n_frames,
            width: self.width,
            height: self.height,
            levels: self.levels,
            mean: &self.mean,
            std: &self.std,
            voltage: &self.voltage,
            mask: self.mask.as_deref(),
            keys: self.keys,
        }
    }
}

/// Writes a linearity set atomically: see [`stage_linearity`].
pub fn write_linearity(path: &Path, set: &LinearitySet) -> Result<(), HostError> {
    write_one(|out| stage_linearity(out, path, set))
}

/// Stages a linearity set in `out`: primary float64 cube of mean frames, extensions `STD`
/// (same cube), `MASK` (uint8, when present) and `REFERENCE` (table, column `VOLTAGE`).
pub fn stage_linearity(out: &mut Outputs, path: &Path, set: &LinearitySet) -> Result<(), HostError> {
    check_linearity(&set.view()).map_err(fault(path))?;
    check_adc_columns(set.n_adc, set.width).map_err(fault(path))?;
    out.write(path, |tmp| {
        let cube = [set.levels, set.height, set.width];
        let mut fits = FitsWriter::create(tmp, path, ImageType::Double, &cube)?;
        fits.adc_keys(set.bit_depth, set.n_adc)?;
        fits.key("NFRAMES", (i64::from(set.n_frames), "frames averaged per illumination level"))?;
        fits.key("BUNIT", ("DN", "mean of the frames at each level"))?;
        write_keys(&mut fits, &set.keys)?;
        fits.image(&set.mean)?;
        fits.add_image("STD", ImageType::Double, &cube)?;
        fits.key("BUNIT", ("DN", "standard deviation of the frames"))?;
        fits.image(&set.std)?;
        if let Some(mask) = &set.mask {
            fits.add_image("MASK", ImageType::UnsignedByte, &[set.height, set.width])?;
            fits.image(mask)?;
        }
        // Last, so that a file cut at an HDU boundary lacks a required HDU rather than
        // reading as a valid set without its (optional) mask.
        fits.add_table("REFERENCE", set.keys.reference.column(), set.keys.reference.unit(), &set.voltage)?;
        fits.finish()
    })
}

/// The optional keys of the primary HDU. A Bayer layout is written as the convention's
/// four keys, from the first stored pixel (`XBAYROFF = YBAYROFF = 0`) of rows stored from
/// the top (`ROWORDER = 'TOP-DOWN'`), so that Siril or PixInsight read the same layout.
fn write_keys(fits: &mut FitsWriter, keys: &SetKeys) -> Result<(), HostError> {
    if let Some(b) = keys.bayer {
        fits.key("BAYERPAT", (b.name().to_string(), "colour filter layout from the first stored pixel"))?;
        fits.key("XBAYROFF", (0i64, "Bayer layout's column offset"))?;
        fits.key("YBAYROFF", (0i64, "Bayer layout's row offset"))?;
        fits.key("ROWORDER", ("TOP-DOWN".to_string(), "first stored row is the top"))?;
    }
    Ok(())
}

/// The optional keys of a set whose frames have `height` rows (`BAYERPAT` where present
/// and not blank: its offsets, of either sign, taken modulo 2; `ROWORDER = 'BOTTOM-UP'`
/// starts the layout at the last stored row). A layout that is none of the four 2 x 2
/// ones, or a row order that is neither, is [`SetKeys::bayer_unread`], not an error: the
/// set's numbers do not depend on them (an X-Trans camera's files must still read).
fn read_keys(r: &mut FitsReader, height: usize) -> Result<SetKeys, HostError> {
    let Some(name) = r.key::<String>(0, PRIMARY, "BAYERPAT")?.filter(|n| !n.trim().is_empty()) else {
        return Ok(SetKeys::default());
    };
    let unread = SetKeys { bayer_unread: true, ..SetKeys::default() };
    let Ok(layout) = crate::formats::bayer::Bayer::parse(&name) else {
        return Ok(unread);
    };
    let mut offset = [0usize; 2];
    for (o, key) in offset.iter_mut().zip(["XBAYROFF", "YBAYROFF"]) {
        *o = r.int_key(0, PRIMARY, key)?.unwrap_or(0).rem_euclid(2) as usize;
    }
    let bottom_up = match r.key::<String>(0, PRIMARY, "ROWORDER")?.map(|s| s.trim().to_ascii_uppercase()) {
        None => false,
        Some(o) if o == "TOP-DOWN" => false,
        Some(o) if o == "BOTTOM-UP" => true,
        Some(_) => return Ok(unread),
    };
    // Stored from the bottom, stored row k is row `height - 1 - k` as shown: of a period
    // of two rows, the same as starting `height - 1` rows on.
    let rows = offset[1] + if bottom_up { (height + 1) % 2 } else { 0 };
    Ok(SetKeys { bayer: Some(layout.shifted(offset[0], rows)), ..SetKeys::default() })
}

/// The pixel-wise correction as written: see [`stage_pixel_correction`].
#[derive(Debug, Clone, Copy)]
pub struct PixelCorrection<'a> {
    /// Coefficient cube, plane-major (`a_k` planes of `height x width`).
    pub coeffs: &'a [f64],
    /// Mask reasons per pixel.
    pub mask: &'a [u8],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Polynomial order.
    pub order: usize,
    /// Camera bits per code.
    pub bit_depth: u32,
    /// Camera ADCs.
    pub n_adc: usize,
}

/// Stages the pixel-wise nonlinearity correction (`dncal linearity`): a float64 cube of
/// the polynomial coefficients (`NAXIS1` columns, `NAXIS2` rows, `NAXIS3 = ORDER + 1`,
/// plane k holds a_k of `m = sum a_k x^k`, x the normalized reference) and the uint8
/// extension `MASK` (non-zero = masked; bit 1 input mask, 2 low signal, 4 anomalous trend,
/// 8 unfitted).
pub fn stage_pixel_correction(out: &mut Outputs, path: &Path, c: &PixelCorrection) -> Result<(), HostError> {
    let PixelCorrection { coeffs, mask, width, height, order, bit_depth, n_adc } = *c;
    if coeffs.len() != (order + 1) * width * height || mask.len() != width * height {
        return Err(format_error(path, "coefficient cube or mask does not match the frame size"));
    }
    out.write(path, |tmp| {
        let mut fits = FitsWriter::create(tmp, path, ImageType::Double, &[order + 1, height, width])?;
        fits.adc_keys(bit_depth, n_adc)?;
        fits.key("ORDER", (order as i64, "m = sum_k a_k x^k, k = 0..ORDER; x = V / max V"))?;
        fits.key("BUNIT", ("DN", "coefficients give DN"))?;
        fits.image(coeffs)?;
        fits.add_image("MASK", ImageType::UnsignedByte, &[height, width])?;
        fits.image(mask)?;
        fits.finish()
    })
}

/// Stages a float64 cube of `levels` images (`NAXIS3 = levels`) with `BUNIT` `unit` (a
/// unit astropy parses: `DN`, `count`, or empty for a dimensionless quantity, which the
/// comment then names).
pub fn stage_cube(out: &mut Outputs, path: &Path, data: &[f64], levels: usize, width: usize, height: usize, (unit, comment): (&str, &str)) -> Result<(), HostError> {
    if data.len() != levels * width * height {
        return Err(format_error(path, "cube does not match its shape"));
    }
    out.write(path, |tmp| {
        let mut fits = FitsWriter::create(tmp, path, ImageType::Double, &[levels, height, width])?;
        fits.key("BUNIT", (unit.to_string(), comment.to_string()))?;
        fits.image(data)?;
        fits.finish()
    })
}

/// Reads a linearity set. Rejects missing keys or extensions, shapes that disagree between
/// the primary cube, `STD`, `MASK` and the rows of `REFERENCE`, NaN or infinite values,
/// negative standard deviations and mask values other than 0 and 1.
pub fn read_linearity(path: &Path) -> Result<LinearitySet, HostError> {
    read_linearity_as(path)
}

/// [`read_linearity`] into cubes of `T`, read directly in parallel with their checksums
/// taken in the same pass and converted as they are read, as cfitsio converts
/// ([`super::direct`]; an `f32` set never holds the `f64` one).
pub fn read_linearity_as<T: Sample>(path: &Path) -> Result<LinearitySet<T>, HostError>
where
    Vec<T>: ReadImage,
{
    read_linearity_planned(path, |_| Ok(()))
}

/// What a linearity set's header says it will take to hold, before any of its values is
/// read: what a command checks its whole need against ([`read_linearity_planned`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinearityShape {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Levels.
    pub levels: usize,
    /// Bytes cfitsio holds of the file itself while it is read: a compressed file's
    /// inflated size (0 for a plain file).
    pub resident: u64,
}

impl LinearityShape {
    /// Pixels of a frame.
    pub fn pixels(&self) -> u64 {
        (self.width as u64).saturating_mul(self.height as u64)
    }

    /// Values of one cube (pixels x levels).
    pub fn values(&self) -> u64 {
        self.pixels().saturating_mul(self.levels as u64)
    }
}

/// [`read_linearity_as`], calling `plan` with the set's shape once its header is read and
/// before any of its values is: a command refuses there, from the header alone, a set
/// whose reading and analysis together would not fit its memory budget.
pub fn read_linearity_planned<T: Sample>(path: &Path, plan: impl FnOnce(&LinearityShape) -> Result<(), HostError>) -> Result<LinearitySet<T>, HostError>
where
    Vec<T>: ReadImage,
{
    // The two cubes are most of the file: their checksums wait until they are read, in
    // the same pass.
    let mut r = FitsReader::open_deferring(path)?;
    let h = read_header(&mut r)?;
    plan(&LinearityShape { width: h.width, height: h.height, levels: h.levels, resident: r.resident() })?;
    let mean: Vec<T> = r.float_pixels(&h.cubes[0])?;
    let std: Vec<T> = r.float_pixels(&h.cubes[1])?;
    let (voltage, mask, reference) = read_reference(&mut r, &h)?;
    let Header { bit_depth, n_adc, n_frames, width, height, levels, keys, .. } = h;
    let keys = SetKeys { reference, ..keys };
    let set = LinearitySet { bit_depth, n_adc, n_frames, width, height, levels, mean, std, voltage, mask, keys };
    check_linearity(&set.view()).map_err(|f| r.fault(f))?;
    r.finish()?;
    Ok(set)
}

/// A linearity set read by blocks of rows from its file (`dncal diagnose` on a set its
/// memory budget cannot hold whole): what [`LinearitySet`] holds besides its cubes, and
/// where the cubes are. Opening it reads every value once and checks it as
/// [`read_linearity_as`] does (same errors), with the checksums.
#[derive(Debug)]
pub struct LinearityRows {
    /// Bits per code of the camera.
    pub bit_depth: u32,
    /// ADCs of the camera; column `c` is read by ADC `c mod n_adc`.
    pub n_adc: usize,
    /// Frames averaged at each level.
    pub n_frames: u32,
    /// Columns per frame.
    pub width: usize,
    /// Rows per frame.
    pub height: usize,
    /// Illumination levels; level 0 is dark.
    pub levels: usize,
    /// Reference photodiode voltage of each level in V.
    pub voltage: Vec<f64>,
    /// Known bad pixels, `mask[row * width + column]`, 1 = bad, 0 = good.
    pub mask: Option<Vec<u8>>,
    /// What the file says of its pixels beyond their values.
    pub keys: SetKeys,
    path: std::path::PathBuf,
    /// The mean and the standard-deviation cube.
    cubes: [StoredFloats; 2],
}

impl LinearityRows {
    /// The file it reads.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Rows `rows` of every level of both cubes as `T` (converted as cfitsio converts):
    /// `mean[(level * rows.len() + row - rows.start) * width + column]`, `std` alike;
    /// `bytes` a buffer the caller reuses.
    pub fn read_rows<T: Sample>(&self, rows: std::ops::Range<usize>, mean: &mut Vec<T>, std: &mut Vec<T>, bytes: &mut Vec<u8>) -> std::io::Result<()> {
        let (w, n) = (self.width, rows.len() * self.width);
        for (cube, out) in self.cubes.iter().zip([mean, std]) {
            out.resize(self.levels * n, T::default());
            for (l, plane) in out.chunks_exact_mut(n.max(1)).enumerate() {
                cube.read((l * self.height + rows.start) * w, plane, bytes)?;
            }
        }
        Ok(())
    }

    /// Pixel `p`'s value at every level of both cubes, as [`LinearityRows::read_rows`]
    /// of one pixel (`mean[level]`, `std[level]`).
    pub fn read_pixel<T: Sample>(&self, p: usize, mean: &mut Vec<T>, std: &mut Vec<T>, bytes: &mut Vec<u8>) -> std::io::Result<()> {
        let frame = self.width * self.height;
        for (cube, out) in self.cubes.iter().zip([mean, std]) {
            out.resize(self.levels, T::default());
            for (l, v) in out.iter_mut().enumerate() {
                cube.read(l * frame + p, std::slice::from_mut(v), bytes)?;
            }
        }
        Ok(())
    }
}

/// Whether the file at `path` says it is a linearity set (its primary HDU has
/// `NFRAMES`), whatever else is wrong with it: which reader's refusal to show.
pub fn is_linearity_set(path: &Path) -> bool {
    FitsReader::open(path).is_ok_and(|mut r| r.is_kind(FileKind::Linearity))
}

/// What a linearity set's keys say, held or read by rows.
pub trait LinearityKeys {
    /// Bits per code.
    fn bit_depth(&self) -> u32;
    /// ADCs (`NADC`).
    fn n_adc(&self) -> usize;
    /// Columns, rows, levels.
    fn shape(&self) -> [usize; 3];
}

impl<T: Sample> LinearityKeys for LinearitySet<T> {
    fn bit_depth(&self) -> u32 {
        self.bit_depth
    }
    fn n_adc(&self) -> usize {
        self.n_adc
    }
    fn shape(&self) -> [usize; 3] {
        [self.width, self.height, self.levels]
    }
}

impl LinearityKeys for LinearityRows {
    fn bit_depth(&self) -> u32 {
        self.bit_depth
    }
    fn n_adc(&self) -> usize {
        self.n_adc
    }
    fn shape(&self) -> [usize; 3] {
        [self.width, self.height, self.levels]
    }
}

/// A linearity set opened to be read by blocks of rows: its header read, its values not
/// yet ([`RowsToCheck::check`] reads and checks them, and gives the [`LinearityRows`]).
pub struct RowsToCheck<'a> {
    r: FitsReader<'a>,
    h: Header,
    at: [StoredFloats; 2],
}

impl RowsToCheck<'_> {
    /// Columns, rows, levels.
    pub fn shape(&self) -> [usize; 3] {
        [self.h.width, self.h.height, self.h.levels]
    }

    /// Reads every value once, holding none, and refuses the set as
    /// [`read_linearity_as`] would (the same faults in the same order, word for word):
    /// the cubes' checksums, the reference and mask, the keys, the values as `T` (a
    /// mean not finite, a deviation not finite, a deviation negative), the reference's
    /// values.
    pub fn check<T: Sample>(self) -> Result<LinearityRows, HostError> {
        let RowsToCheck { mut r, h, at } = self;
        let not_finite = |v: T| !v.into().is_finite();
        let not_a_mean = |v: T| !is_code_mean(v.into(), h.bit_depth);
        let negative = |v: T| (v.into() as f32) < 0.0;
        let never = |_: T| false;
        let [mean_bad, _] = r.scan_floats::<T>(&h.cubes[0], &at[0], [&not_a_mean, &never])?;
        let [std_bad, std_negative] = r.scan_floats::<T>(&h.cubes[1], &at[1], [&not_finite, &negative])?;
        let (voltage, mask, reference) = read_reference(&mut r, &h)?;
        let (frame, _) = check_shape(&h).map_err(|f| r.fault(f))?;
        if let Some(f) = value_fault(mean_bad, std_bad, std_negative, frame, h.width, h.bit_depth) {
            return Err(r.fault(f));
        }
        check_reference(&voltage, h.levels, mask.as_deref(), frame, h.width).map_err(|f| r.fault(f))?;
        let path = r.path().to_path_buf();
        r.finish()?;
        let Header { bit_depth, n_adc, n_frames, width, height, levels, keys, .. } = h;
        let keys = SetKeys { reference, ..keys };
        Ok(LinearityRows { bit_depth, n_adc, n_frames, width, height, levels, voltage, mask, keys, path, cubes: at })
    }
}

/// Opens a linearity set to be read by blocks of rows ([`RowsToCheck`]); `None` where
/// its cubes cannot be read directly (a compressed file, scaled or integer cubes):
/// [`read_linearity_as`] reads those whole.
pub fn open_linearity_rows(path: &Path) -> Result<Option<RowsToCheck<'_>>, HostError> {
    if is_compressed(path)? {
        return Ok(None);
    }
    let mut r = FitsReader::open_deferring(path)?;
    let h = read_header(&mut r)?;
    let (Some(mean_at), Some(std_at)) = (r.stored_floats(&h.cubes[0])?, r.stored_floats(&h.cubes[1])?) else {
        return Ok(None);
    };
    Ok(Some(RowsToCheck { r, h, at: [mean_at, std_at] }))
}

/// What a linearity set's file says before its data: its keys and the headers of its two
/// cubes (same shape).
struct Header {
    bit_depth: u32,
    n_adc: usize,
    n_frames: u32,
    width: usize,
    height: usize,
    levels: usize,
    keys: SetKeys,
    /// The primary cube (means) and extension `STD`.
    cubes: [ImageHeader; 2],
}

fn read_header(r: &mut FitsReader) -> Result<Header, HostError> {
    r.expect_kind(FileKind::Linearity)?;
    let (bit_depth, n_adc, _) = r.adc_keys()?;
    let n_frames = r.required_int(0, PRIMARY, "NFRAMES")?;
    let n_frames = u32::try_from(n_frames)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| r.error(format!("NFRAMES = {n_frames}, must be 1 to {}", u32::MAX)))?;
    let image = r.image(0, PRIMARY, 3)?;
    let (width, height, levels) = (image.naxes[0], image.naxes[1], image.naxes[2]);
    if width == 0 || height == 0 || levels == 0 {
        return Err(r.error(format!("the primary cube is {width} x {height} x {levels}: empty")));
    }
    // Here, before any value is read: both readers refuse it first, and at once.
    check_adc_columns(n_adc, width).map_err(|f| r.fault(f))?;
    let std_hdu = r.require_extension("STD", "per-pixel standard deviations")?;
    let std_image = r.image(std_hdu, "extension STD", 3)?;
    if std_image.naxes != image.naxes {
        return Err(r.error(format!(
            "extension STD is {} but the primary cube is {} (columns x rows x levels)",
            shape_text(&std_image.naxes),
            shape_text(&image.naxes)
        )));
    }
    let keys = read_keys(r, height)?;
    Ok(Header { bit_depth, n_adc, n_frames, width, height, levels, keys, cubes: [image, std_image] })
}

/// A set's reference values, its mask where it has one, and what the reference is.
type ReferenceAndMask = (Vec<f64>, Option<Vec<u8>>, Reference);

/// The reference voltages (extension `REFERENCE`) and the mask (`MASK`, where present)
/// of a set whose header is `h`.
fn read_reference(r: &mut FitsReader, h: &Header) -> Result<ReferenceAndMask, HostError> {
    let (width, height, levels) = (h.width, h.height, h.levels);
    let ref_hdu = r.require_extension("REFERENCE", "reference voltages")?;
    // A photodiode's voltage where the table has one, else a relative exposure (looked
    // for only where the voltage's reader found no such column, so that every other
    // fault of the table is refused as it was).
    let label = "extension REFERENCE";
    let missing = |e: &HostError, column: &str| matches!(e, HostError::Format { message, .. } if message.ends_with(&format!("has no column {column}")));
    let (voltage, reference) = match r.column_f64(ref_hdu, label, Reference::Photodiode.column()) {
        Ok(v) => (v, Reference::Photodiode),
        Err(e) if missing(&e, Reference::Photodiode.column()) => match r.column_f64(ref_hdu, label, Reference::Exposure.column()) {
            Ok(v) => (v, Reference::Exposure),
            Err(e) if missing(&e, Reference::Exposure.column()) => {
                return Err(r.error(format!("the {label} has no column VOLTAGE (a reference photodiode's voltage, V) or EXPOSURE (a relative exposure, t / N^2)")));
            }
            Err(e) => return Err(e),
        },
        Err(e) => return Err(e),
    };
    if voltage.len() != levels {
        return Err(r.error(format!("extension REFERENCE has {} rows, the cube has {levels} levels", voltage.len())));
    }
    let mask = match r.extension("MASK")? {
        None => None,
        Some(hdu) => {
            let mask_image = r.image(hdu, "extension MASK", 2)?;
            if mask_image.naxes != [width, height] {
                return Err(r.error(format!(
                    "extension MASK is {} but frames are {width} x {height} (columns x rows)",
                    shape_text(&mask_image.naxes)
                )));
            }
            let mask: Vec<u8> = r.integer_pixels(&mask_image, "mask values")?.convert().map_err(|(i, v)| {
                r.error(format!("mask value {v} at row {}, column {} is not 0 or 1", i / width, i % width))
            })?;
            Some(mask)
        }
    };
    Ok((voltage, mask, reference))
}

/// Everything a linearity set must satisfy, whether about to be written or just read.
pub fn check_linearity<T: Sample>(s: &SetView<'_, T>) -> Result<(), Fault> {
    let (frame, cube) = check_frame(s.bit_depth, s.n_adc, s.n_frames, [s.width, s.height, s.levels])?;
    for (name, values) in [("mean", s.mean), ("std", s.std)] {
        if values.len() != cube {
            return Err(Fault::CubeLength { name, len: values.len(), width: s.width, height: s.height, levels: s.levels, cube });
        }
    }
    let first = |values: &[T], bad: &dyn Fn(T) -> bool| values.iter().position(|&v| bad(v)).map(|i| (i, values[i]));
    let not_finite = |v: T| !v.into().is_finite();
    // Negative at single precision: a negative subnormal below f32's smallest (a zero
    // written with a rounding error) reads as -0.0 in the f32 reader, which must not
    // accept what this one refuses (found by the `fits_linearity` fuzz target: -8e-322).
    let negative = |v: T| (v.into() as f32) < 0.0;
    let not_a_mean = |v: T| !is_code_mean(v.into(), s.bit_depth);
    if let Some(m) = value_fault(first(s.mean, &not_a_mean), first(s.std, &not_finite), first(s.std, &negative), frame, s.width, s.bit_depth) {
        return Err(m);
    }
    check_reference(s.voltage, s.levels, s.mask, frame, s.width)
}

/// At most one ADC per column: column `c` is read by ADC `c mod NADC`, so a file whose
/// `NADC` exceeds its columns names ADCs no column reads, and the analyses would size
/// their per-ADC work by a count the data do not have. A file's rule (the reader's and
/// the writer's), not [`check_linearity`]'s: a block of a larger set (`dncal.dask`) may
/// be narrower than its ADCs.
fn check_adc_columns(n_adc: usize, width: usize) -> Result<(), Fault> {
    if n_adc > width {
        return Err(Fault::AdcsBeyondColumns { n_adc, width });
    }
    Ok(())
}

/// [`check_frame`] of a header.
fn check_shape(h: &Header) -> Result<(usize, usize), Fault> {
    check_frame(h.bit_depth, h.n_adc, h.n_frames, [h.width, h.height, h.levels])
}

/// The keys and shape a set must have: pixels per frame and values per cube.
fn check_frame(bit_depth: u32, n_adc: usize, n_frames: u32, [width, height, levels]: [usize; 3]) -> Result<(usize, usize), Fault> {
    codes_for(bit_depth)?;
    if n_adc == 0 {
        return Err(Fault::NoAdcs);
    }
    if n_frames == 0 {
        return Err(Fault::NoFrames);
    }
    let frame = width.checked_mul(height).filter(|&n| n > 0);
    match (frame, frame.and_then(|f| f.checked_mul(levels)).filter(|&n| n > 0)) {
        (Some(frame), Some(cube)) => Ok((frame, cube)),
        _ => Err(Fault::Shape { width, height, levels }),
    }
}


/// Whether `v` can be the mean of `bit_depth`-bit codes: finite and within one code
/// range either side of the codes (`-2^b` to `2^(b+1)`: room for a set whose dark was
/// subtracted or whose codes were offset, none for a value that is no code's mean, such
/// as -9.3e18 from a wrong `BZERO`, which would reach the analyses as a "signal").
pub fn is_code_mean(v: f64, bit_depth: u32) -> bool {
    let range = 2f64.powi(bit_depth.min(64) as i32);
    v.is_finite() && v >= -range && v <= 2.0 * range
}

/// The first of a set's value faults in the order they are named: a mean not finite or
/// outside the codes ([`is_code_mean`]), a deviation not finite, a deviation negative
/// (each the first of its kind, as index and value, where there is one).
fn value_fault<T: Sample>(mean_bad: Option<(usize, T)>, std_not_finite: Option<(usize, T)>, std_negative: Option<(usize, T)>, frame: usize, width: usize, bit_depth: u32) -> Option<Fault> {
    let at = |what, value: String, i: usize| Fault::Value { what, value, level: i / frame, row: i % frame / width, column: i % width };
    if let Some((i, v)) = mean_bad {
        if v.into().is_finite() {
            let range = 2f64.powi(bit_depth.min(64) as i32);
            return Some(Fault::MeanRange { value: format!("{v:e}"), level: i / frame, row: i % frame / width, column: i % width, bit_depth, lo: -range, hi: 2.0 * range });
        }
        return Some(at("mean is", v.to_string(), i));
    }
    if let Some((i, v)) = std_not_finite {
        return Some(at("std is", v.to_string(), i));
    }
    std_negative.map(|(i, v)| at("std is negative", format!("({v})"), i))
}

/// The reference voltages (one per level, finite) and the mask (a frame of 0 and 1).
fn check_reference(voltage: &[f64], levels: usize, mask: Option<&[u8]>, frame: usize, width: usize) -> Result<(), Fault> {
    if voltage.len() != levels {
        return Err(Fault::Voltages { len: voltage.len(), levels });
    }
    if let Some(level) = voltage.iter().position(|v| !v.is_finite()) {
        return Err(Fault::Voltage { value: voltage[level], level });
    }
    if let Some(mask) = mask {
        if mask.len() != frame {
            return Err(Fault::MaskLength { len: mask.len(), width, rows: frame / width, frame });
        }
        if let Some(i) = mask.iter().position(|&m| m > 1) {
            return Err(Fault::MaskValue { value: mask[i], row: i / width, column: i % width });
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Errors
