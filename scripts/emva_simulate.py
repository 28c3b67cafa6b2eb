"""Write an EMVA 1288 data set made by the reference's OWN camera simulator.

Independent oracle for dncal's EMVA 1288 code: the frames come from
emva1288.camera.Camera driven by emva1288.camera.DatasetGenerator and
PointsGenerator (PyPI `emva1288` 1.0.2), never from dncal's simulator. Run it
with the venv's python:

    VENV_PY=$(scripts/emva-venv.sh | tail -n 1)
    "$VENV_PY" scripts/emva_simulate.py --out /tmp/emva12 --bits 12 --seed 7

Writes DIR/EMVA1288descriptor.txt, DIR/images/image<N>.png and DIR/truth.json,
and prints the descriptor's path as the last line of stdout (everything else
goes to stderr).

What differs from DatasetGenerator as shipped, and why:
  * Frames over 8 bits are saved as 16-bit grayscale PNG (Pillow 'I;16' from a
    uint16 array) instead of the generator's 32-bit 'I' PNG; 8-bit frames as
    8-bit grayscale ('L'). Every frame is read back and must round-trip exactly.
  * The quantum efficiency is one flat value at one wavelength (an
    emva1288.camera.routines.Qe with a (height, width, 1) array), so the true
    QE is known exactly; the camera's default is a Gaussian over 100 wavelengths.
  * A planted --K is exact: the camera snaps K to a 255-step grid
    linspace(K_min, K_max), so K_min = K_max = K, K_steps = 1 are passed.
    Same for --blackoffset. Without --K the default below is used (or, with
    --auto-gain, the generator's own gain search); without --blackoffset the
    generator's own search (at most 0.5% of dark pixels at 0 DN) is used.
  * Hot pixels: emva1288.camera.bad_images.bad_pixel (DSNU at a fraction of
    the full well), with numpy's global generator seeded and repeated draws
    topped up so exactly --hot distinct pixels are hot; positions are read
    back from the DSNU image. Dead pixels: PRNU factor 0 (the reference has no
    helper for them), at distinct pixels that are not hot.
  * The DSNU image (e-, Gaussian) and PRNU image (1 + Gaussian) are drawn
    from numpy Generators seeded from --seed; the camera's own noise uses
    Camera(seed=--seed).

Hidden effects the reference's camera lacks (all off by default):
  The camera is EffectsCamera, a subclass of emva1288.camera.camera.Camera
  whose grab() runs the reference's own Camera.grab unchanged except for its
  one np.rint call: for the duration of the call, the name `np` inside
  emva1288.camera.camera is a stand-in that forwards everything to numpy but
  hands rint's argument, the analog image K * electrons + U(-0.5, 0.5) +
  blackoffset, to our quantizer, which writes the codes in place; the
  reference then clips to [0, 2^bits-1] and casts as before. So photons, dark
  signal and current, PRNU/DSNU, full-well and ADC clipping and every random
  draw (the uniform dither included) are the reference's own, and with no
  effect enabled the quantizer is np.rint and the frames are byte-identical
  to the plain Camera's for the same seed. The generator's own offset/gain
  searches and PointsGenerator's dark grab also see the effects.
  * --adcs N: column c is read by ADC c mod N (only matters with DNL).
  * --cfa R,R,...: a colour filter, p x p relative responses (row-major, tiled
    from pixel (0, 0)) multiplying the PRNU image: the reference's own per-pixel
    QE factor, so each channel's photons and shot noise follow its response.
    truth.json's prnu_realized_with_dead then holds the pattern too.
  * --dnl-rms R, --dnl-adc A|all: differential nonlinearity of ADC A (or of
    every ADC, each its own draw). Code widths w_k = 1 + R g_k, g_k standard
    normal from numpy.random.default_rng([seed, 4, adc]), clipped to >= 0.2,
    then scaled so the mean over the interior codes 1..2^bits-2 is exactly 1
    (w_0 and w_{2^bits-1} are open-ended and recorded as 1). The transition
    from code k-1 to k sits at t_k = 0.5 + sum_{j=1}^{k-1} w_j (ideal: k - 0.5,
    np.rint's edges), and the code is np.searchsorted(t, analog, 'right'),
    i.e. the number of edges <= analog (np.rint rounds exact halves to even,
    this rounds them up; with a continuous analog value that never matters).
  * --compress A: x = analog - blackoffset becomes x * (1 - A (x/x_max)^3),
    x_max = 2^bits - 1, before quantization (A = 0.05: 5% low at x_max). Past
    the curve's peak, x_peak = x_max (4A)^(-1/3) (1.71 x_max at A = 0.05),
    it is held at its peak value so that a brighter pixel never comes out
    darker (only reached when K * u_esat is well above the ADC range).
    Note: the reference's PointsGenerator puts the top level at an analog
    mean of about 2^bits - 1, which compression pulls below full scale, so a
    compressed exposure series may never fully saturate.
  truth.json records adcs, dnl_adc, dnl_rms {planted, realized per ADC},
  dnl_widths {adc: [w_0 .. w_{2^bits-1}]}, compress and compress_formula; its
  expected_reference block ignores the effects.

Preset: a quantization-limited 8-bit camera (existing options only). Small
gain, full well above the ADC range (255 DN = 127500 e- < 150000 e-), and a
planted offset that puts the dark level on a code (analog dark mean 4.98 +
0.002 * 10 e- = 5.00 DN), so the generator's 50 photon levels land on whole
codes 5 DN apart (15, 20, 25, ... DN: the dark mean plus 250 (k+1)/50) and
the low levels' temporal noise is mostly the reference's uniform dither:
narrow code peaks 5 codes apart, lumpy code occupancy:

    "$VENV_PY" scripts/emva_simulate.py --out /tmp/emva8q --bits 8 \
        --K 0.002 --u-esat 150000 --sigma2-dark 0.5 --blackoffset 4.98 \
        --exposure-fixed 1000000

Seed 1288, temporal noise sqrt(var(A - B) / 2) read back from the frames:
dark 0.06 DN (99.96% of the pixels on code 5), then 0.36, 0.40, 0.43, 0.45,
0.47, 0.49, 0.496 DN at 15..45 DN, 0.50 at 50 DN and rising; each of those
levels has 3 codes with >= 1% of its pixels, and below 45 DN the two codes
between neighbouring peaks are empty. The dither's share of the variance
here is E[|d| (1 - |d|)] for an analog value d off the nearest code, not the
1/12 DN^2 the reference subtracts, so the reference's K comes out about
0.0035 (planted 0.002) and its s2_ydark is clamped at 0.24 DN^2. With
--K 0.02 --u-esat 15000 and no planted offset the first levels are already
0.54 to 0.63 DN.
"""

