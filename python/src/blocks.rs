//! The linearity analysis' stages on one block of pixels, for `dncal.dask.fit_linearity`
//! (`dncal-host`'s `analyses::linearity::stages`): the Python side maps them over a Dask
//! array's blocks and merges what they return. Only integers and multisets cross between
//! blocks (histogram counts, collected values, exact sums' limbs, counts), so any split and
//! any merge order give the in-memory analysis' bits. Private to the package (`_lin_*`).

use dncal_host::analyses::linearity::stages::{counted_means, fill_cube, mask_of, MaskRule, Plan, STATISTICS};
use dncal_host::analyses::linearity::{check_flat_counts, unsaturated_levels, Cube, LinearityError, MAX_ORDER};
use dncal_host::analyses::linearity::run::check_plan;
use dncal_host::model::camera::config::cfa_cell;
use dncal_host::formats::fits::{check_linearity, SetView};
use dncal_host::infra::exact_sum::{ExactRms, ExactSum, LIMBS};
use dncal_host::infra::select::{median_rank, medians_of, Counter, Selection, Tally};
use dncal_host::{HostError, Origin};
use numpy::{Ix1, Ix2, Ix3, PyArray1, PyArray2, PyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::arrays;
use crate::errors::raise;

/// The set's keys, reference and order: the `keys` tuple `dncal.dask` passes to every
/// stage, `(voltage (levels,) V, frames, bit_depth, n_adc, order, flat_level)`.
#[derive(Clone, FromPyObject)]
struct Keys(Vec<f64>, u32, u32, usize, usize, Option<usize>);

impl Keys {
    fn voltage(&self) -> &[f64] {
        &self.0
    }

    fn order(&self) -> usize {
        self.4
    }

    fn plan(&self) -> Plan {
        Plan::new(&self.0, self.2, self.1, self.4, self.5)
    }

    /// A block's view of `(levels, rows, cols)` arrays.
    fn view<'b>(&'b self, mean: &'b [f64], std: &'b [f64], height: usize, width: usize) -> SetView<'b> {
        SetView { bit_depth: self.2, n_adc: self.3, n_frames: self.1, width, height, levels: self.0.len(), mean, std, voltage: &self.0, mask: None, keys: Default::default() }
    }
}

fn linearity_error(source: LinearityError) -> PyErr {
    crate::errors::to_py(HostError::Linearity { origin: Origin::Argument("linearity set"), source })
}

/// The set's keys and reference, and the order against its levels, checked as the
/// in-memory fit checks them (before any block is read).
#[pyfunction]
fn _lin_check(keys: Keys) -> PyResult<()> {
    let order = keys.order();
    if !(1..=MAX_ORDER).contains(&order) {
        return Err(PyValueError::new_err(format!("order {order}: the pixel-wise polynomial order must be 1 to {MAX_ORDER}")));
    }
    // The keys and the reference of a one-pixel set of zeros: its values pass, its keys
    // and reference are the set's.
    let zeros = vec![0.0; keys.voltage().len()];
    check_linearity(&keys.view(&zeros, &zeros, 1, 1)).map_err(|fault| raise("InputError", format!("linearity set: {fault}")))?;
    check_plan(keys.voltage(), order).map_err(linearity_error)
}

/// Stage 1 of a block: (unsaturated levels uint64 (rows, cols), coefficients float64
/// (rows, cols, order + 1), fit residual (rows, cols), flat signal (rows, cols)). The
/// block's values and its part of the input `mask` are checked as the in-memory fit
/// checks the set's, the error naming the block by its first row and column.
#[pyfunction]
#[pyo3(signature = (mean, std, keys, first_row, first_column, mask = None))]
#[allow(clippy::type_complexity)]
fn _lin_fit<'py>(
    py: Python<'py>,
    mean: &Bound<'py, PyAny>,
    std: &Bound<'py, PyAny>,
    keys: Keys,
    first_row: usize,
    first_column: usize,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyArray2<u64>>, Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
    let m = arrays::view::<f64, Ix3>(mean, "mean", "(levels, rows, cols)")?;
    let s = arrays::view::<f64, Ix3>(std, "std", "(levels, rows, cols)")?;
    let (height, width) = (m.shape()[1], m.shape()[2]);
    if s.shape() != m.shape() || m.shape()[0] != keys.voltage().len() {
        return Err(PyValueError::new_err(format!("block: mean {:?}, std {:?}, {} voltages", m.shape(), s.shape(), keys.voltage().len())));
    }
    let k = mask.map(|k| arrays::view::<u8, Ix2>(k, "mask", "(rows, cols)")).transpose()?;
    let set = keys.view(m.as_slice()?, s.as_slice()?, height, width);
    check_linearity(&SetView { mask: k.as_ref().map(|k| k.as_slice()).transpose()?, ..set }).map_err(|fault| raise("InputError", format!("linearity set, the block from row {first_row}, column {first_column} (positions below counted within it): {fault}")))?;
    let fits = py.detach(|| keys.plan().fit(&set, unsaturated_levels(&set)));
    let k1 = keys.plan().k1();
    Ok((
        arrays::new(py, (height, width), fits.valid.iter().map(|&n| n as u64).collect())?,
        arrays::new(py, (height, width, k1), fits.coef)?,
        arrays::new(py, (height, width), fits.resid)?,
        arrays::new(py, (height, width), fits.signal)?,
    ))
}

