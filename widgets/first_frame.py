"""The object in raw colour footage's first frame, as the Targets panel takes it: a box typed in source pixels, or a
mask painted with a brush on the frame (an ipycanvas ``Canvas``), either one given to segmentation.

    first = FirstFrame(side=256)
    first.show(rgb)                                   # the footage's first frame (H, W, 3); box = its middle
    first.given.value = "mask"
    first.stroke([(40, 40), (90, 60)], radius=10)     # what a mouse drag does, in canvas pixels
    first.prompt()                                    # {"first_mask": (H, W) uint8} or {"box": (x, y, w, h)}

The picture is the frame squared (its longer side fills the canvas, from the top left, as the box's pixels are
counted) with the box drawn (mode "box") or the painted mask tinted over it (mode "mask"), on a
:class:`~widgets.brush.BrushCanvas` (without ipycanvas, no mouse painting; :meth:`FirstFrame.stroke` still works).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import ipywidgets as w
import numpy as np

from studio.project.state import ProjectError
from studio.targets.images import crop_square
from widgets.brush import BrushCanvas
from widgets.images import ADD_RGB, MASK_RGB, stroke_mask, tint

GIVEN = ("box", "mask")  # how the object is given: a box or a painted mask
BRUSH_MODES = ("paint", "erase")  # the brush adds to the mask or takes away from it


class FirstFrame:
    """The first-frame box or painted mask (module doc); ``.widget`` is what the Targets panel shows while raw
    footage waits for it."""

    def __init__(self, side: int, on_change=None):
        self.side = side  # canvas side, px
        self.on_change = on_change  # called after the picture changed (the panel mirrors it)
        self.frame: np.ndarray | None = None  # (H, W, 3) uint8: the first frame
        self.mask: np.ndarray | None = None  # (H, W) uint8 {0, 1}: the painted mask, source pixels
        self.picture_rgb: np.ndarray | None = None  # (side, side, 3) uint8: what the picture shows now

        self.given = w.ToggleButtons(options=list(GIVEN), value="box", description="object as")
        self.box = [w.IntText(description=n, layout=w.Layout(width="140px")) for n in ("x", "y", "w", "h")]
        self.paint = BrushCanvas(side, self.stroke, BRUSH_MODES, size=10)  # the picture, painted on
        self.brush, self.mode, self.canvas = self.paint.size, self.paint.mode, self.paint.canvas
        self.clear = w.Button(description="Clear mask", icon="eraser")
        note = "type the box in source pixels, or choose mask and paint the object on the frame"
        if self.paint.note:
            note = f"type the box in source pixels ({self.paint.note})"
        for t in self.box:
            t.observe(lambda _: self.redraw(), names="value")
        self.given.observe(lambda _: self.redraw(), names="value")
        self.clear.on_click(lambda _: self.clear_mask())
        self.widget = w.VBox([
            self.paint.widget,
            w.HTML(f"<i>raw colour footage: {note}</i>"),
            self.given,
            w.HBox(self.box),
            w.HBox([self.mode, self.brush, self.clear]),
        ])  # fmt: skip

    @property
    def scale(self) -> float:
        """Canvas px per source px."""
        return self.side / max(self.frame.shape[:2])

    def show(self, rgb: np.ndarray) -> None:
        """A new first frame ``(H, W, 3)`` uint8: the box guessed as its middle, no mask painted."""
        self.frame = np.asarray(rgb, np.uint8)
        h, wd = self.frame.shape[:2]
        self.mask = np.zeros((h, wd), np.uint8)
        with self.given.hold_trait_notifications():
            self.given.value = "box"
        for t, v in zip(self.box, (wd // 4, h // 4, wd // 2, h // 2), strict=True):
            t.value = v
        self.redraw()

    def picture(self) -> np.ndarray:
        """The frame squared with the box or the painted mask over it, ``(side, side, 3)`` uint8 (module doc)."""
        h, wd = self.frame.shape[:2]
        big = max(h, wd)
        square = np.clip(crop_square(self.frame, (0, 0, big, big), self.side), 0, 255).astype(np.uint8)
        if self.given.value == "mask":
            m = crop_square(self.mask.astype(np.float32), (0, 0, big, big), self.side) >= 0.5
            return tint(square, m.astype(np.uint8), ADD_RGB, 0.55)
        x, y, bw, bh = (int(t.value) for t in self.box)
        s = self.scale
        p0, p1 = (round(x * s), round(y * s)), (round((x + bw) * s) - 1, round((y + bh) * s) - 1)
        cv2.rectangle(square, p0, p1, MASK_RGB, 2)
        return square

    def redraw(self) -> None:
        """Draw the picture as it is now."""
        if self.frame is None:
            return
        self.picture_rgb = self.picture()
        self.paint.put(self.picture_rgb)
        if self.on_change is not None:
            self.on_change(self.picture_rgb)

    def stroke(self, points: Sequence[tuple[float, float]], radius: float, mode: str = "paint") -> None:
        """Paint (or erase, ``mode``) the mask along ``points`` (canvas px) with a round brush of ``radius`` canvas
        px; the mask becomes what is given."""
        if mode not in BRUSH_MODES:
            raise ProjectError(f"the brush paints or erases, not {mode!r}")
        if self.frame is None or not points:
            return
        m = stroke_mask(points, radius, 1.0 / self.scale, self.mask.shape)
        self.mask = self.mask | m if mode == "paint" else self.mask & (1 - m)
        with self.given.hold_trait_notifications():
            self.given.value = "mask"
        self.redraw()

    def clear_mask(self) -> None:
        """Take the painted mask away."""
        if self.mask is not None:
            self.mask[:] = 0
            self.redraw()

    def prompt(self) -> dict:
        """What segmentation is given: ``{"box": (x, y, w, h)}`` or ``{"first_mask": (H, W) uint8}``; a
        :class:`ProjectError` saying what to do when it is empty."""
        if self.given.value == "mask":
            if self.mask is None or not self.mask.any():
                raise ProjectError("paint the object on the first frame first (or give it as a box)")
            return {"first_mask": self.mask.copy()}
        box = tuple(int(t.value) for t in self.box)
        if box[2] <= 0 or box[3] <= 0:
            raise ProjectError(f"the first-frame box needs a width and a height above 0, not {box[2]} × {box[3]}")
        return {"box": box}
