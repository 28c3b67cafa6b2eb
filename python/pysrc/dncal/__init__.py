"""dncal: real-time correction and characterization of scientific camera detectors.

The library behind the ``dncal`` command, on numpy arrays: the same arithmetic (the
fixed-point core and the host library, not a re-implementation), the same messages.

- LUTs (de Wijn 2018, section 4): :func:`build_luts` from code histograms,
  :func:`read_lut` of any format the CLI reads, :meth:`Lut.write` to any it writes.
- Correction: :class:`Corrector` sums uint16 frames through the LUTs into per-state
  uint32 sums, bit for bit what the co-processor computes.
- Characterization: :func:`fit_linearity` (the pixel-wise 4th-order correction),
  :func:`linearity` of a set file, :func:`quantization`, :func:`emva` (the EMVA 1288
  datasheet of a descriptor), :func:`diagnose` of any input.
- The camera simulator: :func:`simulate_frames`, :func:`simulate_histograms`,
  :func:`simulate_linearity` (the sets ``dncal simulate`` writes, as arrays) and
  :func:`camera_config`, so a notebook can plant an effect and look for it.
- :mod:`dncal.dask`: the per-pixel work of sensors larger than one machine.

Units: LUT entries and sums are in 2^-11 DN up to 12-bit codes (divide by 2048 for DN),
2^-(23 - bits) DN above (14 bits: 512 a DN, 16 bits: 128; ``Lut.units_per_dn``); code
widths in DN.
"""

import json as _json
from dataclasses import dataclass as _dataclass
from typing import Any, Dict, Optional

import numpy as _np

from . import errors
from ._dncal import Corrector, Lut, __version__, build_luts, memory_budget, read_histograms, read_lut, set_memory_budget
from . import _dncal
from .errors import DncalError, DncalIOError, InputError, OverBudgetError, ToolError

#: LUT entries and sums per DN, for codes of up to 12 bits (deeper tables have fewer
#: fractional bits: ``Lut.units_per_dn``).
UNITS_PER_DN = 2048


def diagnose(path, *, seed: int = 1, block_rows: Optional[int] = None, spill: bool = False, **flatten) -> Dict[str, Any]:
    """``dncal diagnose PATH --json`` as a dict: what the simulation gets wrong about the
    measured input (a histogram set, a linearity set, an EMVA 1288 descriptor, a K-Cor
    table set...), the cause named, the model extended and the gain measured."""
    return _json.loads(_dncal.diagnose_json(str(path), seed=seed, block_rows=block_rows, spill=spill, **flatten))


def linearity(path, *, order: int = 4, flat_level: Optional[int] = None) -> Dict[str, Any]:
    """``dncal linearity PATH --json`` as a dict: the standard and pixel-wise corrections
    of a linearity set file and their RMS residuals per level (the paper's Fig. 8)."""
    return _json.loads(_dncal.linearity_file_json(str(path), order=order, flat_level=flat_level))


def quantization(*, sigma=None, bias=None, read_noise_e=None, gain_e_per_dn=None, samples: int = 1_000_000) -> Dict[str, Any]:
    """``dncal quantization --json`` as a dict: the worst quantization bias at a noise
    ``sigma`` (DN, or ``read_noise_e`` over ``gain_e_per_dn``), or the noise a ``bias``
    target (DN) needs (the paper's Fig. 1)."""
    return _json.loads(_dncal.quantization_json(sigma=sigma, bias=bias, read_noise_e=read_noise_e, gain_e_per_dn=gain_e_per_dn, samples=samples))


def emva(descriptor, *, release: Optional[str] = None) -> Dict[str, Any]:
    """``dncal emva DESCRIPTOR --json`` as a dict: the EMVA 1288 datasheet (quantum
    efficiency, gain, dark noise, SNR, linearity error, DSNU, PRNU...) of the set an
    ``EMVA1288_Data.txt`` describes, by the definitions of ``release`` ("3.1" or "4.0";
    default the descriptor's own)."""
    return _json.loads(_dncal.emva_json(str(descriptor), release=release))


def camera_config(camera=None) -> Dict[str, Any]:
    """The camera model's configuration as a dict (the keys of its TOML file): the
    built-in camera, or the one of the TOML file ``camera``."""
    return _json.loads(_dncal.camera_json(None if camera is None else str(camera)))


def simulate_frames(n: int, photons: float, *, roi=None, seed: int = 1, camera=None) -> _np.ndarray:
    """``n`` frames of the camera model under uniform light of ``photons`` per pixel and
    frame: uint16 (n, rows, cols), codes in DN. ``roi`` is (width, height, column, row)
    of the sensor (default all of it); frame f is drawn with the seed ``dncal stream``
    uses for frame f of ``seed``. ``camera``: a camera TOML file (default the built-in)."""
    return _dncal.simulate_frames(n, photons, roi=roi, seed=seed, camera=None if camera is None else str(camera))


