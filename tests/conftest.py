"""Shared fixtures. Tests that read ../shared skip with the reason when it is absent."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture(scope="session")
def hand():
    from studio.sim.hand import load_hand

    return load_hand()


@pytest.fixture(scope="session")
def shared_targets() -> Path:
    path = SHARED / "targets"
    if not path.is_dir():
        pytest.skip(f"shared targets not found at {path} (the shared/ folder beside the checkout)")
    return path


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def in_process(capsys):
    """``in_process(verb, *args)`` runs ``shadow-studio`` through ``main()`` in this process and returns it as a
    finished process (returncode, stdout, stderr). The one-line error path is main's own, so a test that proves
    the console script with one real start can check its other inputs here, without ~3 s of imports each."""
    from studio.cli.main import main

    def run(*args) -> subprocess.CompletedProcess:
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:  # argparse's own exit (a bad flag, --help), as the process would end
            code = e.code if isinstance(e.code, int) else 1
        out = capsys.readouterr()
        return subprocess.CompletedProcess(list(args), code, out.out, out.err)

    return run
