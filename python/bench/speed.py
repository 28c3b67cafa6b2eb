"""The Python package's two speed ratios (issue 41), measured in one process on a
release build (scripts/python-bench.sh builds it and runs this):

1. Correcting frames from Python (`Corrector.add`, wall time around the call) against
   the Rust core's own time on the same frames and the same sum buffers (the core's
   work inside a call, timed in Rust: `Corrector._last_core_seconds` of an `add` on
   its own), for one frame a call and for stacks. Also, for information, against a
   corrector made afresh in Rust (`_dncal._core_seconds`: its buffers in another
   memory state, so the ratio mixes the cache's effects with the boundary's).
2. The linearity fit from Python (`fit_linearity` on numpy arrays, wall time around the
   call: checks, copies in, arrays out) against `dncal linearity`'s own analysis time on
   the same set (`linearity_file_json`'s `analysis_s`, the CLI's function).

Runs alternate A and B; each ratio is the median of the per-pair ratios, with the range.
Prints a JSON object (`dncal bench --python PY` runs this file and reports the ratios as
its rows). Usage: python speed.py LINEARITY_SET.fits [--runs N]
"""

import argparse
import json
import statistics
import time

import numpy as np

import dncal
from dncal import _dncal


def ratio_runs(a, b, runs):
    """Median and range of a()/b() over `runs` alternating pairs (seconds each)."""
    a(), b()  # warm: caches, page faults, the pool
    ratios, ta, tb = [], [], []
    for _ in range(runs):
        x, y = a(), b()
        ta.append(x)
        tb.append(y)
        ratios.append(x / y)
    return {"ratio_median": statistics.median(ratios), "ratio_min": min(ratios), "ratio_max": max(ratios), "a_median_s": statistics.median(ta), "b_median_s": statistics.median(tb), "runs": runs, "a_s": ta, "b_s": tb}


def correction(frames_per_call, size, states, runs):
    rng = np.random.default_rng(1)
    steps = rng.integers(1000, 2040, size=(4, 4096), dtype=np.uint32)
    steps[:, 0] = 0
    lut = dncal.Lut(np.cumsum(steps, axis=1, dtype=np.uint32))
    frames = rng.integers(0, 4096, size=(frames_per_call, size, size), dtype=np.uint16)
    c = dncal.Corrector(lut, states, size, size)
    state_list = [i % states for i in range(frames_per_call)]

    def python():
        c.clear()
        t = time.perf_counter()
        c.add(frames, states=state_list)
        return time.perf_counter() - t

    def core():
        c.clear()
        c.add(frames, states=state_list)
        return c._last_core_seconds

    def fresh():
        return _dncal._core_seconds(lut, frames, states)

    r = ratio_runs(python, core, runs)
    f = ratio_runs(python, fresh, runs)
    r["against_a_fresh_core_corrector"] = {k: f[k] for k in ("ratio_median", "ratio_min", "ratio_max", "b_median_s")}
    r.update({"what": f"Corrector.add / core, {frames_per_call} frame(s) of {size} x {size} a call, {states} states", "pixels": frames_per_call * size * size, "pixels_per_s_python": frames_per_call * size * size / r["a_median_s"]})
    return r


def linearity(path, runs):
    from astropy.io import fits

    with fits.open(path) as f:
        mean = np.ascontiguousarray(f[0].data, dtype=np.float64)
        std = np.ascontiguousarray(f["STD"].data, dtype=np.float64)
        voltage = np.ascontiguousarray(f["REFERENCE"].data["VOLTAGE"], dtype=np.float64)
        frames = int(f[0].header["NFRAMES"])

    def python():
        t = time.perf_counter()
        dncal.fit_linearity(mean, std, voltage, frames, keep_corrected=False)
        return time.perf_counter() - t

    def cli():
        return json.loads(_dncal.linearity_file_json(str(path)))["analysis_s"]

    r = ratio_runs(python, cli, runs)
    r["what"] = f"fit_linearity / dncal linearity analysis, {mean.shape[1]} x {mean.shape[2]} pixels, {mean.shape[0]} levels"
    return r


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("linearity_set")
    p.add_argument("--runs", type=int, default=9)
    a = p.parse_args()
    out = {
        "correction": [correction(1, 1024, 4, a.runs), correction(32, 1024, 4, a.runs)],
        "linearity": linearity(a.linearity_set, a.runs),
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
