//! `dncal linearity FILE`: the paper's section 5 on a linearity set: raw, standard and
//! pixel-wise corrections compared as RMS residual per level (Fig. 8), with the
//! coefficients, mask and corrected images written as FITS.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::infra::progress::{spinner, stage};
use crate::formats::report::{wrote, Report};
use crate::formats::fits::{read_linearity_planned, LinearityShape, SetView, stage_cube, stage_pixel_correction, PixelCorrection};
use crate::analyses::linearity::{analyze_unsaturated, LinearityError, check_flat_level, example_row, unsaturated_levels, Cube, LinearityReport, PixelResults, MAX_ORDER};
use crate::analyses::linearity::{held_out::HeldOut, paper_fig8::Fig8};
use crate::formats::plots::{level_lines_plot, line_plot_paired, map_plot, Map, Series};
use crate::formats::outputs::OutDir;
use crate::{HostError, Origin};

/// What `linearity` prints.
#[derive(Debug, Serialize)]
pub struct LinearitySummary {
    /// The input.
    pub input: PathBuf,
    /// The analysis.
    #[serde(flatten)]
    pub report: LinearityReport,
    /// Wall time of the analysis (fit, inversion, statistics), s.
    pub analysis_s: f64,
    /// The paper's Fig. 8, as its text states it, against this set's curves.
    pub paper_fig8: Fig8,
    /// The pixel-wise correction of each asked order scored on levels it was not fitted
    /// to (`--held-out`; empty without).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub held_out: Vec<HeldOut>,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

impl Report for LinearitySummary {
    fn text(&self) -> String {
        let r = &self.report;
        let mut t = format!("{}: {} levels x {} pixels, gain level {}, {} masked, analysis {:.2} s\n", self.input.display(), r.levels, r.pixels, r.gain_level, r.masked_pixels, self.analysis_s);
        t += &format!("max RMS over levels: raw {:.3e}, standard {:.3e}, pixel-wise {:.3e}, random {:.3e}\n", r.rms_raw_max, r.rms_standard_max, r.rms_pixelwise_max, r.rms_random_max);
        let f = &self.paper_fig8;
        t += &format!("against the paper's Fig. 8 as its text states it: distance {:.3} (rms over {} statements of the log10 factor outside each; 0 inside all)\n", f.distance, f.statements.len());
        for s in f.statements.iter().filter(|s| s.distance > 0.0) {
            let (lo, hi) = s.range();
            t += &format!("  {:.3}: {} (read: {}); ours {lo:.3e} to {hi:.3e}\n", s.distance, s.paper, s.reading);
        }
        for h in &self.held_out {
            t += &format!("held out (fitted on the even levels, scored on the odd): order {}: median RMS {:.3e}, largest {:.3e}\n", h.order, h.median, h.max);
        }
        t + &wrote(&self.outputs)
    }
}

/// The files of [`linearity`]'s report, in its directory.
const REPORT_FILES: [&str; 5] = ["coefficients.fits", "corrected.fits", "linearity_rms.png", "flat_image.png", "pixels_levels.png"];

/// Creates `dir` and checks the files of [`linearity`]'s report there, before anything is
/// computed.
pub fn expect_report(files: &mut crate::formats::outputs::Outputs, dir: &Path) -> Result<(), HostError> {
    files.create_dir(dir)?;
    files.expect(REPORT_FILES.map(|n| dir.join(n)))
}

/// Analyzes `input`; with `out`, stages in its directory `coefficients.fits` (cube and
/// MASK), `corrected.fits` (pixel-wise corrected normalized intensities, masked pixels
/// filled) `linearity_rms.png` (Fig. 8), `flat_image.png` (Fig. 6) and
/// `pixels_levels.png` (Fig. 7), published by the caller. `flat` is the gain level
/// (default: nearest half the maximum reference).
pub fn linearity(input: &Path, order: usize, flat: Option<usize>, held_out: &[usize], out: Option<OutDir<'_>>) -> Result<LinearitySummary, HostError> {
    linearity_as(input, input, order, flat, held_out, out)
}

/// [`linearity`] of the set at `read_from`, named `input`: for a command that analyzes a
/// set it has staged but not published yet (`demo`).
pub fn linearity_as(read_from: &Path, input: &Path, order: usize, flat: Option<usize>, held_out: &[usize], mut out: Option<OutDir<'_>>) -> Result<LinearitySummary, HostError> {
    for (flag, &o) in std::iter::once(("--order", &order)).chain(held_out.iter().map(|o| ("--held-out", o))) {
        if !(1..=MAX_ORDER).contains(&o) {
            return Err(HostError::Argument { flag: flag.into(), message: format!("{o}: the pixel-wise polynomial order must be 1 to {MAX_ORDER}") });
        }
    }
    if let Some(o) = out.as_mut() {
        expect_report(o.files, o.dir)?;
    }
    stage(&format!("reading {}", input.display()));
    // The corrected cube only for the outputs: without them the report needs its
    // statistics alone.
    let cube = if out.is_some() { Cube::Keep } else { Cube::Skip };
    // The whole run's memory from the header, before either cube is read.
    let set = read_linearity_planned(read_from, |shape| need(shape, order, cube, held_out).check(input, &format!("linearity of {} x {} pixels x {} levels", shape.width, shape.height, shape.levels)))?;
    let (report, px, analysis_s) = fit(&set.view(), &Origin::File(input.into()), order, flat, cube)?;
    let held_out = if held_out.is_empty() { Vec::new() } else { super::held_out::held_out(&set.view(), &report, &px.mask, &super::unsaturated_levels(&set.view()), held_out) };
    let paper_fig8 = super::paper_fig8::compare(&report);
    let mut outputs = Vec::new();
    if let Some(OutDir { files, dir }) = out {
        // Kept above for the outputs; an error rather than outputs left out if not.
        let corrected = px.corrected.as_deref().ok_or_else(|| HostError::Linearity { origin: input.into(), source: LinearityError::NoCorrectedCube })?;
        let c = dir.join("coefficients.fits");
        let pc = PixelCorrection { coeffs: &px.coeffs, mask: &px.mask, width: set.width, height: set.height, order, bit_depth: set.bit_depth, n_adc: set.n_adc };
        stage_pixel_correction(files, &c, &pc)?;
        let k = dir.join("corrected.fits");
        stage_cube(files, &k, corrected, set.levels, set.width, set.height, ("", "dimensionless: intensity normalized to the reference"))?;
        let fig = dir.join("linearity_rms.png");
        let series = |label: &str, v: &[f64]| Series {
            label: label.into(),
            points: report.reference.iter().zip(v).filter(|(_, y)| y.is_finite() && **y > 0.0).map(|(&x, &y)| (x, y.log10())).collect(),
        };
        line_plot_paired(
            files,
            &fig,
            "RMS residual (solid) and random noise (dashed), log10: the paper's Fig. 8",
            "normalized intensity (reference voltage / maximum)",
            "log10 RMS",
            &[
                series("raw", &report.rms_raw),
                series("standard: global cubic, dark, gain", &report.rms_standard),
                series(&format!("pixel-wise order {}, dark, gain", report.order), &report.rms_pixelwise),
                series("raw: random", &report.rms_random_raw),
                series("standard: random", &report.rms_random_standard),
                series("pixel-wise: random", &report.rms_random_pixelwise),
            ],
            1,
            3,
        )?;
        // Fig. 6: the flat, in percent of the top code, scaled +-10% around its median as
        // the paper's (57%, scaled 47-67%).
        let (w, h, np) = (set.width, set.height, set.width * set.height);
        let top = ((1u64 << set.bit_depth) - 1) as f64;
        let g = report.gain_level;
        let flat: Vec<Vec<f64>> = (0..h).map(|r| (0..w).map(|c| 100.0 * set.mean[g * np + r * w + c] / top).collect()).collect();
        let mut sorted: Vec<f64> = flat.iter().flatten().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f64::total_cmp);
        let med = sorted.get(sorted.len() / 2).copied().unwrap_or(50.0);
        let flat_png = dir.join("flat_image.png");
        let title = format!("The flat (level {g}), raw, % of full scale: median {med:.1}%, scaled {:.0}-{:.0}% (the paper's Fig. 6)", med - 10.0, med + 10.0);
        map_plot(
            files,
            &flat_png,
            &Map {
                title: &title,
                x_label: "column",
                y_label: "row",
                values: &flat,
                x_range: (0.0, (w.max(2) - 1) as f64),
                y_range: (0.0, (h.max(2) - 1) as f64),
                scale_label: "% of full scale",
                log: false,
                contours: &[],
                range: Some((med - 10.0, med + 10.0)),
            },
        )?;
        // Fig. 7: 100 pixels of the middle row at every level, three corrections.
        let ex = example_row(&set, &report, &px, corrected, 100);
        let lines = |v: &[Vec<f64>]| -> Vec<Vec<(f64, f64)>> { v.iter().map(|l| l.iter().enumerate().map(|(i, &y)| ((ex.first_column + i) as f64, y)).collect()).collect() };
        let levels_png = dir.join("pixels_levels.png");
        level_lines_plot(
            files,
            &levels_png,
            &format!("Row {}, {} pixels, levels 1-{} (purple dark to yellow bright): the paper's Fig. 7", ex.row, ex.raw.first().map_or(0, Vec::len), set.levels - 1),
            "column",
            "normalized intensity",
            &[
                ("raw: pixel / level mean".to_string(), lines(&ex.raw)),
                ("standard: global cubic, dark, gain".to_string(), lines(&ex.standard)),
                (format!("pixel-wise order {}, dark, gain", report.order), lines(&ex.pixelwise)),
            ],
            (0.95, 1.05),
        )?;
        outputs.extend([c, k, fig, flat_png, levels_png]);
    }
    Ok(LinearitySummary { input: input.into(), report, analysis_s, paper_fig8, held_out, outputs })
}

