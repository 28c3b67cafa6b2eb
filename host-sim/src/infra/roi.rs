//! A region of interest as typed on the command line, `WIDTHxHEIGHT+COLUMN+ROW` (the X11
//! geometry order): the size first, then the top-left corner on the sensor.

use std::fmt;
use std::str::FromStr;

/// `WIDTHxHEIGHT+COLUMN+ROW`, pixels; width and height at least 1. Whether it fits a
/// sensor is for the command that knows the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RoiSpec {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// First column.
    pub column: usize,
    /// First row.
    pub row: usize,
}

impl RoiSpec {
    /// `(width, height, column, row)`.
    pub fn parts(self) -> (usize, usize, usize, usize) {
        (self.width, self.height, self.column, self.row)
    }
}

/// Why a text is not an ROI; each says the text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RoiError {
    /// Not of the form `WIDTHxHEIGHT+COLUMN+ROW`.
    #[error("'{0}' is not WIDTHxHEIGHT+COLUMN+ROW (e.g. 128x64+8+100)")]
    Form(String),
    /// No column or no row.
    #[error("'{0}': an ROI needs at least one column and one row")]
    Empty(String),
}

impl FromStr for RoiSpec {
    type Err = RoiError;

    fn from_str(s: &str) -> Result<Self, RoiError> {
        let bad = || RoiError::Form(s.to_string());
        let (size, corner) = s.split_once('+').ok_or_else(bad)?;
        let (column, row) = corner.split_once('+').ok_or_else(bad)?;
        let (width, height) = size.split_once('x').ok_or_else(bad)?;
        let n = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
        let roi = RoiSpec { width: n(width)?, height: n(height)?, column: n(column)?, row: n(row)? };
        if roi.width == 0 || roi.height == 0 {
            return Err(RoiError::Empty(s.to_string()));
        }
        Ok(roi)
    }
}

impl fmt::Display for RoiSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}+{}+{}", self.width, self.height, self.column, self.row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_prints_the_geometry_form() {
        let r: RoiSpec = "128x64+8+100".parse().unwrap();
        assert_eq!(r.parts(), (128, 64, 8, 100));
        assert_eq!(r.to_string(), "128x64+8+100");
        for bad in ["", "128x64", "128x64+8", "128+8+100", "ax64+8+100", "128x64+-1+0", "128x64+8+100+1", "0x64+0+0", "8x0+0+0"] {
            let e = bad.parse::<RoiSpec>().unwrap_err().to_string();
            assert!(e.starts_with(&format!("'{bad}'")), "{bad}: {e}");
        }
    }
}
