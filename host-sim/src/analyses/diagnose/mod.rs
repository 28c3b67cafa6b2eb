//! `dncal diagnose`: what the baseline simulation gets wrong in measured data, named from a
//! catalog of model extensions, each accepted only if it improves the fit on held-out data.
//!
//! One submodule per data kind: [`histograms`], [`ptc`] (EMVA 1288 photon transfer) with
//! [`codes`] (the code density of its frames) and [`defects`] (the defect pixels of its
//! spatial series), [`linearity`] (linearity sets).

mod channels;
mod codes;
mod cubes;
mod defects;
mod histograms;
mod levels;
mod linearity;
pub mod model;
mod pixel_fit;
mod records;
mod points;
mod ptc;
mod scores;
mod smooth_noise;
mod tasks;
pub mod run;

pub use codes::{diagnose_code_density, CodeDensity};
pub use cubes::blocks_of;
pub(crate) use cubes::tile_bytes;
pub use defects::{diagnose_defects, DefectOutcome};
pub use histograms::{diagnose_histograms, AdcArchitecture, ArchitectureScore};
pub use linearity::{diagnose_linearity, diagnose_linearity_rows, diagnose_linearity_spilled};
pub(crate) use linearity::illumination_bytes;
pub use ptc::diagnose_ptc;
pub use records::{spilled_blocks, RECORD_BYTES, RESIDENT_BYTES};

use serde::Serialize;

use crate::analyses::flatten::FlattenParams;
pub(crate) use crate::infra::stats::mean_sq;

/// Tasks a parallel sum over pixels is cut into. Floating-point addition is not
/// associative: rayon's `reduce`, whose tree follows work stealing, made significances
/// differ at 1e-9 between two runs of the same binary on the same set. Each task's sum is
/// taken in pixel order and the tasks' in task order, so a diagnosis is the same number
/// for number on every run and machine; 64 tasks balance a few cores.
pub(crate) const TASKS: usize = 64;

/// The acceptance threshold, in standard deviations of `mean z^2`.
pub const SIGNIFICANCE: f64 = 5.0;

/// Where the baseline residual of one ADC has structure: a residue modulus and the
/// `chi^2` per degree of freedom of the class means about their common mean (about 1
/// for noise).
#[derive(Debug, Clone, Serialize)]
pub struct ResidueStructure {
    /// The modulus m: classes are codes k mod m.
    pub modulus: usize,
    /// `sum_classes n_c (mean_c - mean)^2 / (m - 1)`: how far the classes differ from each
    /// other. A shift of all the residuals (a scale of the expectation) is no residue
    /// structure: uncentred, it made mod 2 the "strongest structure" of every set whose
    /// residuals were a little off zero (a 16-bit set of random widths: chi^2 1,481 per
    /// class mod 2).
    pub chi2_per_class: f64,
}

/// The baseline fit of one ADC.
#[derive(Debug, Clone, Serialize)]
pub struct AdcBaseline {
    /// ADC index.
    pub adc: usize,
    /// Codes scored (held-out half).
    pub codes_scored: usize,
    /// RMS of the normalized held-out residual.
    pub rms: f64,
    /// Structure by code residue, strongest first.
    pub by_residue: Vec<ResidueStructure>,
}

/// The baseline over the whole input.
#[derive(Debug, Clone, Serialize)]
pub struct Baseline {
    /// "histogram-set".
    pub kind: String,
    /// The model: "ideal ADC, smooth illumination, Poisson counts".
    pub model: String,
    /// Per ADC.
    pub adcs: Vec<AdcBaseline>,
    /// RMS of all normalized held-out residuals.
    pub rms: f64,
}

