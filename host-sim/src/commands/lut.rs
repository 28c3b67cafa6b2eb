//! `dncal lut build`, `lut inspect`, and `lut import` / `lut export` of the
//! K-Coronagraph's table files ([`crate::kcor_tables`]).
//!
//! `build` flattens each ADC's histogram (the paper's procedure, [`crate::flatten`]),
//! quantizes the weights to the core's 2^-24 grid, lets the core build the LUT set by its
//! rounding rule, and writes the LUT FITS and the device image. The float reference must
//! reproduce every entry; `build` checks it and refuses to write otherwise.

use std::path::{Path, PathBuf};

use dncal_core::{encode_image, image_len, LutSet, Weight};
use serde::Serialize;

use crate::commands::Report;
use crate::fits::{read_histograms_for_analysis, read_lut, stage_lut, AdcHistograms, LutTables};
use crate::flatten::{flatten_histogram, to_core_weights, FlattenParams, Flattened};
use crate::reference::ReferenceLut;
use crate::outputs::Outputs;
use crate::HostError;

/// The LUT of one ADC, summarized.
#[derive(Debug, Clone, Serialize)]
pub struct AdcLutSummary {
    /// ADC index.
    pub adc: usize,
    /// Cumulative offset at the top code before normalization, DN.
    pub top_offset_before_dn: f64,
    /// Cumulative offset at the top code after normalization, DN (~0).
    pub top_offset_dn: f64,
    /// Largest |cumulative offset| over the codes, DN.
    pub max_abs_offset_dn: f64,
    /// Smallest and largest weight of the inner codes.
    pub weight_range: (f64, f64),
    /// Top entry, units of 2^-11 DN (must be below 2^23).
    pub top_entry: u32,
}

/// What `lut build` wrote.
#[derive(Debug, Serialize)]
pub struct BuildSummary {
    /// The histogram set read.
    pub input: PathBuf,
    /// The LUT FITS written.
    pub lut_fits: PathBuf,
    /// The device image written.
    pub device_image: PathBuf,
    /// Per ADC.
    pub adcs: Vec<AdcLutSummary>,
    /// The IEEE 1241 histogram test of each ADC (smooth density, the flattening's
    /// parameters): DNL, INL, missing and worst codes, the resolution of the counts.
    pub linearity: Vec<crate::ieee1241::AdcLinearity>,
}

impl Report for BuildSummary {
    fn text(&self) -> String {
        let mut t = format!("read {}\nwrote {} and {}\n", self.input.display(), self.lut_fits.display(), self.device_image.display());
        t += "(code widths: each code's normalized width, the LUT's weights; `lut inspect` shows entry steps, the mean width of two neighbouring codes, a narrower range)\n";
        for a in &self.adcs {
            t += &format!(
                "ADC {}: code widths {:.4}..{:.4} DN, max |cumulative offset| {:.3} DN, top offset {:+.4} DN before normalization, {:+.2e} DN after, top entry {}\n",
                a.adc, a.weight_range.0, a.weight_range.1, a.max_abs_offset_dn, a.top_offset_before_dn, a.top_offset_dn, a.top_entry
            );
            if let Some(l) = self.linearity.get(a.adc) {
                t += &l.text("  ");
                // A LUT corrects widths to the counts' own precision; the paper's ramps hold
                // about 10^6 counts a code (0.1%) against a DN error of a few percent.
                if l.resolution.dnl_sigma_lsb > 0.01 {
                    t += &format!(
                        "  note: at {:.0} counts a code each width in this LUT carries {:.1}% of count noise (1 sigma), which the LUT adds to every pixel it corrects; a few-percent DN error needs 10^4 counts a code or more\n",
                        l.resolution.counts_per_code,
                        100.0 * l.resolution.dnl_sigma_lsb
                    );
                }
            }
        }
        t
    }
}

/// The LUTs built from a histogram set: weights, flattening details, core tables, image.
pub struct BuiltLuts {
    /// Flattening results per ADC.
    pub flattened: Vec<Flattened>,
    /// The weights the core received, per ADC.
    pub weights: Vec<Vec<Weight>>,
    /// The core's entries, per ADC.
    pub tables: Vec<Vec<u32>>,
    /// The device image.
    pub image: Vec<u8>,
}

