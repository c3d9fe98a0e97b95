"""Shared fixtures. Tests that read ../shared skip with the reason when it is absent."""

from __future__ import annotations

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