/// Bytes per pixel of the fits at pixel-wise order `order` beside the cubes ([`fit`]): its
/// unsaturated levels (8), coefficients (8 (order + 1)), residual and flat signal (16),
/// mask (1), corrections at the dark and the flat (16), the three corrections' ends at
/// both (96), the medians' selections and the allocator's rounding, and with
/// [`Cube::Skip`] one level's row of scratch per thread (8 each; [`Cube::Keep`] writes
/// into the cube instead). Measured at order 4 on 256 x 256 and 512 x 512 sets of 41
/// levels: 186 bytes a pixel beyond the cubes, either way, on 2 threads (here 192 and
/// 208).
pub fn fit_bytes_per_pixel(order: usize, cube: Cube) -> u64 {
    let scratch = match cube {
        Cube::Keep => 0,
        Cube::Skip => 8 * crate::infra::budget::threads(),
    };
    152 + 8 * (order as u64 + 1) + scratch
}

/// Bytes per pixel of `--held-out`'s scoring beside the cubes, one order at a time after
/// the fits ([`super::held_out::held_out`]): the fitted coefficients and mask kept (8
/// (order + 1) + 1), the unsaturated levels (8), and each pixel's row of residuals, one
/// value a level (8 `levels` and 56 for its vector and the allocator). Measured at order 4,
/// 41 levels, orders 3 to 6 held out: 417 bytes a pixel beyond the cubes (here 433).
pub fn held_out_bytes_per_pixel(order: usize, levels: usize) -> u64 {
    8 * (order as u64 + 1) + 9 + 8 * levels as u64 + 56
}

