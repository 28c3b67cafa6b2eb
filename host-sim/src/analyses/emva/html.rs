//! The datasheet as a folder a user opens in a browser: `datasheet.html` with the
//! standard's plots (photon transfer, SNR, linearity deviation, spectrograms, defect
//! histograms) as PNGs, and `datasheet.json`. The files are published together or not at
//! all ([`crate::formats::outputs`]), so a failure leaves neither a half-written file nor a
//! datasheet whose pages are of two runs.

use std::path::{Path, PathBuf};

use super::{Datasheet, PtcSummary, Release};
use crate::formats::outputs::{html_escape as esc, html_figure, html_path, Outputs};
use crate::formats::plots::{line_plot, line_plot_styled, PlotStyle, Series};
use crate::HostError;

/// One datasheet row: value with unit, or the reason it has none.
fn row(sheet: &Datasheet, name: &str, key: &str, value: Option<f64>, unit: &str, digits: usize) -> String {
    let shown = match value {
        Some(v) => format!("{v:.digits$} {unit}"),
        None => format!("&ndash; <small>({})</small>", esc(sheet.why(key))),
    };
    format!("<tr><td>{name}</td><td>{shown}</td><td><code>{key}</code></td></tr>\n")
}

/// `log10(count + 1)` over the bins of a histogram: logarithmic counts with empty bins
/// at 0.
fn log_counts(bins: &[f64], counts: &[u64]) -> Vec<(f64, f64)> {
    bins.iter().zip(counts).map(|(&b, &c)| (b, ((c + 1) as f64).log10())).collect()
}

/// Stages the datasheet of `descriptor` in `dir` ([`expect_datasheet`] first), published
/// by the caller with the rest: all files or none ([`crate::formats::outputs`]); returns
/// the files staged.
pub fn write_datasheet(staged: &mut Outputs, dir: &Path, descriptor: &Path, sheet: &Datasheet) -> Result<Vec<PathBuf>, HostError> {
    expect_datasheet(staged, dir)?;
    let mut files = figures(staged, dir, sheet)?;
    let page = dir.join("datasheet.html");
    staged.write_bytes(&page, page_html(descriptor, sheet, &files))?;
    files.push(page);
    let json = dir.join("datasheet.json");
    let text = serde_json::to_string_pretty(sheet).map_err(|e| HostError::encode(json.clone(), e))?;
    staged.write_bytes(&json, text + "\n")?;
    files.push(json);
    Ok(files)
}

/// Creates `dir` and checks every file [`write_datasheet`] may write there (the
/// spectrograms and defect histograms only where the set has the spatial images), before
/// anything is computed.
pub fn expect_datasheet(files: &mut Outputs, dir: &Path) -> Result<(), HostError> {
    files.create_dir(dir)?;
    let names = ["photon_transfer.png", "snr.png", "linearity.png", "spectrograms.png", "defect_histograms.png", "datasheet.html", "datasheet.json"];
    files.expect(names.map(|n| dir.join(n)))
}

/// The photon-transfer figure's data: the measured levels as markers (each one is a
/// measurement; a line between them would be none), the gain's fit as a line, and the
/// fit's range (the levels up to 70% of saturation the gain is fitted to) shaded.
fn ptc_figure(t: &PtcSummary) -> ([Series; 2], PlotStyle) {
    let points: Vec<(f64, f64)> = t.photon_transfer.clone();
    let fitted = &t.photon_transfer[..t.gain_fit_levels.min(t.photon_transfer.len())];
    let (fit_start, fit_end) = (fitted.first().map_or(0.0, |p| p.0), fitted.last().map_or(0.0, |p| p.0));
    let offset = match t.release {
        Release::R3 => 0.0,
        Release::R4 => t.gain_offset_dn2,
    };
    let fit: Vec<(f64, f64)> = [0.0, fit_end].iter().map(|&x| (x, offset + t.gain_dn_per_e * x)).collect();
    let series = [Series { label: "measured levels".into(), points }, Series { label: format!("K = {:.4} DN/e- over the fit range", t.gain_dn_per_e), points: fit }];
    let band = format!("fit range: the {} levels up to 70% of saturation", fitted.len());
    (series, PlotStyle { panels: 1, markers: vec![0], x_band: Some((fit_start, fit_end, band)), ..PlotStyle::default() })
}

