"""The relink control of the Targets panel: a source that moved is told where it is now.

Shown only while the project has a missing source. The artist picks the missing source, types where it is now and
presses Relink (:meth:`Project.relink_source`): the same content keeps every frame, keyframe and result; other
content is read again, as if the source had been re-added.
"""

from __future__ import annotations

import html
from collections.abc import Callable
from pathlib import Path
from typing import Any

import ipywidgets as w

from widgets.state import StudioState


def missing_line(project) -> str:
    """HTML: the missing sources, each with where it was (escaped: a shared project's paths are not markup)."""
    rows = [f"source {m.index} is missing: it was at <code>{html.escape(m.absolute)}</code>"
            for m in project.missing_sources]  # fmt: skip
    return "<br>".join(rows)


class RelinkControl:
    """``widget``: the missing sources, a path box and a Relink button (hidden while nothing is missing)."""

    def __init__(self, state: StudioState, messages, relink: Callable[[int, Path], Any]):
        self.state = state
        self.messages = messages  # widgets.images.Messages of the panel
        self._relink = relink  # relink(source, where): the panel runs the edit (a job: the source is read again)
        self.which = w.Dropdown(description="source", layout=w.Layout(width="160px"))
        self.path = w.Text(placeholder="where that source is now", description="now at")
        self.button = w.Button(description="Relink", icon="link", tooltip="same content keeps every result")
        self.line = w.HTML("")
        self.button.on_click(lambda _: self.messages.run(self.relink))
        self.widget = w.VBox([self.line, w.HBox([self.which, self.path, self.button])])
        self.refresh()

    def refresh(self) -> None:
        """Show or hide the control as the project's sources stand now."""
        p = self.state.project
        missing = [m.index for m in p.missing_sources]
        if list(self.which.options) != [(f"source {i}", i) for i in missing]:
            self.which.options = [(f"source {i}", i) for i in missing]
            self.which.value = missing[0] if missing else None
        self.line.value = missing_line(p)
        self.widget.layout.display = "" if missing else "none"

    def relink(self) -> None:
        """Relink the chosen source to the typed path (an error is said in the panel, nothing changes)."""
        if self.which.value is None:
            return
        where = Path(self.path.value.strip()).expanduser()
        if not where.exists():  # said at once; the rest (the source read again) is the panel's job
            raise FileNotFoundError(f"source not found: {where}")
        self._relink(int(self.which.value), where)
