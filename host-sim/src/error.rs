//! The one error type of the host crate. Library code returns it; only the binary turns
//! it into a message and an exit code.

use std::path::PathBuf;

use dncal_core::CoreError;

/// What an error concerns where that is not a file: the run's parameters, a built-in
/// input, a check's own data. Printed as the label that names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Subject {
    /// `stream`'s ROI, frame count and recorded frames.
    StreamParameters,
    /// The weights `stream` hands the core.
    Weights,
    /// The weights `stream` hands the float reference.
    ReferenceWeights,
    /// The soak's parameters.
    SoakParameters,
    /// The soak's LUT sets.
    SoakLutPool,
    /// The FPGA model as the soak drives it.
    SoakFpga,
    /// The built-in MV-D1024E camera.
    DefaultCamera,
    /// The camera configuration a command was given (file or defaults).
    CameraConfig,
    /// A camera model's true code widths, as LUT weights.
    CameraAdcWidths,
    /// `simulate linearity`'s ROI, levels and frames.
    SimulateLinearityArguments,
    /// Simulated frames' region and light (the Python `simulate_frames`).
    SimulateFramesArguments,
    /// `dncal bench`'s own checks of what it timed.
    Bench,
    /// The LUT set `dncal bench` times.
    BenchLut,
    /// The frame geometry `dncal bench` times.
    BenchGeometry,
    /// The report printed on standard output.
    Stdout,
    /// The noisy LUT weights of the K-Coronagraph model (`kcor-model --lut-noise`).
    KcorLutWeights,
    /// The running `dncal` executable (`bench --whole` runs it again).
    DncalBinary,
    /// A man page as it is rendered (`dncal man`).
    ManPage,
}

impl std::fmt::Display for Subject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Subject::StreamParameters => "stream parameters",
            Subject::Weights => "weights",
            Subject::ReferenceWeights => "reference weights",
            Subject::SoakParameters => "soak parameters",
            Subject::SoakLutPool => "soak LUT pool",
            Subject::SoakFpga => "soak FPGA",
            Subject::DefaultCamera => "default camera",
            Subject::CameraConfig => "camera config",
            Subject::CameraAdcWidths => "camera ADC widths",
            Subject::SimulateLinearityArguments => "simulate linearity arguments",
            Subject::SimulateFramesArguments => "simulated frames arguments",
            Subject::Bench => "bench",
            Subject::BenchLut => "bench LUT",
            Subject::BenchGeometry => "bench geometry",
            Subject::Stdout => "stdout",
            Subject::KcorLutWeights => "K-Cor LUT weights",
            Subject::DncalBinary => "the dncal binary",
            Subject::ManPage => "man page",
        })
    }
}

/// An encoder's error, as the file it writes is wrapped around it.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// JSON (reports, summaries).
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// TOML (camera models).
    #[error(transparent)]
    Toml(#[from] toml::ser::Error),
}

/// What an error concerns where it may be a file or not: the file a LUT or camera was
/// read from, or a [`Subject`] (weights drawn by a model, the built-in camera).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Origin {
    /// A file.
    File(PathBuf),
    /// Not a file.
    Subject(Subject),
    /// An argument of a library call (the Python package's arrays), by its name.
    Argument(&'static str),
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Origin::File(path) => write!(f, "{}", path.display()),
            Origin::Subject(subject) => write!(f, "{subject}"),
            Origin::Argument(name) => f.write_str(name),
        }
    }
}

impl From<&std::path::Path> for Origin {
    fn from(path: &std::path::Path) -> Self {
        Origin::File(path.to_path_buf())
    }
}

impl From<&PathBuf> for Origin {
    fn from(path: &PathBuf) -> Self {
        Origin::File(path.clone())
    }
}

impl From<PathBuf> for Origin {
    fn from(path: PathBuf) -> Self {
        Origin::File(path)
    }
}

impl From<Subject> for Origin {
    fn from(subject: Subject) -> Self {
        Origin::Subject(subject)
    }
}

/// What kind of failure an error is, for callers that sort them (the Python package's
/// exception classes): the data or arguments, the file system, the memory budget, an
/// external program.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// Bad input: a file's or an argument's contents, a rule they break.
    Input,
    /// Reading or writing failed, or a path that cannot be read or written as asked.
    Io,
    /// The work would need more memory than the budget allows.
    OverBudget,
    /// A program the run needs (QEMU, numpy) failed or is missing.
    Tool,
}

