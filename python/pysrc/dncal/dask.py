"""dncal on Dask: the per-pixel work of a sensor larger than one machine.

Two functions: :func:`correct` (frames through the LUTs into per-state sums) and
:func:`fit_linearity` (the pixel-wise linearity analysis), each bit for bit what the
in-memory function gives on the same data.

Every pixel's sum depends only on that pixel's codes, and the ADC that reads it only on
its sensor column; so a frame stack chunked over rows and columns is corrected block by
block, each block by the core (:class:`dncal.Corrector`, with the block's first column),
and the blocks put side by side are bit for bit what one corrector gives the whole
frame. Within a block the frames are added in their order by one corrector, as the
co-processor adds them (the frame axis is one chunk per block: the core's exact sums to
512 frames and its saturation after that are per pixel, in frame order).

Needs ``dask[array]`` (``pip install './python[dask]'``); runs on any scheduler, the
threaded default or a ``dask.distributed`` cluster.
"""

from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

import json as _json
import logging
import time
from contextlib import contextmanager

from . import _dncal
from ._dncal import Corrector, Lut

try:
    import dask
    import dask.array as da
except ImportError as e:  # pragma: no cover - the message is the point
    raise ImportError("dncal.dask needs dask: pip install 'dask[array]' (or './python[dask]')") from e

#: Each global step of :func:`fit_linearity` is logged here at INFO with its wall time
#: and passes over the blocks (``logging.basicConfig(level=logging.INFO)`` shows them).
log = logging.getLogger("dncal.dask")

#: The status counters a correction sums over its blocks.
STATUS_KEYS = ("out_of_range_codes", "saturated_additions", "rejected_lines", "incomplete_frames")


def _check_array(name: str, a, dtype, axes: str, numpy_function: str) -> None:
    """A ``dask.array`` of `dtype` with the three axes `axes`, not empty: else the
    TypeError or ValueError that says which."""
    if not isinstance(a, da.Array):
        raise TypeError(f"{name}: a dask.array is needed, not {type(a).__name__} ({numpy_function} takes numpy arrays)")
    if a.dtype != dtype:
        raise TypeError(f"{name}: dtype {a.dtype}, but {np.dtype(dtype).name} is needed")
    if a.ndim != 3:
        raise ValueError(f"{name}: {a.ndim} dimension(s), but 3 {axes} are needed")
    if 0 in a.shape:
        raise ValueError(f"{name}: empty {a.shape}")


def _entries(lut) -> np.ndarray:
    """The LUT's entries: a :class:`dncal.Lut`, or a uint32 (adcs, codes) array that
    the core checks as it checks every set (another dtype is refused, not cast)."""
    entries = lut.entries if isinstance(lut, Lut) else np.asarray(lut)
    if entries.dtype != np.uint32:
        raise TypeError(f"lut: dtype {entries.dtype}, but a dncal.Lut or uint32 entries are needed")
    Lut(np.require(entries, requirements=["C", "A"]))
    return entries


def _correct_block(block: np.ndarray, entries: np.ndarray, states: int, first_column: int, frame_states: np.ndarray) -> Tuple[np.ndarray, Dict[str, int]]:
    """One block's sums (states, rows, cols) and counters, by the core."""
    # Arrays that came through pickle may be misaligned: aligned, C-ordered copies
    # where they are (a no-op where they are not).
    block = np.require(block, dtype=np.uint16, requirements=["C", "A"])
    entries = np.require(entries, dtype=np.uint32, requirements=["C", "A"])
    c = Corrector(Lut(entries), states, block.shape[1], block.shape[2], first_column=first_column)
    c.add(block, states=frame_states.tolist())
    status = c.status
    return c.sums, {k: int(status[k]) for k in STATUS_KEYS}


def _total(statuses) -> Dict[str, int]:
    """The blocks' counters added in block order (integers: any order gives the same)."""
    total = {k: 0 for k in STATUS_KEYS}
    for s in statuses:
        for k in STATUS_KEYS:
            total[k] += s[k]
    return total


