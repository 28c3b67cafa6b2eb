"""Fixtures: the `dncal` binary of the same build (DNCAL_BIN, set by scripts/python.sh)
and the sets it simulates, so that every test compares the package with the CLI on the
same inputs."""

import json
import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def dncal_bin():
    path = pathlib.Path(os.environ.get("DNCAL_BIN", ROOT / "target" / "checked" / "dncal"))
    if not path.exists():
        pytest.fail(f"no dncal binary at {path}: build it (cargo build --profile checked -p dncal-host) or set DNCAL_BIN")
    return path


@pytest.fixture(scope="session")
def cli(dncal_bin):
    """Runs `dncal ARGS... --json` (quietly) and returns the parsed JSON."""

    def run(*args):
        out = subprocess.run([str(dncal_bin), "--quiet", *map(str, args), "--json"], check=True, capture_output=True, text=True)
        return json.loads(out.stdout)

    return run


@pytest.fixture(scope="session")
def sets(tmp_path_factory, cli):
    """A simulated histogram set (the default camera's ramps) and a small linearity set."""
    d = tmp_path_factory.mktemp("sets")
    cli("simulate", "histograms", "-o", d / "h.fits")
    cli("simulate", "linearity", "--roi", "48x40+100+200", "--levels", "14", "--frames", "16", "-o", d / "lin.fits")
    return d
