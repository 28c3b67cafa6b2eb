//! `dncal._dncal`: the extension module of the `dncal` Python package (`python/pysrc`).
//!
//! A thin layer: every number comes from `dncal-core` (the correction) and `dncal-host`
//! (LUTs, characterizations, diagnose); this crate only turns numpy arrays into slices
//! (frames and linearity cubes read in place), library
//! errors into Python exceptions
//! (`errors.rs`), and summaries into the JSON the CLI's `--json` prints, which the
//! Python side turns into dicts.

use pyo3::prelude::*;

mod analyses;
mod arrays;
mod bench;
mod blocks;
mod correct;
mod errors;
mod luts;
mod simulate;

#[pymodule]
fn _dncal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    luts::register(m)?;
    correct::register(m)?;
    analyses::register(m)?;
    bench::register(m)?;
    blocks::register(m)?;
    simulate::register(m)?;
    Ok(())
}