impl BuiltLuts {
    /// The LUT FITS contents: the tables and the weights they were built from.
    pub fn lut_tables(&self) -> LutTables {
        let weights = Some(self.weights.iter().map(|w| w.iter().map(|x| x.to_bits()).collect()).collect());
        LutTables { frac_bits: dncal_core::FRAC_BITS, tables: self.tables.clone(), weights, kcor_bits: None }
    }
}

/// Flattens `hist` and builds the LUT set in the core; `source` names the input in errors.
pub fn build_luts(hist: &AdcHistograms, params: &FlattenParams, source: &Path) -> Result<BuiltLuts, HostError> {
    let mut flattened = Vec::new();
    let mut weights = Vec::new();
    for (adc, counts) in hist.counts.iter().enumerate() {
        let f = flatten_histogram(counts, params).map_err(|e| HostError::Format { path: source.into(), message: format!("ADC {adc}: {e}") })?;
        let w = to_core_weights(&f.weights).map_err(|e| HostError::Format { path: source.into(), message: format!("ADC {adc}: {e}") })?;
        flattened.push(f);
        weights.push(w);
    }
    let (tables, image) = tables_from_weights(&weights, source)?;
    // The independent float reference must reproduce every entry.
    let reference = ReferenceLut::from_weights(&weights.iter().map(|w| w.iter().map(|x| x.to_num::<f64>()).collect()).collect::<Vec<_>>());
    for (adc, (q, t)) in reference.quantized().iter().zip(&tables).enumerate() {
        if let Some(k) = (0..t.len()).find(|&k| q[k] != t[k] as u64) {
            return Err(HostError::Format { path: source.into(), message: format!("ADC {adc} code {k}: core entry {} differs from the float reference {}", t[k], q[k]) });
        }
    }
    Ok(BuiltLuts { flattened, weights, tables, image })
}

/// The core's LUT entries (units of 2^-11 DN) and device image for per-ADC `weights`;
/// `source` names the input in errors.
pub fn tables_from_weights(weights: &[Vec<Weight>], source: &Path) -> Result<(Vec<Vec<u32>>, Vec<u8>), HostError> {
    let codes = weights.first().map_or(0, Vec::len);
    crate::dispatch_lut_dims!(weights.len(), codes, source.display().to_string(), core_tables(weights, source))
}

fn core_tables<const N: usize, const CODES: usize>(weights: &[Vec<Weight>], source: &Path) -> Result<(Vec<Vec<u32>>, Vec<u8>), HostError> {
    let slices: Vec<&[Weight]> = weights.iter().map(|w| w.as_slice()).collect();
    let slices: &[&[Weight]; N] = slices.as_slice().try_into().map_err(|_| HostError::Format { path: source.into(), message: "ADC count".into() })?;
    let set = Box::new(LutSet::<N, CODES>::from_weights(slices).map_err(|e| HostError::core(format!("{}: LUT from weights", source.display()), e))?);
    let tables = set.tables().iter().map(|t| t.iter().map(|e| e.to_bits()).collect()).collect();
    let mut image = vec![0u8; image_len::<N, CODES>()];
    encode_image(&set, &mut image).map_err(|e| HostError::core("encode device image", e))?;
    Ok((tables, image))
}

/// Where `-o OUT` puts the LUT FITS and the device image: OUT itself if it ends in
/// `.fits` (the image beside it with `.bin`), otherwise `OUT.fits` and `OUT.bin`. OUT
/// is a file prefix ([`check_file_prefix`]), so neither file is hidden in a directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LutOutputs {
    /// The LUT FITS.
    pub fits: PathBuf,
    /// The device image.
    pub image: PathBuf,
}

impl LutOutputs {
    /// The two files, checked ([`Outputs::expect`]), in a new set of outputs.
    fn expect(&self) -> Result<Outputs, HostError> {
        let mut files = Outputs::new();
        files.expect([&self.fits, &self.image])?;
        Ok(files)
    }

    /// The two paths for `-o OUT`, or an error naming OUT if it names a directory.
    pub fn for_prefix(out: &Path) -> Result<Self, HostError> {
        check_file_prefix(out, "OUT.fits and OUT.bin")?;
        Ok(if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("fits")) {
            LutOutputs { fits: out.to_path_buf(), image: out.with_extension("bin") }
        } else {
            let s = out.as_os_str().to_string_lossy();
            LutOutputs { fits: PathBuf::from(format!("{s}.fits")), image: PathBuf::from(format!("{s}.bin")) }
        })
    }
}

