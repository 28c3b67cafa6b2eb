"""dncal.dask.fit_linearity against the in-memory fit on the same set, bit for bit: on
Dask's threaded scheduler and on a LocalCluster of two worker processes, over blocks
whose edges cut through masked pixels (filled from neighbours across the edge)."""

import numpy as np
import pytest

import dncal

da = pytest.importorskip("dask.array")
import dask  # noqa: E402

from dncal import dask as dd  # noqa: E402
from test_analyses import read_set  # noqa: E402


def planted(sets):
    """The simulated set (40 x 48, 14 levels) with an input mask whose bad pixels sit on
    the 13 x 17 blocks' edges and corners, and one dead pixel (no signal) inside."""
    mean, std, voltage, frames = read_set(sets / "lin.fits")
    mask = np.zeros(mean.shape[1:], dtype=np.uint8)
    for r, c in [(12, 16), (13, 17), (12, 17), (25, 33), (26, 34), (0, 0), (39, 47), (20, 5)]:
        mask[r, c] = 1
    mean[:, 30, 40] = mean[0, 30, 40]
    return mean, std, voltage, frames, mask


def same(got, want):
    """The Dask fit's report and arrays equal the in-memory fit's, NaN where it is."""
    assert got.report == want.report
    coefficients, reasons = dask.compute(got.coefficients, got.mask)
    assert np.array_equal(coefficients, want.coefficients, equal_nan=True)
    assert np.array_equal(reasons, want.mask)
    if want.corrected is None:
        assert got.corrected is None
    else:
        assert np.array_equal(got.corrected.compute(), want.corrected, equal_nan=True)


def run(sets, chunks=(13, 17), **kw):
    mean, std, voltage, frames, mask = planted(sets)
    want = dncal.fit_linearity(mean, std, voltage, frames, mask=mask, **kw)
    c = (mean.shape[0],) + chunks
    got = dd.fit_linearity(da.from_array(mean, chunks=c), da.from_array(std, chunks=c), voltage, frames, mask=mask, **kw)
    assert got.coefficients.numblocks[1] * got.coefficients.numblocks[2] > 1, "a test of several blocks"
    # The planted pixels are masked, and some saturate (the set's top levels).
    assert want.report["masked_pixels"] >= 9
    same(got, want)
    return want


def test_blocks_equal_the_in_memory_fit_on_threads(sets):
    want = run(sets)
    assert want.mask[30, 40] != 0 and want.mask[12, 16] & 1
    run(sets, chunks=(7, 48), order=3, flat_level=9, keep_corrected=False)
    run(sets, chunks=(40, 5))