/// Stages the datasheet's figures in `dir`: photon transfer, SNR, linearity and, where
/// the set has the spatial images, the spectrograms and defect histograms.
fn figures(staged: &mut Outputs, dir: &Path, sheet: &Datasheet) -> Result<Vec<PathBuf>, HostError> {
    let (t, s) = (&sheet.temporal, &sheet.spatial);
    let mut files = Vec::new();
    let ptc = dir.join("photon_transfer.png");
    let (series, style) = ptc_figure(t);
    line_plot_styled(staged, &ptc, "Photon transfer: temporal variance above dark against mean above dark", "mean above dark (DN)", "variance - dark variance (DN^2)", &series, &style)?;
    files.push(ptc);

    let snr = dir.join("snr.png");
    let log = |v: f64| if v > 0.0 { v.log10() } else { f64::NAN };
    line_plot(
        staged,
        &snr,
        "Signal-to-noise ratio",
        "log10 photons per pixel",
        "log10 SNR",
        &[
            Series { label: "measured (mean above dark / temporal noise)".into(), points: t.snr.iter().map(|p| (log(p.photons), log(p.measured))).collect() },
            Series { label: "linear model (K, QE, dark noise)".into(), points: t.snr.iter().map(|p| (log(p.photons), log(p.model))).collect() },
        ],
        1,
    )?;
    files.push(snr);

    let lin = dir.join("linearity.png");
    line_plot(
        staged,
        &lin,
        "Linearity: deviation from the fit over 5-95% of saturation",
        "photons per pixel",
        "deviation (%)",
        &[Series { label: "relative deviation".into(), points: t.linearity_deviation_pct.clone() }],
        1,
    )?;
    files.push(lin);

    if let (Some(sp), Some(h)) = (&s.spectrograms, &s.histograms) {
        let freq = |n: usize| move |i: usize| i as f64 / (2.0 * (n.max(2) - 1) as f64);
        let curve = |v: &[f64]| -> Vec<(f64, f64)> { v.iter().enumerate().skip(1).map(|(i, &a)| (freq(v.len())(i), log(a))).collect() };
        // Release 4.0 takes the spectrograms and histograms of high-pass filtered images.
        let r4 = t.release == Release::R4;
        let spec = dir.join("spectrograms.png");
        line_plot(
            staged,
            &spec,
            if r4 { "Spectrograms of the high-pass filtered images (frequency 0 left out)" } else { "Spectrograms (frequency 0 left out)" },
            "cycles per pixel",
            "log10 amplitude (DSNU: DN; PRNU: %)",
            &[
                Series { label: "DSNU horizontal".into(), points: curve(&sp.dsnu_horizontal_dn) },
                Series { label: "PRNU horizontal".into(), points: curve(&sp.prnu_horizontal_pct) },
                Series { label: "DSNU vertical".into(), points: curve(&sp.dsnu_vertical_dn) },
                Series { label: "PRNU vertical".into(), points: curve(&sp.prnu_vertical_pct) },
            ],
            2,
        )?;
        files.push(spec);
        let hist = dir.join("defect_histograms.png");
        line_plot(
            staged,
            &hist,
            "Logarithmic histograms of the averaged images (defect pixels)",
            "deviation (DN)",
            "log10 (pixels + 1)",
            &[
                Series { label: format!("DSNU: {}dark image about its mean", if r4 { "high-pass filtered " } else { "" }), points: log_counts(&h.dsnu.bins, &h.dsnu.counts) },
                Series { label: format!("PRNU: {} high-pass filtered bright - dark", if r4 { "Release 4.0" } else { "5x5" }), points: log_counts(&h.prnu.bins, &h.prnu.counts) },
            ],
            2,
        )?;
        files.push(hist);
    }
    Ok(files)
}

