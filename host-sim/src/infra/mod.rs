//! What every room uses: the memory budget, the core's compile-time sizes at run time,
//! regions of interest, text made safe for a terminal, order statistics, robust statistics and least squares, and the
//! core on several threads. Imports `dncal-core` only.

pub mod allocator;
pub mod budget;
pub mod dims;
pub mod exact_sum;
pub mod frame_sums;
pub mod parallel;
pub mod printable;
pub mod progress;
pub mod recorded;
pub mod roi;
pub mod select;
pub mod stats;
