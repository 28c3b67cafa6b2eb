//! The paper's LUTs as analyses make them: the recipe from histograms to tables
//! ([`build`]) and the `dncal lut` verbs over the formats of [`crate::formats::lut`]
//! ([`run`]: build, import, export, convert, inspect).

pub mod build;
pub mod run;
