//! `dncal lut build`, `inspect`, `import`, `export` and `convert`: argument glue and
//! reports over the LUT home ([`crate::formats::lut`]: every format, read and written)
//! and the recipes ([`crate::analyses::lut::build`]: histograms to LUTs).
//!
//! `build` flattens the ADCs' histograms (`--recipe`: one shared illumination by
//! default, or the paper's per ADC), quantizes the weights to the core's 2^-24 grid,
//! lets the core build the LUT set by its rounding rule, and writes the LUT FITS and the
//! device image. The float reference must reproduce every entry; `build` checks it and
//! refuses to write otherwise.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::analyses::flatten::FlattenParams;
use crate::analyses::lut::build::{build_luts, AdcLutSummary};
use crate::formats::report::Report;
use crate::formats::fits::read_histograms_for_analysis_planned;
use crate::formats::lut::{self, kcor, LutFormat, LutOutputs};
use crate::formats::outputs::Outputs;
use crate::HostError;

pub use crate::formats::lut::inspect::{inspect, InspectAdc, InspectSummary};

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
    pub linearity: Vec<crate::analyses::ieee1241::AdcLinearity>,
    /// With `--truth CONFIG` (the camera the histograms were simulated with), each LUT
    /// against its true ADC: code values and the paper's Fig. 5 beside the limit.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub truth: Vec<crate::analyses::adc::TruthComparison>,
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
            if let Some(c) = self.truth.get(a.adc) {
                t += &c.text("  ");
            }
        }
        t
    }
}

/// `lut build HIST -o OUT`.
///
/// With `truth` (a camera config: the camera the histograms were simulated with, e.g.
/// `[adc] widths_from = "kcor:..."`), each LUT is also compared with its true ADC and
/// judged by the paper's Fig. 5 beside the limit its counts allow; a camera whose ADCs
/// or bits differ from the set's is refused, naming both files, before anything is
/// written.
pub fn build(input: &Path, output: &Path, params: &FlattenParams, truth: Option<&Path>) -> Result<BuildSummary, HostError> {
    let out = LutOutputs::for_prefix(output)?;
    let mut files = out.expect()?;
    let camera = match truth {
        Some(path) => Some(crate::model::sets::camera_from(crate::model::camera::CameraConfig::from_toml_file(path)?, path.into())?),
        None => None,
    };
    let hist = read_histograms_for_analysis_planned(input, |shape| crate::analyses::lut::build::plan_luts(input, shape))?;
    if let (Some(camera), Some(path)) = (&camera, truth) {
        let (adcs, bits) = (camera.adcs.len(), camera.config.bits);
        if adcs != hist.n_adc() || bits != hist.bit_depth {
            return Err(HostError::argument(
                "--truth",
                format!("{} is a camera of {adcs} ADCs of {bits} bits, but {} holds {} ADCs of {} bits", path.display(), input.display(), hist.n_adc(), hist.bit_depth),
            ));
        }
    }
    let built = build_luts(&hist, params, input)?;
    let linearity = crate::analyses::ieee1241::analyse_set(&hist, crate::analyses::ieee1241::Density::Smooth, params, input)?;
    let truth = camera.map(|c| crate::analyses::adc::judge_against(&c, &hist, &built, params)).unwrap_or_default();
    lut::write(&mut files, &built.lut(), LutFormat::Fits, std::slice::from_ref(&out.fits), None, input)?;
    files.write_bytes(&out.image, &built.image)?;
    files.publish()?;
    Ok(BuildSummary { input: input.into(), lut_fits: out.fits, device_image: out.image, adcs: built.summaries(), linearity, truth })
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
    /// Per ADC: our top entry (LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits`) and the largest difference between our
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
    /// Our top entry, LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits`.
    pub top_entry: u32,
    /// Largest |K-Cor value - our entry - half the code's step|, DN: what rounding to
    /// 2^-11 DN loses (below 2^-12 DN plus the weights' grid).
    pub max_rounding_dn: f64,
    /// Smallest and largest step of the K-Cor table, DN.
    pub step_range: (f64, f64),
}


