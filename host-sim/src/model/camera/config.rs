//! Camera parameters, with the paper's MV-D1024E as the default. Every field carries its
//! unit in its name; a TOML file may set any subset of them (`dncal simulate --config`).

use serde::{Deserialize, Serialize};

/// How the camera's ADCs are drawn when no widths or architectures are given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AdcModel {
    /// A nested 1-bit pipeline with the real K-Cor ADCs' statistics
    /// ([`super::nested`], `[adc.nested]`): the default since issue 57.
    #[default]
    Nested,
    /// Pipelined stages of `stage_bits` with DAC-level errors of `stage_error_lsb`
    /// ([`super::adc`]): the built-in camera before issue 57.
    Stages,
}

/// The camera's ADCs: drawn from a model (`model`: the nested pipeline, or pipelined
/// stages with DAC-level errors), or given as measured widths or fitted architectures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdcConfig {
    /// The model the ADCs are drawn from when `widths`, `widths_from` and
    /// `architecture` are not given: `"nested"` (default) or `"stages"`.
    pub model: AdcModel,
    /// The nested pipeline's parameters (`model = "nested"`).
    pub nested: super::nested::NestedPipeline,
    /// `model = "stages"`: bits resolved by each stage, most significant first; they sum
    /// to the bit depth.
    pub stage_bits: Vec<u32>,
    /// `model = "stages"`: rms error of each stage's DAC levels, LSB (one entry per stage).
    pub stage_error_lsb: Vec<f64>,
    /// Seed of the drawn ADCs (either model): the same seed is the same physical ADC set.
    pub seed: u64,
    /// Measured code widths instead of a model: one list of `2^bits` widths (DN)
    /// per ADC, as `dncal diagnose` writes into its model file. Code 0 is open below and
    /// the top code above; the transition into code k is at `-1/2 + sum_{0<j<k} w_j`.
    /// Empty (the default): drawn from `model`.
    pub widths: Vec<Vec<f64>>,
    /// Real ADCs instead: `"kcor:SPEC"` takes the widths from a K-Coronagraph camera's
    /// four deployed tables (SPEC a path with `{adc}` in it, or a prefix; relative to the
    /// TOML file's folder), their DN error without the response correction the tables
    /// also carry, codes below 150 ideal ([`crate::formats::lut::kcor::model_widths`]). Needs 12
    /// bits and 4 ADCs; not with `widths`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub widths_from: Option<String>,
    /// Fitted architectures instead of a model: one per ADC
    /// (`[[adc.architecture]]` tables, `kind = "ideal" | "sar" | "pipelined"`; see
    /// [`super::architecture::Architecture`]), as `dncal diagnose` writes them. Not with
    /// `widths` or `widths_from`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub architecture: Vec<super::architecture::Architecture>,
}

impl Default for AdcConfig {
    fn default() -> Self {
        AdcConfig { model: AdcModel::Nested, nested: Default::default(), stage_bits: STAGE_BITS.to_vec(), stage_error_lsb: STAGE_ERROR_LSB.to_vec(), seed: NESTED_SEED, widths: Vec::new(), widths_from: None, architecture: Vec::new() }
    }
}

/// The default seed of the ADCs. Of the nested pipeline's draws with seeds 13880-14199,
/// 106 of 320 put each of their four ADCs inside the twelve real K-Cor ADCs' range on
/// every statistic (docs/model.md); of those, this one's four medians come nearest the
/// real medians (largest difference 7%). Over all 80 ADCs of every fourth seed of
/// 13880-13959 the medians are rms 3.61% per code (real 3.50), a narrow code every 53.7
/// codes (46.8), sawtooth 0.352 DN (0.370), offsets 0.619 DN peak to peak (0.683), share
/// at mod 256 0.84 (0.79): the built-in camera is a typical draw, picked so that no ADC is
/// an outlier. Seed 13890 was the stage model's.
pub const NESTED_SEED: u64 = 14019;

/// The stage model's default layout and errors (the built-in camera's before issue 57).
const STAGE_BITS: [u32; 4] = [3, 3, 3, 3];
const STAGE_ERROR_LSB: [f64; 4] = [0.15, 0.06, 0.03, 0.015];

impl AdcConfig {
    /// The pre-issue-57 built-in ADCs: four 3-bit stages with DAC-level errors of 0.15,
    /// 0.06, 0.03 and 0.015 LSB.
    pub fn stages() -> Self {
        AdcConfig { model: AdcModel::Stages, seed: 13890, ..AdcConfig::default() }
    }

    /// Ideal ADCs of `bits` bits: one stage without error (the ADC of a camera model
    /// whose data cannot see code widths, or before its measured widths are put in).
    pub fn ideal(bits: u32) -> Self {
        AdcConfig { model: AdcModel::Stages, stage_bits: vec![bits], stage_error_lsb: vec![0.0], ..AdcConfig::default() }
    }

