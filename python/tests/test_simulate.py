"""The camera simulator and the EMVA 1288 datasheet from Python: the same sets and
JSON as the CLI, frames whose statistics are the camera's planted parameters, and the
datasheet of the real 12-bit CCD set in ../shared."""

import os
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

import dncal
from test_analyses import CLI_ONLY, read_set

EMVA = Path(os.environ.get("DNCAL_SHARED", Path(__file__).resolve().parents[3] / "shared")) / "data" / "emva1288-ccd-12bit" / "EMVA1288_Data.txt"


def test_simulate_linearity_is_the_clis_set(sets, cli):
    s = dncal.simulate_linearity(levels=14, frames=16, roi=(48, 40, 100, 200))
    mean, std, voltage, frames = read_set(sets / "lin.fits")
    assert np.array_equal(s.mean, mean) and np.array_equal(s.std, std) and np.array_equal(s.voltage, voltage)
    with fits.open(sets / "lin.fits") as f:
        assert np.array_equal(s.mask, f["MASK"].data)
        assert (s.frames, s.bit_depth, s.n_adc) == (frames, f[0].header["BITDEPTH"], f[0].header["NADC"])
    # The set's fit is `dncal linearity` of the file.
    theirs = cli("linearity", sets / "lin.fits")
    assert s.fit().report == {k: v for k, v in theirs.items() if k not in CLI_ONLY}


def test_simulate_linearity_says_what_the_files_keys_say(tmp_path, cli):
    """A colour camera whose series has a relative exposure for a reference: the set in
    memory carries the layout and the reference's kind the CLI's file declares
    (``BAYERPAT``, the reference column's name), the layout shifted to the region read out
    (from an odd row, GBRG reads as RGGB); the default camera carries neither."""
    cfg = tmp_path / "colour.toml"
    cfg.write_text('[cfa]\nperiod = 2\ncells = [1.23, 0.99, 0.55, 1.23]\nbayer = "GBRG"\n\n[bench]\nreference = "exposure"\n')
    for row, want in ((200, "GBRG"), (201, "RGGB")):
        s = dncal.simulate_linearity(levels=8, frames=4, roi=(16, 8, 100, row), camera=cfg)
        out = tmp_path / f"r{row}.fits"
        cli("simulate", "linearity", "--config", cfg, "--roi", f"16x8+100+{row}", "--levels", "8", "--frames", "4", "-o", out)
        with fits.open(out) as f:
            assert (s.bayer, f[0].header["BAYERPAT"]) == (want, want)
            assert s.reference == "exposure" and f["REFERENCE"].columns.names == ["EXPOSURE"]
            assert np.array_equal(s.voltage, f["REFERENCE"].data["EXPOSURE"])
    plain = dncal.simulate_linearity(levels=8, frames=4, roi=(16, 8, 100, 200))
    assert (plain.bayer, plain.reference) == (None, "photodiode")


def test_simulate_histograms_are_the_clis_counts(sets):
    counts, bits = dncal.read_histograms(sets / "h.fits")
    got = dncal.simulate_histograms()
    assert got.dtype == np.uint64 and np.array_equal(got, counts)
    assert not np.array_equal(dncal.simulate_histograms(seed=5), counts)


def test_frames_have_the_planted_mean_and_photon_transfer():
    """Uniform light on the built-in camera: the mean code is the offset plus (qe x
    photons + dark) / gain, and half the variance of a difference of two frames (the
    fixed pattern cancels) is the shot, dark and read noise over gain squared plus a
    code's 1/12 (the photon transfer curve); values from `camera_config`, not from the
    simulator's arithmetic. At 60 000 photons the shot noise is a third of the variance:
    a simulator without it would be 35% low."""
    c = dncal.camera_config()
    gain, offset, read, qe, dark = c["gain_e_per_dn"], c["offset_dn"], c["read_noise_e"], c["qe"], c["dark_e"]
    for photons in (4000.0, 60000.0):
        f = dncal.simulate_frames(2, photons, roi=(256, 64, 100, 300), seed=3).astype(np.float64)
        assert f.shape == (2, 64, 256)
        electrons = qe * photons + dark
        want_mean = offset + electrons / gain
        assert abs(f.mean() - want_mean) < 0.005 * want_mean, (photons, f.mean(), want_mean)
        want_var = (electrons + read**2) / gain**2 + 1 / 12
        var = np.var(f[0] - f[1]) / 2
        assert abs(var / want_var - 1) < 0.03, (photons, var, want_var)
    again = dncal.simulate_frames(2, photons, roi=(256, 64, 100, 300), seed=3)
    assert again.dtype == np.uint16 and np.array_equal(again, f.astype(np.uint16))
    assert not np.array_equal(dncal.simulate_frames(1, photons, roi=(256, 64, 100, 300), seed=4)[0], again[0])


def test_emva_of_the_real_ccd_set_is_the_clis_datasheet(cli):
    assert EMVA.exists(), f"{EMVA}: the shared data must be beside the project (or DNCAL_SHARED set)"
    sheet = dncal.emva(EMVA)
    assert sheet == cli("emva", EMVA)
    assert sheet["levels"] == 50 and sheet["release"] == "3.1"
    assert dncal.emva(EMVA, release="4.0") == cli("emva", EMVA, "--release", "4.0")


def test_bad_simulator_and_emva_inputs(tmp_path):
    with pytest.raises(dncal.InputError, match="inside the"):
        dncal.simulate_frames(1, 100.0, roi=(10, 10, 100000, 0))
    with pytest.raises(dncal.InputError, match="inside the"):
        dncal.simulate_frames(1, 100.0, roi=(10, 10, 2**64 - 5, 0))  # a region whose end wraps
    with pytest.raises(dncal.InputError, match="ROI"):
        dncal.simulate_linearity(roi=(4, 4, 0, 2**64 - 2))
    with pytest.raises(dncal.InputError, match="not negative"):
        dncal.simulate_frames(1, -1.0, roi=(10, 10, 0, 0))
    with pytest.raises(dncal.InputError, match="ROI"):
        dncal.simulate_linearity(levels=1, roi=(4, 4, 0, 0))
    with pytest.raises(dncal.OverBudgetError):
        dncal.simulate_frames(10**7, 100.0)
    with pytest.raises(dncal.DncalIOError):
        dncal.emva(tmp_path / "missing.txt")
    with pytest.raises(dncal.InputError, match="release"):
        dncal.emva(EMVA, release="5")
    with pytest.raises(dncal.DncalIOError):
        dncal.simulate_linearity(camera=tmp_path / "missing.toml")
    with pytest.raises(OverflowError):
        dncal.simulate_frames(-1, 1.0)