/// `lut import --kcor FILES -o OUT`: the K-Cor tables as our LUT FITS (with the widths,
/// extension `WEIGHTS`, and the scaling, `KCORBITS`) and device image.
pub fn import_kcor(specs: &[String], output: &Path) -> Result<ImportSummary, HostError> {
    let out = LutOutputs::for_prefix(output)?;
    let mut files = out.expect()?;
    let inputs = kcor::files(specs)?;
    let (tables, imported) = kcor::read_set(&inputs)?;
    let bits = tables[0].bits;
    let unit = 4095.0 / ((1u64 << bits) - 1) as f64;
    let adcs = tables
        .iter()
        .zip(&imported.tables)
        .enumerate()
        .map(|(adc, (t, o))| {
            let steps: Vec<f64> = t.entries.windows(2).map(|p| (p[1] - p[0]) as f64 * unit).collect();
            let max_rounding_dn = (0..t.entries.len())
                .map(|k| {
                    let step = if k == 0 { t.entries[0] as f64 * unit } else { steps[k - 1] };
                    (t.entries[k] as f64 * unit - step / 2.0 - crate::infra::dims::units_to_dn(o[k].into(), o.len())).abs()
                })
                .fold(0.0, f64::max);
            let step_range = (steps.iter().cloned().fold(f64::INFINITY, f64::min), steps.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
            ImportedAdc { adc, top_entry: *o.last().unwrap_or(&0), max_rounding_dn, step_range }
        })
        .collect();
    lut::write(&mut files, &imported, LutFormat::Fits, std::slice::from_ref(&out.fits), None, &inputs[0])?;
    lut::write(&mut files, &imported, LutFormat::DeviceImage, std::slice::from_ref(&out.image), None, &inputs[0])?;
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
    let c = convert(input, LutFormat::Kcor, Path::new(prefix), bits)?;
    Ok(ExportSummary { input: c.input, kcor_bits: c.kcor_bits.unwrap_or(23), outputs: c.outputs })
}

/// What `lut convert` read and wrote.
#[derive(Debug, Serialize)]
pub struct ConvertSummary {
    /// The LUT read.
    pub input: PathBuf,
    /// Its format.
    pub from: LutFormat,
    /// The format written.
    pub to: LutFormat,
    /// The files written (four for the K-Cor tables).
    pub outputs: Vec<PathBuf>,
    /// The K-Cor scaling written (last entry `2^bits - 1`), for the K-Cor tables.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub kcor_bits: Option<u32>,
}

impl Report for ConvertSummary {
    fn text(&self) -> String {
        let outputs: Vec<String> = self.outputs.iter().map(|p| p.display().to_string()).collect();
        let scaling = self.kcor_bits.map_or(String::new(), |b| format!(", last entry 2^{b} - 1"));
        format!("read {} ({})\nwrote {} ({}{scaling})\n", self.input.display(), self.from, outputs.join(", "), self.to)
    }
}

/// `lut convert LUT --to FORMAT -o OUT [--bits B]`: a LUT in any format ([`lut::read`])
/// written in `to` ([`lut::output_paths`] says where). All files are written or none.
pub fn convert(input: &Path, to: LutFormat, out: &Path, bits: Option<u32>) -> Result<ConvertSummary, HostError> {
    if bits.is_some() && to != LutFormat::Kcor {
        return Err(HostError::argument("--bits", "sets the scaling of K-Cor tables; give it with --to kcor only"));
    }
    let paths = lut::output_paths(to, out)?;
    let mut files = Outputs::new();
    files.expect(&paths)?;
    let (from, read) = lut::read(input)?;
    // The K-Cor writer's own checks come first there (shape, widths, that the widths
    // rebuild the entries), as `lut export` always made them.
    if to != LutFormat::Kcor {
        lut::validate(&read, input)?;
    }
    let kcor_bits = (to == LutFormat::Kcor).then(|| bits.or(read.kcor_bits).unwrap_or(23));
    lut::write(&mut files, &read, to, &paths, kcor_bits, input)?;
    files.publish()?;
    Ok(ConvertSummary { input: input.into(), from, to, outputs: paths, kcor_bits })
}
