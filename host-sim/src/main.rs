//! `dncal`: the command people run. Library code returns `HostError`; this file parses
//! arguments, prints a readable or JSON (`--json`) summary, and turns errors into a
//! message on stderr and a nonzero exit.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use dncal_core::{Geometry, Mvd1024eLuts};
use dncal_host::camera::calibration::{LinearityParams, RampParams};
use dncal_host::camera::{Camera, CameraConfig};
use dncal_host::commands::{adc, bench, demo, diagnose, kcor, linearity, lut, quantization, simulate, stream};
use dncal_host::firmware::{build_firmware, run_firmware, run_on_host, RunInputs};
use dncal_host::flatten::FlattenParams;
use dncal_host::outputs::{OutDir, Outputs};
use dncal_host::roi::RoiSpec;
use dncal_host::streaming::StreamParams;
use dncal_host::synth::{dn_error_weights, synthetic_frames, Rng};
use dncal_host::HostError;
use serde::Serialize;

#[derive(Parser)]
#[command(name = "dncal", version, about = "Real-time correction and characterization of scientific camera detectors")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
    /// Memory budget: a file or config whose sizes would make a step need more is refused
    /// before anything is allocated (bytes, or K, M, G, T: powers of 1024). Default: 3/4 of
    /// the machine's physical memory.
    #[arg(long, global = true, value_name = "SIZE", value_parser = dncal_host::budget::parse_size)]
    max_memory: Option<u64>,
    /// No stage lines or progress bars on stderr (they show only on a terminal anyway).
    #[arg(long, short, global = true)]
    quiet: bool,
}

/// The datapaths `stream` can drive.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
enum EngineKind {
    /// The correction core, as the MCU runs it.
    Core,
    /// The cycle-level frame-grabber model, configured over SPI by the core's driver and
    /// compared with the core sum by sum.
    Fpga,
}

/// Which datapath `stream` drives. The FPGA model's settings apply to it alone: given
/// with `--engine core` they are refused, not ignored.
#[derive(Args, Debug, Clone)]
struct EngineArgs {
    /// The datapath.
    #[arg(long, value_enum, default_value_t = EngineKind::Core)]
    engine: EngineKind,
    /// FPGA: pixels per clock, 1 to 8 [default: 4].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    taps: Option<usize>,
    /// FPGA: input FIFO depth, pixels [default: 1024].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    fifo_depth: Option<usize>,
    /// FPGA: sum-memory latency, cycles [default: 32].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    mem_latency: Option<u32>,
    /// FPGA: sum-memory bandwidth, 32-bit words per clock (a pixel needs 2) [default: 8].
    #[arg(long, help_heading = "FPGA model (--engine fpga)")]
    mem_words_per_cycle: Option<u32>,
}

impl EngineArgs {
    fn engine(&self) -> Result<dncal_host::streaming::Engine, HostError> {
        let fpga_flags = [("--taps", self.taps.is_some()), ("--fifo-depth", self.fifo_depth.is_some()), ("--mem-latency", self.mem_latency.is_some()), ("--mem-words-per-cycle", self.mem_words_per_cycle.is_some())];
        match self.engine {
            EngineKind::Core => match fpga_flags.iter().find(|f| f.1) {
                Some((flag, _)) => Err(HostError::argument(*flag, "applies to the FPGA model only: add --engine fpga")),
                None => Ok(dncal_host::streaming::Engine::Core),
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
                Ok(dncal_host::streaming::Engine::Fpga(config))
            }
        }
    }
}

#[derive(Args, Clone)]
struct CameraArgs {
    /// Camera parameters (TOML; any field of the default MV-D1024E may be set), or the
    /// model file `dncal diagnose -o DIR` writes (DIR/model.toml).
    #[arg(long, visible_alias = "model", value_name = "TOML")]
    config: Option<PathBuf>,
}

impl CameraArgs {
    fn camera(&self) -> Result<Camera, HostError> {
        match &self.config {
            Some(path) => simulate::camera_from(CameraConfig::from_toml_file(path)?, &path.display().to_string()),
            None => simulate::camera_from(CameraConfig::default(), "default camera"),
        }
    }
}

#[derive(Args, Clone)]
struct FlattenArgs {
    /// Points of the smoothing spline.
    #[arg(long, default_value_t = 50)]
    spline_points: usize,
    /// Width of the running median, codes (odd).
    #[arg(long, default_value_t = 21)]
    median_window: usize,
    /// Lowest codes set to 1.
    #[arg(long, default_value_t = 150)]
    fixed_low_codes: usize,
    /// Keep the last (saturation) code's measured weight instead of setting it to 1.
    #[arg(long)]
    keep_last: bool,
}

impl FlattenArgs {
    fn params(&self) -> FlattenParams {
        FlattenParams { spline_points: self.spline_points, median_window: self.median_window, fixed_low_codes: self.fixed_low_codes, set_last_to_one: !self.keep_last, ..FlattenParams::default() }
    }
}

#[derive(Args, Clone)]
struct RampArgs {
    /// Levels of the first ramp; ramps of this many, one more, ... up to --last-ramp.
    #[arg(long, default_value_t = 130)]
    first_ramp: usize,
    /// Levels of the last ramp.
    #[arg(long, default_value_t = 139)]
    last_ramp: usize,
    /// Pixels of each ADC in the region (256 x 256 pixels / 4 ADCs by default).
    #[arg(long, default_value_t = RampParams::default().pixels_per_adc)]
    pixels_per_adc: u64,
    /// Frames per level.
    #[arg(long, default_value_t = RampParams::default().frames_per_level)]
    frames_per_level: u64,
    /// Relative rms spread of the pixels' mean signal across the region (gamma distributed).
    #[arg(long, default_value_t = RampParams::default().field_spread)]
    field_spread: f64,