    /// Whether the ADCs are drawn from `model` (no widths or architectures given).
    pub fn drawn(&self) -> bool {
        self.widths.is_empty() && self.widths_from.is_none() && self.architecture.is_empty()
    }

    /// Whether `stage_bits` or `stage_error_lsb` differ from their defaults (a config
    /// that sets them means the stage model).
    fn stages_set(&self) -> bool {
        self.stage_bits != STAGE_BITS || self.stage_error_lsb != STAGE_ERROR_LSB
    }
}

/// The lab bench a calibration set is recorded on (the paper's section 3: an LED, an
/// uncoated glass plate sending about 10% of the light to a reference photodiode, a weak
/// ground-glass diffuser before the sensor). Its imperfections are the set's, not the
/// camera's; they act on linearity sets (`simulate linearity`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BenchConfig {
    /// Relative rms of the change of the light's spatial pattern over the recorded region
    /// from one linearity level to the next (dimensionless; 3e-4 is 0.03%): each level's
    /// light is `N_l (1 + illumination_change_rms phi_l(x, y))`, `phi_l` a smooth field
    /// of zero mean and unit rms over the region, drawn independently per level
    /// ([`super::calibration::illumination_change`]). An LED's emission pattern moves with
    /// its drive current and temperature, and a weak diffuser passes part of it; the
    /// reference diode sees the total light, not the pattern, so the voltages are
    /// unchanged. The default is the paper's bench ([`PAPER_ILLUMINATION_CHANGE_RMS`]),
    /// which `diagnose` names (`illumination-change`); 0 is a perfect bench.
    pub illumination_change_rms: f64,
    /// Each linearity level's light off what its reference says, relative rms (a shutter
    /// off its marked time, an aperture off its marked f-number, daylight that drifted
    /// between exposures: 1-5% on the consumer camera of issue 58; 0 on the paper's bench,
    /// whose photodiode sees the light itself): level `l` receives `N_l (1 + e_l)`, `e_l`
    /// normal, drawn per level from `seed`. `diagnose` names it `level-errors`.
    pub level_error_rms: f64,
    /// Each frame's light off its level's, relative rms (a source that flickers, a shutter
    /// that jitters: 1-5% on the consumer camera): frame `f` of level `l` receives `N_l (1 +
    /// e_l) (1 + j_lf)`, `j_lf` normal, alike for every pixel. `diagnose` names it
    /// `light-jitter`.
    pub frame_jitter_rms: f64,
    /// What the set's reference column measures: `"photodiode"` (the light, `VOLTAGE`) or
    /// `"exposure"` (exposure time over f-number squared, `EXPOSURE`: a consumer camera's
    /// series, where `level_error_rms` is the shutter's and the aperture's errors).
    pub reference: crate::formats::fits::Reference,
    /// Seed of the patterns.
    pub seed: u64,
}

/// A colour filter array over the sensor (issue 58): each pixel's response is its cell's
/// times its own gain (`1 + PRNU`). `dncal diagnose` writes what `cfa-pattern` measured.
/// `simulate linearity` writes `bayer` as the set's FITS `BAYERPAT` (of the region read).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CfaConfig {
    /// Pixels a period, rows and columns (2 for a Bayer filter; at most [`MAX_CFA_PERIOD`]).
    pub period: usize,
    /// Each cell's relative response, row-major: cell `(row mod period) * period + column
    /// mod period` of the sensor (dimensionless; the consumer camera of issue 58 had 1.23,
    /// 0.99, 0.55, 1.23).
    pub cells: Vec<f64>,
    /// The Bayer layout (`RGGB`, `GRBG`, `GBRG`, `BGGR`: the colours of the first two
    /// rows' first two pixels), where known; a label, the responses are `cells`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bayer: Option<crate::formats::bayer::Bayer>,
}

/// The cell of a colour filter of period `period` (rows and columns; 0 taken as 1) that
/// the pixel at `column`, `row` lies in, row-major: `(row mod period) * period + column
/// mod period`. The one indexing of the model's `[cfa]`, of what `cfa-pattern` measures
/// and of `dncal linearity`'s 2 x 2 mask medians.
pub fn cfa_cell(column: usize, row: usize, period: usize) -> usize {
    let p = period.max(1);
    (row % p) * p + column % p
}

/// The largest colour filter period a camera model takes (an X-Trans filter's is 6).
pub const MAX_CFA_PERIOD: usize = 8;

impl CfaConfig {
    /// The response of the pixel at `column`, `row` of the sensor.
    pub fn at(&self, column: usize, row: usize) -> f64 {
        self.cells.get(cfa_cell(column, row, self.period)).copied().unwrap_or(1.0)
    }

