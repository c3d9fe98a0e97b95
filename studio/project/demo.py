"""The bundled demo project: the ASL "o" still and the Muybridge horse as ``FOLDER/demo.shadow``.

``shadow-studio demo``, ``shadow-studio lab`` and the notebook studio (``widgets.app.open_studio()``) all start from
this one project; :func:`demo_project` makes it on first use and reopens it afterwards.
"""

from __future__ import annotations

import logging
from pathlib import Path

from studio.assets import asset
from studio.home import studio_home
from studio.project.project import Project
from studio.project.project_format import DOC

log = logging.getLogger(__name__)

DEMO_STILL = asset("targets/asl_o.jpeg")  # the bundled still the demo starts with
PROJECT_NAME = "demo.shadow"  # the project folder inside the demo's folder


def demo_sources() -> list[Path]:
    """The demo's sources in order: the bundled still, then the bundled video."""
    from studio.targets.video import DEFAULT_VIDEO

    return [Path(DEMO_STILL), Path(DEFAULT_VIDEO)]


def demo_project(folder: str | Path | None = None) -> tuple[Project, bool]:
    """``folder/demo.shadow`` (default folder: :func:`studio_home`), opened when there, else made from
    :func:`demo_sources` → ``(project, fresh)``."""
    path = Path(folder if folder is not None else studio_home()) / PROJECT_NAME
    if (path / DOC).is_file():
        return Project.open(path), False
    log.info("making the demo project %s", path)
    return Project.create(path, sources=demo_sources(), title="demo"), True
