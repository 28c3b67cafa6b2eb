#!/usr/bin/env python3
"""Write the astropy-made FITS fixtures that dncal's readers are tested against.

The files go to host-sim/tests/fixtures/ and are committed; host-sim/tests/fits_astropy.rs
reads them and checks every value against the formulas below (written out again there,
independently). Rerun after changing a formula:

    "$(scripts/astropy-venv.sh | tail -n 1)" scripts/make_fits_fixtures.py

Layouts are those of docs/formats.md. a = ADC (row), k = code (column), l = illumination
level, r = frame row, c = frame column; all indices start at 0.

histograms_int32.fits   BITDEPTH 4 (16 codes), NADC 4, int32 (BITPIX 32, no BZERO)
    count(a, k) = 1000 (a + 1) + k^2 + (a k) mod 7
histograms_uint16.fits  BITDEPTH 4, NADC 4, uint16 (BITPIX 16, BZERO 32768)
    count(a, k) = 40000 + 100 a + k                 (all above int16's range)
histograms_uint64.fits  BITDEPTH 4, NADC 4, uint64 (BITPIX 64, BZERO 2^63)
    count(a, k) = 2^63 + 1000 a + k                 (all above int64's range)
linearity.fits          5 columns x 3 rows x 4 levels, BITDEPTH 12, NADC 4, NFRAMES 64
    primary  mean(l, r, c) = 100 + 1000 l + 10 r + c + 0.25          float64, DN
    MASK     mask(r, c)    = 1 if (5 r + c) mod 7 == 0 else 0        uint8
    REFERENCE VOLTAGE(l)   = 0.25 l                                   float64, V
    STD      std(l, r, c)  = 0.5 + 0.125 l + 0.0625 r + 0.03125 c    float64, DN
    (extensions in this order on purpose: readers find them by name, not position;
    every value is a binary fraction, so it is exact in float64 and compares with ==)
lut_uint32.fits         BITDEPTH 4, NADC 4, FRACBITS 11, uint32 (BITPIX 32, BZERO 2^31)
    entry(a, k) = 1024 (2 k + 1) + a, except entry(3, 15) = 2^32 - 16
    (the exception is no valid dncal LUT; it checks the unsigned range above 2^31)
"""

from pathlib import Path

import numpy as np
from astropy.io import fits

OUT = Path(__file__).resolve().parent.parent / "host-sim" / "tests" / "fixtures"
N_ADC, BITS = 4, 4
CODES = 2**BITS


def adc_keys(header, bit_depth=BITS):
    header["BITDEPTH"] = (bit_depth, "bits per ADC code")
    header["NADC"] = (N_ADC, "ADCs; column c is read by ADC c mod NADC")
    header["ADCMAP"] = ("COLMOD", "ADC of column c is c mod NADC")


def write(hdus, name):
    fits.HDUList(hdus).writeto(OUT / name, overwrite=True, output_verify="exception")


def histograms():
    a, k = np.meshgrid(np.arange(N_ADC), np.arange(CODES), indexing="ij")
    counts = {
        "int32": (1000 * (a + 1) + k * k + (a * k) % 7).astype(np.int32),
        "uint16": (40000 + 100 * a + k).astype(np.uint16),
        # Python integers first: 2^63 does not fit numpy's default int64.
        "uint64": np.array(
            [[2**63 + 1000 * int(ai) + int(ki) for ki in range(CODES)] for ai in range(N_ADC)],
            dtype=np.uint64,
        ),
    }
    for dtype, data in counts.items():
        hdu = fits.PrimaryHDU(data)
        adc_keys(hdu.header)
        write([hdu], f"histograms_{dtype}.fits")


def linearity():
    levels, rows, cols = 4, 3, 5
    l, r, c = np.meshgrid(np.arange(levels), np.arange(rows), np.arange(cols), indexing="ij")
    mean = 100.0 + 1000.0 * l + 10.0 * r + c + 0.25
    std = 0.5 + 0.125 * l + 0.0625 * r + 0.03125 * c
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    mask = ((5 * rr + cc) % 7 == 0).astype(np.uint8)
    voltage = 0.25 * np.arange(levels, dtype=np.float64)

    primary = fits.PrimaryHDU(mean.astype(np.float64))
    adc_keys(primary.header, bit_depth=12)
    primary.header["NFRAMES"] = (64, "frames averaged per illumination level")
    primary.header["BUNIT"] = "DN"
    reference = fits.BinTableHDU.from_columns(
        [fits.Column(name="VOLTAGE", format="D", unit="V", array=voltage)], name="REFERENCE"
    )
    write(
        [
            primary,
            fits.ImageHDU(mask, name="MASK"),
            reference,
            fits.ImageHDU(std.astype(np.float64), name="STD"),
        ],
        "linearity.fits",
    )


def lut():
    a, k = np.meshgrid(np.arange(N_ADC), np.arange(CODES), indexing="ij")
    entries = (1024 * (2 * k + 1) + a).astype(np.uint32)
    entries[3, 15] = 2**32 - 16
    hdu = fits.PrimaryHDU(entries)
    adc_keys(hdu.header)
    hdu.header["FRACBITS"] = (11, "entries in units of 2^-FRACBITS DN")
    write([hdu], "lut_uint32.fits")


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    histograms()
    linearity()
    lut()
    for path in sorted(OUT.glob("*.fits")):
        with fits.open(path) as hdul:
            print(path.name, [(h.name, h.data.dtype.name, h.data.shape) for h in hdul])
