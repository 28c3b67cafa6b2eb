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
import os
import sys
import threading
import time
import uuid
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


def worker_environ(keep_mib: float = 1024, pad_mib: float = 256) -> Dict[str, str]:
    """The environment a ``distributed`` worker process should start with for
    :func:`fit_linearity` (and any work that allocates blocks of tens of MiB a task):
    glibc's heap kept, not handed back to the system after every task.

    Give it to the nannies before they start the workers (``MALLOC_*`` is read when a
    process starts, so ``LocalCluster(env=...)`` or ``distributed.nanny.environ`` are too
    late)::

        with dask.config.set({"distributed.nanny.pre-spawn-environ": dncal.dask.worker_environ()}):
            cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1)

    For ``dask worker`` (or ``dask-worker``) export the ``MALLOC_*`` entries in the shell
    that starts it: dask's ``DASK_...`` variables lower-case their keys, which glibc then
    does not read. Where the starting process's own environment already has one of these
    variables, ``distributed`` takes that one instead (a nanny started there before left
    ``MALLOC_TRIM_THRESHOLD_=65536`` in it); this function warns where it does. The
    mapping is the configuration's own ``pre-spawn-environ`` (its ``None`` entries, which
    unset a variable, left out) with three entries set: ``MALLOC_MMAP_THRESHOLD_`` at
    32 MiB (a block's array comes from the heap, not from a mapping of its own), and
    ``MALLOC_TRIM_THRESHOLD_`` (``keep_mib``) and ``MALLOC_TOP_PAD_`` (``pad_mib``): how
    much freed heap a worker keeps, and how much more it asks for when it grows.

    Why: ``distributed`` starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, so every
    task's arrays (a 256 x 256 x 41 block is 21.5 MiB a cube) are new pages, faulted in
    and zeroed by the kernel. On a virtual machine that reports free pages to its host
    (virtio-balloon's free page reporting), such pages may have left the guest, and
    faulting them back costs the host's work: on the developers' 2-vCPU machine a slow
    task's system time was 0.2-0.53 s where a fast one's was under 0.02 s
    (``clear_page_erms`` under the FITS block's byte swap was 11% of all samples). With
    this environment the same tasks took 0-170 page faults instead of 2 000-4 000, and the
    fit from a file on 2 workers 1.35 times the in-memory time as a median of 9 runs
    (1.07-1.70 s) where it took 1.67 (1.14-2.30 s; docs/python.md, "The slow runs"). The
    cost: each worker holds up to ``keep_mib`` of freed heap, which ``distributed`` counts
    as unmanaged memory.
    """
    if not (keep_mib >= 0 and pad_mib >= 0) or keep_mib > 2**31 / 2**20 or pad_mib > 2**31 / 2**20:
        raise ValueError(f"worker_environ: keep_mib {keep_mib} and pad_mib {pad_mib} must be from 0 to 2048")
    env = {str(k): str(v) for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ", default=None) or {}).items() if v is not None}
    kept = {
        "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20),
        "MALLOC_TRIM_THRESHOLD_": str(min(int(keep_mib * 2**20), 2**31 - 1)),
        "MALLOC_TOP_PAD_": str(min(int(pad_mib * 2**20), 2**31 - 1)),
    }
    env.update(kept)
    other = {k: os.environ[k] for k, v in kept.items() if os.environ.get(k, v) != v}
    if other:
        log.warning("worker_environ: this process's environment has %s, which distributed's nannies started from here take instead", ", ".join(f"{k}={v}" for k, v in sorted(other.items())))
    return env


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
    """An aligned, C-ordered array of `dtype` (arrays from pickle may be neither); a
    :class:`Region` read here, on the worker running the task."""
    if isinstance(a, Region):
        a = a.read()
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
    """Tallies of one pass merged (counts added, values appended: a multiset, the order
    does not matter), as words."""
    return _dncal._median_merge([_c(t, np.uint64) for t in tallies])


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


#: Up to this many blocks, a median pass's tallies are added by the caller, not by a task
#: on a worker (a median is two cells, its lower and upper middle; a cell's tally is
#: 256 x 8 bytes a block and a sample of m = (5 x pixels / 2)^(2/3) values over the
#: blocks on the first pass, about 2 m values inside its bracket on the second: 6 m
#: values a median over both passes, 45 000 for a million pixels).
MERGE_HERE = 64


def _gather(tallies: List[Any], *extra: Any) -> Tuple[Any, List[Any]]:
    """One pass's tallies merged, and `extra` delayed values computed in the same round
    trip to the workers."""
    if len(tallies) <= MERGE_HERE:
        # A few blocks' tallies come straight here and are merged here: one hop fewer
        # than a merging task, whose inputs would travel to its worker first.
        (tallies, *done) = dask.compute(tallies, *extra)
        return _merge(list(tallies)), done
    (total, *done) = dask.compute(dask.delayed(_merge)(tallies), *extra)
    return total, done


def _medians(search: Any, tally: Callable[[np.ndarray, bool], Tuple[List[Any], Tuple[Any, ...]]], passes: Optional[List[int]] = None, on_first: Optional[Callable[..., None]] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Exact medians of a `_MedianSearch` over blocks, to its end: passes of the search (a
    sample and a histogram, then the values inside a bracket: two passes unless a bracket
    missed), each `tally(counter, first)` a delayed tally per block, merged and taken by
    the search, and on this call's first pass (`first` true) a tuple of other delayed
    values, computed in the same round trip to the workers and handed to `on_first`
    before the search reads that pass (work that needs the same blocks: a pass fewer)."""
    # A histogram and a sample, a bracket, and (after a miss) up to 7 passes of the radix
    # search from the first pass's 8 bits: 9 at most.
    for n in range(9):
        if search.done:
            break
        if passes is not None:
            passes[0] += 1
        tallies, extra = tally(search.counter(), n == 0)
        total, done = _gather(tallies, *extra)
        if n == 0 and on_first is not None:
            on_first(*done)
        search.advance(_c(total, np.uint64))
    if not search.done:
        raise RuntimeError("the exact median search did not end in 9 passes: the blocks' values changed between passes")
    return search.medians()


# The blocks' tasks, as functions of the module: a task names them, where a lambda of
# the fit would be pickled by value into every task of every pass.


def _mask_tally(counter, fits, first_row, first_column):
    """A block's tally for the mask's medians (the flat's signal, the fit residual)."""
    return _dncal._lin_mask_tally(counter, _f(fits)[3], _f(fits)[2], first_row, first_column)


def _mask_block(fits, mask, signal_medians, residual_medians, first_row, first_column):
    """A block's mask (reasons, uint8)."""
    return _dncal._lin_mask(_f(fits)[3], _f(fits)[2], None if mask is None else _c(mask, np.uint8), signal_medians, residual_medians, (first_row, first_column))


def _good(mask) -> int:
    """A block's count of good pixels."""
    return int(np.count_nonzero(mask == 0))


def _level_tally(counter, mean, mask, fits, voltage, salt):
    """A block's tally for each level's median (`salt`: the block's own sample)."""
    return _dncal._lin_level_tally(counter, _c(mean, np.float64), _c(mask, np.uint8), _f(fits)[0], _c(voltage, np.float64), salt)


def _level_stats(*a):
    """A block's statistics' parts (stage 4 without the cube)."""
    return _level_pass(*a)[0]


def _level_cube(*a):
    """A block's corrected cube, unfilled (stage 4)."""
    return _level_pass(*a)[1]


def _coefficients(fits) -> np.ndarray:
    """A block's coefficients, (order + 1, rows, cols)."""
    return np.moveaxis(fits[1], -1, 0).copy()


def _tally_and_sums(counter, mean, mask, fits, voltage, salt):
    """A block's first level-median tally and its level sums, its block of the cube
    read once for both."""
    m, k, n, v = _c(mean, np.float64), _c(mask, np.uint8), _f(fits)[0], _c(voltage, np.float64)
    return _dncal._lin_level_tally(counter, m, k, n, v, salt), _dncal._lin_level_sums(m, k, n, v)


def _level_pass(mean, std, fits, mask, keys, global_coefficients, level_means, keep):
    """Stage 4 of a block."""
    return _dncal._lin_level_pass(_c(mean, np.float64), _c(std, np.float64), keys, _f(fits)[0], _f(fits)[1], _c(mask, np.uint8), global_coefficients, level_means, keep)


def _fill(block: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A corrected block with its halo, masked pixels filled."""
    return _dncal._lin_fill(_c(block, np.float64), _c(mask, np.uint8))


class FitsCube:
    """One float cube (levels, rows, cols) of a FITS file, read a block at a time where
    the block is needed: what :func:`open_linearity` gives ``dask.array.from_array``.

    It holds only the file's path, the HDU's name and its shape, so a task graph that
    carries it is a few hundred bytes whatever the set's size, and each worker reads its
    own blocks from the file (astropy, memory-mapped: a block's rows are read, nothing
    else) and converts them from FITS's big-endian to native float64."""

    def __init__(self, path: str, hdu: str, shape: Tuple[int, int, int]):
        self.path, self.hdu, self.shape = path, hdu, tuple(shape)
        self.dtype, self.ndim = np.dtype(np.float64), 3

    def __dask_tokenize__(self):
        # The file as it is now: a rewrite changes its inode, size or change time even
        # where it keeps the modification time (`cp -p`, `rsync -t`, tar).
        st = os.stat(self.path)
        return (self.path, self.hdu, self.shape, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)

    def __getitem__(self, index):
        from astropy.io import fits

        with fits.open(self.path, memmap=True, lazy_load_hdus=True) as f:
            return np.array(f[self.hdu].data[index], dtype=np.float64, order="C")


class Region:
    """A block of a :class:`FitsCube` (all levels, rows ``rows``, columns ``cols``), passed
    to a block's task in place of its data: the task reads it where it runs. A block's
    task then depends only on the block's persisted fits, so it runs on the worker that
    holds them, and no block of the cube crosses between workers.

    ``fit`` names the :func:`fit_linearity` call it belongs to: its blocks are kept under
    that name (``None``: never kept) and dropped when that fit ends, and the name is part
    of its token, so two fits never share a persisted key."""

    def __init__(self, cube: FitsCube, rows: slice, cols: slice, fit: Optional[str]):
        self.cube, self.rows, self.cols, self.fit = cube, rows, cols, fit

    def __dask_tokenize__(self):
        return (self.cube.__dask_tokenize__(), self.rows.start, self.rows.stop, self.cols.start, self.cols.stop, self.fit)

    def unkept(self) -> "Region":
        """The same block, read from the file every time (for work after the fit: the
        lazy corrected cube)."""
        return Region(self.cube, self.rows, self.cols, None)

    def read(self) -> np.ndarray:
        """The block, read-only: from this process's keep (:data:`BLOCK_KEEP_MIB`) where a
        task of the same fit read it before, else from the file."""
        if self.fit is None:
            return self.cube[:, self.rows, self.cols]
        key = (self.fit, self.cube.hdu, self.rows.start, self.rows.stop, self.cols.start, self.cols.stop)
        with _KEPT_LOCK:
            kept = _KEPT.get(key)
        if kept is not None:
            return kept
        block = self.cube[:, self.rows, self.cols]
        block.flags.writeable = False
        with _KEPT_LOCK:
            if sum(b.nbytes for b in _KEPT.values()) + block.nbytes <= _keep_budget():
                _KEPT[key] = block
        return block


#: A fit passes over a file's cube several times (the fits, the median passes, the
#: statistics); each process keeps the blocks its tasks read, up to this many MiB, and
#: drops them when the fit's report is made (on every worker of a ``distributed`` client).
#: A worker process takes its budget from ``DNCAL_DASK_BLOCK_KEEP_MIB`` in its environment
#: (0 keeps none); this default is what applies where that is not set. The
#: first blocks read are kept, not the last: the passes visit the blocks in the same
#: order, so a keep that cannot hold them all still saves every pass its first blocks'
#: reads, where evicting the oldest would save none.
BLOCK_KEEP_MIB = 512.0
_KEPT: Dict[Any, np.ndarray] = {}
_KEPT_LOCK = threading.Lock()


def _keep_budget() -> int:
    """Bytes of blocks a process keeps."""
    try:
        mib = float(os.environ.get("DNCAL_DASK_BLOCK_KEEP_MIB", BLOCK_KEEP_MIB))
    except ValueError:
        mib = BLOCK_KEEP_MIB
    return int(max(mib, 0.0) * 2**20)


def _drop_kept(fit: str) -> int:
    """Drops this process's blocks kept for fit `fit`; how many there were."""
    with _KEPT_LOCK:
        mine = [k for k in _KEPT if k[0] == fit]
        for k in mine:
            del _KEPT[k]
    return len(mine)


def _forget_blocks(fit: str) -> None:
    """Drops fit `fit`'s kept blocks here and on the workers of the current distributed
    client (where one is in use). A failure to reach the workers is logged, never raised:
    it must not replace the fit's own error, and the blocks then stay until the workers
    end."""
    _drop_kept(fit)
    if "distributed" not in sys.modules:
        return
    try:
        from distributed import get_client

        client = get_client()
    except (ImportError, ValueError):
        return
    try:
        client.run(_drop_kept, fit)
    except Exception as e:  # noqa: BLE001 - see the docstring
        log.warning("the workers' kept blocks of fit %s were not dropped: %s", fit, e)


def _regions(a, row_chunks, col_chunks, fit: Optional[str]):
    """The blocks of `a` as :class:`Region` s of fit `fit`, where `a` is a cube
    :func:`open_linearity` made, unchanged (the same graph: an assignment into it, or a
    rechunk, makes another) ; else None."""
    source = getattr(a, "_dncal_source", None)
    if source is None or source[1] != a.name or a.chunks[1:] != (row_chunks, col_chunks):
        return None
    r0, c0 = np.cumsum((0,) + row_chunks), np.cumsum((0,) + col_chunks)
    return [[Region(source[0], slice(int(r0[i]), int(r0[i + 1])), slice(int(c0[j]), int(c0[j + 1])), fit) for j in range(len(col_chunks))] for i in range(len(row_chunks))]


def open_linearity(path, chunks: Tuple[int, int] = (256, 256)):
    """A linearity set in a FITS file (as ``dncal simulate linearity`` writes it, and
    ``dncal linearity`` reads it) as a :class:`dncal.LinearitySet` whose ``mean`` and
    ``std`` are ``dask.array`` cubes chunked ``chunks`` (rows, columns), all levels a
    block, each block read from the file by the worker that needs it
    (:class:`FitsCube`): a set larger than any one machine's memory, held as a 16k x 16k
    sensor's data would be, on storage every worker sees. The voltage, the frame count,
    the ADC keys and the mask (small) are read here. Needs astropy.

    Fit it with :func:`fit_linearity` (the set's own ``fit`` is the in-memory one, for
    numpy arrays). Raises :class:`dncal.DncalIOError` for a file that cannot be opened and
    :class:`dncal.InputError` for one that is not a linearity set (a missing extension,
    key or column, cubes of different shapes), naming the file."""
    from . import LinearitySet
    from .errors import DncalIOError, InputError

    try:
        from astropy.io import fits
    except ImportError as e:  # pragma: no cover - the message is the point
        raise ImportError("dncal.dask.open_linearity needs astropy: pip install astropy") from e
    # Absolute: the workers may run elsewhere in the file system's tree.
    path = os.path.abspath(str(path))
    rows_chunk, cols_chunk = (int(c) for c in chunks)
    if rows_chunk < 1 and rows_chunk != -1 or cols_chunk < 1 and cols_chunk != -1:
        raise ValueError(f"chunks: {chunks}, but two positive sizes (rows, columns), or -1 for a whole axis, are needed")
    try:
        f = fits.open(path, memmap=True, lazy_load_hdus=True)
    except OSError as e:
        raise DncalIOError(f"{path}: cannot read: {e}") from e
    try:
        with f:
            names = [h.name for h in f]
            for need in ("STD", "REFERENCE"):
                if need not in names:
                    raise InputError(f"{path}: not a linearity set: no {need} extension")
            header = f[0].header
            shape = tuple(f[0].shape or ())
            if len(shape) != 3 or tuple(f["STD"].shape or ()) != shape:
                raise InputError(f"{path}: not a linearity set: the mean cube is {shape} and STD {tuple(f['STD'].shape or ())}, but two equal (levels, rows, cols) cubes are needed")
            keys = {}
            for key in ("NFRAMES", "BITDEPTH", "NADC"):
                if key not in header:
                    raise InputError(f"{path}: not a linearity set: no {key} key in the primary header")
                keys[key] = int(header[key])
            table = f["REFERENCE"].data
            columns = [c.upper() for c in table.columns.names]
            reference = "photodiode" if "VOLTAGE" in columns else "exposure" if "EXPOSURE" in columns else None
            if reference is None:
                raise InputError(f"{path}: REFERENCE has neither a VOLTAGE nor an EXPOSURE column")
            voltage = np.array(table["VOLTAGE" if reference == "photodiode" else "EXPOSURE"], dtype=np.float64)
            mask = np.array(f["MASK"].data, dtype=np.uint8) if "MASK" in names else np.zeros(shape[1:], dtype=np.uint8)
            # The layout as the file names it from its first stored pixel; offsets or a
            # bottom-up row order are not applied here (the fit does not use the layout).
            simple = int(header.get("XBAYROFF", 0)) % 2 == 0 and int(header.get("YBAYROFF", 0)) % 2 == 0 and str(header.get("ROWORDER", "TOP-DOWN")).strip() == "TOP-DOWN"
            bayer = str(header.get("BAYERPAT", "")).strip() or None
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"{path}: not a linearity set: {e}") from e
    c = (shape[0], shape[1] if rows_chunk == -1 else rows_chunk, shape[2] if cols_chunk == -1 else cols_chunk)
    mean, std = (da.from_array(FitsCube(path, hdu, shape), chunks=c, lock=False, asarray=False, fancy=False) for hdu in ("PRIMARY", "STD"))
    # What fit_linearity needs to hand each task its block's place, not its data.
    for a, hdu in ((mean, "PRIMARY"), (std, "STD")):
        a._dncal_source = (FitsCube(path, hdu, shape), a.name)
    return LinearitySet(mean, std, voltage, mask, keys["NFRAMES"], keys["BITDEPTH"], keys["NADC"], bayer if simple else None, reference)


def fit_linearity(mean, std, voltage, frames: int, *, order: int = 4, flat_level: Optional[int] = None, mask=None, bit_depth: int = 12, n_adc: int = 4, keep_corrected: bool = True):
    run = uuid.uuid4().hex
    try:
        return _fit_linearity(mean, std, voltage, frames, order=order, flat_level=flat_level, mask=mask, bit_depth=bit_depth, n_adc=n_adc, keep_corrected=keep_corrected, run=run)
    finally:
        _forget_blocks(run)


def _fit_linearity(mean, std, voltage, frames: int, *, order: int = 4, flat_level: Optional[int] = None, mask=None, bit_depth: int = 12, n_adc: int = 4, keep_corrected: bool = True, run: Optional[str] = None):
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
    workers); ``mean`` is read once per pass (persist it too where it fits), unless it
    comes from :func:`open_linearity`: then each block's task reads its block from the
    file where it runs, and each process keeps the blocks it read for the passes that
    follow (:data:`BLOCK_KEEP_MIB`).

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
    # Cubes open_linearity made: each task reads its own block from the file.
    regions = _regions(mean, row_chunks, col_chunks, run), _regions(std, row_chunks, col_chunks, run)
    if mask is not None:
        if mask.dtype != np.uint8:
            raise TypeError(f"mask: dtype {mask.dtype}, but uint8 is needed")
        if mask.shape != (rows, cols):
            raise ValueError(f"mask: shape {mask.shape}, but frames are {rows} x {cols}")
        mask = (mask if isinstance(mask, da.Array) else da.from_array(mask)).rechunk((row_chunks, col_chunks))
    mb, sb = mean.to_delayed()[0], std.to_delayed()[0]
    # After the fit (the lazy corrected cube) the blocks are read without being kept.
    later_mb, later_sb = mb, sb
    if regions[0] is not None and regions[1] is not None:
        mb, sb = regions
        later_mb, later_sb = ([[r.unkept() for r in row] for row in rs] for rs in regions)
    kb = None if mask is None else mask.to_delayed()
    r0 = np.cumsum((0,) + row_chunks[:-1])
    c0 = np.cumsum((0,) + col_chunks[:-1])
    grid = [(i, j) for i in range(len(row_chunks)) for j in range(len(col_chunks))]
    keys_d = dask.delayed(keys, pure=True)

    # Stage 1, kept on the workers for the passes that follow. The mask's medians' first
    # pass (a histogram and a sample, the same for any data) comes back with them: a
    # round trip fewer. (The flat's signal, then the residual, by cell of the 2 x 2
    # period: a colour filter's channels.)
    fit = dask.delayed(_fit_block, pure=True)
    mask_search = _dncal._MedianSearch(8, rows * cols // 4)

    def mask_tallies(w):
        return [dask.delayed(_mask_tally)(w, f, int(r0[i]), int(c0[j])) for f, (i, j) in zip(fits, grid)]

    with _step(f"per-pixel fits and the mask's first median pass, {len(grid)} blocks"):
        fits = dask.persist(*[fit(mb[i][j], sb[i][j], None if kb is None else kb[i][j], keys_d, int(r0[i]), int(c0[j])) for i, j in grid])
        total, _ = _gather(mask_tallies(mask_search.counter()))
        mask_search.advance(_c(total, np.uint64))
    if flat_level is not None:
        (reaching,) = dask.compute(dask.delayed(lambda rs: np.sum(np.stack(rs), axis=0))([dask.delayed(_reaching)(f, levels) for f in fits]))
        _dncal._lin_check_flat([int(n) for n in reaching], flat_level)

    # The mask's medians, then each block's mask (kept).
    passes = [0]
    with _step("mask medians, after the first pass", passes):
        med, _ = _medians(mask_search, lambda w, _: (mask_tallies(w), ()), passes)
    mask_fn = dask.delayed(_mask_block, pure=True)
    masks = dask.persist(*[mask_fn(f, None if kb is None else kb[i][j], [float(m) for m in med[:4]], [float(m) for m in med[4:]], int(r0[i]), int(c0[j])) for f, (i, j) in zip(fits, grid)])
    good_count = dask.delayed(sum)([dask.delayed(_good)(m) for m in masks])

    # Each level's median and count of the counted pixels; the global cubic. With the
    # first pass over the cube, in the same round trip and reading of each block, the
    # good pixels' count and each level's exact sums (for its mean): a pass fewer.
    # (The block's level sums and first tally come out of one task, so its block of the
    # cube is read once for both.)
    level_tally = dask.delayed(_level_tally)
    both = dask.delayed(_tally_and_sums, nout=2)
    parts: List[Any] = []

    def tally(w, first):
        if not first:
            return [level_tally(w, mb[i][j], k, f, voltage, b) for b, (f, k, (i, j)) in enumerate(zip(fits, masks, grid))], ()
        pairs = [both(w, mb[i][j], k, f, voltage, b) for b, (f, k, (i, j)) in enumerate(zip(fits, masks, grid))]
        return [p[0] for p in pairs], (good_count, dask.delayed(_add_parts)([p[1] for p in pairs]))

    def check_and_keep(good, level_parts):
        if good == 0:
            _dncal._lin_global(keys, [], [], 0, rows * cols)  # raises AllMasked, as the in-memory fit does
        parts.extend([good, level_parts])

    passes = [0]
    with _step(f"level medians and means ({levels} levels)", passes):
        medians, counts = _medians(_dncal._MedianSearch(levels, rows * cols), tally, passes, on_first=check_and_keep)
    good, level_parts = parts
    global_coefficients = _dncal._lin_global(keys, [float(m) for m in medians], [int(n) for n in counts], good, rows * cols)
    level_means = [float(x) for x in _dncal._lin_means(*_parts(level_parts))]

    # The statistics (without the cube: it is the lazy result below).
    stats = dask.delayed(_level_stats)
    with _step("statistics (inversion, exact sums)"):
        (stat_parts,) = dask.compute(dask.delayed(_add_parts)([stats(mb[i][j], sb[i][j], f, k, keys_d, global_coefficients, level_means, False) for f, k, (i, j) in zip(fits, masks, grid)]))
    masked = rows * cols - good
    report = _json.loads(_dncal._lin_report(keys, level_means, global_coefficients, *_parts(stat_parts), masked, rows * cols))

    k1 = min(max(order, 1), 8) + 1
    at = {g: n for n, g in enumerate(grid)}
    coefficients = da.block([[da.from_delayed(dask.delayed(_coefficients)(fits[at[(i, j)]]), shape=(k1, h, w), dtype=np.float64) for j, w in enumerate(col_chunks)] for i, h in enumerate(row_chunks)])
    reasons = da.block([[da.from_delayed(masks[at[(i, j)]], shape=(h, w), dtype=np.uint8) for j, w in enumerate(col_chunks)] for i, h in enumerate(row_chunks)])
    corrected = None
    if keep_corrected:
        cube = dask.delayed(_level_cube)
        unfilled = da.block([[da.from_delayed(cube(later_mb[i][j], later_sb[i][j], fits[at[(i, j)]], masks[at[(i, j)]], keys_d, global_coefficients, level_means, True), shape=(levels, h, w), dtype=np.float64) for j, w in enumerate(col_chunks)] for i, h in enumerate(row_chunks)])
        corrected = da.map_overlap(_fill, unfilled, reasons[None], depth={0: 0, 1: 1, 2: 1}, boundary="none", dtype=np.float64, align_arrays=False)
    return LinearityFit(report, coefficients, reasons, corrected)


fit_linearity.__doc__ = _fit_linearity.__doc__
