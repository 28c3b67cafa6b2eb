//! `dncal diagnose FILE`: the baseline simulation against measured data, findings from the
//! catalog, held-out gains ([`crate::analyses::diagnose`]).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::analyses::diagnose::model::{extended_model, linearity_model, ptc_model};
use crate::analyses::diagnose::{diagnose_code_density, diagnose_histograms, diagnose_linearity, diagnose_linearity_rows, diagnose_ptc, Diagnosis, Effect, Finding};
use crate::formats::fits::{open_linearity_rows, read_histograms_for_analysis_planned, read_linearity_planned, HistogramShape, READ_BYTES_PER_COUNT};
use crate::formats::outputs::{html_figure, OutDir, Outputs};
use crate::formats::report::Report;
use crate::analyses::flatten::FlattenParams;
use crate::formats::plots::{line_plot, Series};
use crate::HostError;

/// The all-columns code-density `findings` of an EMVA set, or, where some of four
/// interleaved ADCs (column c read by ADC c mod 4, as the MV-D1024E's; `[a, b]` the two
/// halves' histograms per ADC) show a width pattern and others do not, the findings of
/// those ADCs only (a pattern on one ADC, diluted, can pass for all columns'), with the
/// list of those ADCs.
fn code_density_by_adc([a, b]: &[Vec<Vec<u64>>; 2], mut findings: Vec<Finding>) -> (Vec<Finding>, Vec<usize>) {
    let by_adc: Vec<Option<Vec<Finding>>> =
        a.iter().zip(b).enumerate().map(|(adc, (a, b))| diagnose_code_density(a, b, adc).ok().map(|(f, _, _)| f.into_iter().filter(|f| f.effect == Effect::AdcDnl).collect())).collect();
    let named: Vec<usize> = by_adc.iter().enumerate().filter(|(_, f)| f.as_ref().is_some_and(|f| !f.is_empty())).map(|(adc, _)| adc).collect();
    let tested = by_adc.iter().filter(|f| f.is_some()).count();
    if tested == INTERLEAVED_ADCS && !named.is_empty() && named.len() < INTERLEAVED_ADCS {
        findings.retain(|f| f.effect != Effect::AdcDnl);
        for mut f in by_adc.into_iter().flatten().flatten() {
            f.detail = format!("columns c mod {INTERLEAVED_ADCS} = {} only: {}", f.adc.unwrap_or(0), f.detail);
            findings.push(f);
        }
        return (findings, named);
    }
    (findings, Vec::new())
}

/// The interleaved ADCs an EMVA set's columns are tested as (column c by ADC c mod 4).
const INTERLEAVED_ADCS: usize = 4;

/// One input's diagnosis and the files written for it.
#[derive(Debug, Serialize)]
pub struct DiagnoseSummary {
    /// The input.
    pub input: PathBuf,
    /// The diagnosis.
    #[serde(flatten)]
    pub diagnosis: Diagnosis,
    /// Report files.
    pub outputs: Vec<PathBuf>,
}

/// Bytes a linearity diagnosis of `np` pixels keeps beyond the set: its records held
/// (measured sizes, docs/diagnose.md), or spilled (then a block of each kind per thread),
/// and the set's mask.
fn state(np: u64, spilled: bool) -> u64 {
    use crate::infra::budget::bytes_of;
    use crate::analyses::diagnose::{spilled_blocks, RECORD_BYTES, RESIDENT_BYTES};
    if spilled { bytes_of(np, RESIDENT_BYTES).saturating_add(spilled_blocks(np)) } else { bytes_of(np, RESIDENT_BYTES + RECORD_BYTES) }
}

/// Whether the records of `np` pixels go to temporary files, with `beside` bytes (the
/// set held, or its blocks) in a budget of `limit`: where `asked`, or where held they
/// would not fit and spilled they take less (a small set's blocks may be more than its
/// records).
fn spill_records(np: u64, beside: u64, asked: bool, limit: u64) -> bool {
    asked || (state(np, false).saturating_add(beside) > limit && state(np, true) < state(np, false))
}

/// Whether a set of `np` pixels and `levels` levels that can be read by rows is, rather
/// than held: where rows are asked for, or where the set held (as `f32`) does not fit
/// beside the records and `beside` bytes more (the illumination fit's sums, the threads'
/// runs of pixels), the records spilled if that is what makes it fit.
fn read_by_rows(np: u64, levels: u64, beside: u64, rows_asked: bool, spill_asked: bool, limit: u64) -> bool {
    let set = crate::infra::budget::bytes_of(np.saturating_mul(levels), 8).saturating_add(beside);
    rows_asked || state(np, spill_records(np, set, spill_asked, limit)).saturating_add(set) > limit
}

