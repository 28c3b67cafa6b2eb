"""dncal: real-time correction and characterization of scientific camera detectors.

The library behind the ``dncal`` command, on numpy arrays: the same arithmetic (the
fixed-point core and the host library, not a re-implementation), the same messages.

- LUTs (de Wijn 2018, section 4): :func:`build_luts` from code histograms,
  :func:`read_lut` of any format the CLI reads, :meth:`Lut.write` to any it writes.
- Correction: :class:`Corrector` sums uint16 frames through the LUTs into per-state
  uint32 sums, bit for bit what the co-processor computes.
- Characterization: :func:`fit_linearity` (the pixel-wise 4th-order correction),
  :func:`linearity` of a set file, :func:`quantization`, :func:`diagnose` of any input.
- :mod:`dncal.dask`: the per-pixel work of sensors larger than one machine.

Units: LUT entries and sums are in 2^-11 DN (divide by 2048 for DN); code widths in DN.
"""

import json as _json
from dataclasses import dataclass as _dataclass
from typing import Any, Dict, Optional

import numpy as _np

from . import errors
from ._dncal import Corrector, Lut, __version__, build_luts, memory_budget, read_histograms, read_lut, set_memory_budget
from . import _dncal
from .errors import DncalError, DncalIOError, InputError, OverBudgetError, ToolError

#: LUT entries and sums per DN.
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
    "build_luts",
    "diagnose",
    "errors",
    "fit_linearity",
    "linearity",
    "memory_budget",
    "quantization",
    "read_histograms",
    "read_lut",
    "set_memory_budget",
    "__version__",
]
