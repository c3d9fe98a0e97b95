"""How many CPU threads torch's work runs on: one way for every face and every worker, in the lowest
stage that runs torch (every torch user sits on or above ``learn``).

numba's parallel kernels (the renderer, the compiled loss) and torch share one OpenMP runtime. The first parallel
kernel a process launches starts numba's thread pool, and once torch has run, that start sets the *launching
thread's* OpenMP thread count to numba's (every core). A torch thread count set before it was lost: under
``--threads 1`` the self-model search of ``evaluate`` ran on 2 threads, while ``imitate``'s ran on 1 whatever its
``--threads`` (its job queue did not pass the flag on). :func:`set_torch_threads` starts numba's pool first, so the
count it sets holds for the calling thread's later torch work, renders or not (``tests/test_threads.py``).

    with torch_threads(2):          # this block's torch work on 2 threads; the previous count restored after
        imitator.imitate(mask)
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping


def default_threads(environ: Mapping[str, str], cores: int) -> int:
    """Torch threads of one job when nothing else asks: ``OMP_NUM_THREADS`` when the user set it (a positive whole
    number), else 2, or 1 on a 1-core machine.

    With idle OpenMP threads sleeping (OMP_WAIT_POLICY=PASSIVE, set by ``studio/__init__``) 2 beat 1 on the 2-core
    machine: the gradient search 13.8 → 18.4 steps/s with the notebook's main-thread p99 1.3 → 3.5 ms
    (benchmarks/bench_jobs.py --threads 1|2, limit 100 ms); `evaluate`'s "Ours" 7.9 → 6.3 s a target, `imitate` of
    a still 13.0 → 12.1 s. Work spread over worker processes keeps 1 thread each (``WorkerModels.threads``)."""
    text = environ.get("OMP_NUM_THREADS", "").strip()
    if text.isdigit() and int(text) >= 1:
        return int(text)
    return max(1, min(2, cores))


DEFAULT_THREADS = default_threads(
    os.environ, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
)


def set_torch_threads(n: int) -> None:
    """Torch's CPU threads for the calling thread's torch work: ``n`` (≥ 1), kept across numba's parallel kernels."""
    if n < 1:
        raise ValueError(f"torch needs at least 1 CPU thread, not {n}")
    import numba
    import torch

    numba.get_num_threads()  # starts numba's pool now (a no-op once started), so its start cannot reset the count
    torch.set_num_threads(n)


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block with torch on ``n`` CPU threads (:func:`set_torch_threads`); None or 0 leaves torch's setting.

    The previous count is restored after, also when the block raises."""
    if not n:
        yield
        return
    import torch

    previous = torch.get_num_threads()
    set_torch_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
