//! What the user types: `dncal`'s arguments as clap reads them, and their conversion
//! into the library's parameters (checked, with errors naming the option).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use dncal_host::model::camera::calibration::RampParams;
use dncal_host::model::camera::{Camera, CameraConfig};
use dncal_host::model::sets;
use dncal_host::analyses::flatten::{FlattenParams, Recipe};
use dncal_host::analyses::kcor::KcorParams;
use dncal_host::infra::roi::RoiSpec;
use dncal_host::HostError;

#[derive(Parser)]
#[command(name = "dncal", version, about = "Real-time correction and characterization of scientific camera detectors")]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Cmd,
    /// Memory budget: a file or config whose sizes would make a step need more is refused
    /// before anything is allocated (bytes, or K, M, G, T: powers of 1024). Default: 3/4 of
    /// the memory the process can have: physical memory, `ulimit -v` / `-d` and the
    /// cgroup's limit, less what is in use.
    #[arg(long, global = true, value_name = "SIZE", value_parser = dncal_host::infra::budget::parse_size)]
    pub(crate) max_memory: Option<u64>,
    /// No stage lines or progress bars on stderr (they show only on a terminal anyway).
    #[arg(long, short, global = true)]
    pub(crate) quiet: bool,
}

/// The formats `lut export` writes.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ExportFormat {
    /// The K-Coronagraph's four per-ADC tables (`OUT_adc0.bin` .. `OUT_adc3.bin`, little-endian u32; docs/kcor-luts.md).
    Kcor,
}

/// The LUT formats `lut convert` writes.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LutFormatArg {
    /// Our LUT FITS (entries, and the code widths in extension WEIGHTS where known; docs/formats.md).
    Fits,
    /// The device image the co-processor loads (the core's encoding, with its CRC).
    Image,
    /// The K-Coronagraph's four per-ADC tables (little-endian u32; docs/kcor-luts.md).
    Kcor,
}

impl From<LutFormatArg> for dncal_host::formats::lut::LutFormat {
    fn from(a: LutFormatArg) -> Self {
        use dncal_host::formats::lut::LutFormat;
        match a {
            LutFormatArg::Fits => LutFormat::Fits,
            LutFormatArg::Image => LutFormat::DeviceImage,
            LutFormatArg::Kcor => LutFormat::Kcor,
        }
    }
}

/// How the input spread its samples over the ADC's range, for the IEEE 1241 histogram test.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DensityArg {
    /// An illumination ramp smooth over tens of codes: the paper's flattening (spline and
    /// running median); INL only on scales below the median window.
    Smooth,
    /// The standard's linear ramp, overdriving both ends: the same counts a code everywhere.
    Ramp,
    /// The standard's sine-wave histogram test: the arcsine density.
    Sine,
}

impl DensityArg {
    pub(crate) fn density(self) -> dncal_host::analyses::ieee1241::Density {
        use dncal_host::analyses::ieee1241::Density;
        match self {
            DensityArg::Smooth => Density::Smooth,
            DensityArg::Ramp => Density::Ramp,
            DensityArg::Sine => Density::Sine,
        }
    }
}

/// The datapaths `stream` can drive.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum EngineKind {
    /// The correction core, as the MCU runs it.
    Core,
    /// The cycle-level frame-grabber model, configured over SPI by the core's driver and
    /// compared with the core sum by sum.
    Fpga,
}

/// Which datapath `stream` drives. The FPGA model's settings apply to it alone: given
/// with `--engine core` they are refused, not ignored.
#[derive(Args, Debug, Clone)]
pub(crate) struct EngineArgs {
    /// The datapath.
    #[arg(long, value_enum, default_value_t = EngineKind::Core)]
    pub(crate) engine: EngineKind,
    /// FPGA: pixels per clock, 1 to 8 [default: 4].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    pub(crate) taps: Option<usize>,
    /// FPGA: input FIFO depth, pixels [default: 1024].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    pub(crate) fifo_depth: Option<usize>,
    /// FPGA: sum-memory latency, cycles [default: 32].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    pub(crate) mem_latency: Option<u32>,
    /// FPGA: sum-memory bandwidth, 32-bit words per clock (a pixel needs 2) [default: 8].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    pub(crate) mem_words_per_cycle: Option<u32>,
}