/// The diagnosis of the linearity set at `read_from` (named `input`) and its camera
/// model. The set is held as f32 (half the memory of f64; see [`crate::formats::fits::Sample`]),
/// or, where it would not fit the memory budget held or `block_rows` is given, read from
/// its file by blocks of rows: the same diagnosis in a block per thread. A set whose
/// cubes cannot be read directly (a compressed file, scaled cubes) is held. The per-pixel
/// records go to temporary files where they would not fit beside the rest, or `spill`
/// says so: the same diagnosis again.
fn diagnose_linearity_file(read_from: &Path, input: &Path, block_rows: Option<usize>, spill: bool) -> Result<(Diagnosis, crate::model::camera::CameraConfig), HostError> {
    use crate::infra::budget::{bytes_of, limit, Need};
    use crate::formats::fits::LinearityShape;
    let spill_if = |np: u64, beside: u64| spill_records(np, beside, spill, limit());
    let records = |spilled: bool| if spilled { "the mask and the blocks of the spilled records" } else { "the per-pixel records" };
    // The illumination fit's sums and fields: set by the frame's size and the levels,
    // whatever the pixels (up to 72 MiB at 41 levels), held or by rows.
    let grid = |[w, h, l]: [usize; 3]| crate::analyses::diagnose::illumination_bytes(w, h, l);
    let subject = |[w, h, l]: [usize; 3], how: &str| format!("diagnosing the linearity set of {w} x {h} pixels x {l} levels{how}");
    let spin = |[w, h, l]: [usize; 3], how: &str| crate::infra::progress::spinner(&format!("diagnosing {} (linearity set, {w} x {h} pixels, {l} levels{how})", input.display()));
    let failed = |source| HostError::Diagnose { path: input.into(), source };
    let spilling = |spilled: bool| if spilled { ", its records spilled" } else { "" };
    // Decided from the header: held (read and checked in one pass) where the set and the
    // state fit the budget, its records spilled if that makes them fit, else read by
    // rows; the records spilled where held they do not fit beside the set or its blocks.
    // Held, each thread's run of pixels with their levels side by side.
    let tiles = crate::analyses::diagnose::tile_bytes();
    let opened = open_linearity_rows(read_from)?;
    let by_rows = opened.filter(|o| {
        let [w, h, l] = o.shape();
        read_by_rows((w * h) as u64, l as u64, grid(o.shape()).saturating_add(tiles), block_rows.is_some(), spill, limit())
    });
    let Some(opened) = by_rows else {
        // Held (a compressed file, scaled cubes, or a set that fits): the set, the state,
        // the illumination fit and the file cfitsio holds inflated counted together from
        // the header, before the cubes are read.
        let plan = |shape: &LinearityShape| {
            let dims = [shape.width, shape.height, shape.levels];
            let (np, set) = (shape.pixels(), bytes_of(shape.values(), 8));
            let spill = spill_if(np, set.saturating_add(grid(dims)).saturating_add(tiles));
            Need::new().with("the set as f32", set).with(records(spill), state(np, spill)).with("the illumination fit", grid(dims)).with("each thread's run of pixels", tiles).with("the file decompressed", shape.resident).check(input, &subject(dims, ""))
        };
        let set = read_linearity_planned::<f32>(read_from, plan)?;
        let dims = [set.width, set.height, set.levels];
        let np = (set.width * set.height) as u64;
        let spill = spill_if(np, bytes_of(np * set.levels as u64, 8).saturating_add(grid(dims)).saturating_add(tiles));
        let s = spin(dims, spilling(spill));
        let d = if spill { crate::analyses::diagnose::diagnose_linearity_spilled(&set, 0.01) } else { diagnose_linearity(&set, 0.01) }.map_err(failed);
        s.finish_and_clear();
        let d = d?;
        let model = linearity_model(&set, &d);
        return Ok((d, model));
    };
    let shape = opened.shape();
    let np = (shape[0] * shape[1]) as u64;
    let fixed = grid(shape);
    // Blocks of 8 MiB, or what the budget leaves after the state and the illumination fit.
    let blocks = |spilled: bool| crate::analyses::diagnose::blocks_of::<f32>(shape, block_rows, limit().saturating_sub(state(np, spilled)).saturating_sub(fixed));
    let spill = spill_if(np, blocks(false).1.saturating_add(fixed));
    let need = Need::new().with(records(spill), state(np, spill)).with("the illumination fit", fixed);
    need.check(input, &subject(shape, " by rows"))?;
    let (rows, blocks) = blocks(spill);
    need.with(format!("the blocks of {rows} rows of its threads"), blocks).check(input, &subject(shape, " by rows"))?;
    let set = opened.check::<f32>()?;
    let s = spin(shape, &format!(", read by blocks of {rows} rows{}", spilling(spill)));
    let d = diagnose_linearity_rows(&set, Some(rows), spill, 0.01);
    s.finish_and_clear();
    let d = d.map_err(failed)?;
    let model = linearity_model(&set, &d);
    Ok((d, model))
}

/// Bytes per count the diagnosis of a histogram set holds beside the counts read: each
/// ADC's halves, flattening, IEEE 1241 test, residuals and architectures, kept for the
/// report (measured: about 78 bytes a count beside the counts, 102 with them, from 4 to
/// 1024 ADCs of 4096 codes; counted with room, 104).
pub const HISTOGRAM_BYTES_PER_COUNT: u64 = 104;