/// What `linearity` of a set of `shape` holds at most at once, from its header: both
/// cubes as read (f64), the corrected cube where the outputs write it, and the larger of
/// the fits and `held_out`'s scoring, with the file cfitsio holds inflated where it is
/// compressed. Measured on a 512 x 512 x 41 set on 2 threads, the peak less the binary's
/// own (12 MiB) is 0.98 of it (`host-sim/tests/cli_budget.rs`).
pub fn need(shape: &LinearityShape, order: usize, cube: Cube, held_out: &[usize]) -> crate::infra::budget::Need {
    use crate::infra::budget::bytes_of;
    let (np, values) = (shape.pixels(), shape.values());
    let fits = bytes_of(np, fit_bytes_per_pixel(order, cube));
    let scores = if held_out.is_empty() { 0 } else { bytes_of(np, held_out_bytes_per_pixel(order, shape.levels)) };
    let corrected = if cube == Cube::Keep { bytes_of(values, 8) } else { 0 };
    crate::infra::budget::Need::new()
        .with("the two cubes as read", bytes_of(values, 16))
        .with("the corrected cube", corrected)
        .with(if scores > fits { "the held-out scores" } else { "the fits" }, fits.max(scores))
        .with("the file decompressed", shape.resident)
}

/// What the fit needs of a set's reference and levels, before any pixel: at least
/// `order + 3` levels, voltages finite, not negative, not all zero, and at least
/// `order + 3` of them distinct (to [`DISTINCT`] of the largest): equal voltages leave
/// the fit nothing to fit against (it "corrects" perfectly, to zero residual).
pub fn check_plan(voltage: &[f64], order: usize) -> Result<(), LinearityError> {
    if voltage.len() < order + 3 {
        return Err(LinearityError::LevelsForOrder { levels: voltage.len(), order });
    }
    if voltage.iter().any(|v| !(v.is_finite() && *v >= 0.0)) || voltage.iter().cloned().fold(0.0, f64::max) <= 0.0 {
        return Err(LinearityError::ReferenceVoltage);
    }
    let distinct = distinct_voltages(voltage);
    if distinct < order + 3 {
        return Err(LinearityError::DistinctVoltages { distinct, order });
    }
    Ok(())
}

