"""What the Rig panel draws: the camera's photograph with the backdrop's window on it, the clicked corners, the
rectified shadow, and the calibration's progress and outcome in the artist's words.

:func:`photo_picture` scales a photograph to the panel's width and draws the window the homography puts on it
(:data:`OUTLINE_RGB`) or the corners clicked so far (:data:`CORNER_RGB` dots and polygon); :func:`mask_picture`
shows the window's rectified shadow as the studio shows shadows (dark on a light backdrop). :class:`CornerPicker`
holds the picture twice: an ``ipywidgets.Image`` (the PNG a test reads) and an ipycanvas ``Canvas`` that takes the
artist's clicks; one or the other is on show. :class:`WindowView` puts them together: a frame, its window from the
markers or from four clicked corners (the fallback where the markers are not found), and the window's shadow.
:func:`progress_line` and :func:`summary_lines` say how a calibration goes and what it found.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import ipywidgets as w
import numpy as np

from studio.errors import Progress
from studio.review.sheets import shadow_tile
from studio.sim.backdrop import window_corners_m
from studio.targets.backdrop import BackdropNotFound, backdrop_from_corners, binarise, find_backdrop, rectify
from widgets.images import Messages, png, shown_when_drawn

try:  # clicking needs ipycanvas (a dependency); the picture still shows without it
    import ipycanvas
except ImportError:  # pragma: no cover - depends on the environment
    ipycanvas = None

OUTLINE_RGB = (0, 210, 255)  # the window the backdrop's markers (or the corners) put on the photograph
CORNER_RGB = (255, 0, 200)  # clicked corners: dots, and the polygon through them
CORNERS = ("top-left", "top-right", "bottom-right", "bottom-left")  # the click order, as the audience sees it
NO_CANVAS = "clicking corners needs ipycanvas: pip install 'ipycanvas>=0.13' and restart the kernel"


def window_in_photo(H_backdrop_camera: np.ndarray, window_m: float) -> np.ndarray:
    """The window's corners ``(4, 2)`` in camera pixels (TL, TR, BR, BL as the audience sees the backdrop)."""
    p = np.column_stack([window_corners_m(window_m), np.ones(4)]) @ np.linalg.inv(H_backdrop_camera).T
    return p[:, :2] / p[:, 2:]


