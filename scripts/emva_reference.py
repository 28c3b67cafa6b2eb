"""Run the EMVA 1288 reference implementation on a descriptor file; print JSON.

Independent oracle for dncal's EMVA 1288 code: PyPI `emva1288` 1.0.2, run
exactly as its emva1288.process.Emva1288 class does
(ParseEmvaDescriptorFile -> LoadImageData -> Data1288 -> Results1288), logging
quiet. Run with the venv's python:

    VENV_PY=$(scripts/emva-venv.sh | tail -n 1)
    "$VENV_PY" scripts/emva_reference.py path/to/EMVA1288descriptor.txt > ref.json

Prints ONE JSON object on stdout (nothing else goes to stdout; warnings go to
stderr). Keys are the reference's own attribute names:

  scalars (top level): every Results1288 attribute tagged `.. emva1288::`
    (K, inverse_K, QE [%], R, sigma_y_dark, sigma_d, u_p_min, u_e_min,
    u_p_sat, u_e_sat, SNR_max, SNR_max_dB, SNR_max_bit, inverse_SNR_max, DR,
    DR_dB, LE_min, LE_max, u_I_var, u_I_var_DN, u_I_mean, u_I_mean_DN,
    DSNU1288, DSNU1288_DN, DSNU1288_row/_col/_pixel, PRNU1288 [%],
    PRNU1288_row/_col/_pixel, s_2_y(_dark), s_2_y_measured(_dark),
    s_2_y_cav/_rav/_row/_col/_pixel(_dark), sigma_2_y_stack(_dark),
    index_start, index_u_ysat, index_sensitivity_min/_max,
    index_linearity_min/_max; the *_area ones are null without a pixel area)
    plus s2q, linearity_fit_slope, linearity_fit_offset, and spatial_*
    (texp, u_p, L, L_dark, M, N, avg_mean, avg_mean_dark).
  version: the descriptor's 'v' line as the parser reads it; format: bits,
    width, height; emva1288_version; descriptor (absolute path); seconds.
  temporal: texp, u_p, u_y, s2_y, u_ydark, s2_ydark (Data1288 arrays; with a
    single exposure time texp/u_ydark/s2_ydark are repeated per point).
  linearity: relative_deviation (% per temporal point), fit_slope, fit_offset,
    linearity_error_min, linearity_error_max.
  histogram_PRNU, histogram_PRNU_accumulated, histogram_DSNU,
    histogram_DSNU_accumulated: {bins, values, model} as Results1288 gives them.
  spectrogram_horizontal_PRNU, spectrogram_vertical_PRNU,
    spectrogram_horizontal_DSNU, spectrogram_vertical_DSNU: what
    process/plotting.py computes and draws, without matplotlib:
      freq     = routines.GetFrecs(spectrogram)           (cycles/pixel)
      power    = spectrogram (see below)
      plotted  = sqrt(spectrogram)                          (the curve drawn)
      and the horizontal marker lines drawn with it.
    PRNU: data = (sum - sum_dark) / L; spectrogram = FFT1288(data[, rotate])
          / mean(data)        (sic: power divided by the mean, not mean^2)
    DSNU: spectrogram = FFT1288(sum_dark[, rotate], n=L)   (sic: L, not L_dark)

A value that is NaN, infinite or raises becomes null, with "<name>_why"
giving a short reason (array elements that are not finite become null and the
array gets a "<name>_why" too). If the data set cannot be processed at all
(the parser, loader or Data1288 raise), the object has "error" and exits 1.
"""

import json
import logging
import math
import os
import sys
import time
import warnings

import numpy as np

import emva1288
from emva1288.process import routines
from emva1288.process.data import Data1288
from emva1288.process.loader import LoadImageData
from emva1288.process.parser import ParseEmvaDescriptorFile
from emva1288.process.results import Results1288

QUIET = logging.ERROR


def short(exc):
    s = "%s: %s" % (type(exc).__name__, exc)
    return s if len(s) <= 200 else s[:197] + "..."