/// Two reference voltages closer than this fraction of the largest are one level of
/// signal to the fits (1e-6: a millionth of full scale, far below any level spacing).
pub const DISTINCT: f64 = 1e-6;

/// How many of `voltage`'s values differ by more than [`DISTINCT`] of the largest.
pub fn distinct_voltages(voltage: &[f64]) -> usize {
    let vmax = voltage.iter().cloned().fold(0.0, f64::max);
    let mut x: Vec<f64> = voltage.iter().map(|v| v / vmax).filter(|x| x.is_finite()).collect();
    x.sort_by(f64::total_cmp);
    x.windows(2).filter(|w| w[1] - w[0] > DISTINCT).count() + usize::from(!x.is_empty())
}

/// What the fit needs of a set's values (the reader has checked them finite and within
/// the codes): a signal that rises (the levels' means over the pixels span at least
/// [`MIN_SPAN_DN`]) and a noise (at most half the finite deviations zero, as `diagnose`
/// asks): without them every residual and every random floor is zero or undefined, and
/// a report of zeros would read as a perfect camera.
pub fn check_values<T: crate::formats::fits::Sample>(set: &SetView<'_, T>) -> Result<(), LinearityError> {
    let np = set.width * set.height;
    let level_mean = |l: usize| {
        let (sum, n) = set.mean[l * np..(l + 1) * np].iter().map(|&v| v.into()).filter(|v: &f64| v.is_finite()).fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
        sum / n.max(1) as f64
    };
    let means: Vec<f64> = (0..set.levels).map(level_mean).collect();
    let span = means.iter().cloned().fold(f64::NEG_INFINITY, f64::max) - means.iter().cloned().fold(f64::INFINITY, f64::min);
    if span.is_nan() || span < MIN_SPAN_DN {
        return Err(LinearityError::NoSignal { span });
    }
    let (zero, finite) = set.std.iter().map(|&v| v.into()).filter(|v: &f64| v.is_finite()).fold((0usize, 0usize), |(z, n), s| (z + usize::from(s <= 0.0), n + 1));
    if finite == 0 || zero > finite / 2 {
        return Err(LinearityError::NoNoise { zero, finite });
    }
    Ok(())
}

/// The smallest span of the levels' mean signals, DN, that is a linearity set.
pub const MIN_SPAN_DN: f64 = 1.0;