/// An effect of the catalog (`docs/diagnose.md`): what a finding names. Serialized, and
/// displayed, by its name there (`adc-dnl`, ...), which the JSON output, the report and
/// the figures' file names carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Effect {
    /// Code widths that differ from uniform (DN error), per ADC.
    AdcDnl,
    /// One ADC's offset, gain or curvature off the others'.
    AdcMismatch,
    /// A response every pixel shares that bends.
    GlobalNonlinearity,
    /// Each pixel's own bend beyond the shared one.
    PixelNonlinearity,
    /// A departure confined to the lowest signals (charge loss, an offset).
    LowSignalNonlinearity,
    /// A black level the camera subtracted and clipped at code 0: the darkest levels'
    /// means raised, their spread lowered.
    BlackLevelClipped,
    /// Errors of the measurement every pixel shares at a level (light, black level).
    LevelErrors,
    /// The light of each frame off its level's, alike for every pixel (a flicker, a
    /// shutter's jitter): the frames' spread holds more than the sensor's noise.
    LightJitter,
    /// The light's spatial pattern changing between levels, unseen by the reference.
    IlluminationChange,
    /// A response that repeats in rows and columns together with a small period: a colour
    /// filter array (each channel's response relative to their mean).
    CfaPattern,
    /// Pixels the model cannot follow (hot, dead, kinked).
    BadPixels,
    /// A noise larger than the frames' spread says, alike everywhere.
    ExcessNoise,
    /// Noise too low to average below one code.
    InsufficientNoise,
    /// What the extended model leaves.
    Unexplained,
}

/// Whether the camera model carries an effect ([`Effect::in_model`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InModel {
    /// `model.toml` carries it (or, for the noise, it is a property of the data the model
    /// records).
    Yes,
    /// Of the camera, but not in the model yet: named in the file's header.
    NotYet,
    /// Of the measurement (the light source, the frames' independence), not of the
    /// camera: named, never simulated.
    OfTheMeasurement,
}

/// What `diagnose` should name for each planted effect of the hidden-effect generator:
/// the generator is the model's and knows no diagnosis, so the mapping lives here.
impl crate::model::hidden::Hidden {
    /// The effect `diagnose` should name, and the ADC.
    pub fn expected(&self) -> (Effect, Option<usize>) {
        use crate::model::hidden::Hidden;
        let effect = match self {
            Hidden::GlobalNonlinearity { .. } => Effect::GlobalNonlinearity,
            Hidden::PixelNonlinearity { .. } => Effect::PixelNonlinearity,
            Hidden::AdcGain { .. } | Hidden::AdcOffset { .. } | Hidden::AdcCurvature { .. } => Effect::AdcMismatch,
            Hidden::BadPixels { .. } => Effect::BadPixels,
            Hidden::LevelErrors { .. } | Hidden::SeriesDrift { .. } => Effect::LevelErrors,
            Hidden::SubtleBad { .. } => Effect::Unexplained,
            Hidden::ChargeLoss { .. } => Effect::LowSignalNonlinearity,
            Hidden::IlluminationChange { .. } => Effect::IlluminationChange,
            Hidden::Cfa { .. } => Effect::CfaPattern,
            Hidden::LightJitter { .. } => Effect::LightJitter,
        };
        (effect, self.adc())
    }
}

impl Effect {
    /// Whether `model.toml` carries this effect.
    pub fn in_model(self) -> InModel {
        match self {
            Effect::AdcDnl | Effect::GlobalNonlinearity | Effect::PixelNonlinearity | Effect::BadPixels | Effect::InsufficientNoise | Effect::IlluminationChange | Effect::CfaPattern | Effect::BlackLevelClipped => InModel::Yes,
            Effect::AdcMismatch | Effect::Unexplained | Effect::LowSignalNonlinearity => InModel::NotYet,
            Effect::LevelErrors | Effect::LightJitter | Effect::ExcessNoise => InModel::OfTheMeasurement,
        }
    }

    /// Every effect, in the catalog's order.
    pub const ALL: [Effect; 14] = [
        Effect::AdcDnl,
        Effect::AdcMismatch,
        Effect::GlobalNonlinearity,
        Effect::PixelNonlinearity,
        Effect::LowSignalNonlinearity,
        Effect::BlackLevelClipped,
        Effect::LevelErrors,
        Effect::LightJitter,
        Effect::IlluminationChange,
        Effect::CfaPattern,
        Effect::BadPixels,
        Effect::ExcessNoise,
        Effect::InsufficientNoise,
        Effect::Unexplained,
    ];

    /// The catalog's name.
    pub const fn name(self) -> &'static str {
        match self {
            Effect::AdcDnl => "adc-dnl",
            Effect::AdcMismatch => "adc-mismatch",
            Effect::GlobalNonlinearity => "global-nonlinearity",
            Effect::PixelNonlinearity => "pixel-nonlinearity",
            Effect::LowSignalNonlinearity => "low-signal-nonlinearity",
            Effect::BlackLevelClipped => "black-level-clipped",
            Effect::LevelErrors => "level-errors",
            Effect::LightJitter => "light-jitter",
            Effect::IlluminationChange => "illumination-change",
            Effect::CfaPattern => "cfa-pattern",
            Effect::BadPixels => "bad-pixels",
            Effect::ExcessNoise => "excess-noise",
            Effect::InsufficientNoise => "insufficient-noise",
            Effect::Unexplained => "unexplained",
        }
    }
}

