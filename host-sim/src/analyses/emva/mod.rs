//! EMVA 1288 measurement sets and their datasheet.
//!
//! - [`descriptor`]: the standard's text descriptor and its images (temporal and spatial
//!   series);
//! - [`temporal`]: the photon-transfer curve of the two-frame levels;
//! - [`datasheet`]: the temporal quantities (gain, QE, dark noise, saturation, SNR,
//!   sensitivity threshold, dynamic range, linearity, dark current);
//! - [`spatial`]: DSNU and PRNU with their row, column and pixel parts, spectrograms,
//!   histograms and defect pixels from the many-frame series;
//! - [`channels`]: a colour camera's channels, each characterized on its own pixels;
//! - [`sheet`]: the whole datasheet of a set; [`html`]: it as a folder with the plots;
//! - [`fit`]: the standard's three straight-line fits.

pub mod cells;
pub mod channels;
pub mod datasheet;
pub mod descriptor;
pub mod fit;
pub mod highpass;
pub mod html;
pub mod sheet;
pub mod spatial;
pub mod temporal;
pub mod run;

pub use datasheet::{summarize_points, PtcSummary, Release};
pub use descriptor::{code_histogram_halves, code_histograms, load_image, read_descriptor, DescriptorFault, EmvaLevel, EmvaSet, LevelKind, RecordFault, Series, DESCRIPTOR_LIMIT};
pub use fit::fit_line;
pub use sheet::{datasheet, datasheet_of, Datasheet};
pub use temporal::{photon_transfer, photon_transfer_selected, PtcPoint};

/// The temporal datasheet of `points` with `release`'s definitions; an error names the
/// descriptor `path`.
pub fn summarize(path: &std::path::Path, points: &[PtcPoint], release: Release) -> Result<PtcSummary, crate::HostError> {
    summarize_points(points, release).map_err(|source| crate::HostError::Ptc { path: path.to_path_buf(), source })
}