/// The flat level checked against the count of pixels per number of unsaturated levels
/// (`reaching`, (levels + 1,), added over the blocks).
#[pyfunction]
fn _lin_check_flat(reaching: Vec<usize>, flat_level: usize) -> PyResult<()> {
    check_flat_counts(&reaching, flat_level).map_err(|e| raise("InputError", format!("--flat-level: {e} (linearity set)")))
}

/// A search for the exact medians of `queries` sets of about `items` values each spread
/// over blocks (the driver's side): [`Selection`] with two cells per set.
#[pyclass(module = "dncal._dncal", name = "_MedianSearch")]
struct MedianSearch {
    search: Selection,
}

#[pymethods]
impl MedianSearch {
    #[new]
    fn new(queries: usize, items: usize) -> Self {
        MedianSearch { search: Selection::new(2 * queries, items) }
    }

    /// Whether every median is found.
    #[getter]
    fn done(&self) -> bool {
        self.search.done()
    }

    /// What the next pass counts, as words for the blocks.
    fn counter<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u64>>> {
        let w = self.search.counter().to_words();
        arrays::new(py, w.len(), w)
    }

    /// Takes the pass's total: the words of the blocks' tallies merged
    /// (`_median_merge`).
    fn advance(&mut self, total: &Bound<'_, PyAny>) -> PyResult<()> {
        let cells = self.search.values().len();
        let tally = tally_of(total)?;
        if tally.cells() != cells {
            return Err(PyValueError::new_err(format!("tally: {} cells, but this search has {cells}", tally.cells())));
        }
        self.search.advance(tally, &median_rank);
        Ok(())
    }

    /// (medians float64 (queries,), counts of finite values uint64 (queries,)).
    #[allow(clippy::type_complexity)]
    fn medians<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<u64>>)> {
        let m = medians_of(&self.search);
        Ok((arrays::new(py, m.len(), m.iter().map(|x| x.0).collect())?, arrays::new(py, m.len(), m.iter().map(|x| x.1 as u64).collect())?))
    }
}

/// A tally of its words (uint64 (n,)).
fn tally_of(words: &Bound<'_, PyAny>) -> PyResult<Tally> {
    let w = arrays::view::<u64, Ix1>(words, "tally", "(n,)")?;
    Tally::from_words(w.as_slice()?).ok_or_else(|| PyValueError::new_err("tally: not the words of a median search's tally"))
}

/// Blocks' tallies of one pass (their words) merged into one (counts added, values
/// appended: any order gives the same medians). Tallies of different cell counts are
/// refused; counts of different kinds end their medians as NaN (never a wrong value).
#[pyfunction]
fn _median_merge<'py>(py: Python<'py>, tallies: Vec<Bound<'py, PyAny>>) -> PyResult<Bound<'py, PyArray1<u64>>> {
    let mut all = tallies.iter().map(tally_of).collect::<PyResult<Vec<_>>>()?.into_iter();
    let mut total = all.next().ok_or_else(|| PyValueError::new_err("tallies: none to merge"))?;
    if let Some(t) = all.as_slice().iter().find(|t| t.cells() != total.cells()) {
        return Err(PyValueError::new_err(format!("tallies: {} cells and {}, not one pass's", total.cells(), t.cells())));
    }
    py.detach(|| all.for_each(|t| total.merge(t)));
    let w = total.to_words();
    arrays::new(py, w.len(), w)
}