impl EngineArgs {
    pub(crate) fn engine(&self) -> Result<dncal_host::checks::streaming::Engine, HostError> {
        let fpga_flags = [("--taps", self.taps.is_some()), ("--fifo-depth", self.fifo_depth.is_some()), ("--mem-latency", self.mem_latency.is_some()), ("--mem-words-per-cycle", self.mem_words_per_cycle.is_some())];
        match self.engine {
            EngineKind::Core => match fpga_flags.iter().find(|f| f.1) {
                Some((flag, _)) => Err(HostError::argument(*flag, "applies to the FPGA model only: add --engine fpga")),
                None => Ok(dncal_host::checks::streaming::Engine::Core),
            },
            EngineKind::Fpga => {
                let d = dncal_fpga_model::Config::default();
                let config = dncal_fpga_model::Config {
                    taps: self.taps.unwrap_or(d.taps),
                    fifo_depth: self.fifo_depth.unwrap_or(d.fifo_depth),
                    mem_latency: self.mem_latency.unwrap_or(d.mem_latency),
                    mem_words_per_cycle: self.mem_words_per_cycle.unwrap_or(d.mem_words_per_cycle),
                    ..d
                };
                config.validate().map_err(|e| HostError::argument("--engine fpga", e.to_string()))?;
                Ok(dncal_host::checks::streaming::Engine::Fpga(config))
            }
        }
    }
}

#[derive(Args, Clone)]
pub(crate) struct CameraArgs {
    /// Camera parameters (TOML; any field of the default MV-D1024E may be set), or the
    /// model file `dncal diagnose -o DIR` writes (DIR/model.toml).
    #[arg(long, visible_alias = "model", value_name = "TOML")]
    pub(crate) config: Option<PathBuf>,
}

impl CameraArgs {
    pub(crate) fn camera(&self) -> Result<Camera, HostError> {
        match &self.config {
            Some(path) => sets::camera_from(CameraConfig::from_toml_file(path)?, path.as_path().into()),
            None => sets::camera_from(CameraConfig::default(), dncal_host::Subject::DefaultCamera.into()),
        }
    }
}

#[derive(Args, Clone)]
pub(crate) struct FlattenArgs {
    /// How LUT weights come from the histograms: `shared` (one illumination for all ADCs,
    /// fitted to their mean histogram, 20-point spline, no running median; the
    /// default for LUTs) or `paper` (each ADC alone, 50-point spline, 21-code running
    /// median). The histogram analyses (IEEE 1241 test, `diagnose`) always flatten each
    /// ADC alone, with the paper's smoothing unless --recipe paper sets its own.
    #[arg(long, value_enum)]
    pub(crate) recipe: Option<Recipe>,
    /// Points of the smoothing spline (default: the recipe's, 20 shared, 50 paper).
    #[arg(long)]
    pub(crate) spline_points: Option<usize>,
    /// Width of the running median, codes, odd; 1 for none (default: the recipe's, 1
    /// shared, 21 paper).
    #[arg(long)]
    pub(crate) median_window: Option<usize>,
    /// With the shared recipe: below this code the illumination's spline follows the
    /// ADCs' per-code median histogram instead of their mean (default: the recipe's,
    /// 300 shared; 0 for none). docs/kcor-luts.md says why.
    #[arg(long)]
    pub(crate) median_of_adcs_below: Option<usize>,
    /// Lowest codes set to 1.
    #[arg(long, default_value_t = FlattenParams::default().fixed_low_codes)]
    pub(crate) fixed_low_codes: usize,
    /// Keep the last (saturation) code's measured weight instead of setting it to 1.
    #[arg(long)]
    pub(crate) keep_last: bool,
}

impl FlattenArgs {
    /// The flattening, `default` where --recipe is not given.
    pub(crate) fn params_or(&self, default: Recipe) -> FlattenParams {
        let base = self.recipe.unwrap_or(default).params();
        FlattenParams {
            spline_points: self.spline_points.unwrap_or(base.spline_points),
            median_window: self.median_window.unwrap_or(base.median_window),
            median_of_adcs_below: self.median_of_adcs_below.unwrap_or(base.median_of_adcs_below),
            fixed_low_codes: self.fixed_low_codes,
            set_last_to_one: !self.keep_last,
            ..base
        }
    }
    /// The flattening of a command that builds LUTs: the shared recipe by default.
    pub(crate) fn params(&self) -> FlattenParams {
        self.params_or(Recipe::Shared)
    }
}

