"""dncal.dask against the in-memory core on the same frames: on Dask's threaded
scheduler and on a LocalCluster of two worker processes, with sets of many chunks."""

import logging
import os

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


def _refault_count() -> int:
    """Page faults of touching a 24 MiB array again after one of the same size was
    touched and freed (in the process that runs it)."""
    import resource

    a = np.ones(3 * 2**20)
    del a
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = np.ones(3 * 2**20)
    after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    del b
    return after - before


def _without_malloc_vars() -> None:
    for k in [k for k in os.environ if k.startswith("MALLOC_")]:
        del os.environ[k]


def test_worker_environ_keeps_a_workers_heap():
    """With dd.worker_environ in the nannies' pre-spawn environment a worker touches a
    freed block's memory again without faulting it in; with distributed's default (trim
    above 64 KiB) every such block is faulted in anew (24 MiB: 12 huge or 6 144 small
    pages at least). glibc's variables: glibc only."""
    import platform

    distributed = pytest.importorskip("distributed")
    if platform.libc_ver()[0] != "glibc":
        pytest.skip("MALLOC_* are glibc's")
    env = dd.worker_environ(keep_mib=512, pad_mib=64)
    assert env["MALLOC_TRIM_THRESHOLD_"] == str(512 * 2**20) and env["MALLOC_TOP_PAD_"] == str(64 * 2**20)
    assert env["MALLOC_MMAP_THRESHOLD_"] == str(32 * 2**20)
    # A nanny sets its pre-spawn environment in this process's own, where it then wins
    # over the configuration (distributed's rule; an earlier test's cluster may have left
    # it there): each cluster starts from an environment without MALLOC_*, and this
    # process's is put back after, whatever happens.
    saved = {k: v for k, v in os.environ.items() if k.startswith("MALLOC_")}
    try:
        _without_malloc_vars()
        with dask.config.set({"distributed.nanny.pre-spawn-environ": {"OMP_NUM_THREADS": 1, "MALLOC_TRIM_THRESHOLD_": 65536, "UNSET_ME": None}}):
            kept = dd.worker_environ()
            assert kept["OMP_NUM_THREADS"] == "1", "the configuration's own entries are kept"
            assert "UNSET_ME" not in kept, "an entry of None (unset) is left out, not made 'None'"
            assert kept["MALLOC_TRIM_THRESHOLD_"] == str(1024 * 2**20)
            # A variable of this process's own that would win is named.
            os.environ["MALLOC_TRIM_THRESHOLD_"] = "65536"
            said = []
            handler = logging.Handler(logging.WARNING)
            handler.emit = lambda record: said.append(record.getMessage())
            dd.log.addHandler(handler)
            try:
                dd.worker_environ()
            finally:
                dd.log.removeHandler(handler)
            assert any("MALLOC_TRIM_THRESHOLD_=65536" in m for m in said), said
            faults = {}
            for name, environ in (("kept", kept), ("default", None)):
                _without_malloc_vars()
                with dask.config.set({"distributed.nanny.pre-spawn-environ": environ} if environ else {}):
                    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, distributed.Client(cluster) as client:
                        seen = list(client.run(lambda: __import__("os").environ.get("MALLOC_TRIM_THRESHOLD_")).values())
                        assert seen == ["65536" if environ is None else str(1024 * 2**20)]
                        faults[name] = min(client.submit(_refault_count, pure=False).result() for _ in range(3))
    finally:
        _without_malloc_vars()
        os.environ.update(saved)
    assert faults["kept"] < 8 and faults["default"] >= 12, faults
    for bad in ({"keep_mib": -1}, {"pad_mib": float("nan")}, {"keep_mib": 4096}):
        with pytest.raises(ValueError, match="worker_environ"):
            dd.worker_environ(**bad)


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