/// What `diagnose` of a histogram set of `shape` holds, from its header: the counts as
/// read, their analysis ([`HISTOGRAM_BYTES_PER_COUNT`]) and the file cfitsio holds
/// inflated where it is compressed.
fn histograms_need(shape: &HistogramShape) -> crate::infra::budget::Need {
    use crate::infra::budget::bytes_of;
    crate::infra::budget::Need::new()
        .with("the counts as read", bytes_of(shape.counts(), READ_BYTES_PER_COUNT))
        .with("their analysis", bytes_of(shape.counts(), HISTOGRAM_BYTES_PER_COUNT))
        .with("the file decompressed", shape.resident)
}

/// Bytes per pixel `diagnose` of an EMVA set holds beyond the datasheet's: the defect
/// flags and the columns kept (1 each), and while the second half's defect map is made,
/// the first's (flags and scores, 9).
pub const EMVA_DEFECT_BYTES_PER_PIXEL: u64 = 16;

/// Bytes per pixel and thread `diagnose` of an EMVA set holds beyond the datasheet's: the
/// frames each thread decodes in its steps (the photon transfer twice, the code
/// histograms, the halves of the spatial series), 2 or 4 bytes a pixel each, and what the
/// allocator keeps of them per thread. Measured on the real CCD, the diagnosis' peak less
/// the datasheet's: 4 MB on 1 thread, then 3.5 MB (11.5 bytes a pixel) more a thread up to
/// 8 (here 12).
pub const EMVA_THREAD_BYTES_PER_PIXEL: u64 = 12;

/// What `diagnose` of the EMVA set `set` holds at most at once, from its descriptor before
/// any frame is decoded: the datasheet's ([`crate::analyses::emva::sheet::need`]; the
/// defect maps of each half of the spatial series are made as the datasheet's is), the
/// defect flags and maps beside it, the frames its other steps decode on each thread, and
/// the frames' code histograms (two halves, a histogram of `2^bits` codes per column
/// class for each thread and its reduction).
fn emva_need(set: &crate::analyses::emva::EmvaSet) -> crate::infra::budget::Need {
    use crate::infra::budget::{bytes_of, threads};
    let pixels = (set.width as u64).saturating_mul(set.height as u64);
    let classes = if set.width >= 2 * INTERLEAVED_ADCS { INTERLEAVED_ADCS as u64 } else { 1 };
    crate::analyses::emva::sheet::need(set)
        .with("the defect flags and maps", bytes_of(pixels, EMVA_DEFECT_BYTES_PER_PIXEL))
        .with(format!("the frames of its other steps ({} threads)", threads()), bytes_of(pixels, EMVA_THREAD_BYTES_PER_PIXEL * threads()))
        .with("the code histograms", bytes_of(2 * threads() + 2, classes * (8u64 << set.bits)))
}

/// Whether `input` is an EMVA descriptor (text with an `n` record) rather than FITS (which
/// starts with SIMPLE). Only a regular file is looked at, and only one small enough to be
/// a descriptor is read whole; anything larger is left to the FITS readers.
fn looks_like_descriptor(input: &Path) -> Result<bool, HostError> {
    use crate::analyses::emva::DESCRIPTOR_LIMIT;
    if crate::formats::input::starts_with(input, b"SIMPLE")? {
        return Ok(false);
    }
    Ok(match crate::formats::input::read_text(input, DESCRIPTOR_LIMIT) {
        Ok(text) => text.lines().any(|l| l.trim_start().starts_with("n ")),
        Err(HostError::TooLarge { .. } | HostError::NotUtf8 { .. }) => false,
        Err(e) => return Err(e),
    })
}

/// Diagnoses `input` (a histogram set, a linearity set or an EMVA 1288 descriptor); with
/// `out`, stages `residuals.png`, `report.html`, `model.toml` (the extended camera model
/// `dncal simulate --model` reads), one figure per finding and, for EMVA sets, `codes.png`
/// in its directory (published by the caller with the rest of its outputs).
pub fn diagnose(input: &Path, params: &DiagnoseParams, out: Option<OutDir<'_>>) -> Result<DiagnoseSummary, HostError> {
    diagnose_as(input, input, params, out)
}

/// How `diagnose` reads and splits its data.
#[derive(Debug, Clone, Default)]
pub struct DiagnoseParams {
    /// The flattening of a histogram set's counts (the paper's recipe).
    pub flatten: FlattenParams,
    /// Seed of a histogram set's held-out split.
    pub seed: u64,
    /// A linearity set read from its file this many rows at a time instead of held whole
    /// ([`crate::analyses::diagnose::diagnose_linearity_rows`]); without it, so read only where the
    /// set held whole would not fit the memory budget.
    pub block_rows: Option<usize>,
    /// A linearity set's per-pixel records kept in temporary files
    /// ([`crate::analyses::diagnose::diagnose_linearity_spilled`]); without it, so kept only where
    /// they would not fit the memory budget.
    pub spill: bool,
}

