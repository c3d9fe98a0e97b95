"""Torch runs on the threads it was given (studio.learn.threads): numba's pool start no longer resets the count, and the
command line's ``--threads`` reaches the job that does the work."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

# Each check needs a fresh interpreter: numba's pool starts once per process.
_RENDER = """
import json, threading
import numpy as np
import numba, torch
from studio.sim.hand import load_hand
from studio.sim.shadow import ShadowRenderer
hand = load_hand()
def render():  # torch at work, then a batch big enough for numba's parallel kernel
    torch.get_num_threads(); torch.ones(64, 64) @ torch.ones(64, 64)
    ShadowRenderer(hand).render(np.zeros((64, hand.dof)))
"""


def _run(body: str) -> dict:
    code = _RENDER + textwrap.dedent(body)
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}  # the suite's own setting (conftest) off
    env["NUMBA_NUM_THREADS"] = "2"  # numba's pool has 2 threads even on a 1-core machine, so the hazard is real
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_plain_torch_count_is_lost_at_numbas_first_parallel_kernel():
    """The hazard the module guards against: without it, torch's count becomes numba's at the first render."""
    got = _run("""
        torch.set_num_threads(1)
        render()
        print(json.dumps({"torch": torch.get_num_threads(), "numba": numba.get_num_threads()}))
    """)
    assert got == {"torch": 2, "numba": 2}


@pytest.mark.parametrize("n", [1, 2])
def test_the_count_set_holds_across_renders_in_this_and_another_thread(n):
    got = _run(f"""
        from studio.learn.threads import set_torch_threads, torch_threads
        set_torch_threads({n})
        render(); render()
        out = {{"main": torch.get_num_threads()}}
        torch.set_num_threads(3)
        def job():
            with torch_threads({n}):
                render()
                out["job"] = torch.get_num_threads()
        t = threading.Thread(target=job); t.start(); t.join()
        print(json.dumps(out))
    """)
    assert got == {"main": n, "job": n}


def test_the_default_is_two_threads_or_what_omp_num_threads_says():
    from studio.learn.threads import default_threads

    assert default_threads({}, cores=2) == 2 and default_threads({}, cores=16) == 2 and default_threads({}, 1) == 1
    assert default_threads({"OMP_NUM_THREADS": "3"}, cores=2) == 3
    assert default_threads({"OMP_NUM_THREADS": " 1"}, cores=8) == 1
    for junk in ("0", "-2", "two", "", "1.5"):  # not a positive whole number: the studio's own default
        assert default_threads({"OMP_NUM_THREADS": junk}, cores=2) == 2


def test_torch_threads_restores_the_previous_count_and_refuses_zero_through_set():
    import torch

    from studio.learn.threads import set_torch_threads, torch_threads

    before = torch.get_num_threads()
    with pytest.raises(RuntimeError), torch_threads(1):
        assert torch.get_num_threads() == 1
        raise RuntimeError("the block fails")
    assert torch.get_num_threads() == before
    with torch_threads(0):  # 0/None: torch's setting left alone
        assert torch.get_num_threads() == before
    with pytest.raises(ValueError, match="at least 1"):
        set_torch_threads(0)


@pytest.mark.parametrize("n", [1, 2])
def test_the_command_lines_threads_reach_the_job(n):
    """``run_with_bars(..., threads=n)`` (what ``--threads`` feeds) runs the job's torch work on n threads, after a
    render in the job, whatever the calling thread had."""
    got = _run(f"""
        from studio.cli.runs import run_with_bars
        from studio.jobs import Job
        torch.set_num_threads(3 - {n})
        def work(report, cancel):
            render()
            return torch.get_num_threads()
        def run(queue, cancel, on_job, progress):
            return queue.run(Job("probe", work)).result
        print(json.dumps({{"job": run_with_bars(run, True, threads={n})}}))
    """)
    assert got == {"job": n}