def photo_picture(
    photo: np.ndarray, width: int, outline: np.ndarray | None = None, corners: np.ndarray | None = None
) -> np.ndarray:
    """A BGR photograph ``(H, W, 3)`` → RGB ``(h, width, 3)`` uint8 with ``outline (4, 2)`` camera px drawn as a
    closed polygon and ``corners (k, 2)`` camera px as dots joined in order (closed once there are four)."""
    h, wd = photo.shape[:2]
    scale = width / wd
    size = (width, max(1, round(h * scale)))
    rgb = cv2.cvtColor(cv2.resize(photo, size, interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)

    def px(points: np.ndarray) -> np.ndarray:
        return np.round((np.asarray(points, np.float64) + 0.5) * scale - 0.5).astype(np.int32).reshape(-1, 1, 2)

    if outline is not None:  # LINE_8: the colour stays exact (no blending), so a picture test can find it
        cv2.polylines(rgb, [px(outline)], True, OUTLINE_RGB, 2, cv2.LINE_8)
    if corners is not None and len(corners):
        pts = px(corners)
        cv2.polylines(rgb, [pts], len(pts) == 4, CORNER_RGB, 1, cv2.LINE_8)
        for x, y in pts[:, 0]:
            cv2.circle(rgb, (int(x), int(y)), 4, CORNER_RGB, -1, cv2.LINE_8)
    return rgb


def window_mask(photo: np.ndarray, H_backdrop_camera: np.ndarray, window_m: float, resolution: int) -> np.ndarray:
    """The window's shadow in ``photo``: ``(R, R)`` uint8, 1 = shadow (rectified, light divided out, thresholded)."""
    return binarise(rectify(photo, H_backdrop_camera, window_m, resolution))


def mask_picture(mask: np.ndarray, side: int) -> bytes:
    """PNG of a window mask ``(R, R)`` (1 = shadow) as the studio shows shadows: dark on the light backdrop."""
    return png(shadow_tile(mask, side))


class CornerPicker:
    """The photograph, shown as an ``Image`` (``clicking`` off) or as a clickable ``Canvas`` (``clicking`` on).

    ``on_corners(corners (k, 2) camera px)`` hears every click; a fifth click starts a new set. ``width``: the
    picture's width on screen, px (the photograph is scaled to it; clicks are scaled back)."""

    def __init__(self, width: int, on_corners: Callable[[np.ndarray], None]):
        self.width = width  # px on screen
        self.on_corners = on_corners
        self.corners: list[tuple[float, float]] = []  # clicked so far, camera px, in CORNERS order
        self.scale = 1.0  # camera px per screen px of the photograph on show
        self.image = shown_when_drawn(w.Image(format="png", layout=w.Layout(width=f"{width}px")))
        self.canvas = None
        self.note = NO_CANVAS if ipycanvas is None else ""  # why clicking is off ("" when it works)
        if ipycanvas is not None:
            self.canvas = ipycanvas.Canvas(width=width, height=width * 3 // 4, layout=w.Layout(width=f"{width}px"))
            self.canvas.on_mouse_down(self.click)
        self.widget = w.Box([self.image])
        self.clicking = False

    @property
    def clicking(self) -> bool:
        """Whether the clickable canvas is on show (else the plain image)."""
        return self._clicking

    @clicking.setter
    def clicking(self, on: bool) -> None:
        self._clicking = bool(on) and self.canvas is not None
        self.widget.children = [self.canvas if self._clicking else self.image]

    def put(self, rgb: np.ndarray, photo_width: int) -> None:
        """Show ``rgb (h, width, 3)`` uint8, a photograph ``photo_width`` camera px wide."""
        self.scale = photo_width / rgb.shape[1]
        self.image.value = png(rgb)
        if self.canvas is not None:
            if (self.canvas.width, self.canvas.height) != (rgb.shape[1], rgb.shape[0]):
                self.canvas.width, self.canvas.height = rgb.shape[1], rgb.shape[0]
            self.canvas.put_image_data(rgb, 0, 0)

    def next_corner(self) -> str:
        """The corner the next click sets (the first again after four)."""
        return CORNERS[len(self.corners) % 4]

    def click(self, x: float, y: float) -> None:
        """A click at screen ``(x, y)`` px on the picture: the next corner (a fifth click starts over)."""
        if len(self.corners) == 4:
            self.corners = []
        self.corners.append(((x + 0.5) * self.scale - 0.5, (y + 0.5) * self.scale - 0.5))
        self.on_corners(np.array(self.corners))

    def clear(self) -> None:
        """Forget the clicked corners."""
        self.corners = []


class WindowView:
    """The frame on show with the shadow window on it, found from the markers (mode "markers") or from four clicked
    corners (mode "click"), and the window's rectified shadow beside it. Where the markers are not found it says
    why (in ``messages``) and turns to clicking. ``H`` is the window's homography (None: not known)."""

    def __init__(self, messages: Messages, window_m: float, resolution: int, photo_px: int = 480, mask_px: int = 240):
        self.messages = messages  # where it says what it found
        self.window_m, self.resolution, self.photo_px, self.mask_px = window_m, resolution, photo_px, mask_px
        self.photo: np.ndarray | None = None  # the frame on show, (H, W, 3) uint8 BGR
        self.H: np.ndarray | None = None  # (3, 3) camera px → backdrop m of that frame
        self._quiet = False  # set while locate() itself turns the mode to clicking
        self.mode = w.ToggleButtons(options=[("markers", "markers"), ("click corners", "click")], value="markers",
                                    description="window")  # fmt: skip
        self.clear_button = w.Button(description="clear corners")
        self.picker = CornerPicker(photo_px, lambda _: messages.run(self.locate))
        self.mask = shown_when_drawn(w.Image(format="png", layout=w.Layout(width=f"{mask_px}px")))
        self.mode.observe(lambda _: messages.run(self._mode_changed), "value")
        self.clear_button.on_click(lambda _: messages.run(self._clear))
        note = w.HTML(f"<i>{self.picker.note}</i>" if self.picker.note else "")
        self.widget = w.VBox([w.HBox([self.mode, self.clear_button]), w.HBox([self.picker.widget, self.mask]), note])

    @property
    def clicking(self) -> bool:
        """Whether the window comes from clicked corners."""
        return self.mode.value == "click"

    def show(self, photo: np.ndarray) -> None:
        """Show a new frame ``(H, W, 3)`` uint8 BGR (clicked corners are forgotten) and find its window."""
        self.photo = np.array(photo)
        self.picker.clear()
        self.locate(fallback=True)

    def locate(self, fallback: bool = False) -> None:
        """The window in the frame on show, from the four clicked corners or the markers; then draw both pictures.
        ``fallback``: markers not found turn the mode to clicking."""
        self.H = None
        if self.photo is None:
            raise ValueError("press 'Show camera' first")
        corners = np.array(self.picker.corners)
        if self.clicking and len(corners) == 4:
            self.H = backdrop_from_corners(corners, self.window_m)
            self.messages.say("the window is where you clicked: the shadow beside it is rectified from there")
        elif self.clicking:
            self.messages.say(f"click the window's {self.picker.next_corner()} corner as the audience sees the "
                              f"backdrop ({len(corners) + 1} of 4)")  # fmt: skip
        else:
            try:
                self.H = find_backdrop(self.photo)
                self.messages.say("backdrop found: the window is outlined on the photograph")
            except BackdropNotFound as e:  # the fallback: the artist clicks the corners
                self._quiet = fallback
                try:
                    self.mode.value = "click" if fallback else self.mode.value
                finally:
                    self._quiet = False
                self.picker.clicking = self.clicking
                self.messages.say(str(e), error=True)
        outline = window_in_photo(self.H, self.window_m) if self.H is not None and not self.clicking else None
        picture = photo_picture(self.photo, self.photo_px, outline, corners if self.clicking else None)
        self.picker.put(picture, self.photo.shape[1])
        if self.H is None:
            self.mask.value = b""
        else:
            self.mask.value = mask_picture(window_mask(self.photo, self.H, self.window_m, self.resolution),
                                           self.mask_px)  # fmt: skip

    def _mode_changed(self) -> None:
        if self._quiet:
            return
        self.picker.clicking = self.clicking
        if self.photo is not None:
            self.locate()

    def _clear(self) -> None:
        self.picker.clear()
        if self.photo is not None:
            self.locate()


def progress_line(p: Progress) -> str:
    """A calibration's progress event in words."""
    if p.stage == "capture":
        return f"photographed pose {p.step} of {p.total}"
    return f"fitting the rig: {p.step} of {p.total} tries" if p.total else f"{p.stage}…"


def loss_line(before: float, after: float) -> str:
    """The fit's outcome in words: the window IoU loss against the camera's shadows, before → after."""
    change = f"loss {before:.3f} → {after:.3f}"
    if after < before and after <= 0.05:
        return f"the rig's shadows now match the camera's: {change}"
    if after < before:
        return f"the rig's shadows are closer to the camera's, not yet a match: {change} (see the sheet below)"
    return f"no rig matched the camera's shadows better than the one it started from: {change}"


def summary_lines(summary: dict) -> list[str]:
    """What :func:`studio.project.rig_calibration.calibrate_rig` measured, one fact a line."""
    x, y, z = (1000 * float(v) for v in summary["hand_offset_m"])
    return [
        loss_line(float(summary["iou_loss_before"]), float(summary["iou_loss_after"])),
        f"light distance {summary['light_distance_m']:.3f} m (from the hand's mount to the light)",
        f"backdrop distance {summary['backdrop_distance_m']:.3f} m (behind the mount)",
        f"hand offset x {x:+.1f} mm, y {y:+.1f} mm, z {z:+.1f} mm (from its nominal place)",
        f"mount roll {summary['mount_roll_deg']:.2f}° (about the light axis)",
        f"foam {summary['foam_mm']:+.2f} mm (thicker than the model's shell)",
        f"{summary['poses']} poses photographed and fitted in {summary['seconds']:.0f} s",
    ]