def scalar(v):
    """JSON value and reason (None if fine) for one reference result."""
    if v is None:
        return None, "reference returned None"
    if isinstance(v, (bool, np.bool_)):
        return bool(v), None
    if isinstance(v, (int, np.integer)):
        return int(v), None
    if isinstance(v, np.ndarray) and v.size == 1:
        v = v.reshape(())[()]
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None, "not a number: %r" % (v,)
    if math.isnan(f):
        return None, "NaN"
    if math.isinf(f):
        return None, "inf"
    return f, None


def array(v):
    a = np.asarray(v, dtype=float).ravel()
    bad = ~np.isfinite(a)
    out = [None if b else float(x) for x, b in zip(a, bad)]
    why = None
    if bad.any():
        why = "%d of %d values not finite (null)" % (int(bad.sum()), a.size)
    return out, why


class Out:
    def __init__(self):
        self.d = {}

    def put(self, d, name, fn, kind="scalar"):
        """d[name] = fn() converted; on failure null plus d[name + '_why']."""
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                v = fn()
            if kind == "scalar":
                val, why = scalar(v)
            else:
                val, why = array(v)
            if why and caught:
                why += " (%s)" % "; ".join(sorted({str(w.message) for w in caught}))
        except Exception as e:  # noqa: BLE001 - every failure becomes null
            val, why = None, short(e)
        d[name] = val
        if why:
            d[name + "_why"] = why
        return val


def attr(obj, name):
    """The reference's attribute: property value or method result."""
    def f():
        v = getattr(obj, name)
        return v() if callable(v) else v
    return f