/// [`diagnose`] of each of `inputs`; with `out`, the reports in `out` (one input) or in
/// `out/0`, `out/1`, ... (several), all published together: a failure on the last input
/// leaves no report of the first.
pub fn diagnose_files(inputs: &[PathBuf], params: &DiagnoseParams, out: Option<&Path>) -> Result<Vec<DiagnoseSummary>, HostError> {
    let mut staged = Outputs::new();
    if let Some(o) = out {
        expect_reports(&mut staged, inputs.len(), o)?;
    }
    let mut all = Vec::new();
    for (i, input) in inputs.iter().enumerate() {
        let dir = out.map(|o| report_dir(o, i, inputs.len()));
        all.push(diagnose(input, params, dir.as_deref().map(|d| OutDir::new(&mut staged, d)))?);
    }
    staged.publish()?;
    Ok(all)
}

/// Where the report of input `i` of `n` goes in `out`: `out` itself for one input,
/// `out/0`, `out/1`, ... for several.
fn report_dir(out: &Path, i: usize, n: usize) -> PathBuf {
    if n > 1 { out.join(i.to_string()) } else { out.to_path_buf() }
}

/// [`expect_report`] for each of the `n` reports of [`diagnose_files`] in `out`.
pub fn expect_reports(files: &mut Outputs, n: usize, out: &Path) -> Result<(), HostError> {
    (0..n).try_for_each(|i| expect_report(files, &report_dir(out, i, n)))
}

/// The files every report of [`diagnose`] may write, checked and created (the directory)
/// before anything is computed; a histogram set's test figures are named once the set is
/// read, the figures of the findings only once found.
pub fn expect_report(files: &mut Outputs, dir: &Path) -> Result<(), HostError> {
    files.create_dir(dir)?;
    files.expect(["residuals.png", "report.html", "model.toml", "codes.png"].map(|n| dir.join(n)))
}

/// The histogram test figure of each of `n_adc` ADCs a report in `dir` may write
/// (`dnl_inl_adcA.png`), checked before the diagnosis computes.
pub fn expect_adc_figures(files: &mut Outputs, dir: &Path, n_adc: usize) -> Result<(), HostError> {
    files.expect((0..n_adc).map(|a| dir.join(format!("dnl_inl_adc{a}.png"))))
}