import argparse
import json
import os
import shutil
import sys
import time

import numpy as np
from PIL import Image

import emva1288
from emva1288.camera import routines as cam_routines
from emva1288.camera import camera as camera_module
from emva1288.camera import dataset_generator as dataset_generator_module
from emva1288.camera.bad_images import bad_pixel
from emva1288.camera.camera import Camera
from emva1288.camera.dataset_generator import DatasetGenerator

# Default gain per bit depth: high enough that the ADC saturates before the
# default full well (15000 e-), so the spatial point the generator places in
# the middle of the series is not clipped, and (8, 10 bits) the value the
# generator's own gain search picks with the default dark noise.
DEFAULT_K = {8: 0.1, 10: 0.1, 12: 0.3, 14: 1.2, 16: 4.8}

DESCRIPTOR = "EMVA1288descriptor.txt"


def log(*a):
    print(*a, file=sys.stderr)


def dnl_widths(bits, rms, seed, adc):
    """Code widths (LSB) of one ADC: w_k = 1 + rms * g_k, clipped >= 0.2 and
    scaled to a mean of exactly 1 over the interior codes 1..2^bits-2; the
    open-ended end codes 0 and 2^bits-1 are recorded as 1."""
    n = 2 ** bits
    g = np.random.default_rng([seed, 4, adc]).standard_normal(n)
    w = np.ones(n)
    interior = np.clip(1.0 + rms * g[1:n - 1], 0.2, None)
    w[1:n - 1] = interior / interior.mean()
    return w


def code_edges(widths):
    """Transition levels t_k, k = 1..2^bits-1: t_k = 0.5 + sum_{j=1}^{k-1} w_j
    (all widths 1: t_k = k - 0.5, the edges of np.rint)."""
    n = len(widths)
    return 0.5 + np.concatenate(([0.0], np.cumsum(widths[1:n - 1])))


