"""Sculpt by hand, in the Jog tab: the shadow of the pose the sliders command (and of the pose the servos report,
when connected) beside the selected frame's target, with its loss, and "save as keyframe".

A thin face of :mod:`studio.project.sculpt`: the panel tells it the commanded pose (``(21,)`` rad, the hand's joint
order) after every slider move and the measured one after every read-back; the pictures are drawn in the view's own
thread (:class:`widgets.images.Throttle`, at most :data:`MAX_HZ` times a second, the latest poses last), never the
caller's: the first draw loads the losses' code (torch) and compiles the renderer's kernels, seconds the studio does not
wait for when it opens, and a slider's handler never holds the notebook for a render. Without servos the sliders
shape the shadow alone, so an artist can sculpt a shadow at the desk and keep it.
"""

from __future__ import annotations

import html
import logging

import ipywidgets as W
import numpy as np

from studio.errors import StudioError
from studio.project.sculpt import Sculptor, keep_pose, keyframe_at
from studio.sim.hand import Hand
from widgets.images import Messages, Throttle, frame_in_view, frame_picture, mask_picture
from widgets.state import StudioState

log = logging.getLogger(__name__)

PX = 160  # side of each picture, px
MAX_HZ = 10.0  # redraws per second at most (a read-back thread may call faster)


class SculptView:
    """``widget``: target | commanded shadow | measured shadow, the loss line and "save as keyframe"."""

    def __init__(self, state: StudioState, hand: Hand):
        self.state = state
        self.hand = hand
        self.sculptor = Sculptor(hand)
        self.messages = Messages()
        self.commanded: np.ndarray = hand.rest_pose()  # (21,) rad, what the sliders say
        self.measured: np.ndarray | None = None  # (21,) rad, the last read-back (None: not connected)
        self.commanded_shadow: np.ndarray | None = None  # (S, S) uint8 shown under "commanded"
        self.measured_shadow: np.ndarray | None = None
        self.drawer = Throttle(lambda: self.messages.run(self._draw, clear=False), hz=MAX_HZ)  # draws, in its thread
        blank = mask_picture(None, PX)  # until the first draw lands (an empty image is a broken-picture icon)
        self.target_image = frame_picture(PX, blank)
        self.commanded_image = frame_picture(PX, blank)
        self.measured_image = frame_picture(PX, blank)
        self.caption = W.HTML("<i>drawing the shadow of the sliders' pose…</i>")
        tip = "this pose becomes the result of the keyframe at the frame in view"
        self.save_button = W.Button(description="save as keyframe", icon="save", tooltip=tip)
        self.save_button.on_click(lambda _: self.messages.run(self.save))
        pictures = [("target", self.target_image), ("commanded", self.commanded_image),
                    ("measured", self.measured_image)]  # fmt: skip
        self.widget = W.VBox([
            W.HBox([W.VBox([W.HTML(f"<b>{label}</b>"), image]) for label, image in pictures]),
            self.caption, self.save_button, self.messages.widget,
        ])  # fmt: skip
        self.redraw()

    def command(self, theta: np.ndarray) -> None:
        """The sliders now command ``theta (21,)`` rad: redraw its shadow."""
        self.commanded = np.asarray(theta, np.float64).copy()
        self.redraw()

    def measure(self, theta: np.ndarray | None) -> None:
        """The servos report ``theta (21,)`` rad (NaN where one did not answer; None: disconnected)."""
        self.measured = None if theta is None else np.asarray(theta, np.float64).copy()
        self.redraw()

    def redraw(self) -> None:
        """Target, both shadows and the loss of the commanded pose against the frame in view, drawn soon in the view's
        thread (``drawer.settle()`` waits for it)."""
        self.drawer()

    def _draw(self) -> None:
        project = self.state.project
        if not project.frames:
            self.caption.value = "no frames yet: add a source in Targets"
            return
        frame = frame_in_view(self.state)
        self.target_image.value = mask_picture(np.asarray(project.state.targets[frame]), PX)
        scored = self.sculptor.score(project, frame, self.commanded)
        self.commanded_shadow = scored.shadow
        self.commanded_image.value = mask_picture(scored.shadow, PX)
        known = self.measured is not None and np.isfinite(self.measured).all()
        self.measured_shadow = self.sculptor.shadow(project, self.measured) if known else None
        self.measured_image.value = mask_picture(self.measured_shadow, PX)
        k = keyframe_at(project, frame)
        where = f"keyframe {k}'s frame" if k is not None else "a frame that becomes a keyframe when saved"
        collides = "" if scored.collision_free else "; <b style='color:#b00020'>the pose collides with itself</b>"
        self.caption.value = (
            f"frame {frame} ({html.escape(where)}): loss {scored.loss['total']:.4f} "
            f"(IoU loss {scored.loss['iou_loss']:.3f}){collides}"
        )

    def save(self) -> int | None:
        """The commanded pose becomes the result of the keyframe at the frame in view (made one if needed)."""
        project = self.state.project
        if not project.frames:
            raise StudioError("no frames yet: add a source in Targets first")
        frame = frame_in_view(self.state)
        scored = self.sculptor.score(project, frame, self.commanded)
        k = keep_pose(project, frame, scored)
        self.state.changed("project")
        self.messages.say(f"saved as keyframe {k} (loss {scored.loss['total']:.4f}); undo in Keyframes")
        self.redraw()
        return k

    def close(self) -> None:
        """Stop drawing (a draw in progress ends first) and release the collision world."""
        self.drawer.close(wait_s=5.0)
        self.sculptor.close()