/// A block's tally for `counter`: `visit` calls its argument with a cell and values of
/// it (any number of calls a cell); `salt` (the block's place) makes its sample its own.
fn tally<'py>(py: Python<'py>, counter: &[u64], salt: u64, visit: impl FnOnce(&mut dyn FnMut(usize, &[f64])) + Send) -> PyResult<Bound<'py, PyArray1<u64>>> {
    let counter = Counter::from_words(counter).ok_or_else(|| PyValueError::new_err("counter: not the words of a search's counter"))?;
    let w = py.detach(|| {
        let mut t = counter.tally(salt);
        visit(&mut |c, v| counter.add_all(&mut t, c, v));
        t.to_words()
    });
    arrays::new(py, w.len(), w)
}

/// A block's tally of its flat signal (the search's sets 0-3) and fit residual (sets 4-7)
/// by cell of the 2 x 2 period (`(row mod 2) * 2 + column mod 2` of the whole frame: the
/// block starts at row `r0`, column `c0`).
#[pyfunction]
fn _lin_mask_tally<'py>(py: Python<'py>, counter: Vec<u64>, signal: &Bound<'py, PyAny>, resid: &Bound<'py, PyAny>, r0: usize, c0: usize) -> PyResult<Bound<'py, PyArray1<u64>>> {
    let s = arrays::view::<f64, Ix2>(signal, "signal", "(rows, cols)")?;
    let r = arrays::view::<f64, Ix2>(resid, "resid", "(rows, cols)")?;
    let w = s.shape()[1].max(1);
    let (s, r) = (s.as_slice()?, r.as_slice()?);
    tally(py, &counter, ((r0 as u64) << 32) ^ c0 as u64, |f| {
        for (set, values) in [s, r].into_iter().enumerate() {
            let mut by_cell: [Vec<f64>; 4] = Default::default();
            for (p, &v) in values.iter().enumerate() {
                by_cell[cfa_cell(c0 + p % w, r0 + p / w, 2)].push(v);
            }
            for (k, v) in by_cell.iter().enumerate() {
                let q = 4 * set + k;
                f(2 * q, v);
                f(2 * q + 1, v);
            }
        }
    })
}

/// A block's mask reasons, uint8 (rows, cols), given the medians (the signal's by cell of
/// the frame's 2 x 2 period; the block starts at `origin`, row and column).
#[pyfunction]
#[pyo3(signature = (signal, resid, input, median_signal, median_resid, origin))]
fn _lin_mask<'py>(py: Python<'py>, signal: &Bound<'py, PyAny>, resid: &Bound<'py, PyAny>, input: Option<&Bound<'py, PyAny>>, median_signal: [f64; 4], median_resid: [f64; 4], origin: (usize, usize)) -> PyResult<Bound<'py, PyArray2<u8>>> {
    let (r0, c0) = origin;
    let s = arrays::view::<f64, Ix2>(signal, "signal", "(rows, cols)")?;
    let r = arrays::view::<f64, Ix2>(resid, "resid", "(rows, cols)")?;
    let k = input.map(|i| arrays::view::<u8, Ix2>(i, "mask", "(rows, cols)")).transpose()?;
    if let Some(k) = &k {
        if k.shape() != s.shape() {
            return Err(PyValueError::new_err(format!("mask: shape {:?}, but the block is {:?}", k.shape(), s.shape())));
        }
    }
    let shape = (s.shape()[0], s.shape()[1]);
    // The frame's cells as the block's own (it starts at row r0, column c0).
    let own = |frame: [f64; 4]| -> [f64; 4] { std::array::from_fn(|k| frame[cfa_cell(c0 + k % 2, r0 + k / 2, 2)]) };
    let m = mask_of(s.as_slice()?, r.as_slice()?, k.as_ref().map(|k| k.as_slice()).transpose()?, MaskRule { signal: own(median_signal), width: shape.1, resid: own(median_resid) });
    arrays::new(py, shape, m)
}

/// A block's `mean` cube with its mask reasons and unsaturated levels, as slices.
struct Counted<'a> {
    set: SetView<'a>,
    mask: &'a [u8],
    valid: Vec<usize>,
}