def histogram(o, res, name):
    d = {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            h = getattr(res, name)
    except Exception as e:  # noqa: BLE001
        o.d[name] = None
        o.d[name + "_why"] = short(e)
        return
    for k in ("bins", "values", "model"):
        o.put(d, k, lambda k=k: h[k], kind="array")
    o.d[name] = d


def spectrograms(o, res):
    sp = res.spatial

    def prnu(rotate):
        data = (sp["sum"] - sp["sum_dark"])
        data = data / sp["L"]
        data_mean = np.mean(data)
        spec = routines.FFT1288(data, rotate=rotate) / data_mean
        return spec, {"PRNU1288": lambda: res.PRNU1288,
                      "sigma_2_y_stack_line":
                          lambda: 100 * np.sqrt(res.sigma_2_y_stack) / data_mean,
                      "data_mean": lambda: data_mean}

    def dsnu(rotate):
        spec = routines.FFT1288(sp["sum_dark"], rotate=rotate, n=sp["L"])
        return spec, {"DSNU1288_DN": lambda: res.DSNU1288_DN(),
                      "sigma_2_y_stack_dark_line":
                          lambda: np.sqrt(res.sigma_2_y_stack_dark)}

    for name, fn, rotate in (("spectrogram_horizontal_PRNU", prnu, False),
                             ("spectrogram_vertical_PRNU", prnu, True),
                             ("spectrogram_horizontal_DSNU", dsnu, False),
                             ("spectrogram_vertical_DSNU", dsnu, True)):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                spec, lines = fn(rotate)
        except Exception as e:  # noqa: BLE001
            o.d[name] = None
            o.d[name + "_why"] = short(e)
            continue
        d = {}
        o.put(d, "freq", lambda: routines.GetFrecs(spec), kind="array")
        o.put(d, "power", lambda: spec, kind="array")
        o.put(d, "plotted", lambda: np.sqrt(spec), kind="array")
        for k, f in lines.items():
            o.put(d, k, f)
        o.d[name] = d


def nan_hint(res, name):
    """Why the reference gives NaN/None for a result it computed on purpose."""
    try:
        if name.endswith("_area"):
            return "no pixel area given (reference returns None)"
        if name.startswith("DSNU1288"):
            part = name[len("DSNU1288"):].lstrip("_")
            var = "s_2_y_%s_dark" % part if part not in ("", "DN") else "s_2_y_dark"
            v = getattr(res, var)
            if v < 0:
                return "%s = %.6g < 0 (reference returns NaN)" % (var, v)
        if name.startswith("PRNU1288"):
            part = name[len("PRNU1288"):]
            a = getattr(res, "s_2_y" + part)
            b = getattr(res, "s_2_y" + part + "_dark")
            if a - b < 0:
                return ("s_2_y%s - s_2_y%s_dark = %.6g < 0 (sqrt of a negative)"
                        % (part, part, a - b))
        if name.startswith("u_I_"):
            n = len(np.unique(res.temporal["texp"]))
            if n <= 2:
                return ("only %d distinct exposure time(s); reference needs 3 "
                        "(returns NaN)" % n)
            if name.startswith("u_I_var"):
                fit, _ = routines.LinearB(res.temporal["texp"],
                                          res.temporal["s2_ydark"])
                if fit[0] < 0:
                    return ("slope of s2_ydark against texp %.6g < 0 (reference "
                            "returns NaN)" % fit[0])
    except Exception:  # noqa: BLE001
        pass
    return None


# Extra scalars that are not tagged `.. emva1288::` in Results1288.
EXTRA = ("s2q",)


def main(argv):
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        print(__doc__, file=sys.stderr)
        print("usage: emva_reference.py DESCRIPTOR", file=sys.stderr)
        return 2
    fname = os.path.abspath(argv[0])
    t0 = time.time()
    o = Out()
    o.d["descriptor"] = fname
    o.d["emva1288_version"] = emva1288.__version__
    logging.basicConfig()
    try:
        # As Emva1288.__init__, with the loggers quiet.
        parser = ParseEmvaDescriptorFile(fname, loglevel=QUIET)
        o.d["version"] = parser.version
        o.d["format"] = dict(parser.format)
        imgs = LoadImageData(parser.images, loglevel=QUIET)
        dat = Data1288(imgs.data, loglevel=QUIET)
        res = Results1288(dat.data, loglevel=QUIET)
    except Exception as e:  # noqa: BLE001
        o.d.setdefault("version", None)
        o.d["error"] = short(e)
        print(json.dumps(o.d))
        return 1
    o.d["series"] = {k: {"exposures": len(v),
                         "points": sum(len(p) for p in v.values())}
                     for k, v in parser.images.items()}

    # every tagged result, in the reference's own order
    info = routines.cls_1288_info(Results1288)
    names = list(info.keys()) + [n for n in EXTRA if n not in info]
    for name in names:
        if name.startswith("histogram_"):
            continue  # arrays, below
        o.put(o.d, name, attr(res, name))
        if name + "_why" in o.d:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                hint = nan_hint(res, name)
            if hint:
                o.d[name + "_why"] = hint

    lin = {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            L = res.linearity()
        o.put(lin, "relative_deviation", lambda: L["relative_deviation"], kind="array")
        for k in ("fit_slope", "fit_offset", "linearity_error_min",
                  "linearity_error_max"):
            o.put(lin, k, lambda k=k: L[k])
        o.d["linearity_fit_slope"] = lin["fit_slope"]
        o.d["linearity_fit_offset"] = lin["fit_offset"]
        o.d["linearity"] = lin
    except Exception as e:  # noqa: BLE001
        o.d["linearity"] = None
        o.d["linearity_why"] = short(e)

    sp = res.spatial
    for k in ("texp", "u_p", "L", "L_dark", "M", "N", "avg_mean", "avg_mean_dark"):
        o.put(o.d, "spatial_" + k, lambda k=k: sp[k])

    tmp = {}
    for k in ("texp", "u_p", "u_y", "s2_y", "u_ydark", "s2_ydark"):
        o.put(tmp, k, lambda k=k: res.temporal[k], kind="array")
    o.d["temporal"] = tmp

    for h in ("histogram_PRNU", "histogram_PRNU_accumulated",
              "histogram_DSNU", "histogram_DSNU_accumulated"):
        histogram(o, res, h)
    spectrograms(o, res)

    o.d["seconds"] = round(time.time() - t0, 3)
    print(json.dumps(o.d, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