/// [`diagnose`] of the file at `read_from`, named `input` in the report: for a command
/// that diagnoses a file it has staged but not published yet (`demo`).
pub fn diagnose_as(read_from: &Path, input: &Path, params: &DiagnoseParams, mut out: Option<OutDir<'_>>) -> Result<DiagnoseSummary, HostError> {
    // The histogram analyses flatten each ADC alone, whatever recipe builds the LUTs.
    let per_adc = params.flatten.per_adc();
    let (flatten, seed) = (&per_adc, params.seed);
    if let Some(o) = out.as_mut() {
        expect_report(o.files, o.dir)?;
    }
    let is_descriptor = looks_like_descriptor(read_from)?;
    let model: Option<crate::model::camera::CameraConfig>;
    let diagnosis = if is_descriptor {
        let set = crate::analyses::emva::read_descriptor(read_from)?;
        emva_need(&set).check(input, &format!("diagnosing the EMVA 1288 set of {} x {} pixels", set.width, set.height))?;
        let spin = crate::infra::progress::spinner(&format!("diagnosing {} (EMVA 1288 set: photon transfer, code density)", input.display()));
        let points = crate::analyses::emva::photon_transfer(&set)?;
        // The frames' code density: all columns as one ADC, then the columns of each of
        // four interleaved ADCs (column c read by ADC c mod 4, as the MV-D1024E's): where
        // some of them show a width pattern and others do not, it is named on those ADCs
        // only (a pattern on one ADC, diluted, can pass for all columns').
        // One pass over the frames: each half's histogram per column class, summed for
        // all columns.
        let classes = if set.width >= 2 * INTERLEAVED_ADCS { INTERLEAVED_ADCS } else { 1 };
        let halves = crate::analyses::emva::code_histogram_halves(&set, classes)?;
        let pooled = |h: &[Vec<u64>]| -> Vec<u64> { (0..h[0].len()).map(|k| h.iter().map(|c| c[k]).sum()).collect() };
        let (a, b) = (pooled(&halves[0]), pooled(&halves[1]));
        let (mut code_findings, mut dnl_adcs, mut code_density, mut not_tested) = (Vec::new(), Vec::new(), None, Vec::new());
        match diagnose_code_density(&a, &b, 0) {
            Ok((findings, residuals, density)) => {
                (code_findings, dnl_adcs) = if classes == INTERLEAVED_ADCS { code_density_by_adc(&halves, findings) } else { (findings, Vec::new()) };
                code_density = Some((density, residuals));
            }
            // A quantization-limited camera's narrow levels may leave too few codes with
            // counts in both halves: the ADC is then not tested, and the rest still is.
            Err(m) => not_tested.push(format!("adc-dnl (code density): {m}")),
        }
        // The defect pixels first: once both halves of the spatial series confirm them,
        // every later step is taken without them (a hot pixel that saturates at the bright
        // levels moved the level means by 40 pixels' share and read as a 1.5 DN bend,
        // `global-nonlinearity` at 75 sigma).
        let (defect_findings, defects) = match crate::analyses::diagnose::diagnose_defects(&set)? {
            crate::analyses::diagnose::DefectOutcome::Tested { findings, defects } => (findings, defects),
            crate::analyses::diagnose::DefectOutcome::NotTested(why) => {
                not_tested.push(why);
                (Vec::new(), Vec::new())
            }
        };
        // An ADC with named code widths has integral nonlinearity too (its cumulative code
        // offsets, about 2 DN at 3% rms DNL), which moves its level means: the photon
        // transfer is then diagnosed on the other ADCs' columns (with all columns, 3% on
        // one ADC of four read as `global-nonlinearity` at 107 sigma and `unexplained` at 80).
        let pixels = set.width * set.height;
        let keep: Vec<bool> = (0..pixels).map(|i| !dnl_adcs.contains(&((i % set.width) % INTERLEAVED_ADCS)) && !defects.get(i).copied().unwrap_or(false)).collect();
        let kept = keep.iter().filter(|k| **k).count();
        let points = if kept == pixels { points } else { crate::analyses::emva::photon_transfer_selected(&set, &keep)? };
        let mut d = diagnose_ptc(&points, kept, 0.01).map_err(|source| HostError::Diagnose { path: input.into(), source })?;
        if !dnl_adcs.is_empty() {
            let list: Vec<String> = dnl_adcs.iter().map(|a| a.to_string()).collect();
            d.baseline.model += &format!("; the columns of ADC {} left out (named code widths: their integral nonlinearity moves the level means)", list.join(", "));
        }
        let n_defects = defects.iter().filter(|d| **d).count();
        if n_defects > 0 {
            d.baseline.model += &format!("; the {n_defects} defect pixels left out");
        }
        d.findings.extend(code_findings);
        d.findings.extend(defect_findings);
        d.not_tested.extend(not_tested);
        if let Some((density, residuals)) = code_density {
            d.code_density = Some(density);
            d.code_residuals = Some(residuals);
        }
        let sheet = crate::analyses::emva::datasheet_of(&set, &points, None)?;
        let dark = points.first().map_or(0.0, |p| p.dark_mean_dn);
        model = Some(ptc_model(&set, &sheet, dark, &mut d));
        spin.finish_and_clear();
        d
    } else {
        let plan = |shape: &HistogramShape| histograms_need(shape).check(input, &format!("diagnosing the histogram set of {} ADCs of {} codes", shape.n_adc, shape.codes));
        let hist = match read_histograms_for_analysis_planned(read_from, plan) {
            Ok(h) => h,
            // A histogram set too large for the budget: not read again as a linearity set.
            Err(e @ HostError::OverBudget { .. }) => return Err(e),
            Err(e) => {
                // Not a histogram set: a linearity set, or the histogram reader's error (the
                // linearity reader's where the file says it is a linearity set: its fault,
                // not "not a histogram set").
                let (d, model) = match diagnose_linearity_file(read_from, input, params.block_rows, params.spill) {
                    Ok(r) => r,
                    Err(kept @ (HostError::OverBudget { .. } | HostError::Diagnose { .. })) => return Err(kept),
                    Err(le) if crate::formats::fits::is_linearity_set(read_from) => return Err(le),
                    Err(_) => return Err(e),
                };
                return report(input, d, Some(model), out, ("level", "baseline (linear pixels): RMS over pixels"));
            }
        };
        if let Some(o) = out.as_mut() {
            expect_adc_figures(o.files, o.dir, hist.counts.len())?;
        }
        // A stage line: the analysis counts its ADCs on a bar of its own.
        crate::infra::progress::stage(&format!("diagnosing {} (histogram set, {} ADCs of {} codes)", input.display(), hist.counts.len(), 1u64 << hist.bit_depth));
        let d = diagnose_histograms(&hist, flatten, seed);
        let d = d.map_err(|source| HostError::Diagnose { path: input.into(), source })?;
        model = Some(extended_model(&hist, &d, flatten).map_err(|source| HostError::Diagnose { path: input.into(), source })?);
        d
    };
    let labels = if is_descriptor { ("level (by photons)", "baseline (linear camera)") } else { ("code (DN)", "baseline (ideal ADC)") };
    report(input, diagnosis, model, out, labels)
}