/// [`Counted`] of Python arrays, checked against each other.
fn counted_of<'a>(mean: &'a numpy::PyReadonlyArray3<'_, f64>, mask: &'a numpy::PyReadonlyArray2<'_, u8>, valid: &numpy::PyReadonlyArray2<'_, u64>, voltage: &'a [f64]) -> PyResult<Counted<'a>> {
    let (levels, height, width) = (mean.shape()[0], mean.shape()[1], mean.shape()[2]);
    if mask.shape() != [height, width] || valid.shape() != [height, width] || levels != voltage.len() {
        return Err(PyValueError::new_err(format!("block: mean {:?}, mask {:?}, unsaturated levels {:?}, {} voltages", mean.shape(), mask.shape(), valid.shape(), voltage.len())));
    }
    let mean = mean.as_slice()?;
    let set = SetView { bit_depth: 1, n_adc: 1, n_frames: 1, width, height, levels, mean, std: mean, voltage, mask: None, keys: Default::default() };
    Ok(Counted { set, mask: mask.as_slice()?, valid: valid.as_slice()?.iter().map(|&n| n as usize).collect() })
}

/// A block's tally of each level's counted means (set `l` of the search is level `l`);
/// `salt` tells the blocks' samples apart (the block's place).
#[pyfunction]
fn _lin_level_tally<'py>(py: Python<'py>, counter: Vec<u64>, mean: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>, valid: &Bound<'py, PyAny>, voltage: &Bound<'py, PyAny>, salt: u64) -> PyResult<Bound<'py, PyArray1<u64>>> {
    let (m, k, n, v) = block_arrays(mean, mask, valid, voltage)?;
    let c = counted_of(&m, &k, &n, v.as_slice()?)?;
    tally(py, &counter, salt, |f| {
        let mut values = Vec::with_capacity(c.mask.len());
        for l in 0..c.set.levels {
            values.clear();
            values.extend(counted_means(&c.set, c.mask, &c.valid, l));
            f(2 * l, &values);
            f(2 * l + 1, &values);
        }
    })
}

type BlockArrays<'py> = (numpy::PyReadonlyArray3<'py, f64>, numpy::PyReadonlyArray2<'py, u8>, numpy::PyReadonlyArray2<'py, u64>, numpy::PyReadonlyArray1<'py, f64>);

fn block_arrays<'py>(mean: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>, valid: &Bound<'py, PyAny>, voltage: &Bound<'py, PyAny>) -> PyResult<BlockArrays<'py>> {
    Ok((
        arrays::view::<f64, Ix3>(mean, "mean", "(levels, rows, cols)")?,
        arrays::view::<u8, Ix2>(mask, "mask", "(rows, cols)")?,
        arrays::view::<u64, Ix2>(valid, "unsaturated levels", "(rows, cols)")?,
        arrays::view::<f64, Ix1>(voltage, "voltage", "(levels,)")?,
    ))
}

/// Sums' parts as arrays: limbs int64 (n, LIMBS), non-finite sums float64 (n,), counts
/// uint64 (n,).
type Parts<'py> = (Bound<'py, PyArray2<i64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<u64>>);

fn parts<'py>(py: Python<'py>, sums: impl Iterator<Item = ([i64; LIMBS], f64, u64)>) -> PyResult<Parts<'py>> {
    let (mut limbs, mut special, mut counts) = (Vec::new(), Vec::new(), Vec::new());
    for (l, s, n) in sums {
        limbs.extend(l);
        special.push(s);
        counts.push(n);
    }
    let n = counts.len();
    Ok((arrays::new(py, (n, LIMBS), limbs)?, arrays::new(py, n, special)?, arrays::new(py, n, counts)?))
}

/// Parts (as [`parts`] gives them, added over blocks) back into sums with their counts.
fn sums_of(limbs: &Bound<'_, PyAny>, special: &Bound<'_, PyAny>, counts: &Bound<'_, PyAny>) -> PyResult<Vec<ExactRms>> {
    let l = arrays::view::<i64, Ix2>(limbs, "limbs", "(n, limbs)")?;
    let s = arrays::view::<f64, Ix1>(special, "special", "(n,)")?;
    let c = arrays::view::<u64, Ix1>(counts, "counts", "(n,)")?;
    let n = c.shape()[0];
    if l.shape() != [n, LIMBS] || s.shape()[0] != n {
        return Err(PyValueError::new_err(format!("sums: limbs {:?}, special {:?}, counts {:?}", l.shape(), s.shape(), c.shape())));
    }
    let (l, s, c) = (l.as_slice()?, s.as_slice()?, c.as_slice()?);
    Ok((0..n).map(|i| ExactRms::from_parts(l[i * LIMBS..(i + 1) * LIMBS].try_into().unwrap_or([0; LIMBS]), s[i], c[i])).collect())
}

