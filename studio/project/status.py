"""Where a project stands, as plain data that :class:`~studio.project.project.Project` computes: which sources are
missing or changed on disk, which keyframes have no result or a stale one, whether the show is stale, and what
undo and redo can do. The pure functions that read a project (its show clock, :mod:`.show_timing`; its summary,
:mod:`.summary`) take a :class:`ProjectStatus` beside the state instead of the ``Project`` object."""

from __future__ import annotations

import logging
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from studio.imitate.config import LossConfig
from studio.motion.show import Show
from studio.motion.video_timing import VideoTiming
from studio.project.state import Keyframe, PoseResult, ProjectError, ProjectState

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MissingSource:
    """A source that is not where the project last read it."""

    index: int  # source number
    path: str  # the path as given
    absolute: str  # where it was last read


@dataclass(frozen=True)
class ProjectStatus:
    """A project's status at one moment (plain data)."""

    path: str  # the project folder
    missing_sources: tuple[MissingSource, ...] = ()  # sources not where they were last read
    changed_sources: tuple[int, ...] = ()  # sources whose content changed since they were read
    missing: tuple[int, ...] = ()  # keyframe ids with no result, first-appearance order
    stale: tuple[int, ...] = ()  # keyframe ids whose result was computed from inputs that changed since
    pending: tuple[int, ...] = ()  # missing or stale: what a run computes, first-appearance order
    show_stale: bool = False  # the planned show was planned from inputs that changed since (False: none or current)
    can_undo: bool = False  # an edit can be undone
    can_redo: bool = False  # an undone edit can be redone

    def result_state(self, k: int) -> str:
        """``"missing"``, ``"stale"`` or ``"current"`` for keyframe ``k``."""
        return "missing" if k in self.missing else "stale" if k in self.stale else "current"


class ProjectHandle(Protocol):
    """What the runners (:mod:`.jobs`, :mod:`.run`) use of an open :class:`~studio.project.project.Project`: they take
    the object itself; this names its part they need, so that they import nothing of the class that calls them."""

    path: Path

    @property
    def state(self) -> ProjectState: ...

    @property
    def keyframes(self) -> tuple[Keyframe, ...]: ...

    @property
    def results(self) -> dict[int, PoseResult]: ...

    @property
    def show(self) -> Show | None: ...

    @property
    def weights(self) -> LossConfig: ...

    def status(self) -> ProjectStatus: ...

    def assignment(self) -> np.ndarray: ...

    def combined_masks(self) -> np.ndarray: ...

    def keyframe_masks(self, k: int) -> tuple[np.ndarray, np.ndarray]: ...

    def keyframe_inputs(self, k: int) -> str: ...

    def show_inputs(self) -> str: ...

    def show_timing(self, layout: Any = None) -> VideoTiming: ...

    def set_result(self, k: int, pose: Any, loss: Any, shadow: np.ndarray, **fields: Any) -> None: ...

    def refined_together(self, ids: list[int], moved: Any = None) -> None: ...

    def optimise_again(self, ids: list[int]) -> None: ...

    def set_show(self, show: Show | None, inputs: str | None = None) -> None: ...

    def writing(self, what: str, wait: float = 0.0) -> AbstractContextManager[None]: ...


class SourceMissing(ProjectError):
    """A source of the project is not where it was read: put it back or relink it (``source`` names it)."""

    def __init__(self, message: str, source: int):
        super().__init__(message)
        self.source = source  # the source's number


class SourceChanged(ProjectError):
    """A source's content changed on disk since it was read: re-read it before running (``source`` names it)."""

    def __init__(self, message: str, source: int):
        super().__init__(message)
        self.source = source  # the source's number


def check_sources(project: ProjectHandle) -> None:
    """A :class:`SourceChanged` error when a source changed on disk (module doc); nothing is changed. A missing
    source does not stop a run: every frame's mask is stored in the project (a warning says it is missing)."""
    status = project.status()
    for m in status.missing_sources:
        log.warning(
            "%s: source %d is missing (it was at %s); running from the frames stored in the project (relink it to "
            "re-read it or to review it beside the show)", project.path, m.index, m.absolute,
        )  # fmt: skip
    if status.changed_sources:
        i = status.changed_sources[0]
        raise SourceChanged(
            f"{project.path}: source {i} ({project.state.sources[i].path}) changed on disk since it was read; re-read "
            "the sources and run again. Nothing was changed", i,
        )  # fmt: skip
