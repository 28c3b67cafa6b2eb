"""LUTs from Python against the CLI's on the same histogram set, and the formats' round
trips against the CLI's own conversions (byte for byte)."""

import numpy as np
import pytest
from astropy.io import fits

import dncal


def test_histograms_read_as_astropy_reads_them(sets):
    counts, bits = dncal.read_histograms(sets / "h.fits")
    with fits.open(sets / "h.fits") as f:
        theirs = np.asarray(f[0].data)
    assert bits == 12 and counts.dtype == np.uint64 and counts.shape == (4, 4096)
    assert np.array_equal(counts, theirs.astype(np.uint64))


def test_built_luts_equal_lut_build(sets, cli, tmp_path):
    counts, _ = dncal.read_histograms(sets / "h.fits")
    summary = cli("lut", "build", sets / "h.fits", "-o", tmp_path / "cli")
    lut = dncal.build_luts(counts)
    with fits.open(tmp_path / "cli.fits") as f:
        cli_entries = np.asarray(f[0].data)
    assert lut.entries.dtype == np.uint32 and lut.entries.shape == (4, 4096)
    assert np.array_equal(lut.entries, cli_entries)
    assert lut.summaries == summary["adcs"]
    # The weights rebuild the entries; every entry is the core's (below 2^23, rising).
    assert np.array_equal(dncal.Lut.from_weights(lut.weights).entries, lut.entries)
    assert lut.entries.max() < 2**23 and (np.diff(lut.entries.astype(np.int64), axis=1) >= 0).all()
    # The paper's recipe, as `lut build --recipe paper` builds it, is another table.
    cli("lut", "build", sets / "h.fits", "--recipe", "paper", "-o", tmp_path / "paper")
    paper = dncal.build_luts(counts, recipe="paper")
    with fits.open(tmp_path / "paper.fits") as f:
        assert np.array_equal(paper.entries, np.asarray(f[0].data))
    assert not np.array_equal(paper.entries, lut.entries)


@pytest.mark.parametrize("fmt,cli_to", [("fits", "fits"), ("image", "image"), ("kcor", "kcor")])
def test_every_format_written_as_lut_convert_writes_it(sets, cli, tmp_path, fmt, cli_to):
    cli("lut", "build", sets / "h.fits", "-o", tmp_path / "built")
    read_as, lut = dncal.read_lut(tmp_path / "built.fits")
    assert read_as == "lut-fits"
    ours = lut.write(tmp_path / "ours", format=fmt)
    theirs = cli("lut", "convert", tmp_path / "built.fits", "--to", cli_to, "-o", tmp_path / "theirs")["outputs"]
    assert [p.name.replace("ours", "x") for p in ours] == [p.replace(str(tmp_path / "theirs"), "x").lstrip("/") for p in theirs]
    for a, b in zip(ours, theirs):
        if fmt == "fits":
            # FITS: the same tables (DATE and CHECKSUM differ by the second written).
            with fits.open(a) as x, fits.open(b) as y:
                assert len(x) == len(y) >= 2, "the entries and the weights"
                for hx, hy in zip(x, y):
                    assert np.array_equal(hx.data, hy.data)
                    # The same keys and values; DATE, the checksums and HISTORY (the
                    # command line that wrote it) are the run's own.
                    def cards(h):
                        return [(c.keyword, c.value, c.comment) for c in h.cards if c.keyword not in ("DATE", "CHECKSUM", "DATASUM", "HISTORY")]

                    assert cards(hx.header) == cards(hy.header)
        else:
            assert a.read_bytes() == open(b, "rb").read()
        # Read back: the same entries (K-Cor tables are rescaled to their own top, so
        # there the same as the CLI's tables read).
        _, back = dncal.read_lut(a)
        want = dncal.read_lut(b)[1] if fmt == "kcor" else lut
        assert np.array_equal(back.entries, want.entries)


def test_bad_luts_raise_the_clis_message(tmp_path):
    falling = np.tile(np.arange(4096, dtype=np.uint32)[::-1], (4, 1))
    with pytest.raises(dncal.InputError, match="decreases at code 1"):
        dncal.Lut(falling)
    with pytest.raises(dncal.InputError):
        dncal.Lut(np.full((4, 4096), 2**23, dtype=np.uint32))
    with pytest.raises(dncal.InputError, match="3 ADCs"):
        dncal.Lut(np.zeros((3, 4096), dtype=np.uint32))
    with pytest.raises(TypeError, match="dtype int64"):
        dncal.Lut(np.zeros((4, 4096), dtype=np.int64))
    with pytest.raises(TypeError, match="not list"):
        dncal.Lut([[0] * 4096] * 4)
    with pytest.raises(ValueError, match="empty"):
        dncal.Lut(np.zeros((4, 0), dtype=np.uint32))
    with pytest.raises(ValueError, match="ADC of B bits"):
        dncal.build_luts(np.ones((4, 1000), dtype=np.uint64))
    with pytest.raises(dncal.InputError, match="counts: ADC 0"):
        dncal.build_luts(np.zeros((4, 4096), dtype=np.uint64))
    with pytest.raises(ValueError, match='recipe "median"'):
        dncal.build_luts(np.ones((4, 4096), dtype=np.uint64), recipe="median")
    with pytest.raises(dncal.DncalIOError) as e:
        dncal.read_lut(tmp_path / "missing.fits")
    assert isinstance(e.value, OSError) and "missing.fits" in str(e.value)
    garbage = tmp_path / "garbage.fits"
    garbage.write_bytes(b"not a LUT at all" * 10)
    with pytest.raises(dncal.InputError, match="garbage.fits"):
        dncal.read_lut(garbage)


@pytest.mark.parametrize("bits,units", [(12, 2048), (14, 512), (16, 128)])
def test_deep_tables_have_their_own_scale(bits, units):
    # Ideal ADCs at 10^4 counts a code: every entry is its code's centre, k + 1/2 DN,
    # within the counts' noise, on the depth's scale (23-bit entries: 11 fractional
    # bits up to 12-bit codes, 23 - bits above; 2^-11 DN at 16 bits would need 27 bits).
    rng = np.random.default_rng(bits)
    counts = rng.poisson(1e4, (2, 1 << bits)).astype(np.uint64)
    lut = dncal.build_luts(counts)
    assert lut.bit_depth == bits and lut.units_per_dn == units
    assert lut.entries.max() < 2**23
    k = np.arange(1 << bits)
    offset = lut.entries / units - (k + 0.5)
    # A random walk of widths 1% rms each, tied at both ends: sqrt(codes) / 200 DN rms.
    assert np.sqrt(np.mean(offset**2)) < 0.01 * np.sqrt(1 << bits)
    assert abs(lut.entries[0, (1 << bits) // 2] / units - ((1 << bits) // 2 + 0.5)) < 0.03 * np.sqrt(1 << bits)
