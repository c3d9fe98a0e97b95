"""The state every panel shares: one project, its job queue, the current selection, and change notifications.

Widgets are thin (DESIGN §5.7): the project (``studio.project.Project``) holds the artist's work and every edit goes
through its API; panels read it, call it, and re-draw when :meth:`StudioState.changed` fires. Long work runs as jobs
on the project's queue; panels listen to its events. Nothing here draws anything, so tests drive it without a
browser.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from studio.jobs import JobQueue
from studio.project.jobs import queue_for
from studio.project.project import Project

log = logging.getLogger(__name__)

Listener = Callable[[str], None]  # called with what changed: "project", "selection", "jobs", "hardware"


@dataclass
class Selection:
    """What the artist is looking at."""

    frame: int = 0  # index into project.frames (the scrubber's position)
    keyframe: int | None = None  # a keyframe id of project.keyframes (None: the frame's own keyframe)


@dataclass
class StudioState:
    """One open project and everything the panels share about it."""

    project: Project  # the artist's work: every edit goes through its methods (saved atomically, undoable)
    queue: JobQueue  # the project's background jobs (one at a time, FIFO)
    selection: Selection = field(default_factory=Selection)  # the frame and keyframe in view
    extras: dict[str, Any] = field(default_factory=dict)  # panel-to-panel handles (e.g. the jog panel's session)
    _listeners: list[Listener] = field(default_factory=list, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @classmethod
    def open(cls, path: str | Path) -> StudioState:
        """Open the project folder ``NAME.shadow`` and its job queue (thread worker)."""
        project = Project.open(path)
        return cls(project, queue_for(project))

    def on_change(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener(what)`` after every change; returns a function that stops it."""
        with self._lock:
            self._listeners.append(listener)

        def stop() -> None:
            with self._lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)

        return stop

    def changed(self, what: str = "project") -> None:
        """Tell every listener that ``what`` changed (a listener that raises is logged, never breaks the others)."""
        with self._lock:
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener(what)
            except Exception:  # a broken panel must not freeze the studio
                log.exception("a panel failed to redraw after %s changed", what)

    def edit(self, method: str, *args: Any, **kwargs: Any) -> Any:
        """Call ``project.<method>(...)`` (an edit: saved, undoable), then notify; returns what it returned."""
        result = getattr(self.project, method)(*args, **kwargs)
        self.changed("project")
        return result

    def select(self, frame: int | None = None, keyframe: int | None = None) -> None:
        """Move the selection (clamped to the project's frames) and notify; a selection that changes nothing notifies
        no one (a panel's own slider, set to the frame selected, calls back with it)."""
        before = (self.selection.frame, self.selection.keyframe)
        if frame is not None:
            n = len(self.project.frames)
            self.selection.frame = max(0, min(int(frame), n - 1)) if n else 0
        self.selection.keyframe = keyframe
        if (self.selection.frame, self.selection.keyframe) != before:
            self.changed("selection")

    def undo(self) -> bool:
        """Undo the last edit if there is one; returns whether anything changed."""
        if not self.project.can_undo:
            return False
        self.project.undo()
        self.changed("project")
        return True

    def redo(self) -> bool:
        """Redo the last undone edit if there is one; returns whether anything changed."""
        if not self.project.can_redo:
            return False
        self.project.redo()
        self.changed("project")
        return True

    def close(self) -> None:
        """Cancel and stop the job queue (the project itself is always saved)."""
        self.queue.close()