def correct(frames, lut, states: int, first_column: int = 0, frame_states=None) -> Tuple[Any, Any]:
    """Sums a stack of raw frames (a ``dask.array`` of uint16, (frames, rows, cols),
    chunked over rows and columns) through ``lut`` into per-state sums.

    Frame f goes into state ``frame_states[f]`` (default f mod ``states``). Returns
    ``(sums, status)``, both lazy: ``sums`` a ``dask.array`` of uint32 (states, rows,
    cols), units of 2^-11 DN, chunked as the frames' rows and columns; ``status`` a
    ``dask.delayed`` dict of the core's counters (:data:`STATUS_KEYS`) summed over the
    blocks as Python integers (the core's own 32-bit counters saturate; these do not).
    Compute both in one pass: ``dask.compute(sums, status)``.
    """
    _check_array("frames", frames, np.uint16, "(frames, rows, cols)", "dncal.Corrector")
    if not 1 <= states <= 8:
        raise ValueError(f"states: {states}, but the core sums 1 to 8 modulation states")
    n = frames.shape[0]
    if frame_states is None:
        frame_states = np.arange(n) % states
    frame_states = np.asarray(frame_states)
    if frame_states.dtype.kind not in "iu":
        raise TypeError(f"frame_states: dtype {frame_states.dtype}, but integers are needed")
    if frame_states.shape != (n,):
        raise ValueError(f"frame_states: {frame_states.size} values for {n} frames")
    if frame_states.min() < 0 or frame_states.max() >= states:
        raise ValueError(f"frame_states: every state must be 0 to {states - 1}")
    frame_states = frame_states.astype(np.uint8)
    # Checked once here, as the core checks it, before any block runs; given to the
    # graph once, not copied into every task.
    entries = dask.delayed(_entries(lut), pure=True)
    frame_states = dask.delayed(frame_states, pure=True)
    frames = frames.rechunk({0: -1})
    blocks = frames.to_delayed()[0]  # (row blocks, column blocks) of whole frame stacks
    col_starts = np.cumsum((0,) + frames.chunks[2][:-1])
    correct_block = dask.delayed(_correct_block, nout=2, pure=True)
    rows, statuses = [], []
    for i, h in enumerate(frames.chunks[1]):
        row = []
        for j, w in enumerate(frames.chunks[2]):
            # The ADC of a column is the column mod N (N = 1, 2, 4 or 8): mod 8 keeps
            # it, and the block's first column within the core's 16 bits however wide
            # the mosaic.
            column = (first_column + int(col_starts[j])) % 8
            sums, status = correct_block(blocks[i][j], entries, states, column, frame_states)
            row.append(da.from_delayed(sums, shape=(states, h, w), dtype=np.uint32))
            statuses.append(status)
        rows.append(row)
    return da.block(rows), dask.delayed(_total)(statuses)


# ---------------------------------------------------------------------------------------
# The pixel-wise linearity analysis
# ---------------------------------------------------------------------------------------


def _c(a: np.ndarray, dtype) -> np.ndarray:
    """An aligned, C-ordered array of `dtype` (arrays from pickle may be neither)."""
    return np.require(a, dtype=dtype, requirements=["C", "A"])


def _f(fits):
    """A block's stage-1 arrays aligned (they may come through pickle)."""
    return (_c(fits[0], np.uint64), _c(fits[1], np.float64), _c(fits[2], np.float64), _c(fits[3], np.float64))


def _fit_block(mean, std, mask, keys, first_row, first_column):
    """Stage 1 of a block: (unsaturated levels, coefficients, residual, signal)."""
    return _dncal._lin_fit(_c(mean, np.float64), _c(std, np.float64), keys, first_row, first_column, mask=None if mask is None else _c(mask, np.uint8))


def _reaching(fits, levels: int) -> np.ndarray:
    """A block's count of pixels per number of unsaturated levels (levels + 1,)."""
    return np.bincount(fits[0].ravel().astype(np.int64), minlength=levels + 1)


def _merge(tallies: List[Any]):
    """Tallies of one pass added: histograms bin by bin (integers), collected values
    appended per cell (a multiset: the order does not matter)."""
    if isinstance(tallies[0], list):
        return [np.concatenate([t[c] for t in tallies]) for c in range(len(tallies[0]))]
    return np.sum(np.stack(tallies), axis=0, dtype=np.uint64)


def _add_parts(parts: List[Tuple[np.ndarray, np.ndarray, np.ndarray]]):
    """Exact sums' parts added over blocks: limbs and counts as integers; the non-finite
    values' float sums of 0, infinities and NaN (the same in any order)."""
    return (np.sum(np.stack([p[0] for p in parts]), axis=0, dtype=np.int64), np.sum(np.stack([p[1] for p in parts]), axis=0), np.sum(np.stack([p[2] for p in parts]), axis=0, dtype=np.uint64))


def _parts(p):
    """Sums' parts aligned (they may come through pickle)."""
    return (_c(p[0], np.int64), _c(p[1], np.float64), _c(p[2], np.uint64))


@contextmanager
def _step(name: str, passes: Optional[List[int]] = None):
    """Logs a step's wall time (and its passes over the blocks, counted into `passes`)."""
    t = time.perf_counter()
    yield
    extra = f", {passes[0]} passes" if passes else ""
    log.info("%s: %.3f s%s", name, time.perf_counter() - t, extra)