def simulate_histograms(*, seed: int = 4, camera=None) -> _np.ndarray:
    """The per-ADC code histograms of the calibration ramps, uint64 (adcs, codes): what
    ``dncal simulate histograms`` writes (the default ramps, Poisson draws seeded
    ``seed``). :func:`build_luts` takes them."""
    return _dncal.simulate_histograms(seed=seed, camera=None if camera is None else str(camera))


@_dataclass
class LinearitySet:
    """A linearity set in memory (:func:`simulate_linearity`): the arguments
    :func:`fit_linearity` and :func:`dncal.dask.fit_linearity` take."""

    #: Mean frames, float64 (levels, rows, cols), DN; level 0 dark.
    mean: _np.ndarray
    #: Per-pixel standard deviation of the frames, float64 (levels, rows, cols), DN.
    std: _np.ndarray
    #: The reference per level, float64 (levels,): the photodiode's voltage, V, or where
    #: ``reference`` is ``"exposure"`` the exposure time over the f-number squared, s.
    voltage: _np.ndarray
    #: Pixels the camera model knows to be bad (hot, dead), uint8 (rows, cols), 1 = bad.
    mask: _np.ndarray
    #: Frames averaged per level.
    frames: int
    #: Bits per code.
    bit_depth: int
    #: ADCs (column c read by ADC c mod n_adc).
    n_adc: int
    #: The colour filter's layout from the set's first pixel (FITS ``BAYERPAT``: "RGGB",
    #: "GRBG", "GBRG" or "BGGR"), None for a monochrome sensor.
    bayer: Optional[str] = None
    #: What the reference measures: "photodiode" (the light, column ``VOLTAGE``) or
    #: "exposure" (a camera's own relative exposure, column ``EXPOSURE``).
    reference: str = "photodiode"

    def fit(self, **options) -> "LinearityFit":
        """:func:`fit_linearity` of this set (``order``, ``flat_level``, ``keep_corrected``)."""
        return fit_linearity(self.mean, self.std, self.voltage, self.frames, mask=self.mask, bit_depth=self.bit_depth, n_adc=self.n_adc, **options)


def simulate_linearity(*, levels: int = 41, frames: int = 256, roi=None, seed: int = 41, camera=None) -> LinearitySet:
    """The linearity set ``dncal simulate linearity`` writes, in memory: ``levels`` from
    dark to 1.02 x saturation, ``frames`` per level, of the region ``roi`` (width,
    height, column, row; default 128 x 128 at the sensor's center)."""
    return LinearitySet(*_dncal.simulate_linearity(levels=levels, frames=frames, roi=roi, seed=seed, camera=None if camera is None else str(camera)))


@_dataclass
class LinearityFit:
    """The pixel-wise linearity analysis of a set (:func:`fit_linearity`)."""

    #: The report ``dncal linearity --json`` prints under "report": the RMS residual of
    #: the raw, standard and pixel-wise corrections per level, the random noise, the
    #: global cubic.
    report: Dict[str, Any]
    #: Coefficients a_k of each pixel's polynomial, float64 (order + 1, rows, cols); NaN
    #: where a pixel is masked.
    coefficients: _np.ndarray
    #: Why each pixel is masked (0: good), uint8 (rows, cols).
    mask: _np.ndarray
    #: The pixel-wise corrected normalized intensity, float64 (levels, rows, cols),
    #: masked pixels filled from good neighbours; None with ``keep_corrected=False``.
    corrected: Optional[_np.ndarray]


def fit_linearity(mean, std, voltage, frames: int, *, order: int = 4, flat_level: Optional[int] = None, mask=None, bit_depth: int = 12, n_adc: int = 4, keep_corrected: bool = True) -> LinearityFit:
    """The paper's pixel-wise linearity analysis of a set in memory.

    ``mean`` and ``std`` are float64 (levels, rows, cols) in DN, level 0 dark; ``voltage``
    float64 (levels,), the reference photodiode in V; ``frames`` the frames averaged per
    level; ``mask`` optional uint8 (rows, cols), 1 = bad. The same analysis as
    ``dncal linearity`` on the same numbers.
    """
    report, coefficients, reasons, corrected = _dncal.fit_linearity(mean, std, voltage, frames, order=order, flat_level=flat_level, mask=mask, bit_depth=bit_depth, n_adc=n_adc, keep_corrected=keep_corrected)
    return LinearityFit(_json.loads(report), coefficients, reasons, corrected)


__all__ = [
    "Corrector",
    "DncalError",
    "DncalIOError",
    "InputError",
    "Lut",
    "LinearityFit",
    "OverBudgetError",
    "ToolError",
    "UNITS_PER_DN",
    "LinearitySet",
    "build_luts",
    "camera_config",
    "diagnose",
    "emva",
    "errors",
    "fit_linearity",
    "linearity",
    "memory_budget",
    "quantization",
    "read_histograms",
    "read_lut",
    "set_memory_budget",
    "simulate_frames",
    "simulate_histograms",
    "simulate_linearity",
    "__version__",
]