#[derive(Args, Clone)]
pub(crate) struct RampArgs {
    /// Levels of the first ramp; ramps of this many, one more, ... up to --last-ramp.
    #[arg(long, default_value_t = 130)]
    pub(crate) first_ramp: usize,
    /// Levels of the last ramp.
    #[arg(long, default_value_t = 139)]
    pub(crate) last_ramp: usize,
    /// Pixels of each ADC in the region (256 x 256 pixels / 4 ADCs by default).
    #[arg(long, default_value_t = RampParams::default().pixels_per_adc)]
    pub(crate) pixels_per_adc: u64,
    /// Frames per level.
    #[arg(long, default_value_t = RampParams::default().frames_per_level)]
    pub(crate) frames_per_level: u64,
    /// Relative rms spread of the pixels' mean signal across the region (gamma distributed).
    #[arg(long, default_value_t = RampParams::default().field_spread)]
    pub(crate) field_spread: f64,

    /// Seed of the counts.
    #[arg(long, default_value_t = 4)]
    pub(crate) seed: u64,
}

impl RampArgs {
    pub(crate) fn params(&self) -> Result<RampParams, HostError> {
        if self.first_ramp < 2 || self.last_ramp < self.first_ramp {
            return Err(HostError::argument("--first-ramp / --last-ramp", "ramps need --first-ramp >= 2 and --last-ramp >= --first-ramp"));
        }
        if !(0.0..1.0).contains(&self.field_spread) {
            return Err(HostError::argument("--field-spread", "must be in [0, 1)"));
        }
        Ok(RampParams {
            ramp_levels: (self.first_ramp..=self.last_ramp).collect(),
            pixels_per_adc: self.pixels_per_adc,
            frames_per_level: self.frames_per_level,
            field_spread: self.field_spread,
            seed: self.seed,
            ..RampParams::default()
        })
    }
}