impl std::fmt::Display for Effect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a data set cannot be diagnosed: too little of it, or what the tests need is
/// missing. The messages say what is needed; the caller names the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DiagnoseError {
    /// An ADC's histogram could not be flattened (the paper's recipe).
    #[error("ADC {adc}: {source}")]
    Flatten {
        adc: usize,
        #[source]
        source: crate::analyses::flatten::FlattenError,
    },
    /// Too few codes with counts to score.
    #[error("ADC {adc}: only {codes} codes have enough counts to diagnose")]
    TooFewCodes { adc: usize, codes: usize },
    /// Too few codes inside the illuminated peaks for the code-density test.
    #[error("only {codes} codes lie inside illuminated peaks with 20 or more counts in both halves of the levels; the code-density test needs 64")]
    TooFewPeakCodes { codes: usize },
    /// No level above dark in a photon-transfer set.
    #[error("no illuminated levels")]
    NoIlluminatedLevels,
    /// Too few photon-transfer levels below saturation to hold half out.
    #[error("{levels} usable levels below 90% of saturation; the held-out split needs at least 12")]
    TooFewPtcLevels { levels: usize },
    /// A weighted fit of the photon-transfer levels failed (singular).
    #[error("the photon-transfer fit failed")]
    PtcFit,
    /// Too few levels in a linearity set for the held-out split.
    #[error("{levels} levels: the held-out split needs at least 11 (a quartic on the even levels and one on the odd ones)")]
    TooFewLevels { levels: usize },
    /// Too few distinct reference voltages for the held-out split.
    #[error("the reference voltages take {distinct} distinct value(s) (to 1e-6 of the largest); the held-out split needs at least 11 levels of different signal")]
    DistinctLevels { distinct: usize },
    /// More levels than the diagnosis indexes.
    #[error("{levels} levels: at most {} are diagnosed (levels are indexed in 16 bits)", u16::MAX)]
    TooManyLevels { levels: usize },
    /// Too few frames per level for the noise of a mean.
    #[error("{frames} frames per level: the noise of a mean from the frames' standard deviation needs at least 4")]
    TooFewFrames { frames: u32 },
    /// The reference detector's voltages are not positive.
    #[error("the reference voltages are not positive")]
    Reference,
    /// The frames' standard deviations are zero nearly everywhere.
    #[error("the standard deviations are zero at most pixels and levels: the noise of the means is unknown")]
    NoNoise,
    /// More ADCs than the per-ADC tests handle.
    #[error("NADC = {n_adc}: the per-ADC tests are for at most {max} pipelined ADCs (their work grows with the ADCs times the pixels); a set with NADC = 1 is diagnosed pixel by pixel")]
    TooManyAdcs { n_adc: usize, max: usize },
    /// More pixels than a diagnosis indexes.
    #[error("{pixels} pixels: a diagnosis indexes at most {max} pixels (32-bit indices)")]
    TooManyPixels { pixels: usize, max: usize },
    /// No pixel has enough unsaturated levels.
    #[error("no pixel has enough unsaturated levels to fit")]
    NoPixelFits,
    /// The set's file could not be read while it was diagnosed by blocks of rows.
    #[error("{message}")]
    Read { message: String },
}

