"""dncal on Dask: the per-pixel work of a sensor larger than one machine.

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

from typing import Any, Dict, Tuple

import numpy as np

from ._dncal import Corrector, Lut

try:
    import dask
    import dask.array as da
except ImportError as e:  # pragma: no cover - the message is the point
    raise ImportError("dncal.dask needs dask: pip install 'dask[array]' (or './python[dask]')") from e

#: The status counters a correction sums over its blocks.
STATUS_KEYS = ("out_of_range_codes", "saturated_additions", "rejected_lines", "incomplete_frames")


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
    if not isinstance(frames, da.Array):
        raise TypeError(f"frames: a dask.array is needed, not {type(frames).__name__} (dncal.Corrector takes numpy arrays)")
    if frames.dtype != np.uint16:
        raise TypeError(f"frames: dtype {frames.dtype}, but uint16 is needed")
    if frames.ndim != 3:
        raise ValueError(f"frames: {frames.ndim} dimension(s), but 3 (frames, rows, cols) are needed")
    if 0 in frames.shape:
        raise ValueError(f"frames: empty {frames.shape}")
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
