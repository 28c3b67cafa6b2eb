//! The colour channels of a sensor with a colour filter array: which response each
//! pixel's cell has ([`CfaResponse`]), as `cfa-pattern` measures it
//! (`linearity::cfa`) and every population of the diagnosis divides gains by
//! (`points::Pixels::response`).

use serde::Serialize;

/// A response pattern of period `period` in rows and columns: each cell's response
/// relative to the cells' mean (row-major, `period x period`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CfaResponse {
    /// Pixels a period, rows and columns.
    pub period: usize,
    /// Per cell `(row mod period) * period + column mod period`: its median response over
    /// the mean of the cells'.
    pub response: Vec<f64>,
    /// Per cell: the robust pixel-to-pixel spread of the response within the cell,
    /// relative to the cell's own response (PRNU within the channel, with the noise of
    /// the level's means).
    pub prnu_within: Vec<f64>,
    /// The Bayer layout the file declares (`BAYERPAT`), where the pattern is 2 x 2: a
    /// label of the cells, carried into the model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bayer: Option<crate::formats::bayer::Bayer>,
}

impl CfaResponse {
    /// The response of the pixel at `column`, `row` (1 where the table has no such cell).
    pub fn at(&self, column: usize, row: usize) -> f64 {
        self.response.get(crate::model::camera::config::cfa_cell(column, row, self.period)).copied().unwrap_or(1.0)
    }
}