/// One accepted model extension.
#[derive(Debug, Clone, Serialize)]
pub struct Finding {
    /// The effect, from the catalog.
    pub effect: Effect,
    /// The ADC, for per-ADC effects.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adc: Option<usize>,
    /// A pixel count, for pixel effects.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// A noise level, DN, for `insufficient-noise`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_dn: Option<f64>,
    /// Standard deviations by which the extension lowers `mean z^2` on held-out data.
    pub significance: f64,
    /// Held-out RMS of the normalized residual before the extension.
    pub rms_before: f64,
    /// After.
    pub rms_after: f64,
    /// `rms_before / rms_after`.
    pub gain: f64,
    /// Held-out RMS of the normalized residual over *all* the data the baseline is scored
    /// on ([`Baseline::rms`]'s scale, ending at [`Diagnosis::unexplained_rms`]) once this
    /// finding and the model steps before it are in the model: the one scale on which
    /// findings tested on different subsets compare. Findings that enter the model in
    /// one step (the parts of a linearity set's level term, even one named `unexplained`
    /// because no quartic follows it) share its value. `None` where the finding is tested
    /// on other data than those residuals (maps of dark and gain, flagged pixels, the
    /// frames' code density, the dark noise), rescales the noise rather than the model
    /// (`excess-noise`), or names what the model leaves (`unexplained`): it leaves that
    /// scale as it was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub all_data_rms_after: Option<f64>,
    /// The evidence in words.
    pub detail: String,
    /// Held-out residuals just before and just after this extension (for its figure).
    #[serde(skip)]
    pub residuals: Option<AdcResiduals>,
}

impl Finding {
    /// The effect and, for a per-ADC effect, its ADC: `adc-dnl (ADC 2)`.
    pub fn label(&self) -> String {
        match self.adc {
            Some(a) => format!("{} (ADC {a})", self.effect),
            None => self.effect.to_string(),
        }
    }
}

/// What `diagnose` concluded.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// The baseline fit.
    pub baseline: Baseline,
    /// Accepted findings only.
    pub findings: Vec<Finding>,
    /// Held-out RMS of the normalized residual of the extended model.
    pub unexplained_rms: f64,
    /// The code-density test of the frames, for photon-transfer sets.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub code_density: Option<codes::CodeDensity>,
    /// The IEEE 1241 histogram test of each ADC on all its counts, for histogram sets
    /// (null for an ADC it could not analyse; `not_tested` says why).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adc_linearity: Option<Vec<Option<crate::analyses::ieee1241::AdcLinearity>>>,
    /// The ADC architectures scored held out, per ADC with `adc-dnl` (null for the
    /// others), for histogram sets ([`histograms`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adc_architecture: Option<Vec<Option<AdcArchitecture>>>,
    /// Its held-out residuals by code (for the figures).
    #[serde(skip)]
    pub code_residuals: Option<AdcResiduals>,
    /// Per ADC: the baseline and final normalized residuals (for the figures).
    #[serde(skip)]
    pub residuals: Vec<AdcResiduals>,
    /// The accepted shared response curve in DN, `y = S + b2 S^2 + b3 S^3 + ...` above
    /// dark for a linear signal `S` DN: `[b2, b3, ...]` (for the model file).
    #[serde(skip)]
    pub curve_per_dn: Option<Vec<f64>>,
    /// Camera parameters the data measure (for the model file, and in the JSON: the
    /// gain, the light's jitter, a colour filter's cells, what stands in for a missing
    /// dark level; those not measured are left out).
    pub measured: Measured,
    /// Tests the data could not carry, and why (a finding not tested is not a finding
    /// absent).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub not_tested: Vec<String>,
    /// A linearity set read from its file this many rows at a time instead of held
    /// whole ([`diagnose_linearity_rows`]): the same numbers either way.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub block_rows: Option<usize>,
    /// The per-pixel records (fits, scores) kept in temporary files, a block per thread
    /// in memory, instead of held ([`diagnose_linearity_spilled`]): the same numbers.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub records_spilled: bool,
}