/// The datasheet's page: every quantity with its JSON key, the defect pixels, and the
/// `figures` written.
fn page_html(descriptor: &Path, sheet: &Datasheet, figures: &[PathBuf]) -> String {
    let (t, s) = (&sheet.temporal, &sheet.spatial);
    let release = match t.release {
        Release::R3 => "3.1 (as the reference implementation emva1288 1.0.2 computes it)",
        Release::R4 => "4.0",
    };
    let mut html = format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>EMVA 1288 datasheet</title>\
         <style>body{{font-family:sans-serif;max-width:1050px;margin:2em auto}}td,th{{padding:2px 10px;text-align:left}}</style></head><body>\
         <h1>EMVA 1288 datasheet</h1><p>{}<br>{} photon-transfer levels; definitions of Release {release}; descriptor version {}.</p>",
        html_path(descriptor),
        t.levels,
        esc(sheet.version.as_deref().unwrap_or("none"))
    );
    for note in ["levels", "saturation"].iter().filter_map(|k| t.why.get(*k)) {
        html += &format!("<p><b>Note:</b> {}</p>", esc(note));
    }
    html += "<h2>Temporal</h2><table><tr><th>quantity</th><th>value</th><th>JSON key</th></tr>\n";
    html += &row(sheet, "System gain K", "gain_dn_per_e", Some(t.gain_dn_per_e), "DN/e-", 4);
    html += &row(sheet, "1/K", "gain_e_per_dn", Some(t.gain_e_per_dn), "e-/DN", 3);
    html += &row(sheet, "Responsivity R", "responsivity_dn_per_photon", Some(t.responsivity_dn_per_photon), "DN/photon", 5);
    html += &row(sheet, "Quantum efficiency", "quantum_efficiency", Some(100.0 * t.quantum_efficiency), "%", 2);
    html += &row(sheet, "Dark noise", "dark_noise_dn", Some(t.dark_noise_dn), "DN", 3);
    html += &row(sheet, "Dark noise", "dark_noise_e", t.dark_noise_e, "e-", 2);
    html += &row(sheet, "Saturation (mean above dark)", "saturation_dn", Some(t.saturation_dn), "DN", 1);
    html += &row(sheet, "Saturation irradiation", "saturation_photons", t.saturation_photons, "photons", 0);
    html += &row(sheet, "Saturation capacity", "saturation_capacity_e", t.saturation_capacity_e, "e-", 0);
    html += &row(sheet, "SNR max", "snr_max", t.snr_max, "", 1);
    html += &row(sheet, "SNR max", "snr_max_db", t.snr_max_db, "dB", 1);
    html += &row(sheet, "Absolute sensitivity threshold", "sensitivity_threshold_photons", t.sensitivity_threshold_photons, "photons", 2);
    html += &row(sheet, "Absolute sensitivity threshold", "sensitivity_threshold_e", t.sensitivity_threshold_e, "e-", 2);
    html += &row(sheet, "Dynamic range", "dynamic_range", t.dynamic_range, "", 0);
    html += &row(sheet, "Dynamic range", "dynamic_range_db", t.dynamic_range_db, "dB", 1);
    html += &row(sheet, "Linearity error min", "linearity_error_min_pct", t.linearity_error_min_pct, "%", 3);
    html += &row(sheet, "Linearity error max", "linearity_error_max_pct", t.linearity_error_max_pct, "%", 3);
    html += &row(sheet, "Linearity error (mean |deviation|, Release 4.0)", "linearity_error_pct", t.linearity_error_pct, "%", 3);
    html += &row(sheet, "Dark current (mean)", "dark_current_mean_e_per_s", t.dark_current_mean_e_per_s, "e-/s", 2);
    html += &row(sheet, "Dark current (variance)", "dark_current_var_e_per_s", t.dark_current_var_e_per_s, "e-/s", 2);
    html += "</table><h2>Spatial</h2><table><tr><th>quantity</th><th>value</th><th>JSON key</th></tr>\n";
    html += &row(sheet, "DSNU", "dsnu_dn", s.nonuniformity.dsnu_dn, "DN", 3);
    html += &row(sheet, "DSNU", "dsnu_e", s.nonuniformity.dsnu_e, "e-", 2);
    html += &row(sheet, "DSNU row / column / pixel", "dsnu_row_e", s.nonuniformity.dsnu_row_e, "e-", 2);
    html += &row(sheet, "", "dsnu_col_e", s.nonuniformity.dsnu_col_e, "e-", 2);
    html += &row(sheet, "", "dsnu_pixel_e", s.nonuniformity.dsnu_pixel_e, "e-", 2);
    html += &row(sheet, "PRNU", "prnu_pct", s.nonuniformity.prnu_pct, "%", 3);
    html += &row(sheet, "PRNU row / column / pixel", "prnu_row_pct", s.nonuniformity.prnu_row_pct, "%", 3);
    html += &row(sheet, "", "prnu_col_pct", s.nonuniformity.prnu_col_pct, "%", 3);
    html += &row(sheet, "", "prnu_pixel_pct", s.nonuniformity.prnu_pixel_pct, "%", 3);
    html += "</table>";
    match &s.defect_pixels {
        Some(d) => {
            html += &format!(
                "<h2>Defect pixels</h2><p>dncal's criteria (the standard defines no counts; <code>docs/emva.md</code>): hot {} (dark above its median by more than {:.3} DN), dead {} (below half their neighbourhood's response), high PRNU {} (high-pass response beyond {:.3} DN); {} pixels in all{}.</p>",
                d.hot, d.hot_threshold_dn, d.dead, d.high_prnu, d.prnu_threshold_dn, d.total, esc(&d.against())
            );
        }
        None => html += &format!("<h2>Defect pixels</h2><p>{}</p>", esc(sheet.why("defect_pixels"))),
    }
    if let Some(channels) = &s.channels {
        html += "<h2>Channels</h2><p>Each cell of the response pattern characterized on its own pixels, as EMVA 1288 takes a colour camera's channels apart (JSON: <code>channels</code>, the whole datasheet's keys for each).</p>\
                 <table><tr><th>cell (row, column)</th><th>response</th><th>K (DN/e-)</th><th>QE (%)</th><th>dark noise (e-)</th><th>saturation capacity (e-)</th><th>DSNU (e-)</th><th>PRNU (%)</th></tr>\n";
        for c in channels {
            let t = c.temporal.as_ref();
            let cell = |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
            html += &format!(
                "<tr><td>({}, {})</td><td>{:.3}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n",
                c.row,
                c.column,
                c.response,
                cell(t.map(|t| t.gain_dn_per_e), 4),
                cell(t.map(|t| 100.0 * t.quantum_efficiency), 2),
                cell(t.and_then(|t| t.dark_noise_e), 2),
                cell(t.and_then(|t| t.saturation_capacity_e), 0),
                cell(c.nonuniformity.dsnu_e, 2),
                cell(c.nonuniformity.prnu_pct, 3)
            );
        }
        html += "</table>";
    }
    for (file, caption) in [
        ("photon_transfer.png", "Photon transfer"),
        ("snr.png", "SNR"),
        ("linearity.png", "Linearity deviation"),
        ("spectrograms.png", "Spectrograms"),
        ("defect_histograms.png", "Defect-pixel histograms"),
    ] {
        if figures.iter().any(|f| f.ends_with(file)) {
            html += &format!("<h2>{caption}</h2>{}", html_figure(file, 1000, caption, None));
        }
    }
    html + "</body></html>\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 44: on the real CCD, the photon-transfer figure draws every level as a
    /// marker, and its shaded fit range holds exactly the levels the gain was fitted to
    /// (read from the figure's data: the points whose mean lies in the band).
    #[test]
    fn the_photon_transfer_figure_marks_its_levels_and_fit_range() {
        let Some(real) = crate::analyses::emva::descriptor::tests::real_descriptor() else { return };
        let set = crate::analyses::emva::read_descriptor(&real).unwrap();
        let sheet = crate::analyses::emva::datasheet(&set, None).unwrap();
        let t = &sheet.temporal;
        let (series, style) = ptc_figure(t);
        assert_eq!(style.markers, [0]);
        assert_eq!(series[0].points.len(), t.photon_transfer.len());
        let (a, b, label) = style.x_band.clone().unwrap();
        let inside = series[0].points.iter().filter(|p| (a..=b).contains(&p.0)).count();
        assert!(t.gain_fit_levels >= 10 && t.gain_fit_levels < t.photon_transfer.len(), "{}", t.gain_fit_levels);
        assert_eq!(inside, t.gain_fit_levels, "levels in the band {a}..{b}");
        assert!(label.contains(&format!("the {} levels", t.gain_fit_levels)), "{label}");
        assert_eq!(series[1].points.last().unwrap().0, b, "the fit line ends where the range does");
    }
}
