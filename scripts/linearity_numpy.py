#!/usr/bin/env python3
"""The steps of `dncal linearity` (host-sim/src/analyses/linearity/) in numpy and astropy, as a
user would write them: the baseline `dncal bench` times the command against.

    python3 scripts/linearity_numpy.py SET.fits [ORDER]

Prints one JSON line: the largest RMS of the three corrections and the seconds taken.
Same rules as dncal: saturated levels left out per pixel, a pixel-wise polynomial of
ORDER (default 4) in the reference x = V / max V fitted by least squares on each
pixel's unsaturated levels, masks (low signal, no fit, a residual 10x the median; the medians
per cell of the 2 x 2 period), the
standard correction (a global cubic x(m / top) through the median good pixel), the
pixel-wise inversion by Newton's method, dark and gain at the level nearest half the
maximum reference, and the RMS per level. Vectorized over pixels (one least-squares
solve per count of unsaturated levels, Newton on whole arrays).
"""
import json
import sys
import time

import numpy as np
from astropy.io import fits


def main():
    path = sys.argv[1]
    order = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    # Masked and saturated pixels are NaN by design, as in dncal.
    np.seterr(invalid="ignore", divide="ignore")
    t0 = time.perf_counter()
    with fits.open(path) as h:
        mean = h[0].data.astype(np.float64)
        std = h["STD"].data.astype(np.float64)
        bits = int(h[0].header["BITDEPTH"])
        volt = np.asarray(h["REFERENCE"].data["VOLTAGE"], dtype=np.float64)
        mask_in = h["MASK"].data.astype(bool) if "MASK" in h else None
    nl, rows, cols = mean.shape
    m = mean.reshape(nl, -1)
    s = std.reshape(nl, -1)
    npx = m.shape[1]
    top = 2.0**bits - 1
    x = volt / volt.max()
    g = 1 + int(np.argmin(np.abs(x[1:] - 0.5)))

    # Saturation per pixel: the first level at the top code (within 4 sigma), or above
    # half the range where the noise collapses; the pixel's valid levels are those before.
    sat = (m >= top - 4.0 * np.maximum(s, 0.5))
    sat[1:] |= (m[1:] > 0.5 * top) & (s[1:] < 0.5 * s[:-1])
    sat |= ~(np.isfinite(m) & np.isfinite(s))
    valid = np.where(sat.any(axis=0), sat.argmax(axis=0), nl)

    # Pixel-wise fits, one solve per prefix length.
    coef = np.full((order + 1, npx), np.nan)
    resid = np.full(npx, np.nan)
    for n in np.unique(valid):
        if n <= order + 1 or n <= g:
            continue
        sel = valid == n
        a = np.vander(x[:n], order + 1, increasing=True)
        c, *_ = np.linalg.lstsq(a, m[:n, sel], rcond=None)
        coef[:, sel] = c
        resid[sel] = np.sqrt(np.mean((a @ c - m[:n, sel]) ** 2, axis=0))

    signal = m[g] - m[0]
    masked = np.zeros(npx, dtype=bool) if mask_in is None else mask_in.reshape(-1).copy()
    # Each pixel against the median of its cell of the 2 x 2 period (a colour filter's
    # channel): cell (row mod 2) * 2 + column mod 2.
    r_, c_ = np.indices((rows, cols))
    cell = ((r_ % 2) * 2 + c_ % 2).reshape(-1)
    per_cell = lambda v: np.array([np.nanmedian(v[cell == k]) if (cell == k).any() else np.nan for k in range(4)])[cell]
    masked |= ~np.isfinite(signal) | (signal < 0.5 * per_cell(signal))
    masked |= ~np.isfinite(resid)
    masked |= resid > 10.0 * np.maximum(per_cell(resid), 1e-12)
    good = ~masked

    # Standard correction: a global cubic x(m / top) through the median good pixel.
    levels_in = np.arange(nl)[:, None] < valid[None, :]
    med = np.array([np.median(m[l, good & levels_in[l]]) if (good & levels_in[l]).any() else np.nan for l in range(nl)])
    usable = np.array([np.isfinite(med[l]) and 2 * (good & levels_in[l]).sum() > good.sum() for l in range(nl)])
    glob = np.polynomial.polynomial.polyfit(med[usable] / top, x[usable], 3)
    f = np.polynomial.polynomial.polyval(m / top, glob)
    e = (x - x[0]) / (x[g] - x[0])
    std_corr = (f - f[0]) / (f[g] - f[0])

    # Pixel-wise inversion x^ = P^-1(m), Newton from the reference.
    c = coef[:, good]
    xh = np.repeat(x[:, None], c.shape[1], axis=1)
    dc = c[1:] * np.arange(1, order + 1)[:, None]
    target = m[:, good]
    for _ in range(30):
        p = np.polynomial.polynomial.polyval(xh, c, tensor=False)
        d = np.polynomial.polynomial.polyval(xh, dc, tensor=False)
        step = (p - target) / d
        xh -= step
        if np.nanmax(np.abs(step)) < 1e-15:
            break
    pw = (xh - xh[0]) / (xh[g] - xh[0])

    rms = {"raw": [], "standard": [], "pixelwise": []}
    for l in range(1, nl):
        on = good & levels_in[l]
        mean_l = m[l, on].mean()
        rms["raw"].append(np.sqrt(np.mean((m[l, on] / mean_l - 1) ** 2)))
        if l != g:
            rms["standard"].append(np.sqrt(np.nanmean((std_corr[l, on] - e[l]) ** 2)))
            rms["pixelwise"].append(np.sqrt(np.nanmean((pw[l, on[good]] - e[l]) ** 2)))
    print(json.dumps({k: float(np.nanmax(v)) for k, v in rms.items()} | {"masked": int(masked.sum()), "seconds": time.perf_counter() - t0}))


if __name__ == "__main__":
    main()
