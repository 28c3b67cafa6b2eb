//! `dncal emva`: the EMVA 1288 datasheet of a photon-transfer set ([`crate::analyses::emva`]),
//! with its HTML page and figures.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::formats::report::{wrote, Report};
use crate::analyses::emva::{datasheet, html::write_datasheet, read_descriptor, Datasheet, Release};
use crate::HostError;

/// What the text's first line says of the set.
#[derive(Debug, Clone)]
struct Header {
    /// The descriptor, as given.
    path: PathBuf,
    bits: u32,
    width: usize,
    height: usize,
}

/// The datasheet (its JSON is the datasheet's own) and the files written.
#[derive(Debug)]
pub struct EmvaSummary {
    /// The datasheet.
    pub sheet: Datasheet,
    /// The page and figures written.
    pub written: Vec<PathBuf>,
    set: Header,
}

impl Serialize for EmvaSummary {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.sheet.serialize(s)
    }
}

impl Report for EmvaSummary {
    fn text(&self) -> String {
        let page = match self.written.is_empty() {
            // Said where it helps: a user who ran without -o may not know there is a page.
            true => "(-o DIR writes this datasheet as DIR/datasheet.html with the standard's plots, and DIR/datasheet.json)\n".to_string(),
            false => wrote(&self.written),
        };
        datasheet_text(&self.set, &self.sheet) + &page
    }
}

/// Reads the set of `descriptor`, computes its datasheet by `release`'s definitions
/// (the descriptor's own by default) and, with `out`, writes the page into that folder.
pub fn emva(descriptor: &Path, release: Option<Release>, out: Option<&Path>) -> Result<EmvaSummary, HostError> {
    // The datasheet's files first: a directory where one goes is refused before the
    // images are decoded.
    let mut staged = crate::formats::outputs::Outputs::new();
    if let Some(dir) = out {
        crate::analyses::emva::html::expect_datasheet(&mut staged, dir)?;
    }
    let set = read_descriptor(descriptor)?;
    let spin = crate::infra::progress::spinner(&format!("EMVA 1288 datasheet of {} ({} levels)", descriptor.display(), set.levels.len()));
    let sheet = datasheet(&set, release);
    spin.finish_and_clear();
    let sheet = sheet?;
    let written = match out {
        Some(dir) => write_datasheet(&mut staged, dir, descriptor, &sheet)?,
        None => Vec::new(),
    };
    staged.publish()?;
    Ok(EmvaSummary { sheet, written, set: Header { path: set.path, bits: set.bits, width: set.width, height: set.height } })
}

/// The datasheet as text: one quantity a line, `-` with the reason where the set does
/// not give it.
fn datasheet_text(set: &Header, s: &Datasheet) -> String {
    let t = &s.temporal;
    let value = |key: &str, v: Option<f64>, unit: &str, digits: usize| match v {
        Some(v) => format!("{v:.digits$}{unit}"),
        None => format!("- ({})", s.why(key)),
    };
    let release = match t.release {
        Release::R3 => "3.1",
        Release::R4 => "4.0",
    };
    let sp = &s.spatial;
    let mut out = format!(
        "{}: {} bits, {}x{}, {} photon-transfer levels; EMVA 1288 Release {release} definitions (descriptor v {})\n",
        set.path.display(),
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
        value("dsnu_dn", sp.nonuniformity.dsnu_dn, " DN", 3),
        value("dsnu_e", sp.nonuniformity.dsnu_e, " e-", 2),
        value("dsnu_row_e", sp.nonuniformity.dsnu_row_e, " e-", 2),
        value("dsnu_col_e", sp.nonuniformity.dsnu_col_e, " e-", 2),
        value("dsnu_pixel_e", sp.nonuniformity.dsnu_pixel_e, " e-", 2),
        value("prnu_pct", sp.nonuniformity.prnu_pct, " %", 3),
        value("prnu_row_pct", sp.nonuniformity.prnu_row_pct, " %", 3),
        value("prnu_col_pct", sp.nonuniformity.prnu_col_pct, " %", 3),
        value("prnu_pixel_pct", sp.nonuniformity.prnu_pixel_pct, " %", 3),
    );
    out += &match &sp.defect_pixels {
        Some(d) => format!("defect pixels            hot {}, dead {}, high PRNU {} ({} in all; dncal's criteria, docs/emva.md{})\n", d.hot, d.dead, d.high_prnu, d.total, d.against()),
        None => format!("defect pixels            - ({})\n", s.why("defect_pixels")),
    };
    if let Some(channels) = &sp.channels {
        out += &format!("channels                 {} of a response pattern, each on its own pixels (EMVA 1288 takes a colour camera's channels apart):\n", channels.len());
        for c in channels {
            let or_why = |key: &str, v: Option<f64>, unit: &str, digits: usize| match (v, &c.temporal) {
                (Some(v), _) => format!("{v:.digits$}{unit}"),
                (None, Some(t)) => format!("- ({})", t.why.get(key).map_or("not measured", String::as_str)),
                (None, None) => "-".to_string(),
            };
            let t = c.temporal.as_ref();
            out += &format!(
                "  ({}, {}) response {:.3}, {} px: K {}, QE {}, dark noise {}, saturation capacity {}, DSNU {}, PRNU {}{}\n",
                c.row,
                c.column,
                c.response,
                c.pixels,
                or_why("gain_dn_per_e", t.map(|t| t.gain_dn_per_e), " DN/e-", 4),
                or_why("quantum_efficiency", t.map(|t| 100.0 * t.quantum_efficiency), " %", 1),
                or_why("dark_noise_e", t.and_then(|t| t.dark_noise_e), " e-", 2),
                or_why("saturation_capacity_e", t.and_then(|t| t.saturation_capacity_e), " e-", 0),
                or_why("dsnu_e", c.nonuniformity.dsnu_e, " e-", 2),
                or_why("prnu_pct", c.nonuniformity.prnu_pct, " %", 3),
                c.refused.as_ref().map_or(String::new(), |r| format!(" (no photon transfer: {r})")),
            );
        }
    }
    out
}