/// Stage 3 of a block: each level's exact sum of the counted means, as parts.
#[pyfunction]
fn _lin_level_sums<'py>(py: Python<'py>, mean: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>, valid: &Bound<'py, PyAny>, voltage: &Bound<'py, PyAny>) -> PyResult<Parts<'py>> {
    let (m, k, n, v) = block_arrays(mean, mask, valid, voltage)?;
    let c = counted_of(&m, &k, &n, v.as_slice()?)?;
    let sums = py.detach(|| Plan::level_sums(&c.set, c.mask, &c.valid));
    parts(py, sums.into_iter().map(|(s, n): (ExactSum, u64)| {
        let (l, sp) = s.parts();
        (l, sp, n)
    }))
}

/// Each level's mean of the counted pixels from the level sums' parts added over blocks.
#[pyfunction]
fn _lin_means<'py>(py: Python<'py>, limbs: &Bound<'py, PyAny>, special: &Bound<'py, PyAny>, counts: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let c = arrays::view::<u64, Ix1>(counts, "counts", "(n,)")?.as_slice()?.to_vec();
    let l = arrays::view::<i64, Ix2>(limbs, "limbs", "(n, limbs)")?;
    let s = arrays::view::<f64, Ix1>(special, "special", "(n,)")?;
    let (l, s) = (l.as_slice()?, s.as_slice()?);
    if l.len() != c.len() * LIMBS || s.len() != c.len() {
        return Err(PyValueError::new_err("level sums: limbs, special and counts disagree in length"));
    }
    let means: Vec<f64> = (0..c.len()).map(|i| ExactSum::from_parts(l[i * LIMBS..(i + 1) * LIMBS].try_into().unwrap_or([0; LIMBS]), s[i]).value() / c[i].max(1) as f64).collect();
    arrays::new(py, means.len(), means)
}

/// The standard correction's global cubic from the level medians and their counts, with
/// the `good` pixels of `pixels` (none good is the in-memory fit's error).
#[pyfunction]
fn _lin_global(keys: Keys, medians: Vec<f64>, counts: Vec<u64>, good: usize, pixels: usize) -> PyResult<Vec<f64>> {
    if good == 0 {
        return Err(linearity_error(LinearityError::AllMasked { pixels, order: keys.plan().order }));
    }
    let m: Vec<(f64, usize)> = medians.into_iter().zip(counts).map(|(m, n)| (m, n as usize)).collect();
    if m.len() != keys.voltage().len() {
        return Err(PyValueError::new_err(format!("{} level medians for {} levels", m.len(), keys.voltage().len())));
    }
    keys.plan().global(&m, good).map_err(linearity_error)
}

/// Stage 4 of a block: the statistics' sums per level as parts ((levels * 8) rows,
/// level-major) and, with `keep`, the corrected block (levels, rows, cols), masked pixels
/// NaN until filled.
#[pyfunction]
#[pyo3(signature = (mean, std, keys, valid, coef, mask, global_coefficients, level_means, keep))]
#[allow(clippy::too_many_arguments)]
#[allow(clippy::type_complexity)]
fn _lin_level_pass<'py>(
    py: Python<'py>,
    mean: &Bound<'py, PyAny>,
    std: &Bound<'py, PyAny>,
    keys: Keys,
    valid: &Bound<'py, PyAny>,
    coef: &Bound<'py, PyAny>,
    mask: &Bound<'py, PyAny>,
    global_coefficients: Vec<f64>,
    level_means: Vec<f64>,
    keep: bool,
) -> PyResult<(Parts<'py>, Option<Bound<'py, PyArray3<f64>>>)> {
    let m = arrays::view::<f64, Ix3>(mean, "mean", "(levels, rows, cols)")?;
    let k = arrays::view::<u8, Ix2>(mask, "mask", "(rows, cols)")?;
    let n = arrays::view::<u64, Ix2>(valid, "unsaturated levels", "(rows, cols)")?;
    let s = arrays::view::<f64, Ix3>(std, "std", "(levels, rows, cols)")?;
    let a = arrays::view::<f64, Ix3>(coef, "coefficients", "(rows, cols, order + 1)")?;
    let plan = keys.plan();
    let (levels, height, width) = (m.shape()[0], m.shape()[1], m.shape()[2]);
    if s.shape() != m.shape() || a.shape() != [height, width, plan.k1()] || level_means.len() != levels {
        return Err(PyValueError::new_err(format!("block: mean {:?}, std {:?}, coefficients {:?}, {} level means", m.shape(), s.shape(), a.shape(), level_means.len())));
    }
    let c = counted_of(&m, &k, &n, keys.voltage())?;
    let set = keys.view(c.set.mean, s.as_slice()?, height, width);
    let coef = a.as_slice()?;
    let cube = if keep { Cube::Keep } else { Cube::Skip };
    let (acc, corrected) = py.detach(|| plan.level_pass(&set, (&c.valid, coef), c.mask, &global_coefficients, &level_means, cube));
    let p = parts(py, acc.iter().flat_map(|a| a.iter().map(ExactRms::parts)))?;
    Ok((p, corrected.map(|x| arrays::new(py, (levels, height, width), x)).transpose()?))
}

