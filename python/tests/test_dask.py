"""dncal.dask against the in-memory core on the same frames: on Dask's threaded
scheduler and on a LocalCluster of two worker processes, with sets of many chunks."""

import numpy as np
import pytest

import dncal

da = pytest.importorskip("dask.array")
import dask  # noqa: E402

from dncal import dask as dd  # noqa: E402


def lut():
    """Uneven rising entries; the top code's at the core's largest, 2^23 - 1, so that
    530 frames of it pass 2^32."""
    rng = np.random.default_rng(11)
    steps = rng.integers(1000, 2040, size=(4, 4096), dtype=np.uint32)
    steps[:, 0] = 0
    entries = np.cumsum(steps, axis=1, dtype=np.uint32)
    entries[:, -1] = 2**23 - 1
    return dncal.Lut(entries)


def in_memory(l, frames, states, first_column=0, frame_states=None):
    c = dncal.Corrector(l, states, frames.shape[1], frames.shape[2], first_column=first_column)
    c.add(frames, states=None if frame_states is None else list(frame_states))
    return c.sums, c.status


def check(frames, chunks, states, **kw):
    l = lut()
    want_sums, want_status = in_memory(l, frames, states, **kw)
    sums, status = dd.correct(da.from_array(frames, chunks=chunks), l, states, **kw)
    assert sums.numblocks[1] > 1 and sums.numblocks[2] > 1, "a test of several blocks"
    got_sums, got_status = dask.compute(sums, status)
    assert got_sums.dtype == np.uint32 and np.array_equal(got_sums, want_sums)
    for k in dd.STATUS_KEYS:
        assert got_status[k] == want_status[k], k
    return got_status


def frames_with_codes_above_the_top(n, h, w, seed=5):
    return np.random.default_rng(seed).integers(0, 4300, size=(n, h, w), dtype=np.uint16)


def test_blocks_equal_one_corrector_on_threads():
    frames = frames_with_codes_above_the_top(21, 30, 45)
    status = check(frames, (4, 7, 10), 4, first_column=3)
    assert status["out_of_range_codes"] > 0
    check(frames, (21, 16, 16), 3, frame_states=np.arange(21) % 2)


def test_saturation_past_512_frames_is_per_pixel_in_frame_order():
    frames = np.full((530, 6, 9), 4095, dtype=np.uint16)
    frames[::3, 2, 4] = 10
    status = check(frames, (100, 3, 4), 1)
    assert status["saturated_additions"] > 0


def test_on_a_local_cluster_of_two_processes():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, distributed.Client(cluster):
        frames = frames_with_codes_above_the_top(12, 40, 33, seed=9)
        check(frames, (5, 10, 9), 2, first_column=1)


def test_bad_inputs():
    l = lut()
    with pytest.raises(TypeError, match="dask.array"):
        dd.correct(np.zeros((2, 3, 4), dtype=np.uint16), l, 1)
    with pytest.raises(TypeError, match="uint16"):
        dd.correct(da.zeros((2, 3, 4), dtype=np.float32), l, 1)
    with pytest.raises(ValueError, match="3 values for 2 frames"):
        dd.correct(da.zeros((2, 3, 4), dtype=np.uint16), l, 2, frame_states=[0, 1, 0])
    with pytest.raises(ValueError, match="0 to 1"):
        dd.correct(da.zeros((2, 3, 4), dtype=np.uint16), l, 2, frame_states=[0, 2])
    with pytest.raises(dncal.InputError):
        dd.correct(da.zeros((2, 3, 4), dtype=np.uint16), np.zeros((3, 4096), dtype=np.uint32), 1)
    with pytest.raises(TypeError, match="uint32"):
        dd.correct(da.zeros((2, 3, 4), dtype=np.uint16), l.entries.astype(np.int64), 1)
    with pytest.raises(ValueError, match="1 to 8"):
        dd.correct(da.zeros((2, 3, 4), dtype=np.uint16), l, 9)
    with pytest.raises(TypeError, match="integers"):
        dd.correct(da.zeros((2, 3, 4), dtype=np.uint16), l, 2, frame_states=[0.0, 1.5])


def test_a_mosaic_wider_than_the_cores_columns():
    # First columns past 2^16: each block's ADC phase is what the column gives.
    frames = frames_with_codes_above_the_top(3, 4, 24, seed=2)
    check(frames, (3, 2, 6), 1, first_column=65533)