def test_a_colour_filters_channels_are_judged_alike_by_blocks(sets):
    """Issue 58: each pixel's low-signal test is against the median of its cell of the
    2 x 2 period (a Bayer red at 0.45 of the green median was masked, a quarter of the
    sensor). Blocks of 13 x 17 start on odd rows and columns: their cells are the frame's."""
    mean, std, voltage, frames, mask = planted(sets)
    response = np.array([[1.23, 0.99], [0.55, 1.23]])
    cell = np.tile(response, (mean.shape[1] // 2, mean.shape[2] // 2))
    bayer = mean[0] + (mean - mean[0]) * cell
    want = dncal.fit_linearity(bayer, std, voltage, frames, mask=mask)
    plain = dncal.fit_linearity(mean, std, voltage, frames, mask=mask)
    # The same pixels masked for low signal or a residual as without the filter (none of
    # the red channel for it); the green's top levels saturate sooner (too few levels to
    # fit, a different reason), the red's later.
    low_or_trend = np.uint8(2 | 4)
    assert np.array_equal(want.mask & low_or_trend, plain.mask & low_or_trend)
    assert want.report["masked_pixels"] <= plain.report["masked_pixels"] + 5
    c = (mean.shape[0], 13, 17)
    got = dd.fit_linearity(da.from_array(bayer, chunks=c), da.from_array(std, chunks=c), voltage, frames, mask=mask)
    same(got, want)


def test_on_a_local_cluster_of_two_processes(sets):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, distributed.Client(cluster):
        run(sets)


def test_bad_inputs_raise_as_the_in_memory_fit(sets):
    mean, std, voltage, frames, mask = planted(sets)
    c = (mean.shape[0], 13, 17)
    m, s = da.from_array(mean, chunks=c), da.from_array(std, chunks=c)
    with pytest.raises(TypeError, match="mean: a dask.array is needed"):
        dd.fit_linearity(mean, s, voltage, frames)
    with pytest.raises(TypeError, match="std: dtype float32"):
        dd.fit_linearity(m, s.astype(np.float32), voltage, frames)
    with pytest.raises(ValueError, match="voltage: shape"):
        dd.fit_linearity(m, s, voltage[:-1], frames)
    with pytest.raises(ValueError, match="order 9"):
        dd.fit_linearity(m, s, voltage, frames, order=9)
    with pytest.raises(ValueError, match="mean: empty"):
        dd.fit_linearity(m[:, :0], s[:, :0], voltage, frames)
    # A saturated flat, all pixels masked, a NaN in one block, a mask value of 2: the
    # in-memory fit's errors and messages (the NaN's and the mask's name the block).
    negative = voltage.copy()
    negative[2] = -1e-3
    for v, kw in ((voltage, {"flat_level": 13}), (voltage, {"mask": np.ones_like(mask)}), (negative, {})):
        with pytest.raises(dncal.InputError) as want:
            dncal.fit_linearity(mean, std, v, frames, **kw)
        with pytest.raises(dncal.InputError) as got:
            dd.fit_linearity(m, s, v, frames, **kw)
        assert str(got.value) == str(want.value)
    bad = mean.copy()
    bad[3, 20, 30] = np.nan
    with pytest.raises(dncal.InputError, match="the block from row 13, column 17"):
        dd.fit_linearity(da.from_array(bad, chunks=c), s, voltage, frames)
    bad_mask = mask.copy()
    bad_mask[1, 1] = 2
    with pytest.raises(dncal.InputError, match="the block from row 0, column 0"):
        dd.fit_linearity(m, s, voltage, frames, mask=bad_mask)


def test_a_set_read_from_its_file_by_the_workers(sets, tmp_path):
    """Issue 59: open_linearity's cubes are read block by block from the file by the
    workers: the same numbers as the file read whole, a graph that holds no data, and on
    two worker processes the fit equals the in-memory fit of the same file."""
    distributed = pytest.importorskip("distributed")
    fits = pytest.importorskip("astropy.io.fits")
    import pickle

    path = sets / "lin.fits"
    mean, std, voltage, frames = read_set(path)
    with fits.open(path) as f:
        mask = np.asarray(f["MASK"].data, dtype=np.uint8) if "MASK" in f else np.zeros(mean.shape[1:], np.uint8)
    s = dd.open_linearity(path, chunks=(13, 17))
    assert s.mean.chunks == ((14,), (13, 13, 13, 1), (17, 17, 14)) and s.mean.dtype == np.float64
    assert np.array_equal(s.mean.compute(), mean) and np.array_equal(s.std.compute(), std)
    assert np.array_equal(s.voltage, voltage) and s.frames == frames and np.array_equal(s.mask, mask)
    assert (s.bit_depth, s.n_adc, s.reference) == (12, 4, "photodiode")
    graph = len(pickle.dumps(dict(s.mean.__dask_graph__())))
    assert graph < mean.nbytes / 10, f"the graph holds {graph} bytes, the cube {mean.nbytes}"
    want = dncal.fit_linearity(mean, std, voltage, frames, mask=mask)
    # Each task reads its own block (the regions): counted inside the fit, on threads.
    reads = []
    read = dd.Region.read
    dd.Region.read = lambda r: reads.append(r.fit) or read(r)
    try:
        same(dd.fit_linearity(s.mean, s.std, s.voltage, s.frames, mask=s.mask), want)
    finally:
        dd.Region.read = read
    # 12 blocks, each read by the fit (2 cubes), each level-median pass (1) and the
    # statistics (2), under one fit's name; and by the lazy corrected cube (2), unkept.
    # The fit's kept blocks are dropped at its end.
    kept = [r for r in reads if r is not None]
    assert reads.count(None) == 12 * 2 and len(set(kept)) == 1 and len(kept) >= 12 * 5 and len(kept) % 12 == 0, (len(reads), set(reads))
    assert not dd._KEPT
    # A cube rechunked, or written into, is read as any Dask array is (the same numbers).
    other = s.mean.rechunk((14, 20, 20)), s.std.rechunk((14, 20, 20))
    assert dd._regions(other[0], other[0].chunks[1], other[0].chunks[2], "t") is None
    same(dd.fit_linearity(*other, s.voltage, s.frames, mask=s.mask), want)
    edited = dd.open_linearity(path, chunks=(13, 17))
    assert dd._regions(edited.mean, (13, 13, 13, 1), (17, 17, 14), "t") is not None
    edited.mean[:, 30, 40] = edited.mean[0, 30, 40]
    assert dd._regions(edited.mean, (13, 13, 13, 1), (17, 17, 14), "t") is None
    dead = mean.copy()
    dead[:, 30, 40] = dead[0, 30, 40]
    same(dd.fit_linearity(edited.mean, edited.std, s.voltage, s.frames, mask=s.mask), dncal.fit_linearity(dead, std, voltage, frames, mask=mask))
    # -1: a whole axis a block.
    assert dd.open_linearity(path, chunks=(-1, 17)).mean.chunks == ((14,), (40,), (17, 17, 14))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, distributed.Client(cluster):
        same(dd.fit_linearity(s.mean, s.std, s.voltage, s.frames, mask=s.mask, bit_depth=s.bit_depth, n_adc=s.n_adc), want)
    # A file that is missing, or not a linearity set, is named with its fault.
    with pytest.raises(dncal.DncalIOError, match="nothing.fits: cannot read"):
        dd.open_linearity(tmp_path / "nothing.fits")
    with pytest.raises(dncal.InputError, match=r"h.fits: not a linearity set: no STD extension"):
        dd.open_linearity(sets / "h.fits")
    with pytest.raises(ValueError, match="chunks"):
        dd.open_linearity(path, chunks=(0, 17))