/// Refuses an `-o` that names a directory (an existing one, or any path ending in `/`)
/// where a file prefix is expected: `DIR/` would become the hidden files `DIR/.fits` and
/// `DIR/.bin`. `writes` says what the prefix becomes, for the message.
fn check_file_prefix(out: &Path, writes: &str) -> Result<(), HostError> {
    let text = out.as_os_str().to_string_lossy();
    let trailing_separator = text.ends_with(std::path::is_separator);
    if trailing_separator || out.file_name().is_none() || out.is_dir() {
        let example = if trailing_separator { format!("{text}cal") } else { format!("{text}/cal") };
        return Err(HostError::Format { path: out.into(), message: format!("names a directory; -o takes a file prefix OUT and writes {writes} (e.g. -o {example})") });
    }
    Ok(())
}

pub(crate) fn summarize(adc: usize, f: &Flattened, table: &[u32]) -> AdcLutSummary {
    let n = f.weights.len();
    let offsets = crate::flatten::cumulative_offsets(&f.weights);
    let inner = &f.weights[1..n - 1];
    AdcLutSummary {
        adc,
        top_offset_before_dn: f.top_offset_before_dn,
        top_offset_dn: f.top_offset_dn,
        max_abs_offset_dn: offsets.iter().fold(0.0, |m: f64, o| m.max(o.abs())),
        weight_range: (inner.iter().cloned().fold(f64::INFINITY, f64::min), inner.iter().cloned().fold(f64::NEG_INFINITY, f64::max)),
        top_entry: table.last().copied().unwrap_or(0),
    }
}

/// `lut build HIST -o OUT`.
pub fn build(input: &Path, output: &Path, params: &FlattenParams) -> Result<BuildSummary, HostError> {
    let out = LutOutputs::for_prefix(output)?;
    let mut files = out.expect()?;
    let hist = read_histograms_for_analysis(input)?;
    let built = build_luts(&hist, params, input)?;
    let linearity = crate::ieee1241::analyse_set(&hist, crate::ieee1241::Density::Smooth, params, input)?;
    stage_lut(&mut files, &out.fits, &built.lut_tables())?;
    files.write_bytes(&out.image, &built.image)?;
    files.publish()?;
    let adcs = built.flattened.iter().zip(&built.tables).enumerate().map(|(a, (f, t))| summarize(a, f, t)).collect();
    Ok(BuildSummary { input: input.into(), lut_fits: out.fits, device_image: out.image, adcs, linearity })
}

/// One ADC's table as `lut inspect` shows it.
#[derive(Debug, Serialize)]
pub struct InspectAdc {
    /// ADC index.
    pub adc: usize,
    /// Entries, units of 2^-11 DN.
    pub entries: Vec<u32>,
    /// Step between consecutive entries in DN: the mean width of two adjacent codes,
    /// the normalized histogram as the table sees it.
    pub step_dn: Vec<f64>,
    /// Cumulative offset: entry in DN minus (k + 1/2).
    pub cumulative_offset_dn: Vec<f64>,
    /// Largest |cumulative offset|, DN.
    pub max_abs_offset_dn: f64,
    /// Smallest and largest step, DN.
    pub step_range: (f64, f64),
}

/// What `lut inspect` found.
#[derive(Debug, Serialize)]
pub struct InspectSummary {
    /// The file.
    pub path: PathBuf,
    /// "lut-fits" or "device-image".
    pub kind: String,
    /// Bits per code.
    pub bit_depth: u32,
    /// Per ADC.
    pub adcs: Vec<InspectAdc>,
    /// Whether the readable text lists every code (`--table`; JSON always has them).
    #[serde(skip)]
    pub list_codes: bool,
}