    fn check(&self) -> Result<(), ConfigError> {
        if !(1..=MAX_CFA_PERIOD).contains(&self.period) || self.cells.len() != self.period * self.period {
            return Err(ConfigError::CfaCells { period: self.period, cells: self.cells.len() });
        }
        if let Some(v) = self.cells.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
            return Err(ConfigError::NotPositive { field: "cfa.cells", value: *v });
        }
        if let Some(b) = self.bayer {
            if self.period != 2 {
                return Err(ConfigError::Bayer { bayer: b, period: self.period });
            }
        }
        Ok(())
    }
}

/// The largest relative rms of the light's level errors and frame jitter a model takes.
pub const MAX_LIGHT_ERROR_RMS: f64 = 0.2;

/// The bench's pattern change that brings our Fig. 8 nearest the paper's text (issue 42,
/// `docs/paper.md`): the default bench.
pub const PAPER_ILLUMINATION_CHANGE_RMS: f64 = 3e-4;

/// The largest pattern change a configuration may ask for (10% of the light, far beyond
/// any bench that would be called flat).
pub const MAX_ILLUMINATION_CHANGE_RMS: f64 = 0.1;

impl Default for BenchConfig {
    fn default() -> Self {
        BenchConfig { illumination_change_rms: PAPER_ILLUMINATION_CHANGE_RMS, level_error_rms: 0.0, frame_jitter_rms: 0.0, reference: crate::formats::fits::Reference::Photodiode, seed: 735 }
    }
}

/// The largest camera config or model file: 16 MiB holds the measured code widths
/// (`adc.widths`, about 19 bytes a width as `dncal diagnose` writes them; 0.3 MB for four
/// 12-bit ADCs) of twelve 16-bit ADCs; a bigger file is not a config.
pub const CONFIG_LIMIT: crate::formats::input::SizeLimit = crate::formats::input::SizeLimit { what: "camera config", bytes: 16 << 20 };

/// The largest sensor a camera model may have: 2^26 pixels (8192 x 8192), whose pixel
/// maps take about 2 GB.
pub const MAX_PIXELS: usize = 1 << 26;
/// The largest electron count a model parameter may have (full well, dark, noise): 1e7,
/// ten times the largest full wells of scientific sensors.
pub const MAX_ELECTRONS: f64 = 1e7;

/// Everything the camera model needs. Defaults: the PhotonFocus MV-D1024E of the
/// K-Coronagraph (de Wijn 2018): 1024 x 1024, 12 bits, 4 ADCs, ~180 ke- full well,
/// 44 e-/DN, 182 e- read noise, 150 frames/s; QE 30% at 735 nm (the paper's model).
/// The dark signal, offset, PRNU, DSNU, nonlinearity and bad-pixel fraction are not in
/// the paper; the defaults are plausible values for such a sensor, stated as such.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Name for reports.
    pub name: String,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// ADC bit depth B.
    pub bits: u32,
    /// ADCs; column c is read by ADC c mod n_adc.
    pub n_adc: usize,
    /// Quantum efficiency, photoelectrons per photon.
    pub qe: f64,
    /// Full-well capacity, e-.
    pub full_well_e: f64,
    /// Conversion gain, e- per DN.
    pub gain_e_per_dn: f64,
    /// Gaussian read noise, e- rms.
    pub read_noise_e: f64,
    /// Mean dark signal per frame (dark current x exposure), e-.
    pub dark_e: f64,
    /// Black level added before the ADC, DN.
    pub offset_dn: f64,
    /// Pixel-to-pixel gain spread (PRNU), relative rms.
    pub prnu_rms: f64,
    /// Pixel-to-pixel dark spread (DSNU), e- rms.
    pub dsnu_rms_e: f64,
    /// Global nonlinearity: y/FW = x + a2 x^2 + a3 x^3 + ..., x = n/FW; this lists
    /// a2, a3, ...
    pub nonlinearity: Vec<f64>,
    /// Per-pixel rms spread of a2, a3, ... (empty: every pixel follows the global curve).
    pub pixel_nonlinearity_rms: Vec<f64>,
    /// Fraction of bad pixels (half hot: always the top code; half dead: no response).
    pub bad_pixel_fraction: f64,
    /// Highest frame rate, frames/s.
    pub max_frame_rate_hz: f64,
    /// The ADCs: drawn from a model, or measured widths, or fitted architectures.
    pub adc: AdcConfig,
    /// The lab bench the calibration sets are recorded on.
    pub bench: BenchConfig,
    /// A colour filter array, where the sensor has one (`[cfa]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cfa: Option<CfaConfig>,
    /// Seed of the pixel maps (PRNU, DSNU, nonlinearity, bad pixels).
    pub seed: u64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            name: "PhotonFocus MV-D1024E (simulated)".into(),
            width: 1024,
            height: 1024,
            bits: 12,
            n_adc: 4,
            qe: 0.30,
            full_well_e: 180_000.0,
            gain_e_per_dn: 44.0,
            read_noise_e: 182.0,
            dark_e: 400.0,
            offset_dn: 60.0,
            prnu_rms: 0.01,
            dsnu_rms_e: 40.0,
            nonlinearity: vec![-0.02, 0.02],
            pixel_nonlinearity_rms: vec![0.005],
            bad_pixel_fraction: 6.0e-5,
            max_frame_rate_hz: 150.0,
            adc: AdcConfig::default(),
            bench: BenchConfig::default(),
            cfa: None,
            seed: 2018,
        }
    }
}