impl Report for DiagnoseSummary {
    /// The summary as `dncal diagnose` prints it without `--json`: the baseline, each
    /// finding (on the all-data scale and on its own test), what was not tested, and what
    /// is left unexplained.
    fn text(&self) -> String {
        let d = &self.diagnosis;
        let mut t = format!("{}: baseline ({}) held-out RMS {:.3}\n", self.input.display(), d.baseline.model, d.baseline.rms);
        if d.findings.is_empty() {
            t += "  no finding: the baseline explains the data\n";
        }
        for f in &d.findings {
            let all = f.all_data_rms_after.map_or(String::new(), |r| format!("all data -> {r:.3}; "));
            t += &format!("  {}: significance {:.1}, {all}its test RMS {:.3} -> {:.3} (gain {:.2}); {}\n", f.label(), f.significance, f.rms_before, f.rms_after, f.gain, f.detail);
        }
        for note in &d.not_tested {
            t += &format!("  not tested: {note}\n");
        }
        if let Some(rows) = d.block_rows {
            t += &format!("  (the set read from its file {rows} rows at a time: the numbers of the set held whole, in less memory)\n");
        }
        if d.records_spilled {
            t += "  (the per-pixel records kept in temporary files: the numbers of records held, in less memory)\n";
        }
        t += &format!("  all data: RMS {:.3} unexplained (baseline {:.3})\n", d.unexplained_rms, d.baseline.rms);
        t
    }
}

