"""The studio's first-use job compiles the kernels (studio.imitate.kernels) before it builds the retrieval index. The
first run after an install, compiling them up front and saying so, is test_wheel.py's (on the installed wheel)."""

from __future__ import annotations


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


def test_a_process_that_finds_another_compiling_waits_and_then_loads_rather_than_compiling(tmp_path, monkeypatch):
    """Two processes' first runs after an install (the workers of a spread run, two terminals): while one compiles
    the kernels, the other says once that it waits (stage "compile", its item), then finds them in numba's disk
    cache and compiles nothing; a process that finds no one compiling compiles them itself, once."""
    import fcntl
    import threading
    import time

    from studio.home import LOCK_POLL_S as POLL_S
    from studio.imitate import kernels

    lock = tmp_path / "studio-kernels.lock"
    monkeypatch.setattr(kernels, "_lock_path", lambda: lock)
    done = threading.Event()  # "the other process has written the disk cache"
    monkeypatch.setattr(kernels, "kernels_compiled", done.is_set)
    compiled: list[float] = []
    monkeypatch.setattr(kernels, "compile_kernels", lambda renderer, cfg: compiled.append(1.0) or 1.0)
    seen = []
    with open(lock, "a") as other:  # the other process, compiling
        fcntl.flock(other.fileno(), fcntl.LOCK_EX)
        waiter = threading.Thread(target=kernels.compile_first, args=(None, None, seen.append))
        waiter.start()
        time.sleep(4 * POLL_S)
        assert waiter.is_alive() and [(p.stage, p.step, p.item) for p in seen] == [("compile", 0, kernels.WAITING)]
        done.set()
    waiter.join(5)
    assert not waiter.is_alive() and compiled == [] and (seen[-1].stage, seen[-1].step) == ("compile", 1)

    done.clear()
    seen.clear()
    kernels.compile_first(None, None, seen.append)  # nobody else compiling: this process does, saying so
    assert compiled == [1.0] and [(p.step, p.item) for p in seen] == [(0, ""), (1, "")]
