"""The wheel a user outside the repo installs: built, installed into a folder, run from elsewhere on its own assets;
its first run compiles the kernels up front and says so, the next loads them from the disk cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_of_the_tree_is_listed():
    """pyproject's explicit package list (needed for the assets mapping) matches the folders that hold code, and the
    assets' data folders (each a package of data alone)."""
    tomllib = pytest.importorskip("tomllib")  # Python ≥ 3.11
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {"studio.assets"} | {f"studio.assets.{d.name}" for d in (ROOT / "assets").iterdir() if d.is_dir()
                                 and d.name != "__pycache__"}  # fmt: skip
    for top in ("studio", "hardware", "widgets"):
        for init in (ROOT / top).rglob("__init__.py"):
            found.add(".".join(init.parent.relative_to(ROOT).parts))
    assert listed == found


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """``pip wheel --no-deps`` of the checkout, installed with ``pip install --target`` into a fresh folder."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"  # a copy, so that the build leaves nothing in the checkout
    junk = shutil.ignore_patterns(".git", "build", "dist", "*.egg-info", "__pycache__", "data", "out", "runs", "tests")
    shutil.copytree(ROOT, src, ignore=junk)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp / "dist"), str(src)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout + built.stderr
    (wheel,) = (tmp / "dist").glob("shadow_studio-*.whl")
    site = tmp / "site"
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--target", str(site), str(wheel)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    return site


@pytest.fixture(scope="module")
def numba_cache(installed, tmp_path_factory) -> Path:
    """The installed copy's own numba cache (``NUMBA_CACHE_DIR`` of every run here), empty after the install."""
    return tmp_path_factory.mktemp("numba")


def installed_env(site: Path, numba_cache: Path, **extra: str) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(site), "NUMBA_CACHE_DIR": str(numba_cache), **extra}


def run_installed(site: Path, numba_cache: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """``python -m studio.cli ARGS`` with the installed copy first on the path, from a folder outside the checkout."""
    env = installed_env(site, numba_cache)
    return subprocess.run(
        [sys.executable, "-m", "studio.cli", *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=600
    )


FIRST_RUN = """
import json, logging
logging.basicConfig(level=logging.INFO, format="%(message)s")
import studio
from studio.imitate.kernels import _kernels, compile_kernels, kernels_compiled
from studio.imitate.retrieval import RetrievalConfig
from studio.imitate.still import Imitator
before = kernels_compiled()
stages = []
with Imitator(retrieval=RetrievalConfig(size=300)) as im:  # a small index: built in a second
    im.retrieval_index(progress=lambda p: stages.append([p.stage, p.step, p.total]))  # every search starts here
    compile_kernels(im.renderer, im.loss_cfg)  # every kernel has run in this process now
compiled = sum(len(k.stats.cache_misses) for k in _kernels())  # … compiled here, not loaded from the disk cache
print(json.dumps({"before": before, "after": kernels_compiled(), "stages": stages[:2], "compiled": compiled,
                  "studio": studio.__file__}))
"""


@pytest.fixture(scope="module")
def first_runs(installed, numba_cache, tmp_path_factory) -> list[tuple[dict, str]]:
    """The installed copy's first run after the install (studio.imitate.kernels compiles the kernels up front, into
    ``numba_cache``) and the run after it: each one's JSON line and all it logged."""
    runs, where = [], tmp_path_factory.mktemp("first")  # outside the checkout, so its studio/ is not imported
    for _ in range(2):
        env = installed_env(installed, numba_cache, SHADOW_STUDIO_CACHE=str(where / "studio-cache"))
        out = subprocess.run([sys.executable, "-c", FIRST_RUN], capture_output=True, text=True, env=env, cwd=where,
                             timeout=600)  # fmt: skip
        assert out.returncode == 0, out.stderr[-3000:]
        runs.append((json.loads(out.stdout.strip().splitlines()[-1]), out.stderr))
    return runs


@pytest.mark.slow
def test_the_first_run_after_an_install_compiles_the_kernels_and_says_so(installed, first_runs):
    (first, said), (again, said_again) = first_runs
    assert first["studio"].startswith(str(installed)) and again["studio"].startswith(str(installed))
    assert first["before"] is False and first["after"] is True and first["compiled"] == 8
    assert first["stages"] == [["compile", 0, 1], ["compile", 1, 1]]
    assert "first run after this install: compiling the renderer's and the losses' kernels" in said
    assert again["before"] is True and again["stages"][:1] != [["compile", 0, 1]]
    assert "compiling" not in said_again and again["compiled"] == 0  # every kernel loaded from the disk cache


@pytest.mark.slow
def test_wheel_holds_the_assets(installed):
    for rel in ("hand.urdf", "calibration.yaml", "models/selfmodel_cpu128.pt", "models/inverse_cpu128.pt",
                "targets/asl_o.jpeg", "targets/SOURCE.txt",
                "videos/muybridge_horse.gif", "videos/SOURCE.txt"):  # fmt: skip
        assert (installed / "studio" / "assets" / rel).is_file(), rel
    assert (installed / "studio" / "motion" / "show.schema.json").is_file()
    assert not (installed / "assets").exists() and not (installed / "tests").exists()


@pytest.mark.slow
def test_installed_copy_renders_and_imitates_from_outside(installed, numba_cache, first_runs, tmp_path):
    """(After ``first_runs``, which compiled the installed copy's kernels.)"""
    where = subprocess.run(
        [sys.executable, "-c", "import studio, studio.assets as a; print(studio.__file__, a.asset('hand.urdf'))"],
        capture_output=True, text=True, cwd=tmp_path, env=installed_env(installed, numba_cache), timeout=120,
    )  # fmt: skip
    assert where.returncode == 0, where.stderr
    assert all(line.startswith(str(installed)) for line in where.stdout.split()), where.stdout  # not the checkout

    out = run_installed(installed, numba_cache, tmp_path, "render", "rest", "--out", "rest.png", "--resolution", "64")
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "rest.png").is_file()

    target = installed / "studio" / "assets" / "targets" / "asl_v.jpeg"
    out = run_installed(installed, numba_cache, tmp_path, "imitate", str(target), "--out", "o", "--no-clip", "--quiet",
                        "--search-iterations", "5", "--refine-steps", "50")  # fmt: skip
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["out"] == "o" and summary["collision_free"] and (tmp_path / "o" / "keyframes.json").is_file()
    doc = json.loads((tmp_path / "o" / "keyframes.json").read_text())
    assert doc["provenance"]["model"].startswith(str(installed)) and len(doc["poses"]) == 1