/// Stages the report of `diagnosis` (and the extended `model`, if any) in `out`.
fn report(input: &Path, mut diagnosis: Diagnosis, model: Option<crate::model::camera::CameraConfig>, out: Option<OutDir<'_>>, (x_label, base_label): (&str, &str)) -> Result<DiagnoseSummary, HostError> {
    // What the model leaves is listed after what it found (stable: the findings keep the
    // order they entered the model in; a level term named `unexplained` is a model step
    // and keeps its place).
    diagnosis.findings.sort_by_key(|f| f.effect == Effect::Unexplained && f.all_data_rms_after.is_none());
    let mut outputs = Vec::new();
    if let Some(OutDir { files, dir }) = out {
        let n = diagnosis.residuals.len();
        // Per ADC where the residuals are (histograms); one curve over all pixels otherwise
        // (a linearity set or an EMVA series is not split by ADC).
        let whose = |a: usize| if n > 1 { format!("ADC {a}: ") } else { String::new() };
        let mut series: Vec<Series> = diagnosis.residuals.iter().enumerate().map(|(a, r)| Series { label: format!("{}{base_label}", whose(a)), points: r.baseline.iter().map(|&(k, z)| (k as f64, z)).collect() }).collect();
        series.extend(diagnosis.residuals.iter().enumerate().map(|(a, r)| Series { label: format!("{}with the findings", whose(a)), points: r.extended.iter().map(|&(k, z)| (k as f64, z)).collect() }));
        let fig = dir.join("residuals.png");
        line_plot(files, &fig, "Held-out residuals / expected noise, before and after", x_label, "normalized residual", &series, n)?;
        let html_path = dir.join("report.html");
        let mut h = format!(
            "<!doctype html><html><head><meta charset=\"utf-8\"><title>dncal diagnose</title><style>body{{font-family:sans-serif;max-width:1050px;margin:2em auto}}td,th{{padding:2px 10px}}</style></head><body><h1>dncal diagnose: {}</h1>\
             <h2>Findings</h2><p>Each effect the baseline model lacks, in the order they entered the model; significance in standard deviations of the drop of the held-out mean squared residual. \
             RMS of the normalized residual (1 is noise) on two scales: <b>all data</b>, over every held-out point the baseline is scored on, from the baseline (first row) through the model with each finding and those above it to what is left unexplained (last row); \
             and <b>its test</b>, on the held-out data each finding is tested on, before and after adding it (their ratio is the gain). \
             A dash on the all-data scale: the finding is tested on other data (maps of dark and gain, flagged pixels, the frames' code density, the dark noise) and leaves those residuals as they were, or names what the model leaves.</p>\
             <table><tr><th rowspan=\"2\">effect</th><th rowspan=\"2\">ADC</th><th rowspan=\"2\">significance</th><th>all data</th><th colspan=\"3\">its test</th><th rowspan=\"2\">figure</th><th rowspan=\"2\">evidence</th></tr>\
             <tr><th>RMS after</th><th>RMS before</th><th>after</th><th>gain</th></tr>\
             <tr><td>baseline</td><td>-</td><td>-</td><td>{:.3}</td><td>-</td><td>-</td><td>-</td><td>-</td><td>{}</td></tr>",
            crate::formats::outputs::html_path(input),
            diagnosis.baseline.rms,
            crate::formats::outputs::html_escape(&diagnosis.baseline.model),
        );
        // Finding figures are numbered 1, 2, ... in the order of the table, which links them.
        let (mut figure_of, mut figures) = (Vec::with_capacity(diagnosis.findings.len()), 0);
        for f in &diagnosis.findings {
            let number = f.residuals.is_some().then(|| {
                figures += 1;
                figures
            });
            figure_of.push(number);
            let link = number.map_or("-".to_string(), |k| format!("<a href=\"#figure-{k}\">{k}</a>"));
            let all = f.all_data_rms_after.map_or("-".to_string(), |r| format!("{r:.3}"));
            let _ = write!(h, "<tr><td>{}</td><td>{}</td><td>{:.1}</td><td>{all}</td><td>{:.3}</td><td>{:.3}</td><td>{:.2}</td><td>{link}</td><td>{}</td></tr>", f.effect, f.adc.map_or("-".into(), |a| a.to_string()), f.significance, f.rms_before, f.rms_after, f.gain, crate::formats::outputs::html_escape(&f.detail));
        }
        if diagnosis.findings.is_empty() {
            h += "<tr><td colspan=\"9\">no finding: the baseline explains the data to within what the tests resolve</td></tr>";
        }
        let _ = write!(h, "<tr><td><b>left unexplained</b></td><td>-</td><td>-</td><td><b>{:.3}</b></td><td>-</td><td>-</td><td>-</td><td>-</td><td>the extended model's held-out residual over all the data</td></tr></table>", diagnosis.unexplained_rms);
        // One figure per finding: the held-out residuals just before and just after it.
        for (f, number) in diagnosis.findings.iter().zip(&figure_of) {
            let (Some(r), Some(k)) = (&f.residuals, number) else { continue };
            let name = format!("finding-{k}-{}.png", f.effect);
            let what = f.label();
            let series = [
                Series { label: "before".into(), points: r.baseline.iter().map(|&(k, z)| (k as f64, z)).collect() },
                Series { label: format!("with {what}"), points: r.extended.iter().map(|&(k, z)| (k as f64, z)).collect() },
            ];
            // An ADC's code widths are seen by code, except in a linearity set (by level).
            let axis = if f.effect == Effect::AdcDnl && diagnosis.baseline.kind != "linearity-set" { "code (DN)" } else { x_label };
            line_plot(files, &dir.join(&name), &format!("{what}: held-out residuals / noise, before and after (gain {:.2})", f.gain), axis, "normalized residual", &series, 1)?;
            let _ = write!(h, "<h2 id=\"figure-{k}\">Figure {k}: {what}</h2><p>{}</p>{}", crate::formats::outputs::html_escape(&f.detail), html_figure(&name, 1000, &format!("{what}: held-out residuals before and after"), None));
            outputs.push(dir.join(name));
        }
        // The remainder last: what the baseline left, and what the findings leave unexplained.
        let _ = write!(
            h,
            "<h2>Remainder</h2><p>Baseline: {}. Held-out RMS of the normalized residual over all the data: {:.3} before the findings, <b>{:.3} unexplained</b> after all of them (1 is noise).</p>{}",
            crate::formats::outputs::html_escape(&diagnosis.baseline.model),
            diagnosis.baseline.rms,
            diagnosis.unexplained_rms,
            html_figure("residuals.png", 1000, "Held-out residuals over noise, baseline and with the findings", None)
        );
        h += "</body></html>";
        if let Some(r) = &diagnosis.code_residuals {
            let codes_fig = dir.join("codes.png");
            let series = [
                Series { label: "ideal ADC".into(), points: r.baseline.iter().map(|&(k, z)| (k as f64, z)).collect() },
                Series { label: "with the findings".into(), points: r.extended.iter().map(|&(k, z)| (k as f64, z)).collect() },
            ];
            line_plot(files, &codes_fig, "Code density of the frames: held-out residuals / expected noise", "code (DN)", "normalized residual", &series, 1)?;
            h = h.replace("</body></html>", &format!("<h2>Code density of the frames</h2>{}</body></html>", html_figure("codes.png", 1000, "Code density of the frames", None)));
            outputs.push(codes_fig);
        }
        if let Some(tests) = &diagnosis.adc_linearity {
            // The IEEE 1241 histogram test of each ADC on all its counts.
            let mut section = String::from("<h2>ADC histogram test (IEEE 1241)</h2><p>Each ADC on all its counts (smooth density: the paper's spline and running median): DNL and INL, missing, wide and narrow codes by number, the resolution the counts allow, and the structure (periods, bit boundaries, a binary-weighted SAR); docs/adc-histogram-test.md.</p>");
            for (a, t) in tests.iter().enumerate().filter_map(|(a, t)| t.as_ref().map(|t| (a, t))) {
                let name = format!("dnl_inl_adc{a}.png");
                t.figure(files, &dir.join(&name), &format!("ADC {a}: IEEE 1241 histogram test, {:.1} counts a code", t.resolution.counts_per_code))?;
                let _ = write!(section, "<h3>ADC {a}</h3><pre>{}</pre>{}", crate::formats::outputs::html_escape(&t.text("")), html_figure(&name, 1000, &format!("ADC {a}: DNL and INL"), None));
                outputs.push(dir.join(name));
            }
            h = h.replace("</body></html>", &format!("{section}</body></html>"));
        }
        if let Some(archs) = diagnosis.adc_architecture.as_ref().filter(|v| v.iter().any(Option::is_some)) {
            // The architectures of each adc-dnl ADC, held out.
            let mut section = String::from(
                "<h2>ADC architectures</h2><p>Each ADC with <code>adc-dnl</code>: every candidate architecture fitted on one half of the counts and scored on the other (held-out mean z<sup>2</sup>, 1 is noise), against the ideal ADC and the per-code widths. \
                 The one kept is the fewest parameters within one sqrt(2/N) of the best; <b>in the model</b> when it is significant and scores within 5 sqrt(2/N) of the per-code widths (docs/diagnose.md).</p>\
                 <table><tr><th>ADC</th><th>architecture</th><th>parameters</th><th>held-out mean z<sup>2</sup></th><th>significance</th></tr>",
            );
            for a in archs.iter().flatten() {
                let _ = write!(section, "<tr><td>{}</td><td><i>ideal ADC</i></td><td>0</td><td>{:.3}</td><td>-</td></tr><tr><td>{}</td><td><i>per-code widths</i></td><td>-</td><td>{:.3}</td><td>-</td></tr>", a.adc, a.mean_z2_ideal, a.adc, a.mean_z2_widths);
                for (i, c) in a.candidates.iter().enumerate() {
                    let name = if i == 0 { format!("<b>{}</b>{}", crate::formats::outputs::html_escape(&c.name), if a.adopted { " (in the model)" } else { " (kept; not in the model)" }) } else { crate::formats::outputs::html_escape(&c.name) };
                    let _ = write!(section, "<tr><td>{}</td><td>{name}</td><td>{}</td><td>{:.3}</td><td>{:.1}</td></tr>", a.adc, c.parameters, c.mean_z2, c.significance);
                }
            }
            section += "</table>";
            h = h.replace("</body></html>", &format!("{section}</body></html>"));
        }
        files.write_bytes(&html_path, &h)?;
        outputs.extend([fig, html_path]);
        if let Some(m) = model.as_ref().filter(|m| match m.validate() {
            Ok(()) => true,
            Err(e) => {
                eprintln!("dncal: warning: {}: the extended model is not written: {e}", input.display());
                false
            }
        }) {
            let path = dir.join("model.toml");
            let text = toml::to_string(m).map_err(|e| HostError::encode(path.clone(), e))?;
            let note = |f: &Finding| match f.effect.in_model() {
                crate::analyses::diagnose::InModel::NotYet => Some(format!("# not in the camera model yet: {}\n", f.label())),
                crate::analyses::diagnose::InModel::OfTheMeasurement => Some(format!("# of the measurement, not the camera (not simulated): {}\n", f.effect)),
                crate::analyses::diagnose::InModel::Yes => None,
            };
            let mut not_simulated: Vec<String> = diagnosis.findings.iter().filter_map(note).collect();
            if let (false, Some(f)) = (diagnosis.measured.saturated, diagnosis.measured.full_scale_dn) {
                not_simulated.push(format!("# the data do not reach saturation: the full well is at least {f:.0} DN above dark; 1.1 times that is assumed\n"));
            }
            let text = format!("# The model `dncal diagnose` extended from {}: `dncal simulate --model` reads it.\n{}{text}", input.display(), not_simulated.concat());
            files.write_bytes(&path, &text)?;
            outputs.push(path);
        }
    }
    Ok(DiagnoseSummary { input: input.into(), diagnosis, outputs })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Where the set and the records go, against sizes worked by hand: 469 bytes a pixel
    /// of records held, 8 bytes a value of the set held (mean and deviation as `f32`),
    /// and spilled, 13 blocks read and one written by each thread and one more, of at
    /// most 256 KiB (120 bytes a pixel for a small set).
    #[test]
    fn the_set_and_records_go_where_they_fit() {
        let (gib, t) = (1u64 << 30, rayon::current_num_threads() as u64);
        let blocks = |per: u64| 14 * (t + 1) * per;
        let np = 2048 * 2048;
        assert_eq!(state(np, false), np * 469);
        assert_eq!(state(np, true), np + blocks(256 << 10));
        assert_eq!(state(64, true), 64 + blocks(64 * 120));
        // 2048 x 2048 x 41: the set held is 1.31 GiB, its records held 1.83 GiB.
        // 2 GiB: the set is held and its records spilled.
        assert!(spill_records(np, np * 41 * 8, false, 2 * gib));
        assert!(!read_by_rows(np, 41, 0, false, false, 2 * gib));
        // 3 GiB: the set is held and its records spilled; 3.5 GiB: both held.
        assert!(spill_records(np, np * 41 * 8, false, 3 * gib));
        assert!(!spill_records(np, np * 41 * 8, false, 7 * gib / 2));
        assert!(!read_by_rows(np, 41, 0, false, false, 7 * gib / 2));
        // 1 GiB: the set alone does not fit; by rows.
        assert!(read_by_rows(np, 41, 0, false, false, gib));
        // Asked for, whatever fits.
        assert!(read_by_rows(np, 41, 0, true, false, 3 * gib) && spill_records(np, 0, true, 3 * gib));
        // 64 pixels in 48 KiB: beside 16 KiB, their records held (29.3 KiB) fit; beside
        // 30 KiB they do not, but spilled they would take more (the blocks): held (and
        // refused by the budget).
        assert!(!spill_records(64, 16 << 10, false, 48 << 10));
        assert!(!spill_records(64, 30 << 10, false, 48 << 10));
    }
}