impl CameraConfig {
    /// Reads a TOML file whose fields override the defaults; unknown fields are errors.
    pub fn from_toml_file(path: &std::path::Path) -> Result<Self, crate::HostError> {
        let mut config: CameraConfig = crate::formats::input::read_toml(path, CONFIG_LIMIT)?;
        let base = path.parent().unwrap_or(std::path::Path::new("."));
        config.resolve_widths_from(base).map_err(|e| match e {
            inner @ (crate::HostError::Format { .. } | crate::HostError::Lut { .. }) => crate::HostError::WidthsFrom { path: path.into(), inner: Box::new(inner) },
            other => other,
        })?;
        config.validate().map_err(|source| crate::HostError::Config { path: path.into(), source })?;
        Ok(config)
    }

    /// Fills `adc.widths` from `adc.widths_from` (see [`AdcConfig::widths_from`]), a
    /// relative SPEC taken from `base`.
    pub fn resolve_widths_from(&mut self, base: &std::path::Path) -> Result<(), crate::HostError> {
        let Some(from) = self.adc.widths_from.clone() else { return Ok(()) };
        let bad = |message: String| crate::HostError::Format { path: from.clone().into(), message };
        let Some(spec) = from.strip_prefix("kcor:") else {
            return Err(bad("the only source is kcor:SPEC (a K-Coronagraph camera's four tables)".into()));
        };
        if !self.adc.widths.is_empty() {
            return Err(bad("give adc.widths or adc.widths_from, not both".into()));
        }
        if self.bits != 12 || self.n_adc != 4 {
            return Err(bad(format!("K-Cor tables are four 12-bit ADCs; this camera has {} ADCs of {} bits", self.n_adc, self.bits)));
        }
        let spec = if std::path::Path::new(spec).is_absolute() { spec.to_string() } else { base.join(spec).to_string_lossy().into_owned() };
        let files = crate::formats::lut::kcor::expand(&spec)?;
        self.adc.widths = files.iter().map(|f| crate::formats::lut::kcor::KcorTable::read(f).map(|t| crate::formats::lut::kcor::model_widths(&t))).collect::<Result<_, _>>()?;
        Ok(())
    }

    /// Codes of the ADC, 2^B.
    pub fn codes(&self) -> usize {
        1 << self.bits
    }