class Quantizer:
    """Our rule for turning the camera's analog image (DN, float) into codes.

    Called in place on the array the reference would np.rint. With no effect
    it is exactly np.rint. compress: global cubic compression above the black
    offset; dnl: {adc: edges} for ADCs with differential nonlinearity, ADC a
    reading the columns a, a + adcs, a + 2 adcs, ...
    """

    def __init__(self, bits, adcs=1, dnl=None, compress=0.0):
        self.x_max = float(2 ** bits - 1)
        self.adcs = int(adcs)
        self.dnl = dict(dnl or {})
        self.compress = float(compress)
        if self.compress > 0:
            self.x_peak = self.x_max * (4.0 * self.compress) ** (-1.0 / 3.0)

    @property
    def active(self):
        return bool(self.dnl) or self.compress != 0.0

    def __call__(self, img, blackoffset):
        analog = img
        if self.compress != 0.0:
            x = np.minimum(img - blackoffset, self.x_peak)
            analog = blackoffset + x * (1.0 - self.compress * (x / self.x_max) ** 3)
        codes = np.rint(analog)
        for adc, edges in self.dnl.items():
            codes[:, adc::self.adcs] = np.searchsorted(
                edges, analog[:, adc::self.adcs], side="right")
        img[...] = codes


class _NumpyWithOurRint:
    """Stands in for numpy inside emva1288.camera.camera during one grab:
    everything is numpy's except rint(img, img), which hands the analog image
    to the quantizer (the reference calls rint once per grab, in place)."""

    def __init__(self, quantize):
        self._quantize = quantize
        self.calls = 0

    def __getattr__(self, name):
        return getattr(np, name)

    def rint(self, x, out=None):
        if out is not x or not isinstance(x, np.ndarray) or x.dtype.kind != "f":
            raise RuntimeError("emva1288 Camera.grab no longer calls "
                               "np.rint(img, img) on a float image")
        self.calls += 1
        self._quantize(x)
        return x


class EffectsCamera(Camera):
    """The reference's Camera, quantized by a Quantizer (see the docstring)."""

    def __init__(self, quantizer=None, **kwargs):
        super().__init__(**kwargs)
        self.quantizer = quantizer

    def grab(self, radiance, temperature=None, f_number=None):
        if self.quantizer is None:
            return super().grab(radiance, temperature=temperature,
                                f_number=f_number)
        hook = _NumpyWithOurRint(lambda img: self.quantizer(img, self.blackoffset))
        if camera_module.np is not np:
            raise RuntimeError("emva1288.camera.camera.np is already replaced")
        camera_module.np = hook
        try:
            img = super().grab(radiance, temperature=temperature,
                               f_number=f_number)
        finally:
            camera_module.np = np
        if hook.calls != 1:
            raise RuntimeError("Camera.grab called np.rint %d times, expected 1"
                               % hook.calls)
        return img


class PngDatasetGenerator(DatasetGenerator):
    """DatasetGenerator that saves 8-bit or 16-bit grayscale PNG frames."""

    checked_header = False

    def save_image(self, img, name):
        path = os.path.join(self.outdir, "images", name)
        bits = self.cam.bit_depth
        if bits <= 8:
            arr = np.ascontiguousarray(img, dtype=np.uint8)
            mode, png_depth = "L", 8
        else:
            if img.max() > 65535:  # pragma: no cover
                raise ValueError("frame value over 16 bits")
            arr = np.ascontiguousarray(img, dtype=np.uint16)
            mode, png_depth = "I;16", 16
        if int(img.max()) > self.cam.img_max or int(img.min()) < 0:
            raise ValueError("frame outside 0..%d" % self.cam.img_max)
        im = Image.fromarray(arr)
        if im.mode != mode:
            raise ValueError("Pillow made mode %s, wanted %s" % (im.mode, mode))
        im.save(path, format="PNG", compress_level=1)  # zlib level 6 is 4x slower
        # read back: values and format must round-trip exactly
        with Image.open(path) as back:
            if back.mode != mode:
                raise ValueError("%s reads back as mode %s" % (path, back.mode))
            got = np.asarray(back)
        if got.shape != img.shape or not np.array_equal(got.astype(np.int64),
                                                        img.astype(np.int64)):
            raise ValueError("%s does not round-trip" % path)
        if not PngDatasetGenerator.checked_header:
            with open(path, "rb") as f:
                head = f.read(29)
            # IHDR: bit depth at byte 24, colour type (0 = grayscale) at 25
            if head[12:16] != b"IHDR" or head[24] != png_depth or head[25] != 0:
                raise ValueError("%s is not %d-bit grayscale PNG" % (path, png_depth))
            PngDatasetGenerator.checked_header = True


