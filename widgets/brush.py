"""A picture an artist paints on with a round brush: an ipycanvas ``Canvas`` whose mouse drags become strokes.

    brush = BrushCanvas(side=384, on_stroke=lambda points, radius, mode: ..., modes=("add", "erase"))
    brush.put(rgb)            # draw (side, side, 3) uint8
    brush.widget              # the canvas (or, without ipycanvas, an ipywidgets.Image: no painting)

A drag is drawn at once as dabs of the mode's colour (the first mode green, the second red) and handed to
``on_stroke(points [(x, y), ...] canvas px, radius canvas px, mode)`` on release; the owner applies it and redraws.
Used by the Masks panel (expressive paint) and the Targets panel (the object in raw footage's first frame).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import ipywidgets as w
import numpy as np

from widgets.images import ADD_RGB, ERASE_RGB, png

try:  # the brush needs ipycanvas (a dependency); the picture still shows without it
    import ipycanvas
except ImportError:  # pragma: no cover - depends on the environment
    ipycanvas = None

NO_CANVAS = "painting needs ipycanvas: pip install 'ipycanvas>=0.13' and restart the kernel"

Stroke = Callable[[Sequence[tuple[float, float]], float, str], None]  # (points canvas px, radius px, mode)


class BrushCanvas:
    """The paintable picture of the module doc; ``brush`` (size) and ``mode`` are its own widgets."""

    def __init__(self, side: int, on_stroke: Stroke, modes: tuple[str, str], size: int = 8, description="brush"):
        self.side = side  # canvas side, px
        self.on_stroke = on_stroke  # applies a finished drag
        self.modes = modes  # (the adding mode, the taking-away mode)
        self._points: list[tuple[float, float]] | None = None  # the drag in progress, canvas px
        self.size = w.IntSlider(value=size, min=1, max=60, description="brush px")
        self.mode = w.ToggleButtons(options=list(modes), value=modes[0], description=description)
        if ipycanvas is not None:
            self.canvas = ipycanvas.Canvas(width=side, height=side, layout=w.Layout(width=f"{side}px"))
            self.canvas.on_mouse_down(self.mouse_down)
            self.canvas.on_mouse_move(self.mouse_move)
            self.canvas.on_mouse_up(self.mouse_up)
            self.canvas.on_mouse_out(self.mouse_up)
            self.widget: w.Widget = self.canvas
            self.note = ""  # why painting is off ("" when it works)
        else:
            self.canvas, self.image = None, w.Image(format="png", width=side, height=side)
            self.widget, self.note = self.image, NO_CANVAS

    def put(self, rgb: np.ndarray) -> None:
        """Draw ``rgb`` ``(side, side, 3)`` uint8."""
        if self.canvas is not None:
            self.canvas.put_image_data(rgb, 0, 0)
        else:
            self.image.value = png(rgb)

    def mouse_down(self, x: float, y: float) -> None:
        """A drag starts at canvas ``(x, y)``."""
        self._points = [(x, y)]
        self._dab(x, y)

    def mouse_move(self, x: float, y: float) -> None:
        """The drag goes on through ``(x, y)`` (drawn at once, applied on release)."""
        if self._points is not None:
            self._points.append((x, y))
            self._dab(x, y)

    def mouse_up(self, x: float, y: float) -> None:
        """The drag ends: ``on_stroke`` gets it."""
        if self._points is None:
            return
        points, self._points = self._points + [(x, y)], None
        self.on_stroke(points, self.size.value, self.mode.value)

    def _dab(self, x: float, y: float) -> None:
        if self.canvas is not None:
            r, g, b = ADD_RGB if self.mode.value == self.modes[0] else ERASE_RGB
            self.canvas.fill_style = f"rgb({r}, {g}, {b})"
            self.canvas.fill_circle(x, y, self.size.value)