    /// Checks every parameter for range and consistency; the error names the field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let positive = [
            ("width", self.width as f64),
            ("height", self.height as f64),
            ("n_adc", self.n_adc as f64),
            ("qe", self.qe),
            ("full_well_e", self.full_well_e),
            ("gain_e_per_dn", self.gain_e_per_dn),
            ("max_frame_rate_hz", self.max_frame_rate_hz),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::NotPositive { field: name, value: v });
            }
        }
        let non_negative = [
            ("read_noise_e", self.read_noise_e),
            ("dark_e", self.dark_e),
            ("prnu_rms", self.prnu_rms),
            ("dsnu_rms_e", self.dsnu_rms_e),
            ("bad_pixel_fraction", self.bad_pixel_fraction),
            ("bench.illumination_change_rms", self.bench.illumination_change_rms),
            ("bench.level_error_rms", self.bench.level_error_rms),
            ("bench.frame_jitter_rms", self.bench.frame_jitter_rms),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError::Negative { field: name, value: v });
            }
        }
        if !self.offset_dn.is_finite() {
            return Err(ConfigError::NotFinite { field: "offset_dn" });
        }
        if !(1..=16).contains(&self.bits) {
            return Err(ConfigError::Bits { bits: self.bits });
        }
        if self.qe > 1.0 {
            return Err(ConfigError::Qe { qe: self.qe });
        }
        if self.bench.illumination_change_rms > MAX_ILLUMINATION_CHANGE_RMS {
            return Err(ConfigError::IlluminationChange { rms: self.bench.illumination_change_rms });
        }
        for (field, rms) in [("bench.level_error_rms", self.bench.level_error_rms), ("bench.frame_jitter_rms", self.bench.frame_jitter_rms)] {
            if rms > MAX_LIGHT_ERROR_RMS {
                return Err(ConfigError::LightError { field, rms });
            }
        }
        if self.bad_pixel_fraction > 1.0 {
            return Err(ConfigError::BadPixelFraction { fraction: self.bad_pixel_fraction });
        }
        if self.n_adc > 255 || self.width > 65_535 || self.height > 65_535 {
            return Err(ConfigError::Dimensions);
        }
        // Column c is read by ADC c mod n_adc: with fewer columns some ADCs read nothing,
        // and their histograms, LUTs and statistics would be of no pixel.
        if self.n_adc > self.width {
            return Err(ConfigError::AdcsAboveColumns { n_adc: self.n_adc, width: self.width });
        }
        // Physical ranges, so that a typo cannot ask for memory no machine has (issue 18:
        // dark_e = 1e19 made kcor-model ask for 607 GB; a 65535 x 65535 sensor aborted).
        if self.width * self.height > MAX_PIXELS {
            return Err(ConfigError::Sensor { width: self.width, height: self.height });
        }
        if let Some(c) = &self.cfa {
            c.check()?;
        }
        for (name, v) in [("full_well_e", self.full_well_e), ("dark_e", self.dark_e), ("read_noise_e", self.read_noise_e), ("dsnu_rms_e", self.dsnu_rms_e)] {
            if v > MAX_ELECTRONS {
                return Err(ConfigError::Electrons { field: name, value: v });
            }
        }
        if self.nonlinearity.iter().chain(&self.pixel_nonlinearity_rms).any(|a| !a.is_finite()) {
            return Err(ConfigError::NotFinite { field: "nonlinearity" });
        }
        if self.pixel_nonlinearity_rms.len() > self.nonlinearity.len() {
            return Err(ConfigError::PixelNonlinearityTerms);
        }
        // The nested model's own rules, where it draws the ADCs. A config that sets the
        // stage model's fields without `model = "stages"` meant that model (every config
        // before issue 57 did): refused rather than drawn from another.
        if self.adc.model == AdcModel::Nested && self.adc.drawn() {
            if self.adc.stages_set() {
                return Err(ConfigError::StagesWithoutModel);
            }
            self.adc.nested.check(self.bits).map_err(|source| ConfigError::Nested { source })?;
        }
        if self.adc.model == AdcModel::Stages || self.adc.stages_set() {
            self.check_stages()?;
        }
        if !self.adc.widths.is_empty()
            && (self.adc.widths.len() != self.n_adc || self.adc.widths.iter().any(|w| w.len() != self.codes() || w.iter().any(|x| !(x.is_finite() && *x > 0.0))))
        {
            return Err(ConfigError::Widths { n_adc: self.n_adc, codes: self.codes() });
        }
        if !self.adc.architecture.is_empty() {
            if !self.adc.widths.is_empty() || self.adc.widths_from.is_some() {
                return Err(ConfigError::ArchitectureAndWidths);
            }
            if self.adc.architecture.len() != self.n_adc {
                return Err(ConfigError::Architectures { n_adc: self.n_adc, given: self.adc.architecture.len() });
            }
            for (adc, a) in self.adc.architecture.iter().enumerate() {
                a.check(self.bits).map_err(|source| ConfigError::Architecture { adc, source })?;
            }
        }
        Ok(())
    }

    /// The stage model's fields: stages that make up the code, one error per stage.
    fn check_stages(&self) -> Result<(), ConfigError> {
        // Summed wide: a u32 sum of [2^32 - 1, 13] wraps to 12 and passed (issue 18).
        let stage_sum: u64 = self.adc.stage_bits.iter().map(|&b| u64::from(b)).sum();
        if stage_sum != u64::from(self.bits) || self.adc.stage_bits.contains(&0) {
            return Err(ConfigError::StageBits { stage_bits: self.adc.stage_bits.clone(), bits: self.bits });
        }
        if self.adc.stage_error_lsb.len() != self.adc.stage_bits.len() || self.adc.stage_error_lsb.iter().any(|e| !(e.is_finite() && *e >= 0.0)) {
            return Err(ConfigError::StageErrors);
        }
        Ok(())
    }
}

