//! The crate's one error type.

use dncal_core::CoreError;

/// What can go wrong configuring or driving the model.
#[derive(Debug, Clone, PartialEq)]
pub enum FpgaError {
    /// A configuration value out of its range: the field and why.
    Config(&'static str, String),
    /// The core refused something (geometry, LUT image, frame order).
    Core(CoreError),
}

impl From<CoreError> for FpgaError {
    fn from(e: CoreError) -> Self {
        FpgaError::Core(e)
    }
}

impl core::fmt::Display for FpgaError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FpgaError::Config(field, why) => write!(f, "fpga config {field}: {why}"),
            FpgaError::Core(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for FpgaError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            FpgaError::Core(e) => Some(e),
            FpgaError::Config(..) => None,
        }
    }
}
