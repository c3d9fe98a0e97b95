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