/// Camera parameters a diagnosis measured on the way, each `None` when the data do not
/// say (the model file keeps the default camera's value then).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Measured {
    /// Conversion gain, e- per DN (from the noise: variance against signal).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gain_e_per_dn: Option<f64>,
    /// Temporal read noise at dark, DN.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub read_noise_dn: Option<f64>,
    /// Dark level, DN.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub offset_dn: Option<f64>,
    /// Largest signal above dark before saturation, DN.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_scale_dn: Option<f64>,
    /// Whether the data reached saturation (else `full_scale_dn` is only the brightest
    /// level: a lower bound of the full well).
    pub saturated: bool,
    /// Pixel-to-pixel gain spread, relative rms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prnu_rms: Option<f64>,
    /// Pixel-to-pixel dark spread, DN rms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dsnu_dn: Option<f64>,
    /// Pixel-to-pixel rms of the quadratic term `b2` of the response per DN.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pixel_b2_rms_per_dn: Option<f64>,
    /// Fraction of pixels found bad.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bad_fraction: Option<f64>,
    /// Relative rms of the light's pattern change between levels (`illumination-change`),
    /// at the levels above 20% of the top signal.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub illumination_change_rms: Option<f64>,
    /// A colour filter's response pattern (`cfa-pattern`); `prnu_rms` is then within a
    /// channel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cfa: Option<channels::CfaResponse>,
    /// Where the set has no dark level (level 0 not at zero reference): what stands in for
    /// it; `offset_dn` is then the response's intercept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub no_dark: Option<linearity::NoDark>,
    /// The light's relative rms from frame to frame within a level (`light-jitter`), where
    /// it is found: the gain is then the photon transfer's with its term, or withheld.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_jitter_rms: Option<f64>,
    /// The light's relative rms off the reference from level to level (`level-errors`),
    /// where that is named: a shutter's and an aperture's errors on a series given as
    /// exposure, a source that drifted beside a photodiode that did not see it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_level_rms: Option<f64>,
    /// Where the level errors' light part is two groups of levels (two exposure series
    /// that disagree): the brighter group's light over the dimmer's, less 1.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_series_step: Option<f64>,
    /// What the linearity set's reference measures (a photodiode's voltage or a relative
    /// exposure): carried into the model's `[bench] reference`.
    pub reference: crate::formats::fits::Reference,
}

/// `insufficient-noise` when a noise of `sigma_dn` ("{what} {sigma_dn} DN") leaves a
/// worst-case averaging bias above `accuracy_dn` ([`crate::analyses::quantization::worst_bias`]).
pub(crate) fn insufficient_noise(what: &str, sigma_dn: f64, accuracy_dn: f64) -> Option<Finding> {
    let worst = crate::analyses::quantization::worst_bias(sigma_dn).max_abs_bias_dn;
    (worst > accuracy_dn).then(|| Finding {
        residuals: None,
        effect: Effect::InsufficientNoise,
        adc: None,
        count: None,
        sigma_dn: Some(sigma_dn),
        significance: worst / accuracy_dn,
        rms_before: worst,
        rms_after: worst,
        gain: 1.0,
        all_data_rms_after: None,
        detail: format!("{what} {sigma_dn:.3} DN leaves a worst-case averaging bias of {worst:.2e} DN, above {accuracy_dn} DN"),
    })
}

/// `unexplained` for ADC `adc` when the held-out residuals `z` over `codes` still have
/// `mean z^2` more than [`SIGNIFICANCE`] `sqrt(2/N)` above 1; the detail (after
/// `prefix`) names the strongest residue structure.
pub(crate) fn unexplained_by_residue(adc: usize, codes: &[usize], z: &[f64], prefix: &str) -> Option<Finding> {
    let sd = (2.0 / codes.len() as f64).sqrt();
    let mf = mean_sq(z);
    ((mf - 1.0) / sd > SIGNIFICANCE).then(|| {
        let st = by_residue(codes, z);
        Finding {
            residuals: None,
            effect: Effect::Unexplained,
            adc: Some(adc),
            count: None,
            sigma_dn: None,
            significance: (mf - 1.0) / sd,
            rms_before: mf.sqrt(),
            rms_after: mf.sqrt(),
            gain: 1.0,
            all_data_rms_after: None,
            detail: format!("{prefix}held-out residual {:.3} rms where 1 is noise; strongest residue structure mod {} (chi^2 {:.1} per class)", mf.sqrt(), st[0].modulus, st[0].chi2_per_class),
        }
    })
}

/// Held-out normalized residuals of one ADC, as (code, residual).
#[derive(Debug, Clone, Default)]
pub struct AdcResiduals {
    /// Against the baseline.
    pub baseline: Vec<(usize, f64)>,
    /// Against the model with the accepted findings.
    pub extended: Vec<(usize, f64)>,
}

impl AdcResiduals {
    /// The residuals `before` and `after` at `codes`.
    pub fn over(codes: &[usize], before: &[f64], after: &[f64]) -> Self {
        AdcResiduals { baseline: codes.iter().copied().zip(before.iter().copied()).collect(), extended: codes.iter().copied().zip(after.iter().copied()).collect() }
    }
}