def parse_args(argv):
    p = argparse.ArgumentParser(
        description="EMVA 1288 data set from the reference (emva1288 1.0.2) "
                    "camera simulator, with truth.json.",
        epilog="Quantization-limited 8-bit preset (noise < 0.5 DN at the dark "
               "and the first 7 levels, narrow code peaks 5 DN apart): --bits 8 "
               "--K 0.002 --u-esat 150000 --sigma2-dark 0.5 --blackoffset 4.98 "
               "--exposure-fixed 1000000. See the module docstring.")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (DIR/images must not exist, see --force)")
    p.add_argument("--force", action="store_true",
                   help="remove DIR/images, DIR/%s and DIR/truth.json first" % DESCRIPTOR)
    p.add_argument("--seed", type=int, default=1288, help="random seed (default 1288)")
    p.add_argument("--bits", type=int, default=12, choices=[8, 10, 12, 14, 16],
                   help="ADC bits (default 12)")
    p.add_argument("--width", type=int, default=160, help="columns (default 160)")
    p.add_argument("--height", type=int, default=120, help="rows (default 120)")
    p.add_argument("--steps", type=int, default=50,
                   help="temporal points (bright+dark pairs), default 50")
    p.add_argument("--L", type=int, default=16,
                   help="frames of the spatial point, >= 3 (default 16)")
    p.add_argument("--version", default="4.0",
                   help="descriptor 'v' line (default 4.0, the generator's)")

    g = p.add_argument_group("sensor (planted truth)")
    g.add_argument("--K", type=float, default=None,
                   help="system gain DN/e-, exact (default per bits: %s)"
                        % ", ".join("%d: %g" % kv for kv in DEFAULT_K.items()))
    g.add_argument("--auto-gain", action="store_true",
                   help="let the generator's gain search choose K (ignores the default)")
    g.add_argument("--qe", type=float, default=0.5,
                   help="flat quantum efficiency, fraction (default 0.5)")
    g.add_argument("--wavelength", type=float, default=525.0,
                   help="the one wavelength, nm (default 525)")
    g.add_argument("--sigma2-dark", type=float, default=10.0,
                   help="sigma2_dark_0: dark read noise variance, e-^2 (default 10)")
    g.add_argument("--dark-signal", type=float, default=10.0,
                   help="dark_signal_0: dark offset in e- (default 10)")
    g.add_argument("--u-esat", type=float, default=15000.0,
                   help="full well, e- (default 15000)")
    g.add_argument("--dsnu-e", type=float, default=2.0,
                   help="rms of a Gaussian DSNU image, e- (default 2; 0 = none)")
    g.add_argument("--prnu", type=float, default=0.01,
                   help="relative rms of a Gaussian PRNU image (default 0.01; 0 = none)")
    g.add_argument("--dark-current-ref", type=float, default=30.0,
                   help="dark current at --temperature-ref, e-/s (default 30)")
    g.add_argument("--temperature", type=float, default=22.0,
                   help="sensor temperature, C (default 22)")
    g.add_argument("--temperature-ref", type=float, default=30.0,
                   help="reference temperature, C (default 30)")
    g.add_argument("--temperature-doubling", type=float, default=8.0,
                   help="dark current doubling temperature, C (default 8)")
    g.add_argument("--blackoffset", type=float, default=None,
                   help="offset in DN, exact (default: the generator's search)")
    g.add_argument("--hot", type=int, default=0, help="number of hot pixels (default 0)")
    g.add_argument("--hot-level", type=float, default=0.02,
                   help="hot pixel DSNU as a fraction of the full well "
                        "(bad_pixel's bad_value; default 0.02 = 300 e- of the "
                        "default full well; bad_pixel's own default 1.0 saturates "
                        "them, and then the reference's PRNU1288 is NaN)")
    g.add_argument("--cfa", default=None, metavar="R,R,...",
                   help="a colour filter's response pattern: p x p relative "
                        "responses, row-major (4 numbers: 2 x 2), multiplying "
                        "the PRNU image, tiled from pixel (0, 0) (default none)")
    g.add_argument("--dead", type=int, default=0,
                   help="number of dead pixels, PRNU factor 0 (default 0)")
    g.add_argument("--f-number", type=float, default=8.0, help="default 8")
    g.add_argument("--pixel-area", type=float, default=25.0, help="um^2, default 25")

    e = p.add_argument_group("exposure")
    m = e.add_mutually_exclusive_group()
    m.add_argument("--exposure-variation", action="store_true",
                   help="(default) one radiance, exposure time varied from "
                        "--exposure-min to --exposure-max: a dark-current series")
    m.add_argument("--exposure-fixed", type=float, default=None, metavar="NS",
                   help="photon variation at one exposure time, ns")
    e.add_argument("--exposure-min", type=float, default=500000.0,
                   help="ns (default 500000, the camera's)")
    e.add_argument("--exposure-max", type=float, default=500000000.0,
                   help="ns (default 500000000, the camera's)")

    h = p.add_argument_group("hidden effects (the reference's camera has none)")
    h.add_argument("--adcs", type=int, default=1, metavar="N",
                   help="column-interleaved ADCs, column c on ADC c mod N (default 1)")
    h.add_argument("--dnl-rms", type=float, default=0.0, metavar="R",
                   help="rms of the code widths (LSB) of the DNL ADC(s): "
                        "w_k = 1 + R g_k (default 0 = no DNL)")
    h.add_argument("--dnl-adc", default="0", metavar="A",
                   help="which ADC has DNL: 0..N-1 or 'all' (default 0)")
    h.add_argument("--compress", type=float, default=0.0, metavar="A",
                   help="compressive response: x = analog - offset becomes "
                        "x (1 - A (x/x_max)^3), x_max = 2^bits - 1 (default 0)")

    a = p.parse_args(argv)
    if a.adcs < 1 or a.adcs > a.width:
        p.error("--adcs must be in 1..width")
    if not a.dnl_rms >= 0:
        p.error("--dnl-rms must be >= 0")
    if a.dnl_adc == "all":
        a.dnl_adcs = list(range(a.adcs))
    else:
        try:
            a.dnl_adcs = [int(a.dnl_adc)]
        except ValueError:
            p.error("--dnl-adc must be an ADC number or 'all'")
        if not 0 <= a.dnl_adcs[0] < a.adcs:
            p.error("--dnl-adc must be in 0..%d (--adcs %d)" % (a.adcs - 1, a.adcs))
    if a.dnl_rms == 0:
        a.dnl_adcs = []
    if not 0 <= a.compress < 1:
        p.error("--compress must be in [0, 1)")
    if a.L < 3:
        p.error("--L must be >= 3 (a series of 2 frames is read as temporal)")
    if a.steps < 2:
        p.error("--steps must be >= 2")
    if a.width < 8 or a.height < 8:
        p.error("--width and --height must be >= 8")
    if not 0 < a.qe <= 1:
        p.error("--qe must be in (0, 1]")
    if a.hot and not a.hot_level > 0:
        p.error("--hot-level must be > 0")
    if a.hot < 0 or a.dead < 0 or a.hot + a.dead > a.width * a.height:
        p.error("bad --hot/--dead count")
    if a.K is not None and a.K <= 0:
        p.error("--K must be > 0")
    if a.K is not None and a.auto_gain:
        p.error("--K and --auto-gain exclude each other")
    return a


