"""Scaling of dncal.dask.fit_linearity (issue 41; docs/python.md's scaling note),
measured on a release wheel (scripts/python-bench.sh --dask builds it and runs this):

1. A simulated set of SIDE x SIDE pixels at LEVELS levels (the camera model, 16 frames a
   level), fitted in memory (`dncal.fit_linearity`) and on Dask's threaded scheduler in
   CHUNK x CHUNK blocks (`dncal.dask.fit_linearity`), the results checked equal; the
   Dask fit's global steps timed from its log (`dncal.dask.log`).
2. The memory of one chunk: a child process fits a CHUNK x CHUNK x LEVELS set in memory
   and reports its peak resident memory above what it held before the fit (the block's
   working set, beside the block itself: 16 x LEVELS bytes a pixel for mean and std).

Prints a JSON object. Usage: python dask_scale.py [--side 512] [--levels 41] [--chunk 256]
"""

import argparse
import json
import logging
import re
import subprocess
import sys
import time

import numpy as np

import dncal

CHILD = """
import sys, json
import numpy as np
import dncal
d = {k: np.load(f"{sys.argv[1]}/{k}.npy") for k in ("mean", "std", "voltage", "mask", "frames")}
mean, std, voltage, mask = (d[k] for k in ("mean", "std", "voltage", "mask"))
# The peak resident memory of this process image (VmHWM; ru_maxrss would start from the
# parent's peak, inherited through fork).
hwm = lambda: int(open("/proc/self/status").read().split("VmHWM:")[1].split()[0])
before = hwm()
dncal.fit_linearity(mean, std, voltage, int(d["frames"].ravel()[0]), mask=mask, keep_corrected=bool(int(sys.argv[2])))
after = hwm()
print(json.dumps({"before_kib": before, "after_kib": after}))
"""


class Steps(logging.Handler):
    """Collects dncal.dask's step log lines: name, seconds, passes."""

    def __init__(self):
        super().__init__()
        self.steps = []

    def emit(self, record):
        m = re.match(r"(.*): ([0-9.]+) s(?:, (\d+) passes)?$", record.getMessage())
        if m:
            self.steps.append({"step": m.group(1), "seconds": float(m.group(2)), "passes": int(m.group(3)) if m.group(3) else None})


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--side", type=int, default=512)
    p.add_argument("--levels", type=int, default=41)
    p.add_argument("--chunk", type=int, default=256)
    a = p.parse_args()
    import dask
    import dask.array as da
    from dncal import dask as dd

    s = dncal.simulate_linearity(levels=a.levels, frames=16, roi=(a.side, a.side, 0, 0))
    t = time.perf_counter()
    want = s.fit(keep_corrected=False)
    in_memory_s = time.perf_counter() - t

    steps = Steps()
    dd.log.addHandler(steps)
    dd.log.setLevel(logging.INFO)
    c = (a.levels, a.chunk, a.chunk)
    mean, std = da.from_array(s.mean, chunks=c), da.from_array(s.std, chunks=c)
    with dask.config.set(scheduler="threads"):
        t = time.perf_counter()
        got = dd.fit_linearity(mean, std, s.voltage, s.frames, mask=s.mask, bit_depth=s.bit_depth, n_adc=s.n_adc, keep_corrected=False)
        coefficients = got.coefficients.compute()
        dask_s = time.perf_counter() - t
    assert got.report == want.report and np.array_equal(coefficients, want.coefficients, equal_nan=True), "the Dask fit differs from the in-memory one"

    # One chunk's set in a file, fitted in memory by a child whose peak before the fit is
    # the set itself (a block as a worker holds it).
    import tempfile

    mem = {}
    with tempfile.TemporaryDirectory() as d:
        path, k = d, a.chunk
        # One .npy an array: read straight into its array (no archive's buffer).
        for name, v in (("mean", s.mean[:, :k, :k]), ("std", s.std[:, :k, :k]), ("voltage", s.voltage), ("mask", s.mask[:k, :k]), ("frames", np.array(s.frames))):
            np.save(f"{d}/{name}.npy", np.ascontiguousarray(v))
        for keep in (0, 1):
            child = subprocess.run([sys.executable, "-c", CHILD, path, str(keep)], capture_output=True, text=True)
            if child.returncode != 0:
                sys.exit(f"the chunk's fit failed: {child.stderr.strip().splitlines()[-1]}")
            mem[keep] = json.loads(child.stdout.strip().splitlines()[-1])
    print(
        json.dumps(
            {
                "side": a.side,
                "levels": a.levels,
                "chunk": a.chunk,
                "blocks": (a.side // a.chunk) ** 2,
                "threads": dask.system.CPU_COUNT,
                "in_memory_s": in_memory_s,
                "dask_s": dask_s,
                "steps": steps.steps,
                "chunk_fit_peak_above_inputs_mib": (mem[0]["after_kib"] - mem[0]["before_kib"]) / 1024,
                "chunk_fit_with_cube_peak_above_inputs_mib": (mem[1]["after_kib"] - mem[1]["before_kib"]) / 1024,
                "chunk_input_mib": 16 * a.levels * a.chunk * a.chunk / 2**20,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
