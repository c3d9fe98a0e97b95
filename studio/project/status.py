"""Where a project stands, as plain data that :class:`~studio.project.project.Project` computes: which sources are
missing or changed on disk, which keyframes have no result or a stale one, whether the show is stale, and what
undo and redo can do. The pure functions that read a project (its show clock, :mod:`.show_timing`; its summary,
:mod:`.summary`) take a :class:`ProjectStatus` beside the state instead of the ``Project`` object."""

from __future__ import annotations

from dataclasses import dataclass


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
    show_stale: bool = False  # the planned show was planned from inputs that changed since (False: none or current)
    can_undo: bool = False  # an edit can be undone
    can_redo: bool = False  # an undone edit can be redone

    @property
    def pending(self) -> tuple[int, ...]:
        """Keyframe ids a run computes (missing or stale)."""
        return tuple(sorted(set(self.missing) | set(self.stale), key=(self.missing + self.stale).index))

    def result_state(self, k: int) -> str:
        """``"missing"``, ``"stale"`` or ``"current"`` for keyframe ``k``."""
        return "missing" if k in self.missing else "stale" if k in self.stale else "current"
