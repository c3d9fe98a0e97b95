"""Shared by the Targets panel's tests: a one-still project's studio state, and waiting for the panel's job."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from studio.assets import asset

from studio.jobs import JobState
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.targets.images import TargetConfig
from studio.targets.video import VideoConfig
from widgets.state import StudioState

STILL = Path(asset("targets/asl_o.jpeg"))


@contextlib.contextmanager
def one_still_state(tmp_path: Path) -> Iterator[StudioState]:
    """The studio state of a new project of the bundled ASL "o" (48² frames), closed after."""
    project = Project.create(tmp_path / "t.shadow", [STILL], video=VideoConfig(size=48, hz=2.0),
                             still=TargetConfig())  # fmt: skip
    s = StudioState(project, queue_for(project))
    try:
        yield s
    finally:
        s.close()


def finished(panel) -> None:
    """Wait for the panel's job (every edit that reads the sources runs as one) to end well."""
    job = panel.job
    assert job is not None and job.wait(60) == JobState.DONE, (job.error, panel.messages.text)