impl Report for InspectSummary {
    fn text(&self) -> String {
        let mut t = format!("{} ({}, {} bits, {} ADCs)\n", self.path.display(), self.kind, self.bit_depth, self.adcs.len());
        t += "(entry steps: entry k+1 - entry k, the mean width of codes k and k+1; `lut build` reports the single-code widths, a wider range)\n";
        for a in &self.adcs {
            t += &format!("ADC {}: entry steps {:.4}..{:.4} DN, max |cumulative offset| {:.3} DN, top entry {}\n", a.adc, a.step_range.0, a.step_range.1, a.max_abs_offset_dn, a.entries.last().copied().unwrap_or(0));
            if self.list_codes {
                t += "  code      entry          DN     step   offset\n";
                for k in 0..a.entries.len() {
                    let step = if k == 0 { f64::NAN } else { a.step_dn[k - 1] };
                    t += &format!("  {k:4} {:10} {:11.5} {:8.5} {:+8.5}\n", a.entries[k], dncal_core::units_to_dn(a.entries[k].into()), step, a.cumulative_offset_dn[k]);
                }
            }
        }
        t
    }
}

/// The largest device image the core loads (4 ADCs of 14 bits); a longer file is not
/// read whole.
const DEVICE_IMAGE_LIMIT: crate::input::SizeLimit = crate::input::SizeLimit { what: "device image", bytes: image_len::<4, 16384>() as u64 };

/// `lut inspect FILE`: a LUT FITS or a device image (validated by the core). The text
/// lists every code when the caller sets `list_codes`.
pub fn inspect(path: &Path) -> Result<InspectSummary, HostError> {
    let (kind, tables) = if crate::input::starts_with(path, b"DNLT")? {
        let bytes = crate::input::read_regular(path, DEVICE_IMAGE_LIMIT)?;
        if bytes.len() < 16 {
            return Err(HostError::Format { path: path.into(), message: "device image shorter than its 16-byte header".into() });
        }
        let (bits, n) = (bytes[6] as u32, bytes[7] as usize);
        if !(1..=16).contains(&bits) {
            return Err(HostError::Format { path: path.into(), message: format!("device image declares {bits} bits") });
        }
        ("device-image", crate::dispatch_lut_dims!(n, 1usize << bits, path.display().to_string(), parse_image(&bytes, path))?)
    } else {
        let tables = read_lut(path)?.tables;
        // The file format allows any u32; show only what the core would load.
        let (n, codes) = (tables.len(), tables.first().map_or(0, Vec::len));
        crate::dispatch_lut_dims!(n, codes, path.display().to_string(), validate_tables(&tables, path))?;
        ("lut-fits", tables)
    };
    let codes = tables.first().map_or(0, |t| t.len());
    let adcs = tables
        .into_iter()
        .enumerate()
        .map(|(adc, entries)| {
            let dn: Vec<f64> = entries.iter().map(|&e| dncal_core::units_to_dn(e.into())).collect();
            let step_dn: Vec<f64> = dn.windows(2).map(|p| p[1] - p[0]).collect();
            let cumulative_offset_dn: Vec<f64> = dn.iter().enumerate().map(|(k, v)| v - (k as f64 + 0.5)).collect();
            InspectAdc {
                adc,
                max_abs_offset_dn: cumulative_offset_dn.iter().fold(0.0, |m: f64, o| m.max(o.abs())),
                step_range: (step_dn.iter().cloned().fold(f64::INFINITY, f64::min), step_dn.iter().cloned().fold(f64::NEG_INFINITY, f64::max)),
                entries,
                step_dn,
                cumulative_offset_dn,
            }
        })
        .collect();
    Ok(InspectSummary { path: path.into(), kind: kind.into(), bit_depth: codes.trailing_zeros(), adcs, list_codes: false })
}

/// The core's checks of a LUT set (every entry below 2^23, non-decreasing).
fn validate_tables<const N: usize, const CODES: usize>(tables: &[Vec<u32>], path: &Path) -> Result<(), HostError> {
    let mut bits = vec![[0u32; CODES]; N];
    for (dst, src) in bits.iter_mut().zip(tables) {
        dst.copy_from_slice(src);
    }
    let bits: Box<[[u32; CODES]; N]> = bits.into_boxed_slice().try_into().map_err(|_| HostError::Format { path: path.into(), message: "table count".into() })?;
    LutSet::<N, CODES>::from_bits(&bits).map(drop).map_err(|e| HostError::core(path.display().to_string(), e))
}