/// The analysis of a set in memory (`origin` names it in errors): its memory checked
/// against the budget, its levels and
/// reference checked for the pixel-wise order, the flat level checked where one is given
/// (`--flat-level`), then the fits. Returns the report, the per-pixel results and the
/// analysis' wall time, seconds.
pub fn fit(set: &SetView, origin: &Origin, order: usize, flat: Option<usize>, cube: Cube) -> Result<(LinearityReport, PixelResults, f64), HostError> {
    // The fits and their work space, and the corrected cube (f64 per pixel and level)
    // where it is kept, beside the set its caller holds already (`linearity` counts the
    // set too, from its header: [`need`]).
    let (per_pixel, what) = match cube {
        Cube::Keep => (8 * set.levels as u64 + fit_bytes_per_pixel(order, cube), "the pixel-wise analysis (the corrected cube and the fits)"),
        Cube::Skip => (fit_bytes_per_pixel(order, cube), "the pixel-wise analysis (the fits)"),
    };
    crate::infra::budget::check(origin.clone(), what, crate::infra::budget::bytes_of((set.width * set.height) as u64, per_pixel))?;
    check_plan(set.voltage, order).and_then(|()| check_values(set)).map_err(|source| HostError::Linearity { origin: origin.clone(), source })?;
    let start = std::time::Instant::now();
    let valid = unsaturated_levels(set);
    if let Some(l) = flat {
        check_flat_level(&valid, set.levels, l).map_err(|e| HostError::Argument { flag: "--flat-level".into(), message: format!("{e} ({origin})") })?;
    }
    let spin = spinner(&format!("fitting {} pixels ({} levels): standard and pixel-wise corrections", set.width * set.height, set.levels));
    let analysis = analyze_unsaturated(set, order, flat, valid, cube);
    spin.finish_and_clear();
    let (report, px) = analysis.map_err(|source| HostError::Linearity { origin: origin.clone(), source })?;
    Ok((report, px, start.elapsed().as_secs_f64()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::fits::{write_linearity, LinearitySet};
    use crate::model::hidden::{linearity_set, Plant};

    /// Issue 43's reproducers: sets the reader takes but no analysis can use. Each was
    /// "analyzed" with exit 0 (equal voltages printed "standard 0.000e0, pixel-wise
    /// 0.000e0", a perfect correction, beside 60 JSON nulls and a cube of NaN). Now each
    /// is refused naming the file and what is degenerate, and nothing is written.
    #[test]
    fn degenerate_sets_are_refused_before_any_output() {
        let dir = tempfile::tempdir().unwrap();
        let base = linearity_set(&Plant { width: 8, height: 6, levels: 15, ..Plant::default() }, &[], 5);
        let mut one_huge = base.voltage.clone();
        one_huge[5] = 1e308;
        let zero_std = format!("the standard deviations are zero at {0} of {0} pixels and levels", base.std.len());
        let cases: Vec<(&str, LinearitySet, &str)> = vec![
            ("equal", LinearitySet { voltage: vec![2.5; base.levels], ..base.clone() }, "the reference voltages take 1 distinct value(s) (to 1e-6 of the largest); an order-4 fit needs at least 7 levels of different signal"),
            ("huge", LinearitySet { voltage: one_huge, ..base.clone() }, "the reference voltages take 2 distinct value(s)"),
            ("zero-means", LinearitySet { mean: vec![0.0; base.mean.len()], ..base.clone() }, "the means do not change with the level: the levels' mean signals span 0.000e0 DN"),
            ("zero-std", LinearitySet { std: vec![0.0; base.std.len()], ..base.clone() }, &zero_std),
        ];
        for (name, set, expected) in cases {
            let input = dir.path().join(format!("{name}.fits"));
            write_linearity(&input, &set).unwrap();
            let out = dir.path().join(format!("out-{name}"));
            let e = crate::formats::outputs::staged(Some(&out), |o| linearity(&input, 4, None, &[], o)).unwrap_err().to_string();
            assert!(e.starts_with(&format!("{}: ", input.display())) && e.contains(expected), "{name}: {e}");
            assert!(!out.exists(), "{name}: an output directory was left");
        }
        // The set as drawn is analyzed, every maximum a finite number.
        let input = dir.path().join("good.fits");
        write_linearity(&input, &base).unwrap();
        let s = linearity(&input, 4, None, &[], None).unwrap();
        let r = &s.report;
        assert!([r.rms_raw_max, r.rms_standard_max, r.rms_pixelwise_max, r.rms_random_max].iter().all(|v| v.is_finite() && *v > 0.0), "{r:?}");
        assert_eq!(distinct_voltages(&[0.0, 1.0, 1.0 + 1e-7, 2.0]), 3);
        assert_eq!(distinct_voltages(&[]), 0);
    }
}