/// Structure of `z` (indexed by `codes`) by residue classes, strongest first: per modulus
/// `m` (2 to 512) the class means' `chi^2` about the mean of all, per degree of freedom
/// ([`ResidueStructure::chi2_per_class`]).
pub(crate) fn by_residue(codes: &[usize], z: &[f64]) -> Vec<ResidueStructure> {
    let mean = z.iter().sum::<f64>() / z.len().max(1) as f64;
    let mut out: Vec<ResidueStructure> = (1..=9)
        .map(|b| {
            let m = 1usize << b;
            let (mut sum, mut n) = (vec![0.0; m], vec![0usize; m]);
            for (&k, &v) in codes.iter().zip(z) {
                sum[k % m] += v - mean;
                n[k % m] += 1;
            }
            let classes = n.iter().filter(|&&c| c > 0).count();
            let chi2: f64 = sum.iter().zip(&n).filter(|(_, &c)| c > 0).map(|(s, &c)| s * s / c as f64).sum();
            ResidueStructure { modulus: m, chi2_per_class: chi2 / classes.saturating_sub(1).max(1) as f64 }
        })
        .collect();
    out.sort_by(|a, b| b.chi2_per_class.total_cmp(&a.chi2_per_class));
    out
}

/// The flattening `diagnose` applies: `flatten` with empty codes at the ends of the range
/// trimmed (at least 10% of the median count), so that data whose dark level or
/// saturation leave empty codes can be fitted.
pub fn trimmed_params(flatten: &FlattenParams) -> FlattenParams {
    FlattenParams { trim_below_fraction: flatten.trim_below_fraction.max(0.1), ..flatten.clone() }
}


#[cfg(test)]
mod noise_tests {
    use super::*;

    /// The threshold by hand: at sigma = 0.5 DN the worst-case averaging bias is the
    /// leading Fourier term `exp(-2 pi^2 sigma^2) / pi` = 2.2906e-3 DN (the next term,
    /// `exp(-8 pi^2 sigma^2) / (2 pi)`, is 4e-10), so an accuracy 10% below that is
    /// `insufficient-noise` and one 10% above is not.
    #[test]
    fn insufficient_noise_is_named_exactly_above_the_accuracy() {
        let worst = (-2.0 * std::f64::consts::PI.powi(2) * 0.25).exp() / std::f64::consts::PI;
        let f = insufficient_noise("dark noise", 0.5, 0.9 * worst).expect("a bias above the accuracy is named");
        assert_eq!(f.effect, Effect::InsufficientNoise);
        assert!((f.rms_before - worst).abs() < 1e-6 * worst && (f.significance - 1.0 / 0.9).abs() < 1e-5, "{f:?}");
        assert!(insufficient_noise("dark noise", 0.5, 1.1 * worst).is_none());
    }
}

#[cfg(test)]
mod effect_tests {
    use super::Effect;

    /// The JSON name of each effect is the catalog's (serde's kebab-case and `name` agree)
    /// and no two effects share one.
    #[test]
    fn effects_serialize_to_the_catalogs_names() {
        let json: Vec<String> = Effect::ALL.iter().map(|e| serde_json::to_string(e).unwrap()).collect();
        let names: Vec<String> = Effect::ALL.iter().map(|e| format!("\"{e}\"")).collect();
        assert_eq!(json, names);
        let doc = include_str!("../../../../docs/diagnose.md");
        for e in Effect::ALL {
            assert!(doc.contains(&format!("`{e}`")), "{e} is not in docs/diagnose.md's catalog");
        }
        let mut unique = names.clone();
        unique.sort();
        unique.dedup();
        assert_eq!(unique.len(), names.len());
        // ALL holds every variant, in the order of the declaration.
        let index = |e: Effect| match e {
            Effect::AdcDnl => 0,
            Effect::AdcMismatch => 1,
            Effect::GlobalNonlinearity => 2,
            Effect::PixelNonlinearity => 3,
            Effect::LowSignalNonlinearity => 4,
            Effect::BlackLevelClipped => 5,
            Effect::LevelErrors => 6,
            Effect::LightJitter => 7,
            Effect::IlluminationChange => 8,
            Effect::CfaPattern => 9,
            Effect::BadPixels => 10,
            Effect::ExcessNoise => 11,
            Effect::InsufficientNoise => 12,
            Effect::Unexplained => 13,
        };
        assert!(Effect::ALL.iter().enumerate().all(|(i, &e)| index(e) == i));
    }
}
