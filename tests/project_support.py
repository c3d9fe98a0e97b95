"""What the project tests share (tests/test_project.py, tests/test_project_stale.py): small frames, a project of the
``sources`` fixture (a folder of frames and a still), a show that holds the rest pose and a square of paint."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from studio.motion.show import Show
from studio.project.project import Project
from studio.targets.video import VideoConfig

S = 32  # mask side: small and fast
VIDEO = VideoConfig(size=S, fps=8.0, hz=8.0)


def make(tmp_path: Path, sources: list[Path], name: str = "p.shadow") -> Project:
    return Project.create(tmp_path / name, sources=[str(s) for s in sources], video=VIDEO)


def rest_show(hand, seconds: float = 1.0) -> Show:
    q = np.stack([hand.rest_pose(), hand.rest_pose()])
    return Show.from_samples(hand, np.array([0.0, seconds]), q, title="test")


def blob(rng, shape=(S, S)) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    r, c = rng.integers(0, S - 6, 2)
    m[r : r + 6, c : c + 6] = 1
    return m
