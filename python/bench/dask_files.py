"""dncal.dask.fit_linearity from a file on a cluster of worker processes, against the
in-memory fit on the same machine (issue 59, item 5; docs/python.md), on a release
wheel (scripts/python-bench.sh --dask-files builds it and runs this):

1. A simulated set of SIDE x SIDE pixels at LEVELS levels (the camera model, 16 frames a
   level) written to a FITS file as `dncal simulate linearity` writes one.
2. Per run, alternating: the in-memory fit of the arrays (`dncal.fit_linearity`, report
   and coefficients), then for each worker count N a `distributed.LocalCluster` of N
   single-threaded processes (started, and warmed by one fit, before the clock, as a
   running cluster is) fitting
   the set opened with `dncal.dask.open_linearity` (each block read from the file by the
   worker that needs it): `open_linearity`, `fit_linearity` and the coefficients'
   compute, timed together; checked equal to the in-memory fit, bit for bit.
3. Each worker's native threads (the library's rayon pool) are CORES / N (at least 1),
   so N processes use the machine's cores as the in-memory fit does.
4. The workers start with `dncal.dask.worker_environ()` in the nannies' pre-spawn
   environment (glibc's heap kept between tasks); `--default-malloc` starts them with
   distributed's own (`MALLOC_TRIM_THRESHOLD_=65536`).

Prints a JSON object: the in-memory seconds per run, and per N the cluster's seconds,
the per-run ratios (cluster over in-memory, the same run), their median, and the global
steps' times of each run (`dncal.dask.log`).
Usage: python dask_files.py [--side 512] [--levels 41] [--chunk 256] [--workers 1,2,4] [--runs 3]
"""

import argparse
import json
import logging
import os
import statistics
import tempfile
import time

import numpy as np

import dncal
from dask_scale import Steps  # the same directory: the Dask fit's step log, parsed once


def released(client):
    """Waits (up to 10 s) until the scheduler holds no task: everything released."""
    import gc

    gc.collect()
    for _ in range(1000):
        if client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 0:
            return
        time.sleep(0.01)
    raise SystemExit("the cluster still holds tasks of the last fit")


def write_set(path, s):
    """The set as `dncal simulate linearity` writes it (the keys open_linearity reads)."""
    from astropy.io import fits

    primary = fits.PrimaryHDU(s.mean)
    primary.header["BITDEPTH"] = s.bit_depth
    primary.header["NADC"] = s.n_adc
    primary.header["NFRAMES"] = s.frames
    reference = fits.BinTableHDU.from_columns([fits.Column(name="VOLTAGE", format="D", unit="V", array=s.voltage)], name="REFERENCE")
    fits.HDUList([primary, fits.ImageHDU(s.std, name="STD"), fits.ImageHDU(s.mask, name="MASK"), reference]).writeto(path)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--side", type=int, default=512)
    p.add_argument("--levels", type=int, default=41)
    p.add_argument("--chunk", type=int, default=256)
    p.add_argument("--workers", default="1,2,4")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--default-malloc", action="store_true", help="distributed's own worker environment, not dncal.dask.worker_environ()")
    a = p.parse_args()
    import distributed
    from dncal import dask as dd

    counts = [int(n) for n in a.workers.split(",")]
    cores = os.cpu_count() or 1
    s = dncal.simulate_linearity(levels=a.levels, frames=16, roi=(a.side, a.side, 0, 0))
    steps = Steps()
    dd.log.addHandler(steps)
    dd.log.setLevel(logging.INFO)
    import dask

    environ = dask.config.get("distributed.nanny.pre-spawn-environ") if a.default_malloc else dd.worker_environ()
    dask.config.set({"distributed.nanny.pre-spawn-environ": environ})
    out = {"worker_environ_asked": {k: str(v) for k, v in environ.items() if k.startswith("MALLOC_")}, "side": a.side, "levels": a.levels, "chunk": a.chunk, "blocks": (-(-a.side // a.chunk)) ** 2, "cores": cores, "runs": a.runs, "in_memory_s": [], "clusters": {}}
    with tempfile.TemporaryDirectory() as d:
        path = f"{d}/lin.fits"
        write_set(path, s)
        out["file_mib"] = os.path.getsize(path) / 2**20
        clusters = {}
        try:
            for n in counts:
                threads = str(max(1, cores // n))
                cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, env={"RAYON_NUM_THREADS": threads})
                clusters[n] = (cluster, distributed.Client(cluster, set_as_default=False))
                out["clusters"][n] = {"workers": n, "native_threads_a_worker": int(threads), "seconds": []}
                # What the workers got (this process's own environment wins over the
                # configuration's).
                got = clusters[n][1].run(lambda: sorted((k, v) for k, v in os.environ.items() if k.startswith("MALLOC_")))
                out["clusters"][n]["workers_malloc"] = [dict(e) for e in {tuple(e) for e in got.values()}]
            # One fit per cluster first, not timed: the workers import dncal and astropy
            # and the file comes into the page cache, as on a cluster already running.
            for n, (_, client) in clusters.items():
                with client.as_current():
                    f = dd.open_linearity(path, chunks=(a.chunk, a.chunk))
                    dd.fit_linearity(f.mean, f.std, f.voltage, f.frames, mask=f.mask, bit_depth=f.bit_depth, n_adc=f.n_adc, keep_corrected=False).coefficients.compute()
                    del f
                released(client)
            for _ in range(a.runs):
                t = time.perf_counter()
                want = s.fit(keep_corrected=False)
                out["in_memory_s"].append(time.perf_counter() - t)
                for n, (_, client) in clusters.items():
                    steps.steps = []
                    with client.as_current():
                        t = time.perf_counter()
                        f = dd.open_linearity(path, chunks=(a.chunk, a.chunk))
                        got = dd.fit_linearity(f.mean, f.std, f.voltage, f.frames, mask=f.mask, bit_depth=f.bit_depth, n_adc=f.n_adc, keep_corrected=False)
                        coefficients = got.coefficients.compute()
                        out["clusters"][n]["seconds"].append(time.perf_counter() - t)
                    if got.report != want.report or not np.array_equal(coefficients, want.coefficients, equal_nan=True):
                        raise SystemExit(f"{n} workers: the fit from the file differs from the in-memory fit")
                    out["clusters"][n].setdefault("steps", []).append(steps.steps)
                    # The fit's persisted blocks are released before the next run, which
                    # would otherwise find the same keys (the same file and arguments)
                    # still held and skip the per-pixel fits.
                    del got, f, coefficients
                    released(client)
        finally:
            for cluster, client in clusters.values():
                client.close()
                cluster.close()
    for n, c in out["clusters"].items():
        c["ratios"] = [x / m for x, m in zip(c["seconds"], out["in_memory_s"])]
        c["median_ratio"] = statistics.median(c["ratios"])
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