def main(argv):
    a = parse_args(argv)
    t0 = time.time()
    W, H = a.width, a.height
    out = os.path.abspath(a.out)
    os.makedirs(out, exist_ok=True)
    if a.force:
        shutil.rmtree(os.path.join(out, "images"), ignore_errors=True)
        for f in (DESCRIPTOR, "truth.json"):
            if os.path.exists(os.path.join(out, f)):
                os.remove(os.path.join(out, f))
    elif os.path.exists(os.path.join(out, "images")):
        sys.exit("emva_simulate: %s exists (use --force)" % os.path.join(out, "images"))

    # Flat QE at one wavelength: u_e = u_p * qe * prnu exactly.
    qe = cam_routines.Qe(qe=np.full((H, W, 1), a.qe),
                         wavelength=np.array([a.wavelength]),
                         width=W, height=H)

    # DSNU (e-) and PRNU (factor) images, seeded independently of the camera.
    dsnu = np.zeros((H, W))
    if a.dsnu_e > 0:
        dsnu += np.random.default_rng([a.seed, 1]).normal(0.0, a.dsnu_e, (H, W))
    dsnu_gauss = dsnu.copy()
    prnu = np.ones((H, W))
    if a.prnu > 0:
        prnu += np.random.default_rng([a.seed, 2]).normal(0.0, a.prnu, (H, W))
        np.clip(prnu, 0.0, None, out=prnu)
    prnu_gauss = prnu.copy()
    # A colour filter: the PRNU image times the tiled cell responses (the
    # reference's own per-pixel QE factor, so photon and shot noise follow it).
    cfa = None
    if a.cfa:
        cfa = [float(v) for v in a.cfa.split(",")]
        period = int(round(len(cfa) ** 0.5))
        if period * period != len(cfa) or period < 1 or min(cfa) <= 0:
            sys.exit("emva_simulate: --cfa needs p x p positive numbers")
        cells = np.array(cfa).reshape(period, period)
        prnu *= np.tile(cells, (H // period + 1, W // period + 1))[:H, :W]

    # Hot pixels with the reference's bad_pixel (global numpy RNG, draws with
    # replacement, so top up until the count of distinct hot pixels is --hot).
    hot = np.zeros((H, W), dtype=bool)
    if a.hot:
        shim = Camera(width=W, height=H, bit_depth=a.bits, u_esat=a.u_esat,
                      qe=qe, dsnu=dsnu, prnu=prnu)
        np.random.seed(a.seed % 2**32)
        while hot.sum() < a.hot:
            before = dsnu.copy()
            bad_pixel(shim, int(a.hot - hot.sum()), bad_value=a.hot_level)
            hot |= dsnu != before
        assert shim.DSNU is dsnu
    dead = np.zeros((H, W), dtype=bool)
    if a.dead:
        free = np.flatnonzero(~hot.ravel())
        pick = np.random.default_rng([a.seed, 3]).choice(free, a.dead, replace=False)
        dead.ravel()[pick] = True
        prnu[dead] = 0.0

    cam_kwargs = dict(
        bit_depth=a.bits, width=W, height=H, qe=qe,
        f_number=a.f_number, pixel_area=a.pixel_area,
        temperature=a.temperature, temperature_ref=a.temperature_ref,
        temperature_doubling=a.temperature_doubling,
        exposure_min=a.exposure_min, exposure_max=a.exposure_max,
        dark_current_ref=a.dark_current_ref, dark_signal_0=a.dark_signal,
        sigma2_dark_0=a.sigma2_dark, u_esat=a.u_esat,
        dsnu=dsnu, prnu=prnu, seed=a.seed)
    K_source = "planted (--K)"
    K = a.K
    if K is None and not a.auto_gain:
        K = DEFAULT_K[a.bits]
        K_source = "default for %d bits" % a.bits
    if a.auto_gain:
        K_source = "generator's gain search (temporal dark noise > 0.5 DN)"
    else:
        cam_kwargs.update(K=K, K_min=K, K_max=K, K_steps=1)
    if a.blackoffset is not None:
        cam_kwargs.update(blackoffset=a.blackoffset, blackoffset_min=a.blackoffset,
                          blackoffset_max=a.blackoffset, blackoffset_steps=1)
        bo_source = "planted (--blackoffset)"
    else:
        bo_source = "generator's search (<= 0.5% of dark pixels at 0 DN)"

    # Hidden effects: our quantizer inside the reference's own grab.
    widths = {adc: dnl_widths(a.bits, a.dnl_rms, a.seed, adc) for adc in a.dnl_adcs}
    quantizer = Quantizer(a.bits, adcs=a.adcs, compress=a.compress,
                          dnl={adc: code_edges(w) for adc, w in widths.items()})
    cam_kwargs["quantizer"] = quantizer

    # DatasetGenerator builds its camera as dataset_generator.Cam(**kwargs).
    if dataset_generator_module.Cam is not Camera:
        raise RuntimeError("emva1288.camera.dataset_generator.Cam is not Camera")
    dataset_generator_module.Cam = EffectsCamera
    try:
        gen = PngDatasetGenerator(steps=a.steps, L=a.L, version=a.version,
                                  image_format="png", outdir=out,
                                  exposure_fixed=a.exposure_fixed, **cam_kwargs)
    finally:
        dataset_generator_module.Cam = Camera
    cam = gen.cam
    descriptor = gen.descriptor_path
    t_gen = time.time() - t0

    # ---------------------------------------------------------------- truth
    K = float(cam.K)
    bo = float(cam.blackoffset)
    u_i = float(cam._u_i())  # e-/s at a.temperature (docstring says DN/s; it is e-)
    spatial_texp = float(list(gen.points["spatial"].keys())[0])
    spatial_rad = gen.points["spatial"][list(gen.points["spatial"].keys())[0]][0]
    cam.exposure = spatial_texp
    spatial_up = float(np.sum(cam.get_photons(spatial_rad), axis=2).mean())
    img_max = cam.img_max
    n_img = len(os.listdir(os.path.join(out, "images")))

    # Expected dark electrons per pixel at the spatial exposure, clipped as the
    # camera clips (full well in e-, ADC range in DN): what DSNU1288 sees.
    # Same for the bright spatial frames: what PRNU1288 sees (noise-free).
    dark_e = dsnu + a.dark_signal + u_i * spatial_texp * 1e-9
    bright_e = dark_e + spatial_up * a.qe * prnu

    def to_dn(e):
        return np.clip(np.clip(e, 0, a.u_esat) * K + bo, 0, img_max)

    dark_dn, bright_dn = to_dn(dark_e), to_dn(bright_e)
    s2_diff = np.var(bright_dn, ddof=1) - np.var(dark_dn, ddof=1)
    prnu_expected = None
    if s2_diff > 0:
        prnu_expected = float(100 * np.sqrt(s2_diff)
                              / (bright_dn.mean() - dark_dn.mean()))

    def sd(x):
        return float(np.std(x, ddof=1)) if x.size > 1 else 0.0

    # The simulator quantises as rint(K*e + U(-0.5, 0.5) + offset): that is
    # 1/6 DN^2 of quantisation variance, not the 1/12 the reference subtracts.
    s2q_sim = 1.0 / 6.0
    if a.exposure_fixed is None:
        t_dark = 0.0     # reference: intercept of s2_ydark against texp
    else:
        t_dark = float(round(a.exposure_fixed))
    s2_ydark = K * K * (a.sigma2_dark + u_i * t_dark * 1e-9) + s2q_sim
    s2_ydark_ref = max(s2_ydark, 0.24)  # the reference's clamp
    # light e- at which the pixel saturates: full well or ADC, whichever first
    t_sat = a.exposure_max if a.exposure_fixed is None else t_dark
    dark_sat = a.dark_signal + u_i * t_sat * 1e-9
    fw_light = a.u_esat - dark_sat
    adc_light = (img_max - bo) / K - dark_sat
    truth = {
        "generator": "emva1288 %s camera simulator (Camera/DatasetGenerator/"
                     "PointsGenerator), frames saved by scripts/emva_simulate.py"
                     % emva1288.__version__,
        "command_line": [os.path.basename(sys.executable)] + sys.argv,
        "seed": a.seed,
        "bits": a.bits, "width": W, "height": H,
        "steps": a.steps, "L": a.L, "version": a.version,
        "images": n_img,
        "image_format": "png %d-bit grayscale" % (8 if a.bits <= 8 else 16),
        "mode": "exposure_variation" if a.exposure_fixed is None else "exposure_fixed",
        "exposure_fixed_ns": t_dark if a.exposure_fixed is not None else None,
        "exposure_min_ns": a.exposure_min, "exposure_max_ns": a.exposure_max,
        "spatial_exposure_ns": spatial_texp,
        "spatial_photons": spatial_up,
        "spatial_light_e": spatial_up * a.qe,
        "K": K, "K_source": K_source,
        "QE": a.qe, "wavelength_nm": a.wavelength,
        "sigma2_dark_0_e2": a.sigma2_dark,
        "sigma_d_e": float(np.sqrt(a.sigma2_dark)),
        "dark_signal_0_e": a.dark_signal,
        "dark_current_e_per_s": u_i,
        "dark_current_ref_e_per_s": a.dark_current_ref,
        "temperature_C": a.temperature, "temperature_ref_C": a.temperature_ref,
        "temperature_doubling_C": a.temperature_doubling,
        "u_esat_e": a.u_esat,
        "blackoffset_DN": bo, "blackoffset_source": bo_source,
        "f_number": a.f_number, "pixel_area_um2": a.pixel_area,
        "dsnu_e": a.dsnu_e,
        "dsnu_e_realized": sd(dsnu_gauss),
        "dsnu_e_realized_with_hot": sd(dsnu),
        "prnu": a.prnu,
        "prnu_realized": sd(prnu_gauss),
        "prnu_realized_with_dead": sd(prnu),
        "cfa": cfa,
        "hot": {"count": int(hot.sum()), "level_e": a.hot_level * a.u_esat,
                "positions_row_col": np.argwhere(hot).tolist()},
        "dead": {"count": int(dead.sum()), "prnu_factor": 0.0,
                 "positions_row_col": np.argwhere(dead).tolist()},
        "saturation": {
            "limited_by": "full_well" if fw_light < adc_light else "adc",
            "light_e_at_full_well": fw_light,
            "light_e_at_adc_max": adc_light,
        },
        # What the reference should report given the simulator's quirks
        # (approximate where noted); compare these with emva_reference.py.
        "expected_reference": {
            "K": K,
            "QE_percent": 100.0 * a.qe,
            "sigma_y_dark_DN": float(np.sqrt(s2_ydark_ref)),
            "sigma_d_e": float(np.sqrt(s2_ydark_ref - 1.0 / 12.0) / K),
            "u_I_mean_e_per_s": u_i if a.exposure_fixed is None else None,
            "u_I_var_e_per_s": u_i if a.exposure_fixed is None else None,
            "DSNU1288_e_approx": sd(dark_dn) / K,
            "PRNU1288_percent_approx": prnu_expected,
        },
        "notes": [
            "positions are [row, col], 0-based",
            "quantisation in the simulator is rint(K*e + U(-0.5,0.5) + offset): about "
            "1/6 DN^2 of variance, the reference subtracts 1/12, so the reference's "
            "sigma_d is sqrt(sigma2_dark_0 + 1/(12 K^2)) (expected_reference.sigma_d_e), "
            "not sqrt(sigma2_dark_0) (sigma_d_e)",
            "the reference clamps s2_ydark at 0.24 DN^2 before sigma_y_dark",
            "the camera clips electrons to [0, u_esat] (dark signal included) and DN "
            "to [0, 2^bits-1]",
            "dark current is Poisson in electrons: mean and variance both grow by "
            "dark_current_e_per_s * texp",
            "DSNU1288 includes hot pixels; PRNU1288 includes dead pixels",
            "expected_reference.*_approx are the noise-free model of the spatial "
            "frames, clipped as the camera clips (PRNU1288 null when the bright "
            "spatial variance is below the dark one, as the reference then gives NaN)",
        ],
        "adcs": a.adcs,
        "dnl_adc": a.dnl_adcs,
        "dnl_rms": {
            "planted": a.dnl_rms if a.dnl_adcs else 0.0,
            "realized": {str(adc): float(np.sqrt(np.mean((w[1:-1] - 1.0) ** 2)))
                         for adc, w in widths.items()},
        },
        "dnl_widths": {str(adc): w.tolist() for adc, w in widths.items()},
        "dnl_rule": "column c is read by ADC c mod adcs; a DNL ADC's code is "
                    "searchsorted(t, analog, 'right') with t_k = 0.5 + "
                    "sum_{j=1}^{k-1} w_j, k = 1..2^bits-1 (w_0, w_max nominal 1); "
                    "other ADCs: rint(analog); then clip to [0, 2^bits-1]. "
                    "dnl_rms.realized: rms of w - 1 over codes 1..2^bits-2",
        "compress": a.compress,
        "compress_formula": "analog = blackoffset + x * (1 - compress * (x / x_max)^3), "
                            "x = min(analog_camera - blackoffset, x_peak), "
                            "x_max = 2^bits - 1 = %d, x_peak = x_max * "
                            "(4 compress)^(-1/3); applied before quantization"
                            % img_max,
        "generation_seconds": round(t_gen, 3),
    }
    if quantizer.active:
        truth["notes"].append(
            "hidden effects (dnl_*, compress) are not in expected_reference")
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
        f.write("\n")

    clipped = int(np.count_nonzero((bright_dn >= img_max)
                                   | (dark_e + spatial_up * a.qe * prnu >= a.u_esat)))
    if clipped:
        log("emva_simulate: WARNING %d pixels of the spatial point are saturated "
            "(noise-free); PRNU1288 will be off" % clipped)
    log("emva_simulate: %d images, K=%.6g DN/e- (%s), blackoffset=%g DN, "
        "QE=%g, dark current %.4g e-/s, %.2f s"
        % (n_img, K, K_source, bo, a.qe, u_i, t_gen))
    print(descriptor)


if __name__ == "__main__":
    main(sys.argv[1:])