/// Why a camera configuration cannot be built: the field and the rule it breaks. The
/// messages name the TOML field as the user wrote it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// The bench's pattern change is beyond what the model is for.
    #[error("bench.illumination_change_rms = {rms}: at most 0.1 (a relative change of the light's pattern between levels; the paper's bench needs about 3e-4)")]
    IlluminationChange {
        /// The value given.
        rms: f64,
    },
    /// The light's errors beyond what a relative model holds (a normal draw of 20% rms
    /// is negative one time in 3.5 million).
    #[error("{field} = {rms}: at most 0.2 (relative, rms; a consumer camera's series is off by 0.01-0.05)")]
    LightError {
        /// The field.
        field: &'static str,
        /// The value given.
        rms: f64,
    },
    /// A quantity that must be positive is not.
    #[error("{field} must be positive and finite, got {value}")]
    NotPositive { field: &'static str, value: f64 },
    /// A quantity that must be at least zero is not.
    #[error("{field} must be non-negative and finite, got {value}")]
    Negative { field: &'static str, value: f64 },
    /// A value or coefficient that is NaN or infinite.
    #[error("{field} must be finite")]
    NotFinite { field: &'static str },
    /// Bits per code outside what the formats hold.
    #[error("bits must be 1..=16, got {bits}")]
    Bits { bits: u32 },
    /// A quantum efficiency above 1.
    #[error("qe is a fraction (0, 1], got {qe}")]
    Qe { qe: f64 },
    /// More bad pixels than pixels.
    #[error("bad_pixel_fraction must be <= 1, got {fraction}")]
    BadPixelFraction { fraction: f64 },
    /// ADCs or a side beyond the 8- and 16-bit registers.
    #[error("n_adc = {n_adc} ADCs on width = {width} columns: column c is read by ADC c mod n_adc, so every ADC needs a column (n_adc <= width)")]
    AdcsAboveColumns { n_adc: usize, width: usize },
    #[error("at most 255 ADCs and 65535 x 65535 pixels")]
    Dimensions,
    /// A colour filter whose cells are not `period x period`.
    #[error("cfa: period {period} needs period x period cells (period 1 to {MAX_CFA_PERIOD}); {cells} given")]
    CfaCells { period: usize, cells: usize },
    /// A Bayer layout on a filter that is not 2 x 2.
    #[error("cfa.bayer = \"{bayer}\" is a 2 x 2 layout: it needs period 2 (the period is {period})")]
    Bayer { bayer: crate::formats::bayer::Bayer, period: usize },
    /// A sensor larger than the model holds in memory.
    #[error("width x height = {width} x {height} exceeds {MAX_PIXELS} pixels (8192 x 8192), the largest sensor the model holds in memory")]
    Sensor { width: usize, height: usize },
    /// A charge beyond any sensor's full well.
    #[error("{field} = {value:e} electrons exceeds {MAX_ELECTRONS:e}, above any sensor's full well")]
    Electrons { field: &'static str, value: f64 },
    /// A pixel-to-pixel spread for a nonlinearity term the camera does not have.
    #[error("pixel_nonlinearity_rms has more terms than nonlinearity")]
    PixelNonlinearityTerms,
    /// Pipeline stages that do not make up the code.
    #[error("adc.stage_bits {stage_bits:?} must be positive and sum to bits = {bits}")]
    StageBits { stage_bits: Vec<u32>, bits: u32 },
    /// Measured code widths of the wrong shape or sign.
    #[error("adc.widths needs {n_adc} lists of {codes} positive widths (or none)")]
    Widths { n_adc: usize, codes: usize },
    /// Stage errors that do not match the stages.
    #[error("adc.stage_error_lsb needs one non-negative value per stage")]
    StageErrors,
    /// Stage errors so large that a code has no width.
    #[error("ADC {adc}: code {code} has no width (stage errors {stage_error_lsb:?} LSB are too large)")]
    NoWidth { adc: usize, code: usize, stage_error_lsb: Vec<f64> },
    /// Fitted architectures beside measured widths.
    #[error("give adc.architecture or adc.widths (widths_from), not both")]
    ArchitectureAndWidths,
    /// Not one architecture per ADC.
    #[error("adc.architecture needs one entry per ADC ({n_adc}), got {given}")]
    Architectures { n_adc: usize, given: usize },
    /// An architecture that is not one of a `bits`-bit ADC.
    #[error("adc.architecture of ADC {adc}: {source}")]
    Architecture { adc: usize, source: super::architecture::ArchitectureError },
    /// Stage-model fields under the nested model.
    #[error("adc.stage_bits / adc.stage_error_lsb describe model = \"stages\", but adc.model is \"nested\" (the default since issue 57): add model = \"stages\" to [adc] to draw pipelined stages")]
    StagesWithoutModel,
    /// The nested model's parameters.
    #[error("adc.nested: {source}")]
    Nested { source: super::nested::NestedError },
    /// Transition levels that are not an ADC's.
    #[error("transition levels must be 2^B - 1 strictly increasing values")]
    Levels,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_bits_that_wrap_a_u32_sum_are_refused() {
        // [2^32 - 1, 13] sums to 12 in u32 arithmetic (issue 18: accepted, then a capacity
        // overflow); [2^32 - 64, 76] to 12 as well.
        for bits in [vec![u32::MAX, 13], vec![u32::MAX - 63, 76]] {
            let c = CameraConfig { adc: AdcConfig { stage_bits: bits.clone(), stage_error_lsb: vec![0.0; 2], ..AdcConfig::stages() }, ..CameraConfig::default() };
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("must be positive and sum to bits = 12"), "{bits:?}: {e}");
        }
        let ok = CameraConfig { adc: AdcConfig { stage_bits: vec![6, 6], stage_error_lsb: vec![0.0; 2], ..AdcConfig::stages() }, ..CameraConfig::default() };
        assert_eq!(ok.validate(), Ok(()));
    }

    /// The error is a value a caller can match on, and the host's error keeps it as its
    /// source under the file's name.
    #[test]
    fn a_config_error_is_typed_and_the_hosts_errors_source() {
        let e = CameraConfig { qe: 2.0, ..CameraConfig::default() }.validate().unwrap_err();
        assert_eq!(e, ConfigError::Qe { qe: 2.0 });
        let host = crate::HostError::Config { path: std::path::PathBuf::from("cam.toml"), source: e.clone() };
        assert_eq!(host.to_string(), "cam.toml: qe is a fraction (0, 1], got 2");
        let source = std::error::Error::source(&host).and_then(|s| s.downcast_ref::<ConfigError>());
        assert_eq!(source, Some(&e));
    }

    /// A config with every table a camera config or model file has: the top level,
    /// `[adc]`, `[bench]`, and one `[[adc.architecture]]` of each kind (3 ADCs of 4 bits).
    /// Every field and kind is named below without `..`, so a new field or kind does not
    /// compile until it is named here, where a new table is then to be filled in (a table
    /// left empty or skipped when serialized would escape the walk below).
    fn every_table() -> CameraConfig {
        use super::super::architecture::Architecture;
        let config = CameraConfig {
            width: 8,
            height: 4,
            bits: 4,
            n_adc: 3,
            adc: AdcConfig {
                model: AdcModel::Stages,
                nested: super::super::nested::NestedPipeline { drop_dn: 0.2, ..Default::default() },
                stage_bits: vec![2, 2],
                stage_error_lsb: vec![0.1, 0.05],
                seed: 7,
                widths: Vec::new(),
                widths_from: None,
                architecture: vec![
                    Architecture::Ideal {},
                    Architecture::Sar { weight_error_lsb: vec![0.0, 0.1, -0.2, 0.3] },
                    Architecture::Pipelined { stage_bits: vec![2, 2], offset_lsb: vec![vec![0.0, 0.1, -0.1, 0.2], vec![0.0, 0.05, 0.0, -0.05]], subrange_gain_error: vec![0.0, 0.1, -0.1, 0.0] },
                ],
            },
            bench: BenchConfig { illumination_change_rms: 1e-3, level_error_rms: 0.02, frame_jitter_rms: 0.01, reference: crate::formats::fits::Reference::Exposure, seed: 5 },
            cfa: Some(CfaConfig { period: 2, cells: vec![1.2, 1.0, 0.6, 1.2], bayer: Some(crate::formats::bayer::Bayer::Gbrg) }),
            ..CameraConfig::default()
        };
        let CameraConfig { name: _, width: _, height: _, bits: _, n_adc: _, qe: _, full_well_e: _, gain_e_per_dn: _, read_noise_e: _, dark_e: _, offset_dn: _, prnu_rms: _, dsnu_rms_e: _, nonlinearity: _, pixel_nonlinearity_rms: _, bad_pixel_fraction: _, max_frame_rate_hz: _, adc, bench, cfa, seed: _ } = &config;
        let Some(CfaConfig { period: _, cells: _, bayer: _ }) = cfa else { unreachable!("set above") };
        let AdcConfig { model: _, nested: _, stage_bits: _, stage_error_lsb: _, seed: _, widths: _, widths_from: _, architecture } = adc;
        let BenchConfig { illumination_change_rms: _, level_error_rms: _, frame_jitter_rms: _, reference: _, seed: _ } = bench;
        let kinds: Vec<&str> = architecture.iter().map(|a| match a { Architecture::Ideal {} => "ideal", Architecture::Sar { .. } => "sar", Architecture::Pipelined { .. } => "pipelined" }).collect();
        assert_eq!(kinds, ["ideal", "sar", "pipelined"], "one architecture of each kind");
        config
    }

    /// One step of the way to a table in a TOML value: a key, or an index in an array.
    #[derive(Debug, Clone)]
    enum Step {
        Key(String),
        Index(usize),
    }

    /// Every table in `v` (`v` itself first where it is one), as the steps to it.
    fn tables(v: &toml::Value, at: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
        match v {
            toml::Value::Table(t) => {
                out.push(at.clone());
                for (k, child) in t {
                    at.push(Step::Key(k.clone()));
                    tables(child, at, out);
                    at.pop();
                }
            }
            toml::Value::Array(a) => {
                for (i, child) in a.iter().enumerate() {
                    at.push(Step::Index(i));
                    tables(child, at, out);
                    at.pop();
                }
            }
            _ => {}
        }
    }

    fn table_at<'a>(v: &'a mut toml::Value, steps: &[Step]) -> &'a mut toml::Table {
        let v = steps.iter().fold(v, |v, step| match step {
            Step::Key(k) => &mut v.as_table_mut().unwrap()[k],
            Step::Index(i) => &mut v.as_array_mut().unwrap()[*i],
        });
        v.as_table_mut().unwrap()
    }

    /// `adc.architecture[1]`, or "the top level" for no steps.
    fn path_text(steps: &[Step]) -> String {
        let mut s = String::new();
        for step in steps {
            match step {
                Step::Key(k) if s.is_empty() => s.push_str(k),
                Step::Key(k) => s.push_str(&format!(".{k}")),
                Step::Index(i) => s.push_str(&format!("[{i}]")),
            }
        }
        if s.is_empty() { "the top level".into() } else { s }
    }

    /// Issue 56: `kind = "ideal"` took any other key and ignored it, while the same key
    /// under `sar`, `pipelined` or at the top level was refused. Here every table of a
    /// config with every table (serialized, then walked, so a table added to the model is
    /// walked too) gets, one at a time, each key any other table has (with that table's
    /// value, so the type is right and only the place is wrong: `weight_error_lsb` under
    /// `ideal`, `stage_bits` under `sar`, `seed` under an architecture, `kind` at the top
    /// level) and a made-up one; the config loader refuses each on one line naming the
    /// file and the field. The config as serialized loads back equal.
    #[test]
    fn an_unknown_field_in_any_table_is_refused_naming_it() {
        let config = every_table();
        let value = toml::Value::try_from(&config).unwrap();
        let mut all = Vec::new();
        tables(&value, &mut Vec::new(), &mut all);
        let mut names: Vec<String> = all.iter().map(|s| path_text(s)).collect();
        names.sort();
        // A table added to the model shows up here by itself; this list says it was seen.
        assert_eq!(names, ["adc", "adc.architecture[0]", "adc.architecture[1]", "adc.architecture[2]", "adc.nested", "bench", "cfa", "the top level"]);
        // Each key of any table, with its value there (the first table that has it).
        let mut keys: std::collections::BTreeMap<String, toml::Value> = std::collections::BTreeMap::new();
        for steps in &all {
            for (k, v) in table_at(&mut value.clone(), steps).iter() {
                keys.entry(k.clone()).or_insert_with(|| v.clone());
            }
        }
        keys.insert("planted_field".into(), toml::Value::Integer(1));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cam.toml");
        std::fs::write(&path, toml::to_string(&value).unwrap()).unwrap();
        assert_eq!(CameraConfig::from_toml_file(&path).unwrap(), config);
        let mut refused = std::collections::BTreeSet::new();
        for steps in &all {
            for (k, v) in &keys {
                let mut planted = value.clone();
                let table = table_at(&mut planted, steps);
                if table.contains_key(k) {
                    continue;
                }
                table.insert(k.clone(), v.clone());
                let text = toml::to_string(&planted).unwrap();
                std::fs::write(&path, &text).unwrap();
                let where_ = path_text(steps);
                let e = match CameraConfig::from_toml_file(&path) {
                    Ok(_) => panic!("{k} in {where_} accepted:\n{text}"),
                    Err(e) => e.to_string(),
                };
                assert!(e.starts_with(&format!("{}: ", path.display())) && e.contains(&format!("unknown field `{k}`")) && !e.contains('\n'), "{k} in {where_}: {e}");
                refused.insert((where_, k.clone()));
            }
        }
        // The issue's own cases were among them; 30 keys in all (20 at the top level, 5 in
        // adc, 2 in bench, 1 to 4 in an architecture, the made-up one), 146 places.
        for (table, key) in [("adc.architecture[0]", "weight_error_lsb"), ("adc.architecture[0]", "planted_field"), ("adc.architecture[1]", "stage_bits"), ("bench", "planted_field"), ("the top level", "kind")] {
            assert!(refused.contains(&(table.to_string(), key.to_string())), "{key} in {table} not tried");
        }
        assert!(refused.len() >= 146, "{}", refused.len());
    }

    #[test]
    fn sizes_and_electrons_beyond_physical_ranges_are_refused() {
        let e = CameraConfig { dark_e: 1e19, ..CameraConfig::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("dark_e = 1e19") && e.contains("1e7"), "{e}");
        let e = CameraConfig { full_well_e: 2e7, ..CameraConfig::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("full_well_e"), "{e}");
        let e = CameraConfig { width: 65_535, height: 65_535, ..CameraConfig::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("65535 x 65535 exceeds 67108864 pixels"), "{e}");
        // The edges are accepted.
        assert_eq!(CameraConfig { width: 8192, height: 8192, dark_e: 1e7, ..CameraConfig::default() }.validate(), Ok(()));
    }
}
