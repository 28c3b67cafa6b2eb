"""The Corrector against an independent numpy model of the datapath: each pixel adds
entries[adc(column)][min(code, top)] into its state's sum, column c read by ADC
c mod 4; exact to 512 frames a state, then clipped at 2^32 - 1 and counted."""

import numpy as np
import pytest

import dncal

TOP = 4095
U32_MAX = 2**32 - 1


def ramp_lut(seed=3):
    """A LUT of uneven but rising entries, different per ADC (steps of 0.49 to 1 DN:
    the top stays below 2^23)."""
    rng = np.random.default_rng(seed)
    steps = rng.integers(1000, 2040, size=(4, 4096), dtype=np.uint32)
    steps[:, 0] = 0
    return dncal.Lut(np.cumsum(steps, axis=1, dtype=np.uint32))


def model(entries, frames, states, first_column=0):
    """Sums (states, rows, cols) as uint64, and codes above the top."""
    n, h, w = frames.shape
    adc = (first_column + np.arange(w)) % 4
    sums = np.zeros((max(states) + 1, h, w), dtype=np.uint64)
    for f, s in zip(frames, states):
        sums[s] += entries[adc[None, :], np.minimum(f, TOP)]
    return sums, int((frames > TOP).sum())


def test_sums_equal_the_numpy_model():
    lut = ramp_lut()
    rng = np.random.default_rng(7)
    frames = rng.integers(0, 4200, size=(9, 6, 11), dtype=np.uint16)
    c = dncal.Corrector(lut, 3, 6, 11, first_column=5)
    assert c.add(frames[:4]) == 4
    assert c.add(frames[4]) == 1  # one frame, next state in the cycle
    assert c.add(frames[5:], states=[2, 0, 0, 1]) == 4
    states = [0, 1, 2, 0, 1, 2, 0, 0, 1]
    want, above = model(lut.entries, frames, states, first_column=5)
    assert c.sums.dtype == np.uint32 and c.sums.shape == (3, 6, 11)
    assert np.array_equal(c.sums.astype(np.uint64), want)
    assert list(c.frames_per_state) == [4, 3, 2]
    assert c.status["out_of_range_codes"] == above > 0
    assert c.status["saturated_additions"] == 0 and c.status["frames"] == 9
    c.clear()
    assert not c.sums.any() and c.status["frames"] == 0


def test_past_512_frames_the_sums_clip_and_count():
    top = np.zeros((4, 4096), dtype=np.uint32)
    top[:, -1] = 2**23 - 1
    top = np.maximum.accumulate(top, axis=1)
    c = dncal.Corrector(dncal.Lut(top), 1, 2, 3)
    frames = np.full((520, 2, 3), TOP, dtype=np.uint16)
    for chunk in np.array_split(frames, 7):  # cut into calls anywhere: one run
        c.add(np.ascontiguousarray(chunk))
    per_frame = np.uint64(2**23 - 1)
    totals = np.arange(1, 521, dtype=np.uint64) * per_frame
    clipped = int((totals > U32_MAX).sum()) * 6
    assert (c.sums == min(int(totals[-1]), U32_MAX)).all()
    assert c.status["saturated_additions"] == clipped == 8 * 6


def test_frames_are_read_in_place():
    lut = ramp_lut()
    frames = np.zeros((3, 256, 256), dtype=np.uint16)
    c = dncal.Corrector(lut, 1, 256, 256)
    c.add(frames)
    assert c._last_input_address == frames.__array_interface__["data"][0]
    one = frames[1]  # a contiguous view into the stack: still no copy
    c.add(one, state=0)
    assert c._last_input_address == one.__array_interface__["data"][0]


def test_bad_frames_say_what_is_needed():
    c = dncal.Corrector(ramp_lut(), 2, 4, 8)
    good = np.zeros((2, 4, 8), dtype=np.uint16)
    with pytest.raises(TypeError, match="dtype float64, but uint16"):
        c.add(good.astype(np.float64))
    with pytest.raises(TypeError, match="dtype int32"):
        c.add(good.astype(np.int32))
    with pytest.raises(TypeError, match=">u2|uint16"):
        c.add(good.astype(">u2"))
    with pytest.raises(ValueError, match="not C-contiguous"):
        c.add(np.zeros((2, 8, 4), dtype=np.uint16).transpose(0, 2, 1))
    with pytest.raises(ValueError, match="not C-contiguous"):
        c.add(np.asfortranarray(good[0]))
    with pytest.raises(ValueError, match="4 x 9 pixels"):
        c.add(np.zeros((4, 9), dtype=np.uint16))
    with pytest.raises(ValueError, match="empty"):
        c.add(np.zeros((0, 4, 8), dtype=np.uint16))
    with pytest.raises(ValueError, match="dimension"):
        c.add(np.zeros(32, dtype=np.uint16))
    with pytest.raises(TypeError, match="not list"):
        c.add([[0] * 8] * 4)
    # A buffer one byte off (as pickle can give): refused, not read misaligned.
    raw = np.zeros(2 * 4 * 8 * 2 + 1, dtype=np.uint8)
    shifted = np.frombuffer(raw.data, dtype=np.uint16, offset=1, count=2 * 4 * 8).reshape(2, 4, 8)
    assert not shifted.flags.aligned
    with pytest.raises(ValueError, match="not aligned"):
        c.add(shifted)
    with pytest.raises(ValueError, match="3 values for 2 frames"):
        c.add(good, states=[0, 1, 0])
    with pytest.raises(dncal.InputError, match="modulation state 2 not below 2"):
        c.add(good, states=[0, 2])
    with pytest.raises(TypeError, match="not both"):
        c.add(good[0], state=0, states=[0])
    # Nothing of the refused calls was added.
    assert not c.sums.any() and c.status["frames"] == 0
    with pytest.raises(ValueError, match="geometry"):
        dncal.Corrector(ramp_lut(), 9, 4, 8)
    with pytest.raises(OverflowError):
        dncal.Corrector(ramp_lut(), 1, 70000, 8)