def _medians(queries: int, tally: Callable[[np.ndarray], List[Any]], passes: Optional[List[int]] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Exact medians of `queries` sets spread over blocks: passes of the radix search,
    each `tally(counter)` a delayed tally per block, merged and taken by the search."""
    search = _dncal._MedianSearch(queries)
    # 8 bits a pass: at most 8 histogram passes and one collection.
    for _ in range(9):
        if search.done:
            break
        if passes is not None:
            passes[0] += 1
        (total,) = dask.compute(dask.delayed(_merge)(tally(search.counter())))
        search.advance([_c(v, np.float64) for v in total] if isinstance(total, list) else _c(total, np.uint64))
    if not search.done:
        raise RuntimeError("the exact median search did not end in 9 passes: the blocks' values changed between passes")
    return search.medians()


def _level_pass(mean, std, fits, mask, keys, global_coefficients, level_means, keep):
    """Stage 4 of a block."""
    return _dncal._lin_level_pass(_c(mean, np.float64), _c(std, np.float64), keys, _f(fits)[0], _f(fits)[1], _c(mask, np.uint8), global_coefficients, level_means, keep)


def _fill(block: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A corrected block with its halo, masked pixels filled."""
    return _dncal._lin_fill(_c(block, np.float64), _c(mask, np.uint8))


def fit_linearity(mean, std, voltage, frames: int, *, order: int = 4, flat_level: Optional[int] = None, mask=None, bit_depth: int = 12, n_adc: int = 4, keep_corrected: bool = True):
    """The pixel-wise linearity analysis of a set held as Dask arrays: bit for bit what
    :func:`dncal.fit_linearity` gives on the same numbers in memory.

    ``mean`` and ``std`` are ``dask.array`` float64 (levels, rows, cols) in DN, chunked
    over rows and columns (the level axis is made one chunk); ``voltage`` float64
    (levels,), V; ``mask`` optional uint8 (rows, cols), numpy or Dask, 1 = bad.

    The work per pixel runs on the blocks; the global steps are reductions over them
    whose results do not depend on the split: the mask's two medians and each level's
    median (exact radix selections, a few passes of histograms over the blocks), each
    level's mean and the RMS statistics (exact sums, rounded once). Each block's fits
    are persisted between the passes (about 8 x (order + 4) bytes per pixel on the
    workers); ``mean`` is read once per pass (persist it too where it fits).

    Returns a :class:`dncal.LinearityFit` whose ``report`` is computed (a dict, as the
    in-memory one) and whose ``coefficients``, ``mask`` and ``corrected`` are Dask arrays
    (the corrected cube lazy: computing or storing it runs the inversion again, block by
    block, with the masked pixels filled across block edges from a one-pixel halo).
    """
    from . import LinearityFit

    for name, a in (("mean", mean), ("std", std)):
        _check_array(name, a, np.float64, "(levels, rows, cols)", "dncal.fit_linearity")
    if std.shape != mean.shape:
        raise ValueError(f"std: shape {std.shape}, but mean is {mean.shape}")
    voltage = np.asarray(voltage)
    if voltage.dtype != np.float64:
        raise TypeError(f"voltage: dtype {voltage.dtype}, but float64 is needed")
    levels, rows, cols = mean.shape
    if voltage.shape != (levels,):
        raise ValueError(f"voltage: shape {voltage.shape}, but ({levels},) for {levels} levels")
    voltage = _c(voltage, np.float64)
    keys = (voltage, frames, bit_depth, n_adc, order, flat_level)
    _dncal._lin_check(keys)
    mean = mean.rechunk({0: -1})
    std = std.rechunk(mean.chunks)
    row_chunks, col_chunks = mean.chunks[1], mean.chunks[2]
    if mask is not None:
        if mask.dtype != np.uint8:
            raise TypeError(f"mask: dtype {mask.dtype}, but uint8 is needed")
        if mask.shape != (rows, cols):
            raise ValueError(f"mask: shape {mask.shape}, but frames are {rows} x {cols}")
        mask = (mask if isinstance(mask, da.Array) else da.from_array(mask)).rechunk((row_chunks, col_chunks))
    mb, sb = mean.to_delayed()[0], std.to_delayed()[0]
    kb = None if mask is None else mask.to_delayed()
    r0 = np.cumsum((0,) + row_chunks[:-1])
    c0 = np.cumsum((0,) + col_chunks[:-1])
    grid = [(i, j) for i in range(len(row_chunks)) for j in range(len(col_chunks))]
    keys_d = dask.delayed(keys, pure=True)

    # Stage 1, kept on the workers for the passes that follow.
    fit = dask.delayed(_fit_block, pure=True)
    with _step(f"per-pixel fits, {len(grid)} blocks"):
        fits = dask.persist(*[fit(mb[i][j], sb[i][j], None if kb is None else kb[i][j], keys_d, int(r0[i]), int(c0[j])) for i, j in grid])
        dask.compute([dask.delayed(len)(f) for f in fits])
    if flat_level is not None:
        (reaching,) = dask.compute(dask.delayed(lambda rs: np.sum(np.stack(rs), axis=0))([dask.delayed(_reaching)(f, levels) for f in fits]))
        _dncal._lin_check_flat([int(n) for n in reaching], flat_level)

    # The mask's medians, then each block's mask (kept).
    passes = [0]
    with _step("mask medians", passes):
        # (The flat's signal, then the residual, by cell of the 2 x 2 period: a colour filter's channels.)
        med, _ = _medians(8, lambda w: [dask.delayed(lambda w, f, r, c: _dncal._lin_mask_tally(w, _f(f)[3], _f(f)[2], r, c))(w, f, int(r0[i]), int(c0[j])) for f, (i, j) in zip(fits, grid)], passes)
    mask_fn = dask.delayed(lambda f, k, s, r, i, j: _dncal._lin_mask(_f(f)[3], _f(f)[2], None if k is None else _c(k, np.uint8), s, r, (i, j)), pure=True)
    masks = dask.persist(*[mask_fn(f, None if kb is None else kb[i][j], [float(m) for m in med[:4]], [float(m) for m in med[4:]], int(r0[i]), int(c0[j])) for f, (i, j) in zip(fits, grid)])
    (good,) = dask.compute(dask.delayed(sum)([dask.delayed(lambda m: int(np.count_nonzero(m == 0)))(m) for m in masks]))
    if good == 0:
        _dncal._lin_global(keys, [], [], 0, rows * cols)  # raises AllMasked, as the in-memory fit does

    # Each level's median and count of the counted pixels; the global cubic.
    level_tally = dask.delayed(lambda w, m, k, f, v: _dncal._lin_level_tally(w, _c(m, np.float64), _c(k, np.uint8), _f(f)[0], _c(v, np.float64)))
    passes = [0]
    with _step(f"level medians ({levels} levels)", passes):
        medians, counts = _medians(levels, lambda w: [level_tally(w, mb[i][j], k, f, voltage) for f, k, (i, j) in zip(fits, masks, grid)], passes)
    global_coefficients = _dncal._lin_global(keys, [float(m) for m in medians], [int(n) for n in counts], good, rows * cols)
    # Each level's mean of the counted pixels (exact sums).
    sums = dask.delayed(lambda m, k, f, v: _dncal._lin_level_sums(_c(m, np.float64), _c(k, np.uint8), _f(f)[0], _c(v, np.float64)))
    with _step("level means (exact sums)"):
        (level_parts,) = dask.compute(dask.delayed(_add_parts)([sums(mb[i][j], k, f, voltage) for f, k, (i, j) in zip(fits, masks, grid)]))
    level_means = [float(x) for x in _dncal._lin_means(*_parts(level_parts))]

    # The statistics (without the cube: it is the lazy result below).
    stats = dask.delayed(lambda *a: _level_pass(*a)[0])
    with _step("statistics (inversion, exact sums)"):
        (stat_parts,) = dask.compute(dask.delayed(_add_parts)([stats(mb[i][j], sb[i][j], f, k, keys_d, global_coefficients, level_means, False) for f, k, (i, j) in zip(fits, masks, grid)]))
    masked = rows * cols - good
    report = _json.loads(_dncal._lin_report(keys, level_means, global_coefficients, *_parts(stat_parts), masked, rows * cols))

    k1 = min(max(order, 1), 8) + 1
    at = {g: n for n, g in enumerate(grid)}
    coefficients = da.block([[da.from_delayed(dask.delayed(lambda f: np.moveaxis(f[1], -1, 0).copy())(fits[at[(i, j)]]), shape=(k1, h, w), dtype=np.float64) for j, w in enumerate(col_chunks)] for i, h in enumerate(row_chunks)])
    reasons = da.block([[da.from_delayed(masks[at[(i, j)]], shape=(h, w), dtype=np.uint8) for j, w in enumerate(col_chunks)] for i, h in enumerate(row_chunks)])
    corrected = None
    if keep_corrected:
        cube = dask.delayed(lambda *a: _level_pass(*a)[1])
        unfilled = da.block([[da.from_delayed(cube(mb[i][j], sb[i][j], fits[at[(i, j)]], masks[at[(i, j)]], keys_d, global_coefficients, level_means, True), shape=(levels, h, w), dtype=np.float64) for j, w in enumerate(col_chunks)] for i, h in enumerate(row_chunks)])
        corrected = da.map_overlap(_fill, unfilled, reasons[None], depth={0: 0, 1: 1, 2: 1}, boundary="none", dtype=np.float64, align_arrays=False)
    return LinearityFit(report, coefficients, reasons, corrected)