/// A corrected block with a one-pixel halo (levels, rows, cols), its masked pixels filled
/// from their good neighbours (`mask` (1, rows, cols) or (rows, cols)); a new array.
#[pyfunction]
fn _lin_fill<'py>(py: Python<'py>, cube: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let c = arrays::view::<f64, Ix3>(cube, "corrected", "(levels, rows, cols)")?;
    let k: Vec<u8> = match arrays::view::<u8, Ix3>(mask, "mask", "(1, rows, cols)") {
        Ok(k3) => k3.as_slice()?.to_vec(),
        Err(_) => arrays::view::<u8, Ix2>(mask, "mask", "(rows, cols)")?.as_slice()?.to_vec(),
    };
    let (levels, height, width) = (c.shape()[0], c.shape()[1], c.shape()[2]);
    if k.len() != height * width {
        return Err(PyValueError::new_err(format!("mask: {} pixels, but the block is {height} x {width}", k.len())));
    }
    let mut out = c.as_slice()?.to_vec();
    py.detach(|| fill_cube(&mut out, &k, width, height));
    arrays::new(py, (levels, height, width), out)
}

/// The report (the JSON of `dncal linearity --json`'s "report") from the reductions.
#[pyfunction]
#[pyo3(signature = (keys, level_means, global_coefficients, limbs, special, counts, masked, pixels))]
#[allow(clippy::too_many_arguments)]
fn _lin_report(
    keys: Keys,
    level_means: Vec<f64>,
    global_coefficients: Vec<f64>,
    limbs: &Bound<'_, PyAny>,
    special: &Bound<'_, PyAny>,
    counts: &Bound<'_, PyAny>,
    masked: usize,
    pixels: usize,
) -> PyResult<String> {
    let plan = keys.plan();
    let sums = sums_of(limbs, special, counts)?;
    if sums.len() != plan.levels * STATISTICS || level_means.len() != plan.levels {
        return Err(PyValueError::new_err(format!("{} sums and {} level means for {} levels", sums.len(), level_means.len(), plan.levels)));
    }
    let acc: Vec<[ExactRms; STATISTICS]> = sums.chunks(STATISTICS).map(|c| std::array::from_fn(|i| c[i].clone())).collect();
    let report = plan.report(&acc, &level_means, global_coefficients, masked, pixels);
    serde_json::to_string(&report).map_err(|e| PyValueError::new_err(e.to_string()))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<MedianSearch>()?;
    m.add_function(wrap_pyfunction!(_median_merge, m)?)?;
    for f in [
        wrap_pyfunction!(_lin_check, m)?,
        wrap_pyfunction!(_lin_fit, m)?,
        wrap_pyfunction!(_lin_check_flat, m)?,
        wrap_pyfunction!(_lin_mask_tally, m)?,
        wrap_pyfunction!(_lin_mask, m)?,
        wrap_pyfunction!(_lin_level_tally, m)?,
        wrap_pyfunction!(_lin_level_sums, m)?,
        wrap_pyfunction!(_lin_means, m)?,
        wrap_pyfunction!(_lin_global, m)?,
        wrap_pyfunction!(_lin_level_pass, m)?,
        wrap_pyfunction!(_lin_fill, m)?,
        wrap_pyfunction!(_lin_report, m)?,
    ] {
        m.add_function(f)?;
    }
    Ok(())
}