#[derive(Subcommand)]
pub(crate) enum Cmd {
    /// Write calibration data sets from the camera model.
    Simulate {
        #[command(subcommand)]
        what: SimulateCmd,
    },
    /// Build or inspect per-ADC lookup tables.
    Lut {
        #[command(subcommand)]
        what: LutCmd,
    },
    /// Stream frames through the core and compare them with the float reference.
    Stream {
        #[command(flatten)]
        camera: CameraArgs,
        /// Histogram set to build the LUTs from (default: the camera's true code widths).
        #[arg(long, value_name = "FITS")]
        hist: Option<PathBuf>,
        #[command(flatten)]
        flatten: FlattenArgs,
        /// Frames (frame f has modulation state f mod states).
        #[arg(long, default_value_t = 8)]
        frames: u32,
        /// Modulation states.
        #[arg(long, default_value_t = 4)]
        states: u8,
        /// ROI as WIDTHxHEIGHT+COLUMN+ROW (default: the whole sensor).
        #[arg(long)]
        roi: Option<RoiSpec>,
        /// Seed of the frames.
        #[arg(long, default_value_t = 735)]
        seed: u64,
        /// Replay recorded frames (a FITS cube of raw codes: columns x rows x frames)
        /// instead of sampling the camera model; every frame is streamed, the ROI is the
        /// cube's size at COLUMN, ROW of --roi (default 0, 0).
        #[arg(long, value_name = "FITS", conflicts_with = "frames")]
        frames_from: Option<PathBuf>,
        #[command(flatten)]
        engine: EngineArgs,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// The main job: calibrate, build LUTs, stream, check, report (default camera).
    Demo {
        #[command(flatten)]
        camera: CameraArgs,
        /// Output folder.
        #[arg(short, long, default_value = "dncal-demo")]
        out: PathBuf,
        /// Frames to stream.
        #[arg(long, default_value_t = 8)]
        frames: u32,
        #[command(flatten)]
        ramp: RampArgs,
        #[command(flatten)]
        flatten: FlattenArgs,
        /// Folder of the K-Coronagraph's deployed tables (`Photonfocus_MV-D1024E_13889_adc{0..3}_20131203.bin`
        /// among them): Fig. 5 is judged on that real camera's 4th ADC too. `scripts/demo.sh`
        /// passes `../shared/data/kcor-luts` when it is there.
        #[arg(long, value_name = "DIR")]
        kcor_tables: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// ADC characterization (paper section 4, Fig. 3): histograms, LUTs, cumulative offsets.
    Adc {
        #[command(flatten)]
        camera: CameraArgs,
        /// Measured histogram set to characterize (default: simulate the ramps; then the
        /// results are also compared with the simulated ADCs' true code widths).
        #[arg(long, conflicts_with = "from_luts")]
        hist: Option<PathBuf>,
        /// Characterize real ADCs from K-Coronagraph tables instead: one camera per use (a
        /// prefix, or a path with {adc} in it); see docs/kcor-luts.md.
        #[arg(long, value_name = "SPEC")]
        from_luts: Vec<String>,
        /// Output folder for the figures and the LUT files.
        #[arg(short, long, default_value = "dncal-adc")]
        out: PathBuf,
        /// The input's density over the codes, for the IEEE 1241 histogram test (DNL,
        /// INL, missing and worst codes); the LUTs use --recipe's flattening.
        #[arg(long, value_enum, default_value_t = DensityArg::Smooth)]
        density: DensityArg,
        #[command(flatten)]
        ramp: RampArgs,
        #[command(flatten)]
        flatten: FlattenArgs,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// The K-Coronagraph model (paper section 4, Figs. 4-5): polarimetric error from DN error.
    KcorModel {
        #[command(flatten)]
        camera: CameraArgs,
        /// Which ADC (the paper used the camera's 4th).
        #[arg(long, default_value_t = KcorParams::default().adc)]
        adc: usize,
        /// Exposure time of one frame, ms.
        #[arg(long, default_value_t = KcorParams::default().exposure_s * 1e3)]
        exposure_ms: f64,
        /// Grid steps in I (Q gets twice as many, from -I to I).
        #[arg(long, default_value_t = KcorParams::default().steps)]
        steps: usize,
        /// Relative Gaussian noise on the histogram the LUT is built from.
        #[arg(long, default_value_t = KcorParams::default().lut_noise)]
        lut_noise: f64,
        /// LUT to apply (any format: LUT FITS, device image, K-Cor table; default: the true widths with --lut-noise).
        #[arg(long)]
        lut: Option<PathBuf>,
        /// With --lut: the histogram set the LUT was built from. Also runs the limit its
        /// counts allow (the true widths with 1/sqrt(counts) noise a code, median of 5
        /// draws) and says how much of it the LUT reaches, at this run's --q-fraction
        /// (0.01 for the figure `adc` and `lut build --truth` print).
        #[arg(long, requires = "lut", value_name = "H.fits")]
        limit_from: Option<PathBuf>,
        /// Largest |Q| of the grid as a fraction of the brightest I.
        #[arg(long, default_value_t = KcorParams::default().q_fraction)]
        q_fraction: f64,
        /// Seed of that noise.
        #[arg(long, default_value_t = KcorParams::default().seed)]
        seed: u64,
        /// Noise realizations of the LUT (seeds SEED, SEED+1, ...): the reduction's spread
        /// over draws; the figures show the first.
        #[arg(long, default_value_t = 1)]
        realizations: usize,
        /// Folder for the figures kcor_raw.png and kcor_lut.png.
        #[arg(short, long)]
        out: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Pixel-wise nonlinearity (paper section 5, Fig. 8) of a linearity set.
    Linearity {
        /// The linearity set (FITS, as `simulate linearity` writes or astropy).
        file: PathBuf,
        /// Order of the pixel-wise polynomial (the paper: 4).
        #[arg(long, default_value_t = 4)]
        order: usize,
        /// Level used as the flat (gain), 1 to levels - 1 (default: nearest half the
        /// maximum reference; the paper's Figs. 6-7 flat is near 57%, level 22 of 0-40).
        #[arg(long)]
        flat_level: Option<usize>,
        /// Also score the pixel-wise correction of these orders on levels it was not
        /// fitted to (fitted on the even levels, scored on the odd), e.g. `--held-out
        /// 3,4,5,6`: whether a higher order helps, on data it did not see.
        #[arg(long, value_delimiter = ',', num_args = 1..)]
        held_out: Vec<usize>,
        /// Folder for coefficients.fits, corrected.fits and the figures (Figs. 6-8).
        #[arg(short, long)]
        out: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// What the baseline simulation gets wrong in measured data: findings, held-out gains.
    Diagnose {
        /// Measured data: histogram sets, linearity sets (FITS) and EMVA 1288 descriptors.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        #[command(flatten)]
        flatten: FlattenArgs,
        /// Seed of the held-out split.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Read a linearity set from its file this many rows at a time instead of holding
        /// it (the same diagnosis in less memory; automatic where the set held whole would
        /// not fit --max-memory). A compressed set, or one with scaled cubes, is held.
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
        block_rows: Option<u64>,
        /// Keep a linearity set's per-pixel records (each pixel's fits and scores, about
        /// 300 bytes a pixel) in temporary files, a block per thread in memory (the same
        /// diagnosis; automatic where they would not fit --max-memory). TMPDIR says where.
        #[arg(long)]
        spill: bool,
        /// Report folder (one subfolder per input when several).
        #[arg(short, long)]
        out: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Quantization bias of averaged readouts (paper section 2).
    Quantization {
        /// Noise rms, DN: print the worst-case bias over lambda mod 1.
        #[arg(long)]
        sigma: Option<f64>,
        /// Noise as read noise in electrons (with --gain-e-per-dn) instead of --sigma.
        #[arg(long, requires = "gain_e_per_dn", conflicts_with = "sigma")]
        read_noise_e: Option<f64>,
        /// Conversion gain, e-/DN, for --read-noise-e.
        #[arg(long)]
        gain_e_per_dn: Option<f64>,
        /// Worst-case bias target, DN: print the smallest noise that meets it.
        #[arg(long)]
        bias: Option<f64>,
        /// Write the paper's Fig. 1 (|delta| over lambda mod 1 and sigma) as a PNG.
        #[arg(long)]
        figure: Option<PathBuf>,
        /// Monte Carlo readouts for the check at the worst lambda.
        #[arg(long, default_value_t = 1_000_000)]
        samples: u64,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// The EMVA 1288 datasheet of a measured set: gain, QE, dark noise, saturation, SNR,
    /// sensitivity threshold, dynamic range, linearity, dark current, DSNU, PRNU, defects.
    Emva {
        /// The set's descriptor (EMVA1288_Data.txt); its images must lie inside its folder.
        descriptor: PathBuf,
        /// The standard's release whose definitions apply: 3.1 or 4.0 (default: the
        /// descriptor's `v` record; 3.1 when it has none).
        #[arg(long, value_parser = dncal_host::analyses::emva::Release::parse)]
        release: Option<dncal_host::analyses::emva::Release>,
        /// Write the datasheet (datasheet.html with its plots, datasheet.json) here.
        #[arg(short, long)]
        out: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Size the frame-grabber datapath for a camera system (default: the K-Cor's two
    /// 1024 x 1024 cameras at 150 frames/s), measured in the cycle-level FPGA model at 1,
    /// 2, 4 and 8 taps; optionally write a LUT FITS file as `$readmemh` files.
    FpgaSize {
        /// Cameras (one datapath each).
        #[arg(long, default_value_t = 2)]
        cameras: u32,
        /// Frame width and height, pixels.
        #[arg(long, default_value_t = 1024)]
        size: u16,
        /// Frames per second per camera.
        #[arg(long, default_value_t = 150.0)]
        frame_rate: f64,
        /// Modulation states (sum banks).
        #[arg(long, default_value_t = 4)]
        states: u8,
        /// Input FIFO depth, pixels (taps, blanking and memory bandwidth are set per row).
        #[arg(long, default_value_t = dncal_fpga_model::Config::default().fifo_depth)]
        fifo_depth: usize,
        /// Sum-memory latency, cycles.
        #[arg(long, default_value_t = dncal_fpga_model::Config::default().mem_latency)]
        mem_latency: u32,
        /// LUT (any format: LUT FITS, device image, K-Cor table) to write as `$readmemh` files (with --out).
        #[arg(long, value_name = "LUT", requires = "out")]
        lut: Option<PathBuf>,
        /// Folder for the `$readmemh` files.
        #[arg(short, long, requires = "lut")]
        out: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Speed as ratios against references run in the same process (issue 17's targets).
    Bench {
        /// Runs; each times every variant once.
        #[arg(long, default_value_t = 7)]
        runs: usize,
        /// Frames of 1024 x 1024 pixels per timing (the parallel path clears its sums once
        /// per timing, as a DAQ does once per readout: few frames weigh that clear more).
        #[arg(long, default_value_t = 32)]
        frames: usize,
        /// Leave numpy out.
        #[arg(long)]
        no_numpy: bool,
        /// A Python interpreter that imports the `dncal` package (a release wheel, as
        /// `scripts/python-bench.sh` installs into target/python-bench-venv): adds the
        /// package's rows, `Corrector.add` against the core and `fit_linearity` against
        /// `linearity`'s analysis, from python/bench/speed.py.
        #[arg(long, value_name = "PYTHON")]
        python: Option<PathBuf>,
        /// Also run the whole commands against issue 17's limits: `linearity` on a 1024 x
        /// 1024 x 41-level set, `diagnose` on 2048 x 2048 x 41 (3.4 GB of FITS simulated in
        /// TMPDIR first) and the demo, each its own process, wall time and peak memory
        /// (about 8 minutes at these sizes on 2 cores).
        #[arg(long)]
        whole: bool,
        /// Side of the `linearity` set of --whole, pixels (limits checked at 1024 only).
        #[arg(long, default_value_t = dncal_host::checks::bench::whole::LINEARITY_SIDE, requires = "whole")]
        linearity_side: usize,
        /// Side of the `diagnose` set of --whole, pixels (limits checked at 2048 only).
        #[arg(long, default_value_t = dncal_host::checks::bench::whole::DIAGNOSE_SIDE, requires = "whole")]
        diagnose_side: usize,
        /// Fail (exit 1) where a row's median ratio is more than 25% below the floor
        /// recorded for it (host-sim/src/checks/bench/ratchet.rs; rows against a fixed
        /// reference are reported, not checked).
        #[arg(long)]
        check: bool,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Run the core on the Cortex-M4 firmware in QEMU and on the host; compare the sums.
    FirmwareCheck {
        /// Frames per modulation state.
        #[arg(long, default_value_t = 8)]
        frames_per_state: u32,
        /// Modulation states.
        #[arg(long, default_value_t = 4)]
        states: u8,
        /// Line width and frame height, pixels (the firmware takes at most 64 x 64 x 4 sums).
        #[arg(long, default_value_t = 64)]
        size: u16,
        /// Seed of the synthetic LUTs and lines.
        #[arg(long, default_value_t = 2018)]
        seed: u64,
        /// Have QEMU count every instruction the firmware executes (seconds instead of a
        /// fraction of one), and print them per pixel by place in the source.
        #[arg(long)]
        count_instructions: bool,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Shell completions on stdout: `dncal completions bash > /etc/bash_completion.d/dncal`
    /// (or `~/.local/share/bash-completion/completions/dncal`; zsh: a file `_dncal` in `$fpath`).
    Completions {
        /// bash, elvish, fish, powershell or zsh.
        shell: clap_complete::Shell,
    },
    /// The manual page (roff) on stdout, `man -l <(dncal man)`; with `-o DIR`, one page per
    /// command and subcommand (dncal.1, dncal-lut-build.1, ...) written into DIR.
    Man {
        /// Folder for every page (created; the pages are published together).
        #[arg(short, long)]
        out: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
pub(crate) enum SimulateCmd {
    /// Per-ADC code histograms of illumination ramps (a histogram set).
    Histograms {
        #[command(flatten)]
        camera: CameraArgs,
        #[command(flatten)]
        ramp: RampArgs,
        /// Output FITS file.
        #[arg(short, long)]
        out: PathBuf,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Mean and standard deviation frames at illumination levels (a linearity set).
    Linearity {
        #[command(flatten)]
        camera: CameraArgs,
        /// Illumination levels, the first dark.
        #[arg(long, default_value_t = 41)]
        levels: usize,
        /// Frames per level.
        #[arg(long, default_value_t = 256)]
        frames: u32,
        /// ROI as WIDTHxHEIGHT+COLUMN+ROW (default: 128x128 at the sensor center); COLUMN a
        /// multiple of the camera's ADCs, so that the set's column c is ADC c mod NADC's.
        #[arg(long)]
        roi: Option<RoiSpec>,
        /// Seed of the frames.
        #[arg(long, default_value_t = 41)]
        seed: u64,
        /// Output FITS file.
        #[arg(short, long)]
        out: PathBuf,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
pub(crate) enum LutCmd {
    /// Flatten a histogram set into LUTs: writes the LUT FITS and the device image.
    Build {
        /// Histogram set (FITS).
        hist: PathBuf,
        /// Output: OUT.fits (LUT) and OUT.bin (device image); OUT may end in .fits.
        #[arg(short, long)]
        out: PathBuf,
        #[command(flatten)]
        flatten: FlattenArgs,
        /// The camera the histograms were simulated with (TOML, e.g. `[adc] widths_from =
        /// "kcor:..."`): also compare each LUT with its true ADC and judge it by the
        /// paper's Fig. 5 (|Q| <= 0.01 I_max) beside the limit its counts allow.
        #[arg(long, value_name = "TOML")]
        truth: Option<PathBuf>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Read the K-Coronagraph's deployed tables (4096 little-endian u32 per ADC, ending at
    /// 2^22 - 1 or 2^23 - 1): writes our LUT FITS (with the code widths) and device image.
    Import {
        /// The four tables of ADC 0-3, or one prefix (the files starting with it and
        /// containing adc0 .. adc3) or path with {adc} in it.
        #[arg(long, required = true, num_args = 1..=4, value_name = "FILE")]
        kcor: Vec<String>,
        /// Output: OUT.fits (LUT) and OUT.bin (device image); OUT may end in .fits.
        #[arg(short, long)]
        out: PathBuf,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Write a LUT FITS (from `lut build` or `lut import`) as the four files a K-Cor DAQ
    /// loads: PREFIX_adc0.bin .. PREFIX_adc3.bin (or PREFIX with {adc} replaced).
    Export {
        /// LUT FITS.
        lut: PathBuf,
        /// The file format to write.
        #[arg(long, value_enum)]
        format: ExportFormat,
        /// Output prefix.
        #[arg(short, long)]
        out: String,
        /// Scaling: the last entry is 2^BITS - 1 (22 or 23); default the imported
        /// tables' own, else 23.
        #[arg(long)]
        bits: Option<u32>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Write a LUT in another format: our LUT FITS, the device image or the K-Cor
    /// tables (the input's format is read from its bytes).
    Convert {
        /// LUT in any format: LUT FITS, device image, or one of a camera's K-Cor tables
        /// (its name says its ADC, adc0 .. adc3; the other three are found beside it).
        lut: PathBuf,
        /// The format to write.
        #[arg(long, value_enum)]
        to: LutFormatArg,
        /// Output: OUT.fits, OUT.bin (OUT may end in .fits for the LUT FITS), or the K-Cor
        /// tables OUT_adc0.bin .. OUT_adc3.bin (OUT with {adc} replaced, if it has it).
        #[arg(short, long)]
        out: PathBuf,
        /// K-Cor scaling: the last entry is 2^BITS - 1 (22 or 23); default the imported
        /// tables' own, else 23.
        #[arg(long)]
        bits: Option<u32>,
        /// Print a JSON summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Show the tables, steps (each the mean width of two neighbouring codes) and
    /// cumulative offsets of a LUT in any format (LUT FITS, device image, K-Cor tables).
    Inspect {
        /// LUT FITS, device image, or one of a camera's K-Cor tables.
        file: PathBuf,
        /// Also list every code (code, entry, DN, step, offset) in the readable output.
        #[arg(long)]
        table: bool,
        /// Print a JSON summary on stdout (with every table).
        #[arg(long)]
        json: bool,
    },
}
