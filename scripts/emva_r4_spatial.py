"""EMVA 1288 Release 4.0 nonuniformities of a descriptor's spatial series; print JSON.

An oracle for dncal's Release 4.0 spatial quantities, written apart from them.
Release 4.0 (section 8.1) computes DSNU and PRNU and their row, column and pixel
parts (eqs. 35-41, 66-67) from the averaged images high-pass filtered: each
image minus its smoothing by a 7 x 7 box, an 11 x 11 box and a 3 x 3 binomial
filter, one after the other. Here:

  * the descriptor is parsed and the frames are loaded by the reference
    implementation's own parser and image loader (emva1288 1.0.2);
  * the three smoothing filters are applied one after the other, each as a
    "valid" moving sum (numpy cumulative sums), so that only pixels whose
    whole window lies inside the image remain, (M - 18) x (N - 18) of them;
  * the temporal noise to take out is *measured*: every frame is filtered on
    its own, and the per-pixel variance over the frames (1/(L-1)), averaged
    over the pixels, is the temporal variance of one filtered pixel; the same
    for the means of each filtered column and row. Divided by L, these stand
    where eqs. 37-40 have sigma^2/L, sigma^2/(LM) and sigma^2/(LN). (dncal
    computes the same terms in closed form from the unfiltered temporal
    variance and the filter's white-noise gains.)

Run with the venv's python:  "$VENV_PY" scripts/emva_r4_spatial.py DESCRIPTOR

Prints {"bright": {...}, "dark": {...}} with, per series: L, M, N (filtered
size), mean (unfiltered averaged image, DN), total, row, col, pixel (DN^2).
"""

import json
import logging
import os
import sys

import numpy as np
from emva1288.process.parser import ParseEmvaDescriptorFile
from emva1288.process.routines import load_image


def moving_sum(a, n, axis):
    """Sum of n consecutive elements along axis, 'valid' (length - n + 1)."""
    c = np.cumsum(a, axis=axis, dtype=np.float64)
    zero = np.zeros_like(np.take(c, [0], axis=axis))
    c = np.concatenate([zero, c], axis=axis)
    hi = np.take(c, np.arange(n, c.shape[axis]), axis=axis)
    lo = np.take(c, np.arange(0, c.shape[axis] - n), axis=axis)
    return hi - lo


def smooth(img):
    """7 x 7 box, then 11 x 11 box, then 3 x 3 binomial, each 'valid'."""
    s = img.astype(np.float64)
    for n in (7, 11):
        s = moving_sum(moving_sum(s, n, 0), n, 1) / (n * n)
    # binomial [1 2 1]/4 along each axis
    s = (s[:-2, :] + 2 * s[1:-1, :] + s[2:, :]) / 4
    s = (s[:, :-2] + 2 * s[:, 1:-1] + s[:, 2:]) / 4
    return s


def high_pass(img):
    s = smooth(img)
    return img[9:-9, 9:-9].astype(np.float64) - s


def series(paths):
    frames = [load_image(p).astype(np.float64) for p in paths]
    L = len(frames)
    avg = sum(frames) / L
    f_avg = high_pass(avg)
    M, N = f_avg.shape
    filtered = np.stack([high_pass(f) for f in frames])
    t_pixel = filtered.var(axis=0, ddof=1).mean()
    t_col = filtered.mean(axis=1).var(axis=0, ddof=1).mean()   # column means
    t_row = filtered.mean(axis=2).var(axis=0, ddof=1).mean()   # row means
    mu = f_avg.mean()
    total = ((f_avg - mu) ** 2).sum() / (M * N) - t_pixel / L
    cav = ((f_avg.mean(axis=0) - mu) ** 2).sum() / N - t_col / L
    rav = ((f_avg.mean(axis=1) - mu) ** 2).sum() / M - t_row / L
    d = M * N - M - N
    return {
        "L": L, "M": M, "N": N,
        "mean": float(avg.mean()),
        "total": float(total),
        "col": float((M * N - M) / d * cav - N / d * (total - rav)),
        "row": float((M * N - N) / d * rav - M / d * (total - cav)),
        "pixel": float(M * N / d * (total - cav - rav)),
        "temporal_pixel": float(t_pixel), "temporal_col_mean": float(t_col),
        "temporal_row_mean": float(t_row),
    }


def main(argv):
    path = os.path.abspath(argv[1])
    p = ParseEmvaDescriptorFile(path, loglevel=logging.WARNING)
    spatial = p.images["spatial"]
    if len(spatial) != 1:
        raise SystemExit("expected one spatial exposure, found %d" % len(spatial))
    (texp, levels), = spatial.items()
    dark = levels[0.0]
    bright = [v for k, v in levels.items() if k != 0.0]
    if len(bright) != 1:
        raise SystemExit("expected one bright spatial series")
    print(json.dumps({"bright": series(bright[0]), "dark": series(dark)}))


if __name__ == "__main__":
    main(sys.argv)
