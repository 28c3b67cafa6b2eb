"""Characterizations and diagnose from Python against the CLI's --json on the same
files; the in-memory linearity fit against `dncal linearity` on the set's own file."""

import math

import numpy as np
import pytest
from astropy.io import fits

import dncal


# What `dncal linearity` prints beyond the report: the run's own (input, time, files)
# and the paper's Fig. 8 read from the report (`paper_fig8`, computed from its curves).
CLI_ONLY = ("input", "analysis_s", "outputs", "paper_fig8")

def without_timing(d):
    return {k: v for k, v in d.items() if k != "analysis_s"}


def test_diagnose_is_the_clis_json(sets, cli):
    for name in ["h.fits", "lin.fits"]:
        assert dncal.diagnose(sets / name) == cli("diagnose", sets / name)


def test_linearity_of_a_file_is_the_clis_json(sets, cli):
    assert without_timing(dncal.linearity(sets / "lin.fits")) == without_timing(cli("linearity", sets / "lin.fits"))


def test_quantization_is_the_clis_json(cli):
    assert dncal.quantization(sigma=0.3) == cli("quantization", "--sigma", "0.3")
    assert dncal.quantization(bias=0.01) == cli("quantization", "--bias", "0.01")


def read_set(path):
    with fits.open(path) as f:
        mean = np.ascontiguousarray(f[0].data, dtype=np.float64)
        std = np.ascontiguousarray(f["STD"].data, dtype=np.float64)
        voltage = np.ascontiguousarray(f["REFERENCE"].data["VOLTAGE"], dtype=np.float64)
        frames = int(f[0].header["NFRAMES"])
    return mean, std, voltage, frames


def test_fit_linearity_on_arrays_equals_the_cli_on_the_file(sets, cli, dncal_bin, tmp_path):
    import subprocess

    mean, std, voltage, frames = read_set(sets / "lin.fits")
    fit = dncal.fit_linearity(mean, std, voltage, frames)
    theirs = cli("linearity", sets / "lin.fits")
    assert fit.report == {k: v for k, v in theirs.items() if k not in CLI_ONLY}
    subprocess.run([str(dncal_bin), "--quiet", "linearity", str(sets / "lin.fits"), "-o", str(tmp_path / "out")], check=True, capture_output=True)
    with fits.open(tmp_path / "out" / "coefficients.fits") as f:
        coeffs, mask = f[0].data, f["MASK"].data
    assert fit.coefficients.shape == (5,) + mean.shape[1:]
    assert np.array_equal(fit.coefficients, coeffs, equal_nan=True)
    assert np.array_equal(fit.mask, mask)
    with fits.open(tmp_path / "out" / "corrected.fits") as f:
        assert np.array_equal(fit.corrected, f[0].data, equal_nan=True)
    # keep_corrected=False: the same report without the cube.
    lean = dncal.fit_linearity(mean, std, voltage, frames, keep_corrected=False)
    assert lean.corrected is None and lean.report == fit.report


def test_bad_linearity_inputs(sets):
    mean, std, voltage, frames = read_set(sets / "lin.fits")
    bad = mean.copy()
    bad[3, 2, 1] = math.nan
    with pytest.raises(dncal.InputError, match="mean is NaN at level 3, row 2, column 1"):
        dncal.fit_linearity(bad, std, voltage, frames)
    with pytest.raises(dncal.InputError, match="REFERENCE VOLTAGE"):
        dncal.fit_linearity(mean, std, np.zeros_like(voltage), frames)
    with pytest.raises(ValueError, match="voltage: 3 values"):
        dncal.fit_linearity(mean, std, voltage[:3].copy(), frames)
    with pytest.raises(ValueError, match="std: shape"):
        dncal.fit_linearity(mean, std[:, :-1].copy(), voltage, frames)
    with pytest.raises(ValueError, match="order 9"):
        dncal.fit_linearity(mean, std, voltage, frames, order=9)
    with pytest.raises(dncal.InputError, match="an order-8 fit needs at least 11"):
        dncal.fit_linearity(mean[:10].copy(), std[:10].copy(), voltage[:10].copy(), frames, order=8)
    with pytest.raises(TypeError, match="dtype float32"):
        dncal.fit_linearity(mean.astype(np.float32), std, voltage, frames)


def test_a_fit_over_the_memory_budget_is_refused_as_the_cli_refuses_it(sets, dncal_bin, tmp_path):
    import subprocess

    # 512 KiB: the arrays are the caller's, and their analysis (the corrected cube, 8
    # bytes a value, and the fits, 192 bytes a pixel: 570 KiB) is refused. The CLI
    # refuses the whole run from the file's header (issue 56): the cubes as read (420 KiB)
    # and the same analysis, its parts the same numbers.
    mean, std, voltage, frames = read_set(sets / "lin.fits")
    before = dncal.memory_budget()
    dncal.set_memory_budget(512 * 1024)
    try:
        with pytest.raises(dncal.OverBudgetError) as e:
            dncal.fit_linearity(mean, std, voltage, frames)
    finally:
        dncal.set_memory_budget(before)
    assert isinstance(e.value, MemoryError) and dncal.memory_budget() == before
    out = subprocess.run([str(dncal_bin), "--max-memory", "512K", "linearity", str(sets / "lin.fits"), "-o", str(tmp_path / "out")], capture_output=True, text=True)
    theirs = out.stderr.strip()
    assert out.returncode == 1 and theirs == f"dncal: error: {sets / 'lin.fits'}: linearity of 48 x 40 pixels x 14 levels (the two cubes as read 420.0 KiB + the corrected cube 210.0 KiB + the fits 360.0 KiB) needs about 990.0 KiB, more than the memory budget of 512.0 KiB (--max-memory)", out.stderr
    assert str(e.value) == "linearity set: the pixel-wise analysis (the corrected cube and the fits) needs about 570.0 KiB, more than the memory budget of 512.0 KiB (--max-memory)"


def test_missing_and_bad_files_raise_their_class(tmp_path):
    with pytest.raises(dncal.DncalIOError):
        dncal.diagnose(tmp_path / "nothing.fits")
    junk = tmp_path / "junk.fits"
    junk.write_bytes(b"SIMPLE  =                    T" + b" " * 3000)
    with pytest.raises(dncal.InputError, match="junk.fits"):
        dncal.diagnose(junk)
