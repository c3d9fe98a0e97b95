"""Shared fixtures. Tests that read ../shared skip with the reason when it is absent."""

from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings
from PIL import Image

from studio.motion.show import Show, save_show

SHARED = Path(__file__).resolve().parents[2] / "shared"

# pytest-xdist runs one worker per core: each one's torch (and its subprocesses') on 1 thread, not the studio's
# default of 2 (studio.learn.threads.default_threads honours OMP_NUM_THREADS), so the workers do not oversubscribe the
# cores. Set before anything imports torch or studio.learn.threads; a value set by the caller is kept.
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    os.environ.setdefault("OMP_NUM_THREADS", "1")

# On CI (``CI`` set) the property tests draw the same examples every run: a counterexample is found where tests are
# written and run by hand (random draws, kept in .hypothesis/), never first in the run that judges an unrelated change.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Files that hold a slow test run first, the others after, each file's tests in their own order: xdist hands a
    worker whole files (``--dist loadfile``) in this order, so the short files fill the end of both workers' queues
    instead of one long file running alone while the other worker waits (the suite's wall time on CI's two cores)."""
    slow = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow)  # stable: each group keeps its collection order


@pytest.fixture(autouse=True)
def estop_file(tmp_path_factory, monkeypatch) -> Path:
    """Every test has an e-stop latch file of its own (``$SHADOW_STUDIO_ESTOP``, inherited by its subprocesses): an
    e-stop pressed in one test, or on this machine, never stops another's servos. The path, not yet created."""
    path = tmp_path_factory.mktemp("estop", numbered=True) / "estop.json"
    monkeypatch.setenv("SHADOW_STUDIO_ESTOP", str(path))
    return path


@pytest.fixture(autouse=True)
def no_index_warmup(monkeypatch) -> None:
    """Studios opened by tests build no retrieval index in the background (widgets.index_warmup: each test's
    studio would start a build its close cancels); the searches build it when they need it, and one test turns
    the warm-up back on."""
    monkeypatch.setenv("SHADOW_STUDIO_NO_INDEX_WARMUP", "1")


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


@pytest.fixture(scope="session")
def free_poses(hand):
    """``free_poses(n, seed)`` → ``(n, 21)`` collision-free poses of the self-exploration sampler, from ``seed``."""
    from studio.sim.physics import CollisionWorld
    from studio.sim.sampling import sample_poses

    def draw(n: int, seed: int) -> np.ndarray:
        rng, out = np.random.default_rng(seed), []
        with CollisionWorld(hand) as world:
            while len(out) < n:
                q = sample_poses(hand, 1, rng)[0][0]
                if not world.in_collision(q)[0]:
                    out.append(q)
        return np.stack(out)

    return draw


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


def _write_frames(folder: Path, n: int = 8, seed: int = 0) -> Path:
    """A frame folder of n binary 64² masks: a static body and an arm that swings through three positions."""
    folder.mkdir(parents=True, exist_ok=True)
    yy, xx = np.mgrid[:64, :64]
    for i in range(n):
        m = ((yy - 40) ** 2 + (xx - 32) ** 2 < 12**2).astype(np.uint8)
        ang = [-0.8, 0.0, 0.8][(i // 3) % 3]
        cx, cy = 32 + 20 * math.sin(ang), 40 - 20 * math.cos(ang)
        m |= ((yy - cy) ** 2 + (xx - cx) ** 2 < 6**2).astype(np.uint8)
        Image.fromarray(m * 255).save(folder / f"{i:05d}.png")
    return folder


def _write_still(path: Path) -> Path:
    """A ring (its hole is the expressive region) on black."""
    yy, xx = np.mgrid[:64, :64]
    r2 = (yy - 32) ** 2 + (xx - 32) ** 2
    Image.fromarray(((r2 < 24**2) & (r2 > 10**2)).astype(np.uint8) * 255).save(path)
    return path


@pytest.fixture(scope="session")
def write_sources():
    """``write_sources(folder)`` → two project sources written there: a frame folder of 8 binary masks (a static
    body, an arm swinging through three positions) and a ring still (its hole is the expressive region)."""
    return lambda folder: [_write_frames(Path(folder) / "clip"), _write_still(Path(folder) / "ring.png")]


@pytest.fixture
def sources(tmp_path, write_sources) -> list[Path]:
    return write_sources(tmp_path / "src")


@pytest.fixture
def poses(tmp_path, hand) -> Path:
    """A keyframes file of two keyframes near rest (plans in about a second; the limits and paths tests)."""
    q = hand.rest_pose()
    q2 = q.copy()
    q2[1] += 0.3
    path = tmp_path / "kf.json"
    keyframes = [{"t": 1.0, "pose": hand.pose_to_dict(q2)}, {"t": 2.0, "pose": hand.pose_to_dict(q)}]
    path.write_text(json.dumps({"keyframes": keyframes}))
    return path


@pytest.fixture
def show_file(tmp_path, hand) -> Path:
    """A three-sample show file at rest (the limits and paths tests)."""
    q = hand.rest_pose()
    return save_show(Show.from_samples(hand, [0.0, 0.5, 1.0], np.stack([q, q, q])), tmp_path / "show.json")
