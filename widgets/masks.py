"""The Masks panel: a frame picker (:mod:`widgets.frame_picker`: a frame picked here is selected in every tab),
the selected frame's target with its expressive mask drawn over it (automatic in orange, painted additions green,
erasures red), and a brush on an ipycanvas ``Canvas`` to paint additions and erasures: brush size, mode add / erase,
clear, undo. Each stroke is rasterised into the project's square frame ``(S, S)`` and saved with
``project.paint(frame, additions=..., erasures=...)`` (the separate PNGs of DESIGN §4), one undoable edit per stroke.

    panel = MasksPanel(state)
    panel.stroke([(10, 10), (60, 40)], radius=6, mode="add")    # what a mouse drag does, in canvas pixels

Without ipycanvas installed the picture is an ``ipywidgets.Image`` (no mouse painting; :meth:`MasksPanel.stroke`
still works, and the panel says how to get the brush).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import ipywidgets as w
import numpy as np

from studio.project.state import ProjectError
from widgets.brush import BrushCanvas
from widgets.frame_picker import frame_picker
from widgets.images import (
    ADD_RGB,
    ERASE_RGB,
    FRAME_EDGE,
    MASK_RGB,
    Messages,
    frame_in_view,
    grey_rgb,
    legend,
    stroke_mask,
    tint,
    title,
    upscale,
)
from widgets.state import StudioState

log = logging.getLogger(__name__)

CANVAS_PX = 384  # side of the drawing canvas, px (the project's S × S frame is scaled to it)
MODES = ("add", "erase")  # brush modes: paint additions or erasures


class MasksPanel:
    """The Masks panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState, side: int = CANVAS_PX):
        self.state = state
        self.side = side  # canvas side, px
        self.messages = Messages()
        self.paint = BrushCanvas(side, self._stroked, MODES, description="mode")  # the picture, painted on
        self.brush, self.mode, self.canvas = self.paint.size, self.paint.mode, self.paint.canvas
        self.mouse_down, self.mouse_move, self.mouse_up = (
            self.paint.mouse_down,
            self.paint.mouse_move,
            self.paint.mouse_up,
        )
        self.clear = w.Button(description="Clear paint", icon="eraser")
        self.undo = w.Button(description="Undo", icon="undo")
        self.info = w.Label()
        self.frame_picker, stop_picker = frame_picker(state)  # selects the frame in view in every tab
        picture, note = self.paint.widget, self.paint.note
        self.clear.on_click(lambda _: self.messages.run(self._clear))
        self.undo.on_click(lambda _: self.messages.run(self.state.undo))
        keys = [(MASK_RGB, "expressive region (the Exp. terms weigh it)"), (ADD_RGB, "painted in"),
                (ERASE_RGB, "painted out")]  # fmt: skip
        self.legend = legend(keys, then="drag on the frame to paint in the mode chosen")
        framed = w.Box([picture], layout={"border": FRAME_EDGE, "width": "fit-content"})  # the frame's edge
        self.widget = w.VBox([
            title("Masks"),
            self.frame_picker,
            framed,
            self.legend,
            w.HBox([self.mode, self.brush]),
            w.HBox([self.clear, self.undo, self.info]),
            w.HTML(f"<i>{note}</i>" if note else ""),
            self.messages.widget,
        ])  # fmt: skip
        self._stops = [stop_picker, state.on_change(self._changed)]
        self.redraw()

    def close(self) -> None:
        """Stop following the state (the widget stays as it is)."""
        for stop in self._stops:
            stop()

    # ---------------------------------------------------------------- the picture
    @property
    def frame(self) -> int:
        return frame_in_view(self.state)

    def picture(self) -> np.ndarray:
        """The selected frame's target with its expressive mask and paint over it, ``(side, side, 3)`` uint8."""
        s = self.state.project.state
        f = self.frame
        key = s.frames[f].key
        rgb = tint(grey_rgb(s.targets[f]), self.state.project.combined_mask(f), MASK_RGB, 0.5)
        if key in s.additions:
            rgb = tint(rgb, s.additions[key], ADD_RGB, 0.6)
        if key in s.erasures:
            rgb = tint(rgb, s.erasures[key], ERASE_RGB, 0.6)
        return upscale(rgb, self.side)

    def _changed(self, what: str) -> None:
        if what in ("project", "selection"):
            self.redraw()

    def redraw(self) -> None:
        """Draw the selected frame as the project has it now."""
        p = self.state.project
        if not p.frames:
            return
        key = p.frames[self.frame].key
        painted = [n for n, layer in (("additions", p.state.additions), ("erasures", p.state.erasures)) if key in layer]
        self.info.value = f"frame {self.frame}" + (f" (painted: {', '.join(painted)})" if painted else "")
        self.undo.disabled = not p.can_undo
        self.paint.put(self.picture())

    # ---------------------------------------------------------------- painting
    def rasterise(self, points: Sequence[tuple[float, float]], radius: float) -> np.ndarray:
        """A stroke through ``points`` (canvas px) with a round brush of ``radius`` (canvas px) as ``(S, S)`` uint8
        {0, 1} in the project's square frame."""
        size = self.state.project.state.auto.shape[-1]
        return stroke_mask(points, radius, size / self.side, (size, size))

    def stroke(self, points: Sequence[tuple[float, float]], radius: float, mode: str = "add") -> None:
        """Paint one stroke through ``points`` ``[(x, y), ...]`` (canvas px, origin top left) with a round brush of
        ``radius`` canvas px: ``mode`` "add" paints additions (and takes back erasures there), "erase" the
        reverse. Saved as one undoable ``project.paint`` edit."""
        if mode not in MODES:
            raise ProjectError(f"the brush mode is 'add' or 'erase', not {mode!r}")
        if not points:
            return
        s = self.state.project.state
        key = s.frames[self.frame].key
        blank = np.zeros(s.auto.shape[1:], np.uint8)
        add = np.array(s.additions.get(key, blank), np.uint8)
        erase = np.array(s.erasures.get(key, blank), np.uint8)
        m = self.rasterise(points, radius)
        if mode == "add":
            add, erase = add | m, erase & (1 - m)
        else:
            add, erase = add & (1 - m), erase | m
        self.state.edit("paint", self.frame, additions=add, erasures=erase)

    def _clear(self) -> None:
        self.state.edit("clear_paint", self.frame)

    def _stroked(self, points: Sequence[tuple[float, float]], radius: float, mode: str) -> None:
        """A drag ended on the canvas: saved as a stroke (an error shows in the panel)."""
        self.messages.run(self.stroke, points, radius, mode)


def masks_panel(state: StudioState) -> w.Widget:
    """The Masks panel's widget (module doc)."""
    return MasksPanel(state).widget