fn parse_image<const N: usize, const CODES: usize>(bytes: &[u8], path: &Path) -> Result<Vec<Vec<u32>>, HostError> {
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

/// What `lut import --kcor` read and wrote.
#[derive(Debug, Serialize)]
pub struct ImportSummary {
    /// The four tables read, ADC 0 to 3.
    pub inputs: Vec<PathBuf>,
    /// Their scaling: last entry `2^bits - 1`.
    pub kcor_bits: u32,
    /// The LUT FITS written.
    pub lut_fits: PathBuf,
    /// The device image written.
    pub device_image: PathBuf,
    /// Per ADC: our top entry (units of 2^-11 DN) and the largest difference between our
    /// entry (a code's center) and the K-Cor value of the code (its top), in DN.
    pub adcs: Vec<ImportedAdc>,
}

impl Report for ImportSummary {
    fn text(&self) -> String {
        let mut t = format!("read {} K-Cor tables (last entry 2^{} - 1)\nwrote {} and {}\n", self.inputs.len(), self.kcor_bits, self.lut_fits.display(), self.device_image.display());
        for a in &self.adcs {
            t += &format!("ADC {}: K-Cor steps {:.4}..{:.4} DN, top entry {}, largest rounding {:.2e} DN\n", a.adc, a.step_range.0, a.step_range.1, a.top_entry, a.max_rounding_dn);
        }
        t
    }
}

/// One imported ADC.
#[derive(Debug, Serialize)]
pub struct ImportedAdc {
    /// ADC index.
    pub adc: usize,
    /// Our top entry, units of 2^-11 DN.
    pub top_entry: u32,
    /// Largest |K-Cor value - our entry - half the code's step|, DN: what rounding to
    /// 2^-11 DN loses (below 2^-12 DN plus the weights' grid).
    pub max_rounding_dn: f64,
    /// Smallest and largest step of the K-Cor table, DN.
    pub step_range: (f64, f64),
}

/// The four files `specs` names: one spec (a prefix or a path with `{adc}`), or four paths.
pub fn kcor_files(specs: &[String]) -> Result<[PathBuf; 4], HostError> {
    match specs {
        [one] => crate::kcor_tables::expand(one),
        [a, b, c, d] => Ok([a, b, c, d].map(PathBuf::from)),
        _ => Err(HostError::Argument { flag: "--kcor".into(), message: format!("{} files given; give the four tables of ADC 0-3, or one prefix", specs.len()) }),
    }
}

/// `lut import --kcor FILES -o OUT`: the K-Cor tables as our LUT FITS (with the widths,
/// extension `WEIGHTS`, and the scaling, `KCORBITS`) and device image.
pub fn import_kcor(specs: &[String], output: &Path) -> Result<ImportSummary, HostError> {
    use crate::kcor_tables::KcorTable;
    let out = LutOutputs::for_prefix(output)?;
    let mut files = out.expect()?;
    let inputs = kcor_files(specs)?;
    let tables: Vec<KcorTable> = inputs.iter().map(|p| KcorTable::read(p)).collect::<Result<_, _>>()?;
    let bits = tables[0].bits;
    if let Some((i, t)) = tables.iter().enumerate().find(|(_, t)| t.bits != bits) {
        return Err(HostError::Format { path: inputs[i].clone(), message: format!("ends at 2^{} - 1 where ADC 0's table ends at 2^{bits} - 1: one camera's tables share a scaling", t.bits) });
    }
    let weights: Vec<Vec<Weight>> = tables.iter().zip(&inputs).map(|(t, p)| t.weights(p)).collect::<Result<_, _>>()?;
    let (ours, image) = tables_from_weights(&weights, &inputs[0])?;
    let unit = 4095.0 / ((1u64 << bits) - 1) as f64;
    let adcs = tables
        .iter()
        .zip(&ours)
        .enumerate()
        .map(|(adc, (t, o))| {
            let steps: Vec<f64> = t.entries.windows(2).map(|p| (p[1] - p[0]) as f64 * unit).collect();
            let max_rounding_dn = (0..t.entries.len())
                .map(|k| {
                    let step = if k == 0 { t.entries[0] as f64 * unit } else { steps[k - 1] };
                    (t.entries[k] as f64 * unit - step / 2.0 - dncal_core::units_to_dn(o[k].into())).abs()
                })
                .fold(0.0, f64::max);
            let step_range = (steps.iter().cloned().fold(f64::INFINITY, f64::min), steps.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
            ImportedAdc { adc, top_entry: *o.last().unwrap_or(&0), max_rounding_dn, step_range }
        })
        .collect();
    let raw = Some(weights.iter().map(|w| w.iter().map(|x| x.to_bits()).collect()).collect());
    stage_lut(&mut files, &out.fits, &LutTables { frac_bits: dncal_core::FRAC_BITS, tables: ours, weights: raw, kcor_bits: Some(bits) })?;
    files.write_bytes(&out.image, &image)?;
    files.publish()?;
    Ok(ImportSummary { inputs: inputs.to_vec(), kcor_bits: bits, lut_fits: out.fits, device_image: out.image, adcs })
}

/// What `lut export --format kcor` wrote.
#[derive(Debug, Serialize)]
pub struct ExportSummary {
    /// The LUT FITS read.
    pub input: PathBuf,
    /// The scaling written: last entry `2^bits - 1`.
    pub kcor_bits: u32,
    /// The four tables written, ADC 0 to 3.
    pub outputs: Vec<PathBuf>,
}

impl Report for ExportSummary {
    fn text(&self) -> String {
        let outputs: Vec<String> = self.outputs.iter().map(|p| p.display().to_string()).collect();
        format!("read {}\nwrote {} (K-Cor tables, last entry 2^{} - 1)\n", self.input.display(), outputs.join(", "), self.kcor_bits)
    }
}

/// `lut export --format kcor LUT -o PREFIX [--bits B]`: the four K-Cor tables from the
/// LUT's widths (extension `WEIGHTS`), at the LUT's own K-Cor scaling if imported, else
/// `bits` (23 if not given). The widths must rebuild the file's tables in the core (else
/// the file was edited and the two disagree). All four are written or none.
pub fn export_kcor(input: &Path, prefix: &str, bits: Option<u32>) -> Result<ExportSummary, HostError> {
    use crate::kcor_tables::{export_path, KcorTable, KCOR_CODES, KCOR_SCALINGS};
    let err = |message: String| HostError::Format { path: input.into(), message };
    if !prefix.contains("{adc}") {
        check_file_prefix(Path::new(prefix), "OUT_adc0.bin .. OUT_adc3.bin")?;
    }
    let outputs: Vec<PathBuf> = (0..4).map(|a| export_path(prefix, a)).collect();
    let mut files = Outputs::new();
    files.expect(&outputs)?;
    let lut = read_lut(input)?;
    if lut.n_adc() != 4 || lut.tables[0].len() != KCOR_CODES {
        return Err(err(format!("{} ADCs of {} codes; K-Cor tables are four ADCs of 4096 codes", lut.n_adc(), lut.tables[0].len())));
    }
    let Some(raw) = &lut.weights else {
        return Err(err("no WEIGHTS extension: the code widths a K-Cor table needs are not in this LUT (LUT files written by `lut build` or `lut import` carry them)".into()));
    };
    let bits = bits.or(lut.kcor_bits).unwrap_or(23);
    if !KCOR_SCALINGS.contains(&bits) {
        return Err(err(format!("--bits {bits}: K-Cor tables end at 2^22 - 1 or 2^23 - 1")));
    }
    let weights: Vec<Vec<Weight>> = raw.iter().map(|w| w.iter().map(|&b| Weight::from_bits(b)).collect()).collect();
    let (rebuilt, _) = tables_from_weights(&weights, input)?;
    if let Some(adc) = (0..4).find(|&a| rebuilt[a] != lut.tables[a]) {
        return Err(err(format!("ADC {adc}: the WEIGHTS extension does not rebuild the tables (the file was edited?); refusing to export")));
    }
    let tables: Vec<KcorTable> =
        weights.iter().enumerate().map(|(adc, w)| KcorTable::from_weights(w, bits).ok_or_else(|| err(format!("ADC {adc}: the weights sum to zero")))).collect::<Result<_, _>>()?;
    for (t, path) in tables.iter().zip(&outputs) {
        files.write_bytes(path, t.to_bytes())?;
    }
    files.publish()?;
    Ok(ExportSummary { input: input.into(), kcor_bits: bits, outputs })
}