/// An I/O error in the words of the rest of our messages: the system's text, its first
/// letter lower-case, without Rust's ` (os error N)` (`no such file or directory`).
fn io_text(e: &std::io::Error) -> String {
    let text = e.to_string();
    let text = match text.rfind(" (os error ") {
        Some(i) if text.ends_with(')') => &text[..i],
        _ => &text,
    };
    let mut chars = text.chars();
    match (chars.next(), chars.next()) {
        (Some(a), Some(b)) if a.is_ascii_uppercase() && b.is_ascii_lowercase() => a.to_ascii_lowercase().to_string() + &text[1..],
        _ => text.to_string(),
    }
}

/// Everything host-side work can fail with; each variant names the file or step.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    /// A file could not be read or written.
    #[error("{path}: {}", io_text(source))]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The core rejected something.
    #[error("{context}: {source}")]
    Core {
        /// What was being done.
        context: String,
        /// The core's error.
        source: CoreError,
    },
    /// A program the run needs failed or is missing.
    #[error("{program}: {message}")]
    Tool {
        /// The program.
        program: String,
        /// What happened.
        message: String,
    },
    /// An input that is not a regular file (a device, FIFO, socket or directory): reading
    /// it could block for ever or never end ([`crate::formats::input`]).
    #[error("{path}: is a {kind}, not a regular file")]
    NotRegular {
        /// The path given.
        path: PathBuf,
        /// What it is instead ("character device", "FIFO", "directory", ...).
        kind: &'static str,
    },
    /// An input larger than any file of its kind can be ([`crate::formats::input::SizeLimit`]).
    #[error("{path}: {len} bytes; {what} files are at most {limit} bytes")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size, bytes (at least `limit + 1` if it grew while read).
        len: u64,
        /// The kind of file, as in "camera config".
        what: &'static str,
        /// The kind's largest size, bytes.
        limit: u64,
    },
    /// An output path that names a directory, device or FIFO: an output file renamed over
    /// it would fail or replace it ([`crate::formats::outputs`]).
    #[error("{path}: is a {kind}; an output file cannot replace it")]
    OutputNotFile {
        /// The target.
        path: PathBuf,
        /// What it is ("directory", "FIFO", ...).
        kind: &'static str,
    },
    /// An output that is one of the command's inputs ([`crate::formats::same_file`]).
    #[error("{path}: is the input {input} (or a link to it); writing it would replace that input: name another output")]
    OutputIsInput {
        /// The output.
        path: PathBuf,
        /// The input, as it was named.
        input: PathBuf,
    },
    /// An output another run is writing now ([`crate::formats::outputs`]).
    #[error("{path}: another dncal run{} is writing this output now; run again when it has finished, or name another output", pid.map_or(String::new(), |p| format!(" (process {p})")))]
    Busy {
        /// The output.
        path: PathBuf,
        /// The process holding it, where its lock file says.
        pid: Option<u32>,
    },
    /// A step would need more memory than the budget ([`crate::infra::budget`], `--max-memory`).
    #[error("{origin}: {what} needs about {}, more than the memory budget of {} (--max-memory)", crate::infra::budget::human(*bytes), crate::infra::budget::human(*limit))]
    OverBudget {
        /// The file (or the built-in configuration) whose sizes ask for it.
        origin: Origin,
        /// What needs the memory.
        what: String,
        /// The estimate, bytes.
        bytes: u64,
        /// The budget, bytes.
        limit: u64,
    },
    /// A command-line value clap's types cannot judge alone (out of range for the data,
    /// or given with an option it does not apply to): a usage error, exit code 2.
    #[error("{flag}: {message}")]
    Argument {
        /// The option, as typed (`--order`).
        flag: String,
        /// What is wrong with its value.
        message: String,
    },
    /// The FPGA model refused its configuration or a frame.
    #[error("FPGA model: {source}")]
    Fpga {
        /// The model's error.
        #[source]
        source: dncal_fpga_model::FpgaError,
    },
    /// A camera configuration file (a TOML file, a model file) that cannot be built.
    #[error("{path}: {source}")]
    Config {
        /// The file.
        path: PathBuf,
        /// The rule it breaks.
        #[source]
        source: crate::model::camera::ConfigError,
    },
    /// A data set that cannot be diagnosed (too little of it, or what a test needs is
    /// missing).
    #[error("{path}: {source}")]
    Diagnose {
        /// The file.
        path: PathBuf,
        /// What is missing.
        #[source]
        source: crate::analyses::diagnose::DiagnoseError,
    },
    /// A linearity set that cannot be corrected as asked.
    #[error("{origin}: {source}")]
    Linearity {
        /// The file (or the arrays' argument).
        origin: Origin,
        /// Why.
        #[source]
        source: crate::analyses::linearity::LinearityError,
    },
    /// A photon-transfer set that cannot be characterized.
    #[error("{path}: {source}")]
    Ptc {
        /// The descriptor.
        path: PathBuf,
        /// Why.
        #[source]
        source: crate::analyses::emva::datasheet::PtcError,
    },
    /// Something that is not a file is not what it must be ([`Subject`]).
    #[error("{subject}: {message}")]
    Invalid {
        /// What it concerns.
        subject: Subject,
        /// What is wrong.
        message: String,
    },
    /// A camera configuration not from a file (built in, or a library call's argument)
    /// that cannot be built.
    #[error("{origin}: {source}")]
    BuiltInConfig {
        /// Which.
        origin: Origin,
        /// The rule it breaks.
        #[source]
        source: crate::model::camera::ConfigError,
    },
    /// Code widths that are not LUT weights (NaN, negative, 256 DN or more).
    #[error("{subject}: {source}")]
    Weights {
        /// Whose widths.
        subject: Subject,
        /// The code and width.
        #[source]
        source: crate::analyses::flatten::FlattenError,
    },
    /// The FPGA model refused what a check gave it.
    #[error("{subject}: {source}")]
    FpgaIn {
        /// The check.
        subject: Subject,
        /// The model's error.
        #[source]
        source: dncal_fpga_model::FpgaError,
    },
    /// A FITS data set whose contents break a rule of its format.
    #[error("{path}: {source}")]
    FitsContent {
        /// The file.
        path: PathBuf,
        /// The rule.
        #[source]
        source: crate::formats::fits::Fault,
    },
    /// Reading or writing something that is not a file failed (stdout, a rendering).
    #[error("{subject}: {}", io_text(source))]
    IoOf {
        /// What was read or written.
        subject: Subject,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A LUT set or camera of a shape the core is not built for.
    #[error("{origin}: {n_adc} ADCs of {codes} codes: the core is built for 1, 2, 4 or 8 ADCs of 8, 10, 12, 14 or 16 bits (8 ADCs up to 12 bits)")]
    UnsupportedDims {
        /// Whose shape.
        origin: Origin,
        /// ADCs.
        n_adc: usize,
        /// Codes per ADC.
        codes: usize,
    },
    /// A fault at a line of an EMVA 1288 descriptor (a record, an image it names, or the
    /// set's levels).
    #[error("{path}: line {line}: {fault}")]
    DescriptorLine {
        /// The descriptor.
        path: PathBuf,
        /// The line, from 1.
        line: usize,
        /// What is wrong.
        #[source]
        fault: crate::analyses::emva::DescriptorFault,
    },
    /// A fault of an EMVA 1288 descriptor or image not tied to one line.
    #[error("{path}: {fault}")]
    DescriptorFile {
        /// The descriptor, or the image.
        path: PathBuf,
        /// What is wrong.
        #[source]
        fault: crate::analyses::emva::DescriptorFault,
    },
    /// A file that must be text holds bytes that are not UTF-8.
    #[error("{path}: not UTF-8 text (byte {valid_up_to} is invalid)")]
    NotUtf8 {
        /// The file.
        path: PathBuf,
        /// The offset of the first invalid byte.
        valid_up_to: usize,
    },
    /// The illumination shared by a set's ADCs (the smooth density of their mean
    /// histogram) could not be fitted.
    #[error("{origin}: the illumination shared by the ADCs (fitted to their mean histogram): {source} (too few ramp levels or counts for a smooth illumination, or the fit starts below the data: more levels, a higher --fixed-low-codes, or --recipe paper)")]
    SharedFlatten {
        /// The histogram set.
        origin: Origin,
        /// Why.
        #[source]
        source: crate::analyses::flatten::FlattenError,
    },
    /// One ADC's histogram of a set could not be flattened into LUT weights.
    #[error("{origin}: ADC {adc}: {source}")]
    AdcFlatten {
        /// The histogram set.
        origin: Origin,
        /// The ADC.
        adc: usize,
        /// Why.
        #[source]
        source: crate::analyses::flatten::FlattenError,
    },
    /// One ADC's histogram of a set failed the IEEE 1241 histogram test.
    #[error("{path}: ADC {adc}: IEEE 1241 histogram test ({} density): {source}", .density.name())]
    Ieee1241 {
        /// The histogram set.
        path: PathBuf,
        /// The ADC.
        adc: usize,
        /// The input density the test assumed.
        density: crate::analyses::ieee1241::Density,
        /// Why.
        #[source]
        source: crate::analyses::ieee1241::TestError,
    },
    /// A report or model could not be encoded for the file it goes to.
    #[error("{path}: {source}")]
    Encode {
        /// The file.
        path: PathBuf,
        /// The encoder's error.
        #[source]
        source: EncodeError,
    },
    /// A camera configuration whose `adc.widths_from` tables are wrong (the tables' own
    /// error inside).
    #[error("{path}: adc.widths_from: {inner}")]
    WidthsFrom {
        /// The configuration file.
        path: PathBuf,
        /// The tables' error (it names the table file).
        inner: Box<HostError>,
    },
    /// A LUT file's or set's fault ([`crate::formats::lut::LutFault`]).
    #[error("{origin}: {fault}")]
    Lut {
        /// The LUT file (or the prefix or histogram set it comes from, or the argument).
        origin: Origin,
        /// What is wrong.
        #[source]
        fault: crate::formats::lut::LutFault,
    },
    /// An output path that cannot take the outputs ([`crate::formats::outputs::OutputFault`]).
    #[error("{path}: {fault}")]
    Output {
        /// The path.
        path: PathBuf,
        /// What is wrong.
        #[source]
        fault: crate::formats::outputs::OutputFault,
    },
    /// A histogram set or recorded frames that the streamed camera cannot take
    /// ([`crate::checks::stream_run::StreamInputFault`]).
    #[error("{path}: {fault}")]
    StreamInput {
        /// The histogram set or frame cube.
        path: PathBuf,
        /// What is wrong.
        #[source]
        fault: crate::checks::stream_run::StreamInputFault,
    },
    /// A firmware file (the ELF, or an output of its run) that is not what it must be
    /// ([`crate::checks::firmware::FirmwareFault`]).
    #[error("{path}: {fault}")]
    Firmware {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        #[source]
        fault: crate::checks::firmware::FirmwareFault,
    },
    /// A file's contents are not what they must be.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

impl HostError {
    /// `message` about `subject`.
    pub fn invalid(subject: Subject, message: impl Into<String>) -> Self {
        HostError::Invalid { subject, message: message.into() }
    }
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        HostError::Io { path: path.into(), source }
    }
    /// A usage error of option `flag`.
    pub fn argument(flag: impl Into<String>, message: impl Into<String>) -> Self {
        HostError::Argument { flag: flag.into(), message: message.into() }
    }
    /// What kind of failure this is.
    pub fn kind(&self) -> ErrorKind {
        match self {
            HostError::Io { .. } | HostError::IoOf { .. } | HostError::NotRegular { .. } | HostError::OutputNotFile { .. } | HostError::Output { .. } | HostError::Busy { .. } => ErrorKind::Io,
            HostError::OverBudget { .. } => ErrorKind::OverBudget,
            HostError::Tool { .. } => ErrorKind::Tool,
            HostError::WidthsFrom { inner, .. } => inner.kind(),
            _ => ErrorKind::Input,
        }
    }
    /// The process exit code for this error: 2 for usage errors (as clap's own), 1 for
    /// everything else (bad data, I/O, a failed tool).
    pub fn exit_code(&self) -> u8 {
        match self {
            HostError::Argument { .. } | HostError::OutputIsInput { .. } => 2,
            _ => 1,
        }
    }
    /// `fault` of the LUT file `path`.
    pub fn lut(origin: impl Into<Origin>, fault: crate::formats::lut::LutFault) -> Self {
        HostError::Lut { origin: origin.into(), fault }
    }
    /// `source` encoding what goes to `path`.
    pub fn encode(path: impl Into<PathBuf>, source: impl Into<EncodeError>) -> Self {
        HostError::Encode { path: path.into(), source: source.into() }
    }
    /// A core error while doing `context`.
    pub fn core(context: impl Into<String>, source: CoreError) -> Self {
        HostError::Core { context: context.into(), source }
    }
}