    /// Seed of the counts.
    #[arg(long, default_value_t = 4)]
    seed: u64,
}

impl RampArgs {
    fn params(&self) -> Result<RampParams, HostError> {
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
enum Cmd {
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
        #[arg(long, default_value_t = 3)]
        adc: usize,
        /// Exposure time of one frame, ms.
        #[arg(long, default_value_t = 1.0)]
        exposure_ms: f64,
        /// Grid steps in I (Q gets twice as many, from -I to I).
        #[arg(long, default_value_t = 100)]
        steps: usize,
        /// Relative Gaussian noise on the histogram the LUT is built from.
        #[arg(long, default_value_t = 0.01)]
        lut_noise: f64,
        /// LUT to apply (FITS or device image; default: the true widths with --lut-noise).
        #[arg(long)]
        lut: Option<PathBuf>,
        /// Largest |Q| of the grid as a fraction of the brightest I.
        #[arg(long, default_value_t = 1.0)]
        q_fraction: f64,
        /// Seed of that noise.
        #[arg(long, default_value_t = 2018)]
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
        #[arg(long, value_parser = dncal_host::emva::Release::parse)]
        release: Option<dncal_host::emva::Release>,
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
        #[arg(long, default_value_t = 1024)]
        fifo_depth: usize,
        /// Sum-memory latency, cycles.
        #[arg(long, default_value_t = 32)]
        mem_latency: u32,
        /// LUT FITS file to write as `$readmemh` files (with --out).
        #[arg(long, value_name = "FITS", requires = "out")]
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
enum SimulateCmd {
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
        /// ROI as WIDTHxHEIGHT+COLUMN+ROW (default: 128x128 at the sensor center).
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
enum LutCmd {
    /// Flatten a histogram set into LUTs: writes the LUT FITS and the device image.
    Build {
        /// Histogram set (FITS).
        hist: PathBuf,
        /// Output: OUT.fits (LUT) and OUT.bin (device image); OUT may end in .fits.
        #[arg(short, long)]
        out: PathBuf,
        #[command(flatten)]
        flatten: FlattenArgs,
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
        #[arg(long, value_parser = ["kcor"])]
        format: String,
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
    /// Show the tables, steps (each the mean width of two neighbouring codes) and
    /// cumulative offsets of a LUT FITS or device image.
    Inspect {
        /// LUT FITS or device image.
        file: PathBuf,
        /// Also list every code (code, entry, DN, step, offset) in the readable output.
        #[arg(long)]
        table: bool,
        /// Print a JSON summary on stdout (with every table).
        #[arg(long)]
        json: bool,
    },
}

fn print<T: Serialize>(json: bool, value: &T, text: impl FnOnce(&T) -> String) -> Result<(), HostError> {
    let out = if json {
        let mut s = serde_json::to_string_pretty(value).map_err(|e| HostError::Format { path: "stdout".into(), message: e.to_string() })?;
        s.push('\n');
        s
    } else {
        text(value)
    };
    to_stdout(out.as_bytes())
}

/// Writes `bytes` to stdout; a closed pipe (`dncal ... | head`) is the reader's choice,
/// not an error.
fn to_stdout(bytes: &[u8]) -> Result<(), HostError> {
    match std::io::stdout().lock().write_all(bytes) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(HostError::io("stdout", e)),
        _ => Ok(()),
    }
}

/// The datasheet as text: one quantity a line, `-` with the reason where the set does
/// not give it.
fn emva_text(descriptor: &std::path::Path, set: &dncal_host::emva::EmvaSet, s: &dncal_host::emva::Datasheet) -> String {
    let t = &s.temporal;
    let value = |key: &str, v: Option<f64>, unit: &str, digits: usize| match v {
        Some(v) => format!("{v:.digits$}{unit}"),
        None => format!("- ({})", s.why(key)),
    };
    let release = match t.release {
        dncal_host::emva::Release::R3 => "3.1",
        dncal_host::emva::Release::R4 => "4.0",
    };
    let sp = &s.spatial;
    let mut out = format!(
        "{}: {} bits, {}x{}, {} photon-transfer levels; EMVA 1288 Release {release} definitions (descriptor v {})\n",
        descriptor.display(),
        set.bits,
        set.width,
        set.height,
        t.levels,
        s.version.as_deref().unwrap_or("none")
    );
    for key in ["levels", "saturation"] {
        if let Some(note) = t.why.get(key) {
            out += &format!("note: {note}\n");
        }
    }
    out += &format!(
        "system gain K            {:.4} DN/e- ({:.3} e-/DN), {} levels up to 70% of saturation\n\
         responsivity R           {:.5} DN/photon\n\
         quantum efficiency       {:.1} %\n\
         dark noise               {:.3} DN (measured {:.3} DN) = {} \n\
         saturation               {:.1} DN above dark at {}\n\
         saturation capacity      {}\n\
         SNR max                  {} ({})\n\
         sensitivity threshold    {} ({})\n\
         dynamic range            {} ({})\n\
         linearity error          {} .. {}; mean |deviation| {}\n\
         dark current             {} (mean), {} (variance)\n\
         DSNU                     {} = {}; row {}, column {}, pixel {}\n\
         PRNU                     {}; row {}, column {}, pixel {}\n",
        t.gain_dn_per_e,
        t.gain_e_per_dn,
        t.gain_fit_levels,
        t.responsivity_dn_per_photon,
        100.0 * t.quantum_efficiency,
        t.dark_noise_dn,
        t.dark_noise_measured_dn,
        value("dark_noise_e", t.dark_noise_e, " e-", 2),
        t.saturation_dn,
        value("saturation_photons", t.saturation_photons, " photons", 0),
        value("saturation_capacity_e", t.saturation_capacity_e, " e-", 0),
        value("snr_max", t.snr_max, "", 1),
        value("snr_max_db", t.snr_max_db, " dB", 1),
        value("sensitivity_threshold_photons", t.sensitivity_threshold_photons, " photons", 2),
        value("sensitivity_threshold_e", t.sensitivity_threshold_e, " e-", 2),
        value("dynamic_range", t.dynamic_range, "", 0),
        value("dynamic_range_db", t.dynamic_range_db, " dB", 1),
        value("linearity_error_min_pct", t.linearity_error_min_pct, " %", 3),
        value("linearity_error_max_pct", t.linearity_error_max_pct, " %", 3),
        value("linearity_error_pct", t.linearity_error_pct, " %", 3),
        value("dark_current_mean_e_per_s", t.dark_current_mean_e_per_s, " e-/s", 2),
        value("dark_current_var_e_per_s", t.dark_current_var_e_per_s, " e-/s", 2),
        value("dsnu_dn", sp.dsnu_dn, " DN", 3),
        value("dsnu_e", sp.dsnu_e, " e-", 2),
        value("dsnu_row_e", sp.dsnu_row_e, " e-", 2),
        value("dsnu_col_e", sp.dsnu_col_e, " e-", 2),
        value("dsnu_pixel_e", sp.dsnu_pixel_e, " e-", 2),
        value("prnu_pct", sp.prnu_pct, " %", 3),
        value("prnu_row_pct", sp.prnu_row_pct, " %", 3),
        value("prnu_col_pct", sp.prnu_col_pct, " %", 3),
        value("prnu_pixel_pct", sp.prnu_pixel_pct, " %", 3),
    );
    out += &match &sp.defect_pixels {
        Some(d) => format!("defect pixels            hot {}, dead {}, high PRNU {} ({} in all; dncal's criteria, docs/emva.md)\n", d.hot, d.dead, d.high_prnu, d.total),
        None => format!("defect pixels            - ({})\n", s.why("defect_pixels")),
    };
    out
}

/// One `wrote PATH` line per file written.
fn wrote(paths: &[PathBuf]) -> String {
    paths.iter().map(|p| format!("wrote {}\n", p.display())).collect()
}

/// The readable lines of an ADC characterization.
fn adc_text(r: &adc::AdcReport) -> String {
    let mut t = String::new();
    for a in &r.adcs {
        t += &format!(
            "ADC {}: DN error {:.2}% rms per code, cumulative offset {:.3} DN peak to peak (max |offset| {:.3} DN, largest step {:.3} DN)\n",
            a.adc, a.width_rms_pct, a.offset_p2p_dn, a.lut.max_abs_offset_dn, a.max_offset_step_dn
        );
        if let Some(c) = &a.truth {
            t += &format!(
                "  vs the true ADC: widths {:.4} DN rms; code centers rms {:.4} DN raw -> {:.4} DN with LUT (max {:.3} -> {:.3})\n",
                c.width_err_rms_dn, c.rms_raw_dn, c.rms_lut_dn, c.max_raw_dn, c.max_lut_dn
            );
        }
    }
    t
}

/// Runs `command` with its output directory `dir`, if any, in a fresh set of outputs, and
/// publishes them: all files of the command or, if it fails, none.
fn staged<T>(dir: Option<&Path>, command: impl FnOnce(Option<OutDir<'_>>) -> Result<T, HostError>) -> Result<T, HostError> {
    let mut files = Outputs::new();
    let result = command(dir.map(|d| OutDir::new(&mut files, d)))?;
    files.publish()?;
    Ok(result)
}

/// [`staged`] for a command that always has an output directory.
fn staged_in<T>(dir: &Path, command: impl FnOnce(OutDir<'_>) -> Result<T, HostError>) -> Result<T, HostError> {
    let mut files = Outputs::new();
    let result = command(OutDir::new(&mut files, dir))?;
    files.publish()?;
    Ok(result)
}

fn main() -> ExitCode {
    let cli = match parse() {
        Ok(cli) => cli,
        Err(e) => return usage_error(e),
    };
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("dncal: error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

/// The command line as clap reads it, negative numbers taken as values everywhere
/// (`--sigma -1`, not an unknown flag `-1`).
fn command() -> clap::Command {
    fn negatives(c: clap::Command) -> clap::Command {
        c.allow_negative_numbers(true).mut_subcommands(negatives)
    }
    negatives(<Cli as clap::CommandFactory>::command())
}

fn parse() -> Result<Cli, clap::Error> {
    let matches = command().try_get_matches()?;
    dncal_host::fits::record_parameters(effective_parameters(&matches));
    <Cli as clap::FromArgMatches>::from_arg_matches(&matches)
}

/// Every argument's value as the command runs with it, defaults included and marked:
/// `subcommand: name=value name=value (default) ...`, for the FITS files' HISTORY (the
/// command line alone does not say what the defaults were).
fn effective_parameters(matches: &clap::ArgMatches) -> String {
    let (mut path, mut parts) = (Vec::new(), Vec::new());
    // A global argument (`--quiet`, `--max-memory`) is in every level's matches: once.
    let mut seen = std::collections::HashSet::new();
    let mut m = matches;
    loop {
        for id in m.ids().filter(|id| seen.insert(id.as_str().to_string())) {
            // A group's id has no values of its own (an error here, not a panic).
            let Ok(Some(values)) = m.try_get_raw(id.as_str()) else { continue };
            let values: Vec<String> = values.map(|v| v.to_string_lossy().into_owned()).collect();
            let default = m.value_source(id.as_str()) == Some(clap::parser::ValueSource::DefaultValue);
            parts.push(format!("{id}={}{}", values.join(","), if default { " (default)" } else { "" }));
        }
        match m.subcommand() {
            Some((name, sub)) => {
                path.push(name.to_string());
                m = sub;
            }
            None => break,
        }
    }
    format!("{}: {}", path.join(" "), parts.join(" "))
}

/// `dncal man`: the top page on stdout, or every page into `out`.
fn man_pages(out: Option<&Path>) -> Result<(), HostError> {
    fn render(cmd: &clap::Command) -> Result<Vec<u8>, HostError> {
        let mut page = Vec::new();
        clap_mangen::Man::new(cmd.clone()).render(&mut page).map_err(|e| HostError::io("man page", e))?;
        Ok(page)
    }
    let mut cmd = command();
    cmd.build();
    let Some(dir) = out else {
        return to_stdout(&render(&cmd)?);
    };
    let mut files = dncal_host::outputs::Outputs::new();
    files.create_dir(dir)?;
    // Each subcommand's page is named by its path (`dncal-lut-build.1`), as git's are.
    fn walk(cmd: &clap::Command, name: String, dir: &Path, files: &mut dncal_host::outputs::Outputs) -> Result<(), HostError> {
        let named = cmd.clone().name(name.clone());
        files.write_bytes(&dir.join(format!("{name}.1")), render(&named)?)?;
        for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
            walk(sub, format!("{name}-{}", sub.get_name()), dir, files)?;
        }
        Ok(())
    }
    walk(&cmd, "dncal".into(), dir, &mut files)?;
    let written = files.publish()?;
    to_stdout(format!("wrote {} manual pages into {}\n", written.len(), dir.display()).as_bytes())
}

/// clap's help and version as clap prints them; its usage errors in the one-line format
/// of every other error, exit code 2 (bad data is exit 1), naming the subcommand whose
/// `--help` explains: `dncal: error: invalid value 'abc' for '--sigma <SIGMA>': invalid
/// float literal (see dncal quantization --help)`.
fn usage_error(e: clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
        let _ = e.print();
        return ExitCode::SUCCESS;
    }
    // A command given without its subcommand: its help, on stderr, exit 2 (as clap does).
    if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
        let _ = e.print();
        return ExitCode::from(2);
    }
    let text = e.render().to_string();
    // The error is what precedes the first blank line (a missing-arguments error lists
    // them on the lines below its first); the rest is usage and tips.
    let message: Vec<&str> = text.lines().take_while(|l| !l.trim().is_empty()).map(str::trim).collect();
    let message = message.join(" ");
    let message = message.trim_start_matches("error: ");
    // The subcommand path: the words of the command line that name subcommands.
    let mut cmd = command();
    let mut path = vec!["dncal".to_string()];
    // (`args_os`: an argument that is not Unicode must not panic here.)
    for word in std::env::args_os().skip(1) {
        let Some(sub) = word.to_str().and_then(|w| cmd.find_subcommand(w)).cloned() else { continue };
        path.push(sub.get_name().to_string());
        cmd = sub;
    }
    eprintln!("dncal: error: {message} (see {} --help)", path.join(" "));
    ExitCode::from(2)
}

fn run(cli: Cli) -> Result<ExitCode, HostError> {
    if let Some(bytes) = cli.max_memory {
        dncal_host::budget::set_limit(bytes);
    }
    dncal_host::commands::progress::set_quiet(cli.quiet);
    match cli.command {
        Cmd::Simulate { what: SimulateCmd::Histograms { camera, ramp, out, json } } => {
            let cam = camera.camera()?;
            let s = simulate::simulate_histograms(&cam, &ramp.params()?, out)?;
            print(json, &s, |s| format!("wrote {} ({} ADCs x {} codes, {} levels, {:.1} s)\n", s.output.display(), s.n_adc, 1u32 << s.bit_depth, s.levels, s.seconds))?;
        }
        Cmd::Simulate { what: SimulateCmd::Linearity { camera, levels, frames, roi, seed, out, json } } => {
            let cam = camera.camera()?;
            let paper = LinearityParams::paper(&cam);
            let roi = match roi {
                Some(r) => {
                    let (w, h, x, y) = r.parts();
                    (x, y, w, h)
                }
                None => paper.roi,
            };
            let p = LinearityParams { levels, frames, roi, seed, ..paper };
            let s = simulate::simulate_linearity(&cam, &p, out)?;
            print(json, &s, |s| format!("wrote {} ({}x{} pixels, {} levels x {} frames, {} masked, {:.1} s)\n", s.output.display(), s.width, s.height, s.levels, s.frames, s.masked_pixels, s.seconds))?;
        }
        Cmd::Lut { what: LutCmd::Build { hist, out, flatten, json } } => {
            let s = lut::build(&hist, &out, &flatten.params())?;
            print(json, &s, |s| {
                let mut t = format!("read {}\nwrote {} and {}\n", s.input.display(), s.lut_fits.display(), s.device_image.display());
                t += "(code widths: each code's normalized width, the LUT's weights; `lut inspect` shows entry steps, the mean width of two neighbouring codes, a narrower range)\n";
                for a in &s.adcs {
                    t += &format!(
                        "ADC {}: code widths {:.4}..{:.4} DN, max |cumulative offset| {:.3} DN, top offset {:+.4} DN before normalization, {:+.2e} DN after, top entry {}\n",
                        a.adc, a.weight_range.0, a.weight_range.1, a.max_abs_offset_dn, a.top_offset_before_dn, a.top_offset_dn, a.top_entry
                    );
                }
                t
            })?;
        }
        Cmd::Lut { what: LutCmd::Import { kcor, out, json } } => {
            let s = lut::import_kcor(&kcor, &out)?;
            print(json, &s, |s| {
                let mut t = format!("read {} K-Cor tables (last entry 2^{} - 1)\nwrote {} and {}\n", s.inputs.len(), s.kcor_bits, s.lut_fits.display(), s.device_image.display());
                for a in &s.adcs {
                    t += &format!("ADC {}: K-Cor steps {:.4}..{:.4} DN, top entry {}, largest rounding {:.2e} DN\n", a.adc, a.step_range.0, a.step_range.1, a.top_entry, a.max_rounding_dn);
                }
                t
            })?;
        }
        Cmd::Lut { what: LutCmd::Export { lut: file, format: _, out, bits, json } } => {
            let s = lut::export_kcor(&file, &out, bits)?;
            print(json, &s, |s| format!("read {}\nwrote {} (K-Cor tables, last entry 2^{} - 1)\n", s.input.display(), s.outputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "), s.kcor_bits))?;
        }
        Cmd::Lut { what: LutCmd::Inspect { file, table, json } } => {
            let s = lut::inspect(&file)?;
            print(json, &s, |s| {
                let mut t = format!("{} ({}, {} bits, {} ADCs)\n", s.path.display(), s.kind, s.bit_depth, s.adcs.len());
                t += "(entry steps: entry k+1 - entry k, the mean width of codes k and k+1; `lut build` reports the single-code widths, a wider range)\n";
                for a in &s.adcs {
                    t += &format!("ADC {}: entry steps {:.4}..{:.4} DN, max |cumulative offset| {:.3} DN, top entry {}\n", a.adc, a.step_range.0, a.step_range.1, a.max_abs_offset_dn, a.entries.last().copied().unwrap_or(0));
                    if table {
                        t += "  code      entry          DN     step   offset\n";
                        for k in 0..a.entries.len() {
                            let step = if k == 0 { f64::NAN } else { a.step_dn[k - 1] };
                            t += &format!("  {k:4} {:10} {:11.5} {:8.5} {:+8.5}\n", a.entries[k], dncal_core::units_to_dn(a.entries[k].into()), step, a.cumulative_offset_dn[k]);
                        }
                    }
                }
                t
            })?;
        }
        Cmd::Stream { camera, hist, flatten, frames, states, roi, seed, frames_from, engine, json } => {
            let cam = camera.camera()?;
            let mut p = StreamParams::full_frame(&cam, frames);
            p.states = states;
            p.seed = seed;
            p.engine = engine.engine()?;
            let fit = |what: &str, v: usize| u16::try_from(v).map_err(|_| HostError::Format { path: what.into(), message: format!("{v} does not fit 16 bits") });
            if let Some(r) = roi {
                let (w, h, x, y) = r.parts();
                (p.width, p.height, p.first_column, p.first_row) = (fit("--roi", w)?, fit("--roi", h)?, fit("--roi", x)?, fit("--roi", y)?);
            }
            if let Some(path) = frames_from {
                let cube = dncal_host::fits::read_frames(&path)?;
                if p.first_column as usize + cube.width > cam.config.width || p.first_row as usize + cube.height > cam.config.height {
                    return Err(HostError::Format { path, message: format!("{}x{} frames at ({}, {}) do not fit the {}x{} sensor", cube.width, cube.height, p.first_column, p.first_row, cam.config.width, cam.config.height) });
                }
                p.width = fit("--frames-from", cube.width)?;
                p.height = fit("--frames-from", cube.height)?;
                p.frames = u32::try_from(cube.frames).map_err(|_| HostError::Format { path: path.clone(), message: "too many frames".into() })?;
                p.recorded = Some(std::sync::Arc::new(cube));
            }
            let r = stream::stream(&cam, hist.as_deref(), &flatten.params(), &p)?;
            print(json, &r, dncal_host::streaming::StreamReport::text)?;
            return Ok(if r.passed() { ExitCode::SUCCESS } else { ExitCode::FAILURE });
        }
        Cmd::Adc { from_luts, out, json, .. } if !from_luts.is_empty() => {
            let r = staged_in(&out, |o| adc::from_luts(&from_luts, o))?;
            print(json, &r, |r| {
                let mut t = String::from("camera                               ADC  DN error  max |offset|  trend bow  period  stage fit (held out): 1x12 2x6 3x4 4x3 4+8\n");
                for a in &r.adcs {
                    let fits: Vec<String> = a.stage_fits.iter().map(|f| format!("{:.2}", f.held_out_explained)).collect();
                    let period = a.period_codes.map_or("-".to_string(), |p| p.to_string());
                    t += &format!("{:36} {:3}  {:6.2} %  {:8.3} DN  {:7.1} DN  {period:>6}  {}\n", a.camera, a.adc, a.dn_error_rms_pct, a.offset_max_dn, a.trend_bow_dn, fits.join(" "));
                }
                if let (Some(s), Some(o)) = (r.mean_correlation_same_camera, r.mean_correlation_other_cameras) {
                    t += &format!("DN-error correlation: {s:.3} between ADCs of one camera, {o:.3} across cameras\n");
                }
                t + &format!("figures: {}\n", r.figures.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "))
            })?;
        }
        Cmd::Adc { camera, hist, out, ramp, flatten, json, .. } => {
            let cam = camera.camera()?;
            let ramp = ramp.params()?;
            let (r, _) = staged_in(&out, |o| adc::run(&cam, hist.as_deref(), &ramp, &flatten.params(), o))?;
            print(json, &r, |r| {
                let mut t = format!("{}: {} ADCs\n", r.histograms.display(), r.adcs.len());
                t += &adc_text(r);
                t += &format!("figures: {}\n", r.figures.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
                t
            })?;
        }
        Cmd::KcorModel { camera, adc, exposure_ms, steps, lut_noise, lut, q_fraction, seed, realizations, out, json } => {
            let cam = camera.camera()?;
            let p = dncal_host::kcor::KcorParams { adc, exposure_s: exposure_ms * 1e-3, steps, lut_noise, q_fraction, seed, ..Default::default() };
            let spin = dncal_host::commands::progress::spinner(&format!("K-Coronagraph model: ADC {adc}, {steps} steps of the Stokes map, {realizations} realization(s)"));
            let s = staged(out.as_deref(), |o| kcor::kcor_model(&cam, &p, lut.as_deref(), realizations, o));
            spin.finish_and_clear();
            let s = s?;
            print(json, &s, |s| {
                let r = &s.result;
                let mut t = format!(
                    "K-Cor model, ADC {}, {} ms frames: {:.4e} e-/s per B_sun per pixel, 1 DN in a state = {:.3e} B_sun in Q; I up to {:.3e} B_sun\n",
                    p.adc, exposure_ms, r.electrons_per_s_per_bsun, r.bsun_per_dn, r.i_max_bsun
                );
                t += &format!(
                    "max |systematic error in Q|: {:.3e} B_sun raw, {:.3e} B_sun with the LUT ({}): {:.1}x less\n",
                    r.max_abs_sys_err_bsun_raw, r.max_abs_sys_err_bsun_lut, s.lut_source, r.reduction
                );
                t += &format!(
                    "rms  |systematic error in Q|: {:.3e} B_sun raw, {:.3e} B_sun with the LUT: {:.1}x less\n",
                    r.rms_sys_err_bsun_raw, r.rms_sys_err_bsun_lut, r.rms_reduction
                );
                if !s.realizations.is_empty() {
                    let spread = |f: fn(&kcor::Realization) -> f64| {
                        let v: Vec<f64> = s.realizations.iter().map(f).collect();
                        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
                        (lo, dncal_host::stats::median(v), hi)
                    };
                    let (a, b, c) = spread(|x| x.reduction);
                    let (d, e, f) = spread(|x| x.rms_reduction);
                    t += &format!(
                        "over {} noise realizations: reduction of max |dQ| {a:.2}x / {b:.2}x / {c:.2}x, of rms dQ {d:.2}x / {e:.2}x / {f:.2}x (min / median / max)\n",
                        s.realizations.len()
                    );
                }
                t + &wrote(&s.figures)
            })?;
        }
        Cmd::Linearity { file, order, flat_level, out, json } => {
            let s = staged(out.as_deref(), |o| linearity::linearity(&file, order, flat_level, o))?;
            print(json, &s, |s| {
                let r = &s.report;
                let mut t = format!("{}: {} levels x {} pixels, gain level {}, {} masked, analysis {:.2} s\n", s.input.display(), r.levels, r.pixels, r.gain_level, r.masked_pixels, s.analysis_s);
                t += &format!(
                    "max RMS over levels: raw {:.3e}, standard {:.3e}, pixel-wise {:.3e}, random {:.3e}\n",
                    r.rms_raw_max, r.rms_standard_max, r.rms_pixelwise_max, r.rms_random_max
                );
                t + &wrote(&s.outputs)
            })?;
        }
        Cmd::Diagnose { files, flatten, seed, out, json } => {
            let several = files.len() > 1;
            let dirs: Vec<Option<PathBuf>> = (0..files.len()).map(|i| out.as_ref().map(|o| if several { o.join(format!("{i}")) } else { o.clone() })).collect();
            // One set for all inputs: a failure on the last leaves no report of the first.
            let mut staged = Outputs::new();
            for d in dirs.iter().flatten() {
                diagnose::expect_report(&mut staged, d)?;
            }
            let mut all = Vec::new();
            for (f, dir) in files.iter().zip(&dirs) {
                all.push(diagnose::diagnose(f, &flatten.params(), seed, dir.as_deref().map(|d| OutDir::new(&mut staged, d)))?);
            }
            staged.publish()?;
            let text = diagnose::DiagnoseSummary::text;
            if several {
                print(json, &all, |all| all.iter().map(text).collect::<String>())?;
            } else {
                print(json, &all[0], text)?;
            }
        }
        Cmd::Quantization { sigma, read_noise_e, gain_e_per_dn, bias, figure, samples, json } => {
            let sigma = match (sigma, read_noise_e, gain_e_per_dn) {
                (Some(s), _, _) => Some(s),
                (None, Some(r), Some(g)) if g > 0.0 => Some(r / g),
                (None, Some(_), Some(g)) => return Err(HostError::Argument { flag: "--gain-e-per-dn".into(), message: format!("{g} e-/DN must be > 0") }),
                _ => None,
            };
            if sigma.is_none() && bias.is_none() && figure.is_none() {
                return Err(HostError::argument("quantization", "give --sigma (or --read-noise-e with --gain-e-per-dn), --bias or --figure"));
            }
            if let Some(path) = &figure {
                dncal_host::outputs::write_one(|o| quantization::figure(o, path))?;
                if !json {
                    println!("wrote {}", path.display());
                }
            }
            // One JSON object per request; both requests give a combined object.
            let at = sigma.map(|s| quantization::at_sigma(s, samples, 1)).transpose()?;
            let needed = bias.map(quantization::for_bias).transpose()?;
            match (at, needed) {
                (Some(a), None) => print(json, &a, |a| {
                    let mut t = format!(
                        "noise {:.4} DN: worst-case bias {:.4e} DN at lambda mod 1 = {:.4}\n  Fourier series {:+.6e}, eq. 4 {:+.6e}, exact sum {:+.6e}, Monte Carlo {:+.6e} +- {:.1e} DN ({} readouts)\n",
                        a.sigma, a.max_abs_bias_dn, a.at_lambda_frac, a.fourier_bias_dn, a.erf_bias_dn, a.exact_bias_dn, a.monte_carlo_bias_dn, a.monte_carlo_se_dn, a.monte_carlo_samples
                    );
                    if a.sigma == 0.0 {
                        t += "  (without noise the bias is a sawtooth whose jump is at lambda mod 1 = 0.5: the worst case is the value beside the jump, which the other three give; a Fourier series converges to the middle of a jump, 0)\n";
                    }
                    t
                })?,
                (None, Some(b)) => print(json, &b, |b| format!("worst-case bias <= {} DN needs noise >= {:.4} DN\n", b.bias, b.sigma))?,
                (Some(a), Some(b)) => {
                    let both = serde_json::json!({ "at_sigma": a, "for_bias": b });
                    print(json, &both, |_| {
                        format!(
                            "noise {:.4} DN: worst-case bias {:.4e} DN at lambda mod 1 = {:.4}\nworst-case bias <= {} DN needs noise >= {:.4} DN\n",
                            a.sigma, a.max_abs_bias_dn, a.at_lambda_frac, b.bias, b.sigma
                        )
                    })?
                }
                (None, None) => {}
            }
        }
        Cmd::Emva { descriptor, release, out, json } => {
            let set = dncal_host::emva::read_descriptor(&descriptor)?;
            let spin = dncal_host::commands::progress::spinner(&format!("EMVA 1288 datasheet of {} ({} levels)", descriptor.display(), set.levels.len()));
            let sheet = dncal_host::emva::datasheet(&set, release);
            spin.finish_and_clear();
            let sheet = sheet?;
            let written = match &out {
                Some(dir) => dncal_host::emva::html::write_datasheet(dir, &descriptor, &sheet)?,
                None => Vec::new(),
            };
            print(json, &sheet, |s| emva_text(&descriptor, &set, s) + &wrote(&written))?;
        }
        Cmd::Completions { shell } => {
            // Into memory first: clap_complete panics on a failed write (a closed pipe).
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut command(), "dncal", &mut script);
            to_stdout(&script)?;
        }
        Cmd::Man { out } => man_pages(out.as_deref())?,
        Cmd::Demo { camera, out, frames, ramp, flatten, json } => {
            let cam = camera.camera()?;
            let s = demo::demo(&cam, &out, &ramp.params()?, &flatten.params(), frames)?;
            let ok = s.stream.passed() && s.stream_fpga.passed() && s.stream_fpga.fpga.is_some();
            print(json, &s, |s| {
                let mut t = format!("dncal demo on {}: {} ramp levels, {:.1} s\n", s.camera, s.ramp_levels, s.seconds);
                t += &format!(
                    "stream: {} frames, {} pixels, {} mismatches, max |error| {:.3e} DN (bound {:.3e}), core {:.3e} pixels/s\n",
                    s.stream.frames, s.stream.pixels, s.stream.mismatches, s.stream.max_abs_err_dn, s.stream.bound_dn, s.stream.pixels_per_s
                );
                if let Some(f) = &s.stream_fpga.fpga {
                    t += &format!("fpga model: {} frames, {} pixels, {} mismatches against the core, {} against the reference, {:.3} pixels per clock, {} dropped\n", s.stream_fpga.frames, s.stream_fpga.pixels, f.mismatches_vs_core, f.mismatches_vs_reference, f.pixels_per_clock, f.fifo_overflows);
                }
                t += &adc_text(&s.adc);
                for (what, d) in [("histograms", &s.diagnose), ("linearity set", &s.diagnose_linearity)] {
                    let names: Vec<String> = d.diagnosis.findings.iter().map(|f| format!("{}{} (gain {:.2})", f.effect, f.adc.map_or(String::new(), |a| format!(" ADC {a}")), f.gain)).collect();
                    t += &format!("diagnose {what}: {}\n", if names.is_empty() { "no finding".to_string() } else { names.join(", ") });
                }
                t += &format!("report: {}\n", s.report.display());
                t
            })?;
            return Ok(if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE });
        }
        Cmd::FpgaSize { cameras, size, frame_rate, states, fifo_depth, mem_latency, lut, out, json } => {
            let config = dncal_fpga_model::Config { fifo_depth, mem_latency, ..Default::default() };
            config.validate().map_err(|e| HostError::argument("--fifo-depth / --mem-latency", e.to_string()))?;
            if cameras == 0 {
                return Err(HostError::argument("--cameras", "must be at least 1"));
            }
            if !(frame_rate.is_finite() && frame_rate > 0.0) {
                return Err(HostError::argument("--frame-rate", format!("{frame_rate} Hz must be finite and > 0")));
            }
            if size == 0 || size > 8192 {
                return Err(HostError::argument("--size", format!("{size}: 1 to 8192 pixels (the model holds a frame's sums in memory)")));
            }
            // The core's bound on modulation states, said here with the option's name.
            if states == 0 || usize::from(states) > dncal_core::MAX_STATES {
                return Err(HostError::argument("--states", format!("{states}: 1 to {} modulation states", dncal_core::MAX_STATES)));
            }
            let system = dncal_fpga_model::sizing::System { cameras, width: size, height: size, frame_rate_hz: frame_rate, ..Default::default() };
            let r = dncal_host::commands::fpga::fpga_size(&system, states, &config, lut.as_deref(), out.as_deref())?;
            print(json, &r, |r| {
                let s = &r.sizing;
                let mut t = format!(
                    "{} camera(s) of {}x{} at {} frames/s: {:.1} Mpixel/s; sum memory {:.2} GB/s (a 32-bit read and write per pixel), {:.1} MiB per camera for {} states\n",
                    s.system.cameras, s.system.width, s.system.height, s.system.frame_rate_hz, s.pixels_per_s / 1e6, s.sum_bandwidth_bytes_per_s / 1e9, s.sum_memory_bytes as f64 / 1048576.0, states
                );
                for row in &s.taps {
                    t += &format!(
                        "{} taps: clock {:.1} MHz per camera, {} cycles per frame, {:.3} pixels/clock, latency {} cycles, FIFO high water {} ({} dropped), read-modify-writes in flight up to {}, LUT BRAM {} bits; {}\n",
                        row.taps, row.clock_mhz, row.cycles_per_frame, row.pixels_per_clock, row.latency_cycles, row.fifo_high_water, row.fifo_overflows, row.inflight_high_water, row.bram_bits, row.lut_access
                    );
                }
                for f in &r.readmemh {
                    t += &format!("wrote {}\n", f.display());
                }
                t
            })?;
        }
        Cmd::FirmwareCheck { frames_per_state, states, size, seed, json } => return firmware_check(frames_per_state, states, size, seed, json),
        Cmd::Bench { runs, frames, no_numpy, json } => {
            let pb = dncal_host::commands::progress::bar(runs as u64, "bench");
            let r = bench::bench(&bench::BenchParams { runs, frames, numpy: !no_numpy }, |_| pb.inc(1))?;
            pb.finish_and_clear();
            print(json, &r, |r| {
                let mut t = format!("{}; {} runs; ratios are per run (median, min-max)\n", r.machine, r.runs);
                for x in &r.ratios {
                    let target = x.target.map_or(String::new(), |g| format!("  target >= {g}: {}", if x.holds == Some(true) { "holds" } else { "NOT MET" }));
                    t += &format!(
                        "{:<22} {:>8.1} {}  vs {:<24} {:>8.1}: {:.2}x ({:.2}-{:.2}){target}\n",
                        x.name, x.rate, x.unit, x.baseline, x.baseline_rate, x.ratio_median, x.ratio_min, x.ratio_max
                    );
                }
                for n in &r.notes {
                    t += &format!("note: {n}\n");
                }
                t
            })?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn firmware_check(frames_per_state: u32, states: u8, size: u16, seed: u64, json: bool) -> Result<ExitCode, HostError> {
    let geometry = Geometry::new(size, size, states, 130).map_err(|e| HostError::core("geometry from --size/--states", e))?;
    let mut rng = Rng::new(seed);
    let weights: Vec<_> = (0..4).map(|_| dn_error_weights(&mut rng, 4096)).collect();
    let luts = Mvd1024eLuts::from_weights(&[&weights[0], &weights[1], &weights[2], &weights[3]]).map_err(|e| HostError::core("LUTs from weights", e))?;
    let frames = synthetic_frames(&mut rng, geometry, frames_per_state * states as u32, 1.5, 4096);
    let inputs = RunInputs { luts, geometry, frames, capture_histograms: true };
    let host = run_on_host(&inputs)?;
    let elf = build_firmware()?;
    let fw = run_firmware(&elf, &inputs, &host.outputs.sums, Duration::from_secs(600))?;
    let mismatches = fw.outputs.sums.iter().zip(&host.outputs.sums).filter(|(a, b)| a != b).count() + fw.outputs.sums.len().abs_diff(host.outputs.sums.len());
    let same_status = fw.outputs.status == host.outputs.status && fw.outputs.frames_per_state == host.outputs.frames_per_state;
    let same_hist = fw.outputs.histograms == host.outputs.histograms;
    let ok = mismatches == 0 && same_status && same_hist;
    if json {
        let summary = serde_json::json!({
            "pixels": host.outputs.sums.len(),
            "frames": inputs.frames.len(),
            "mismatches": mismatches,
            "status_equal": same_status,
            "histograms_equal": same_hist,
            "noise_sigma_dn": host.noise.as_ref().ok().map(|r| r.sigma_dn),
            "firmware_log": fw.log,
            "ok": ok,
        });
        println!("{summary:#}");
    } else {
        print!("{}", fw.stdout);
        println!("host: {} frames of {}x{} in {} states, {} sums", inputs.frames.len(), size, size, states, host.outputs.sums.len());
        println!("firmware vs host: {mismatches} sum mismatches, status equal: {same_status}, histograms equal: {same_hist}");
        for line in &fw.log {
            println!("firmware log: {line}");
        }
    }
    Ok(if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
