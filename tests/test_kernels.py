"""The first run after an install compiles the kernels up front and says so (studio.imitate.kernels), in a fresh
numba cache (a subprocess: this one's kernels are loaded already); the next run loads them and says nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

FIRST_RUN = """
import json, logging
logging.basicConfig(level=logging.INFO, format="%(message)s")
from studio.imitate.kernels import _kernels, compile_kernels, kernels_compiled
from studio.imitate.retrieval import RetrievalConfig
from studio.imitate.still import Imitator
before = kernels_compiled()
stages = []
with Imitator(retrieval=RetrievalConfig(size=300)) as im:  # a small index: built in a second
    im.retrieval_index(progress=lambda p: stages.append([p.stage, p.step, p.total]))  # every search starts here
    compile_kernels(im.renderer, im.loss_cfg)  # every kernel has run in this process now
compiled = sum(len(k.stats.cache_misses) for k in _kernels())  # … compiled here, not loaded from the disk cache
print(json.dumps({"before": before, "after": kernels_compiled(), "stages": stages[:2], "compiled": compiled}))
"""


def run_first(cache: str) -> tuple[dict, str]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, SHADOW_STUDIO_CACHE=cache + "-studio")
    out = subprocess.run([sys.executable, "-c", FIRST_RUN], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1]), out.stderr


@pytest.mark.slow
def test_the_first_run_after_an_install_compiles_the_kernels_and_says_so(tmp_path):
    first, said = run_first(str(tmp_path / "numba"))
    assert first["before"] is False and first["after"] is True and first["compiled"] == 8
    assert first["stages"] == [["compile", 0, 1], ["compile", 1, 1]]
    assert "first run after this install: compiling the renderer's and the losses' kernels" in said
    again, said = run_first(str(tmp_path / "numba"))
    assert again["before"] is True and again["stages"][:1] != [["compile", 0, 1]]
    assert "compiling" not in said and again["compiled"] == 0  # every kernel loaded from the disk cache


def test_the_studios_first_use_job_compiles_the_kernels_before_it_builds_the_index(tmp_path, monkeypatch):
    """The notebook's background job (widgets.index_warmup → index_job) on a fresh install: the kernels' compile
    (stage "compile") comes before the index's build, so the artist's first optimisation waits for neither. Here
    the kernels are loaded already, so the install is made fresh by the check alone (a tiny index, its own cache)."""
    from studio.imitate import kernels
    from studio.imitate.retrieval import RetrievalConfig
    from studio.jobs import JobQueue, JobState
    from studio.project.jobs import index_job

    monkeypatch.setattr(kernels, "kernels_compiled", lambda: False)
    monkeypatch.setenv("SHADOW_STUDIO_CACHE", str(tmp_path))
    stages: list[str] = []
    with JobQueue() as queue:
        queue.subscribe(lambda e: stages.append(e.stage) if e.total and e.stage not in stages else None)
        job = queue.submit(index_job(retrieval=RetrievalConfig(size=200)))
        assert job.wait(120) == JobState.DONE, job.error
    assert stages[:2] == ["compile", "index"] and job.result == 200
