"""Saving a project and walking its edits: the write lock, the save that never overwrites another process's work,
and undo / redo (mixed into :class:`~studio.project.project.Project`).

Every edit makes a new state; :meth:`History._commit` saves it (:func:`~studio.project.project_format.save_state`,
under the project's write lock, :mod:`studio.project.lock`) and records the change, so :meth:`History.undo` and
:meth:`History.redo` walk the list of changes (saved like edits). An edit that raises, or changes nothing, records
nothing. The history lives as long as the ``Project`` object.
"""

from __future__ import annotations

import logging
from contextlib import AbstractContextManager
from dataclasses import dataclass
from datetime import datetime, timezone

from studio.project.lock import ProjectChanged, stamp
from studio.project.project_format import save_state
from studio.project.state import ProjectState, same

log = logging.getLogger(__name__)

MAX_UNDO = 200  # changes kept for undo


@dataclass(frozen=True)
class Change:
    """One recorded edit: the states before and after it."""

    label: str  # what the edit was ("move frame 5 to keyframe 0")
    before: ProjectState
    after: ProjectState


def now_text() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


class History:
    """Saving and undo of ``Project`` (it provides ``path``, ``_state``, ``_lock``, ``_writer`` (a
    :class:`~studio.project.lock.WriterLock`), ``_stamp``, ``_undo``, ``_redo`` and ``_check_sources``)."""

    def writing(self, what: str, wait: float = 0.0) -> AbstractContextManager[None]:
        """``with project.writing("project run"):`` hold the project's write lock for a whole run (the second
        writer is refused with who holds it, or waits up to ``wait`` s): :mod:`studio.project.lock`."""
        return self._writer.hold(what, wait)

    def _save(self, state: ProjectState) -> None:
        """Save ``state`` under the write lock, unless another process saved the project since this object read it
        (then :class:`~studio.project.lock.ProjectChanged`: nothing is saved, nothing of theirs is lost)."""
        with self._writer.for_save():
            if stamp(self.path) != self._stamp:
                raise ProjectChanged(
                    f"{self.path} was saved by another process since it was opened here; reopen it to see that work "
                    "(this change was not saved)"
                )
            save_state(self.path, state, now_text())
            self._stamp = stamp(self.path)

    def _commit(self, label: str, new: ProjectState) -> None:
        old = self._state
        if same(new, old):
            log.debug("%s: %s changes nothing", self.path, label)
            return
        self._save(new)
        self._state = new
        self._undo = (self._undo + [Change(label, old, new)])[-MAX_UNDO:]
        self._redo = []
        log.debug("%s: %s", self.path, label)

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    @property
    def history(self) -> list[str]:
        """Labels of the edits that :meth:`undo` would undo, oldest first."""
        return [c.label for c in self._undo]

    def undo(self) -> str | None:
        """Undo the last edit (saved like an edit); its label, or None when there is nothing to undo."""
        return self._walk(self._undo, self._redo, back=True)

    def redo(self) -> str | None:
        """Redo the last undone edit; its label, or None when there is nothing to redo."""
        return self._walk(self._redo, self._undo, back=False)

    def _walk(self, source: list[Change], target: list[Change], back: bool) -> str | None:
        """Move the last change of ``source`` to ``target``, saving the state before it (``back``) or after it."""
        with self._lock:
            if not source:
                return None
            change = source[-1]
            state = change.before if back else change.after
            self._save(state)
            target.append(source.pop())
            self._state = state
            if change.before.sources != change.after.sources:
                self._check_sources()
            return change.label
