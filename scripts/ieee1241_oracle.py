#!/usr/bin/env python3
"""Independent oracle for the ADC histogram (code-density) test of IEEE Std 1241, and an
independent SAR ADC simulator to feed it. Written from the standard's definitions; it
shares no code with dncal. numpy + astropy only (the `--engine adctoolbox` options also
need the MIT-licensed PyPI package `adctoolbox`, see below).

    python3 scripts/ieee1241_oracle.py analyse HIST.fits --input ramp|sine --out result.json
        [--engine native|adctoolbox]
    python3 scripts/ieee1241_oracle.py simulate-sar --bits 12 --adcs 4 --counts-per-code 400
        --input ramp|sine --seed S --out HIST.fits --truth truth.json
        [--ideal-adc A ...] [--mismatch SIGMA] [--plant-weight ADC:BIT:ERROR_LSB ...]
        [--overdrive LSB] [--engine native|adctoolbox]

Without numpy/astropy in the running python, the script runs itself again under
target/adctoolbox-venv/bin/python when that exists.

Histogram FITS (docs/formats.md section 1): primary image int64, data[adc, code], shape
(NADC, 2^BITDEPTH), keys BITDEPTH, NADC, ADCMAP='COLMOD', BUNIT='count'.

Conventions of `analyse` (per ADC row, codes and transitions numbered from 0):
  * Analysed codes: first_code = (first non-empty code) + 1 to last_code = (last
    non-empty code) - 1, inclusive. The two end bins hold the overdrive of the input and
    are excluded. Empty codes inside that range are missing codes.
  * Transition k is the lower edge of code k. With CH_{k-1} = counts of codes 0..k-1
    and S = all counts of the row, its estimate is
        ramp: T_k = CH_{k-1}                    (code widths proportional to counts)
        sine: T_k = -cos(pi * CH_{k-1} / S)     (IEEE 1241 sine histogram; offset and
                                                amplitude unknown, removed below)
    for k = first_code .. last_code + 1 (n + 1 transitions for n analysed codes).
  * Width of code k: W_k = T_{k+1} - T_k; Q = mean of W over the analysed codes
    = (T_{last_code+1} - T_{first_code}) / n. DNL_k = W_k / Q - 1 (LSB). Missing: -1.
  * INL is given at the transitions k = first_code .. last_code + 1, in LSB of Q:
        inl_endpoint[k] = (T_k - line through the first and last transition) / Q
                        (= cumulative DNL; 0 at both ends)
        inl_bestfit[k]  = (T_k - least-squares line of T over k) / Q
  * widest_codes / narrowest_codes: the 10 analysed codes of largest / smallest DNL as
    [code, dnl], ties in code order.

Model of `simulate-sar` (native engine): a binary-weighted SAR ADC per row. Bit j's
capacitor is 2^j unit capacitors, each 1 + SIGMA * N(0,1) (default SIGMA 0.05); exact
weights for --ideal-adc rows; --plant-weight ADC:BIT:ERR adds ERR unit capacitors (LSB)
to that bit's weight. The DAC level of code k is V(k) = sum_j bit_j(k) W_j. The SAR
(bit j = 1 when vin >= DAC level so far + W_j) outputs code k for vin in
[V(k), U(k)), U(k) = min over the 0 bits j of k of V(k's bits above j, then bit j set);
code 0 extends to -inf, the all-ones code to +inf. When V is monotonic, U(k) = V(k+1)
(transition level of code k = V(k)); otherwise the region can be empty: true width
max(0, U(k) - V(k)), missing when 0 (so W_10 = 1024 - 1.2 at 12 bits makes codes 1023
and 3071 missing and codes 1022 and 3070 0.8 LSB wide). Counts are Poisson, with the
mean of the input's density integrated exactly over each code's interval:
    ramp: uniform from OVERDRIVE LSB below the first transition to OVERDRIVE above the
          last; mean count = counts-per-code * width / Q (Q as above)
    sine: centre mid-way between the first and last transitions, amplitude half their
          distance + OVERDRIVE LSB; P = (asin(z_hi) - asin(z_lo)) / pi, total mean
          counts-per-code * 2^bits.
truth.json gives per ADC the weights (unit capacitors, LSB first), the true widths in
units of their mean Q over codes 1 .. 2^bits - 2 (null for the two end codes; the
analysed range of a well overdriven histogram), so truth dnl = width - 1, and the true
missing codes.

--engine adctoolbox (needs target/adctoolbox-venv; re-runs itself there when adctoolbox
is not importable): simulate-sar takes its weights from adctoolbox.sar_ideal_weights +
sar_apply_cap_mismatch (per-bit Gaussian, sigma / sqrt(unit caps)) and its codes from
adctoolbox.sar_convert on evenly spaced ramp samples or evenly spaced sine phases (no
Poisson); truth widths from those weights as above. analyse feeds the row, expanded to
samples, to compute_inl_from_ramp (code_min/code_max = end bins, endpoints and fit) or
compute_inl_from_sine (clip_percent=0). Its sine DNL is labelled one code low by
adctoolbox; it is put here at the right codes. Its sine DNL is scaled by n_total/n (n_total
= n + 2 codes) and mean-removed, its INL is cumsum(DNL) only: inl_endpoint = [0] + that,
inl_bestfit = null.
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENV_PY = ROOT / "target" / "adctoolbox-venv" / "bin" / "python"


def rerun_in_venv(missing):
    """Run this script again under target/adctoolbox-venv when this python lacks a module."""
    if VENV_PY.exists() and Path(sys.prefix).resolve() != VENV_PY.parent.parent.resolve():
        os.execv(str(VENV_PY), [str(VENV_PY), __file__] + sys.argv[1:])
    sys.exit(f"{missing} is not importable (pip install numpy astropy; for --engine "
             f"adctoolbox: python3 -m venv {VENV_PY.parent.parent}; pip install adctoolbox "
             "numpy astropy)")


try:
    import numpy as np
    from astropy.io import fits
except ImportError as e:
    rerun_in_venv(e.name)


# ---------------------------------------------------------------- analysis (IEEE 1241)

def analyse_row(counts, kind):
    counts = np.asarray(counts, dtype=np.int64)
    nonempty = np.flatnonzero(counts)
    if nonempty.size == 0:
        return {"error": "empty row"}
    first, last = int(nonempty[0]) + 1, int(nonempty[-1]) - 1
    if last < first:
        return {"error": "fewer than three non-empty codes"}
    ch = np.cumsum(counts)                     # ch[i] = counts of codes 0..i
    ch_before = ch[first - 1:last + 1].astype(np.float64)   # CH_{k-1}, k = first..last+1
    if kind == "ramp":
        t = ch_before
    else:
        t = -np.cos(np.pi * ch_before / float(ch[-1]))
    k = np.arange(first, last + 2)
    width = np.diff(t)
    q = (t[-1] - t[0]) / width.size
    if not q > 0:
        return {"error": "no counts in the analysed range", "first_code": first, "last_code": last}
    dnl = width / q - 1.0
    inl_end = (t - (t[0] + (k - first) * q)) / q
    kc = k - k.mean()
    slope, icpt = np.polyfit(kc, t, 1)
    inl_fit = (t - (icpt + slope * kc)) / q
    return summarise(first, last, counts, dnl, inl_end, inl_fit)


def summarise(first, last, counts, dnl, inl_end, inl_fit):
    codes = np.arange(first, last + 1)
    wide = np.argsort(-dnl, kind="stable")[:10]
    narrow = np.argsort(dnl, kind="stable")[:10]
    return {
        "first_code": first,
        "last_code": last,
        "total_count": int(np.sum(counts)),
        "transitions": "inl_* index i is transition first_code + i (lower edge of that code), "
                       "first_code .. last_code + 1",
        "dnl": [float(x) for x in dnl],
        "inl_endpoint": [float(x) for x in inl_end],
        "inl_bestfit": None if inl_fit is None else [float(x) for x in inl_fit],
        "max_abs_dnl": float(np.max(np.abs(dnl))),
        "max_abs_inl_endpoint": float(np.max(np.abs(inl_end))),
        "max_abs_inl_bestfit": None if inl_fit is None else float(np.max(np.abs(inl_fit))),
        "missing_codes": [int(c) for c in codes[counts[first:last + 1] == 0]],
        "widest_codes": [[int(codes[i]), float(dnl[i])] for i in wide],
        "narrowest_codes": [[int(codes[i]), float(dnl[i])] for i in narrow],
    }


def analyse_row_adctoolbox(counts, kind):
    import adctoolbox.aout as aout
    counts = np.asarray(counts, dtype=np.int64)
    nonempty = np.flatnonzero(counts)
    if nonempty.size < 3:
        return {"error": "fewer than three non-empty codes"}
    lo, hi = int(nonempty[0]), int(nonempty[-1])
    if counts.sum() > 300_000_000:
        return {"error": "too many counts to expand into samples for adctoolbox"}
    samples = np.repeat(np.arange(counts.size), counts)
    first, last = lo + 1, hi - 1
    if kind == "ramp":
        r_end = aout.compute_inl_from_ramp(samples, code_min=lo, code_max=hi, endpoint="endpoints")
        r_fit = aout.compute_inl_from_ramp(samples, code_min=lo, code_max=hi, endpoint="fit")
        assert r_end["code"][0] == first and r_end["code"][-1] == last
        return summarise(first, last, counts, r_end["dnl"], r_end["inl"], r_fit["inl"])
    inl, dnl, code = aout.compute_inl_from_sine(samples, clip_percent=0.0)
    # adctoolbox labels the width of code lo + 1 + i as code lo + i; put it at its code.
    assert code[0] == lo and dnl.size == last - first + 1
    return summarise(first, last, counts, dnl, np.concatenate(([0.0], inl)), None)


def cmd_analyse(a):
    with fits.open(a.hist) as h:
        hdr, data = h[0].header, np.asarray(h[0].data)
    bits, nadc = int(hdr["BITDEPTH"]), int(hdr["NADC"])
    if data.shape != (nadc, 2**bits):
        sys.exit(f"shape {data.shape} is not (NADC, 2^BITDEPTH) = ({nadc}, {2**bits})")
    if np.any(data < 0):
        sys.exit("negative counts")
    row_fn = analyse_row_adctoolbox if a.engine == "adctoolbox" else analyse_row
    adcs = []
    for adc in range(nadc):
        r = row_fn(data[adc], a.input)
        adcs.append({"adc": adc, **r})
    out = {"file": str(a.hist), "input": a.input, "engine": a.engine, "bitdepth": bits,
           "nadc": nadc, "adcs": adcs}
    Path(a.out).write_text(json.dumps(out, indent=1) + "\n")


# ---------------------------------------------------------------- SAR ADC simulator

def sar_regions(w):
    """Lower and upper input edges (unit caps) of every code of a SAR ADC whose bit
    weights are w[0] (LSB) .. w[N-1] (MSB). Empty regions have upper <= lower."""
    n = w.size
    k = np.arange(2**n, dtype=np.int64)
    bits = (k[:, None] >> np.arange(n)) & 1
    v = bits @ w
    upper = np.full(k.size, np.inf)
    for j in range(n):
        zero = bits[:, j] == 0
        nxt = ((k[zero] >> (j + 1)) << (j + 1)) | (1 << j)
        upper[zero] = np.minimum(upper[zero], v[nxt])
    lower = v.copy()
    lower[0] = -np.inf
    return lower, upper


def parse_plants(plants, adcs, bits):
    out = []
    for p in plants:
        try:
            adc, bit, err = p.split(":")
            adc, bit, err = int(adc), int(bit), float(err)
        except ValueError:
            sys.exit(f"--plant-weight {p!r}: want ADC:BIT:ERROR_LSB")
        if not (0 <= adc < adcs and 0 <= bit < bits):
            sys.exit(f"--plant-weight {p!r}: ADC or BIT out of range")
        out.append((adc, bit, err))
    return out


def weights_native(a, rng, plants):
    ws = []
    for adc in range(a.adcs):
        w = np.array([rng.normal(1.0, a.mismatch, 2**j).sum() for j in range(a.bits)])
        if adc in a.ideal_adc:
            w = 2.0 ** np.arange(a.bits)
        ws.append(w)
    for adc, bit, err in plants:
        ws[adc][bit] += err
    return ws


def weights_adctoolbox(a, rng, plants):
    import adctoolbox as at
    ideal = at.sar_ideal_weights(a.bits)                 # MSB first, / 2^bits
    ws = []
    for adc in range(a.adcs):
        w = at.sar_apply_cap_mismatch(ideal, a.mismatch, rng)
        if adc in a.ideal_adc:
            w = ideal.copy()
        ws.append(w[::-1] * 2**a.bits)                   # LSB first, unit caps
    for adc, bit, err in plants:
        ws[adc][bit] += err
    return ws


def input_range(lower, upper, od):
    lo_t, hi_t = upper[0], lower[-1]                     # first and last transitions
    return lo_t, hi_t, lo_t - od, hi_t + od


def counts_native(a, rng, lower, upper, q):
    lo_t, hi_t, lo, hi = input_range(lower, upper, a.overdrive)
    if a.input == "ramp":
        seg = np.clip(np.minimum(upper, hi) - np.maximum(lower, lo), 0.0, None)
        mean = a.counts_per_code * seg / q
    else:
        c, amp = (lo_t + hi_t) / 2, (hi_t - lo_t) / 2 + a.overdrive
        z_lo = np.arcsin(np.clip((lower - c) / amp, -1, 1))
        z_hi = np.arcsin(np.clip((upper - c) / amp, -1, 1))
        mean = a.counts_per_code * 2**a.bits * np.clip(z_hi - z_lo, 0, None) / np.pi
    return rng.poisson(mean)


def counts_adctoolbox(a, rng, lower, upper, w):
    import adctoolbox as at
    fs = 2.0**a.bits
    w_msb = w[::-1] / fs
    lo_t, hi_t, lo, hi = input_range(lower, upper, a.overdrive)
    n = int(round(a.counts_per_code * 2**a.bits))
    u, hist = rng.uniform(), np.zeros(2**a.bits, dtype=np.int64)
    place = 2 ** np.arange(a.bits - 1, -1, -1)
    for s in range(0, n, 1 << 21):
        i = np.arange(s, min(n, s + (1 << 21))) + u
        if a.input == "ramp":
            vin = lo + (hi - lo) * i / n
        else:
            c, amp = (lo_t + hi_t) / 2, (hi_t - lo_t) / 2 + a.overdrive
            vin = c + amp * np.sin(2 * np.pi * i / n)
        code = at.sar_convert(vin / fs, w_msb).astype(np.int64) @ place
        hist += np.bincount(code, minlength=2**a.bits)
    return hist


def cmd_simulate(a):
    if a.engine == "adctoolbox":
        ensure_adctoolbox()
    plants = parse_plants(a.plant_weight, a.adcs, a.bits)
    rng = np.random.default_rng(a.seed)
    ws = (weights_adctoolbox if a.engine == "adctoolbox" else weights_native)(a, rng, plants)
    hist = np.zeros((a.adcs, 2**a.bits), dtype=np.int64)
    truth = []
    for adc, w in enumerate(ws):
        lower, upper = sar_regions(w)
        width = np.clip(upper - lower, 0.0, None)[1:-1]   # codes 1 .. 2^bits - 2
        q = width.mean()
        if a.engine == "adctoolbox":
            hist[adc] = counts_adctoolbox(a, rng, lower, upper, w)
        else:
            hist[adc] = counts_native(a, rng, lower, upper, q)
        rel = width / q
        truth.append({
            "adc": adc,
            "ideal": adc in a.ideal_adc,
            "weights_unit_caps": [float(x) for x in w],
            "q_unit_caps": float(q),
            "widths": [None] + [float(x) for x in rel] + [None],
            "missing_codes": [int(c) + 1 for c in np.flatnonzero(width <= 0)],
            "max_abs_dnl": float(np.max(np.abs(rel - 1))),
        })
    hdu = fits.PrimaryHDU(hist)
    hdu.header["BITDEPTH"] = (a.bits, "bits per ADC code")
    hdu.header["NADC"] = (a.adcs, "number of ADCs")
    hdu.header["ADCMAP"] = ("COLMOD", "column c read by ADC c mod NADC")
    hdu.header["BUNIT"] = "count"
    hdu.header["HISTORY"] = "ieee1241_oracle.py " + " ".join(sys.argv[1:])
    hdu.writeto(a.out, overwrite=True, checksum=True)
    Path(a.truth).write_text(json.dumps({
        "bits": a.bits, "nadc": a.adcs, "input": a.input, "engine": a.engine, "seed": a.seed,
        "mismatch": a.mismatch, "overdrive_lsb": a.overdrive,
        "counts_per_code": a.counts_per_code,
        "plants": [{"adc": p[0], "bit": p[1], "error_lsb": p[2]} for p in plants],
        "widths_note": "widths[k] = true width of code k / mean width of codes 1..2^bits-2; "
                       "null for codes 0 and 2^bits-1; truth dnl = widths - 1",
        "adcs": truth}, indent=1) + "\n")


def ensure_adctoolbox():
    try:
        import adctoolbox  # noqa: F401
    except ImportError:
        rerun_in_venv("adctoolbox")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    an = sub.add_parser("analyse")
    an.add_argument("hist")
    an.add_argument("--input", choices=["ramp", "sine"], required=True)
    an.add_argument("--out", required=True)
    an.add_argument("--engine", choices=["native", "adctoolbox"], default="native")
    si = sub.add_parser("simulate-sar")
    si.add_argument("--bits", type=int, default=12)
    si.add_argument("--adcs", type=int, default=4)
    si.add_argument("--counts-per-code", type=float, default=400)
    si.add_argument("--input", choices=["ramp", "sine"], required=True)
    si.add_argument("--seed", type=int, default=0)
    si.add_argument("--out", required=True)
    si.add_argument("--truth", required=True)
    si.add_argument("--ideal-adc", type=int, action="append", default=[])
    si.add_argument("--mismatch", type=float, default=0.05)
    si.add_argument("--plant-weight", action="append", default=[])
    si.add_argument("--overdrive", type=float, default=3.0, help="LSB beyond each end")
    si.add_argument("--engine", choices=["native", "adctoolbox"], default="native")
    a = p.parse_args()
    if a.cmd == "simulate-sar" and not (1 <= a.bits <= 16 and a.adcs >= 1):
        sys.exit("--bits 1..16, --adcs >= 1")
    t0 = time.perf_counter()
    if a.cmd == "analyse":
        if a.engine == "adctoolbox":
            ensure_adctoolbox()
        cmd_analyse(a)
    else:
        cmd_simulate(a)
    print(f"{a.cmd}: {time.perf_counter() - t0:.2f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
