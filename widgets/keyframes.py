"""The Keyframes panel: a τ slider whose cluster count updates live (computed, the project untouched until "Apply τ"
re-clusters it; it follows the project after an undo, a redo or another panel's edit; the count at any τ, and the
keyframes "Apply τ" makes, come at once from the clustering's merge orders that the project keeps,
:meth:`~studio.project.project.Project.merge_orders`, worked out again in the panel's own thread only when what the
clustering reads changes: targets, expressive masks, paint), a strip of the clusters
(representative framed in the colour of its result's status, member count, time range, status and loss), and the
keyframe edits: add
one at the scrubber's frame, remove one, move the frame to another cluster, a keyframe's show time and hold flag,
undo and redo. Every edit goes through :meth:`StudioState.edit` (saved, undoable).

    panel = KeyframesPanel(state)     # panel.widget goes in the notebook; tests set values and .click() buttons
"""

from __future__ import annotations

import html
import logging
import threading

import ipywidgets as w
import numpy as np

from studio.errors import count
from studio.project.edits import combined_masks
from studio.project.state import AWAITS, Keyframe
from studio.project.status import ProjectStatus
from studio.review.preview_strips import STATUS_RGB  # a result's status: the Review strip's colours
from widgets.images import (
    MASK_RGB,
    Messages,
    Throttle,
    frame_in_view,
    grey_rgb,
    legend,
    png,
    tint,
    title,
    upscale,
)
from widgets.state import StudioState
from widgets.words import loss, seconds, span

log = logging.getLogger(__name__)

CARD_PX = 96  # side of a cluster's picture in the strip, px
FRAME_PX = 5  # width of the status frame drawn around a card's picture, px
TIME_STEP_S = 0.001  # keyframe times are kept to the millisecond (a browser's spinner adds 0.1 in binary)


class KeyframesPanel:
    """The Keyframes panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState):
        self.state = state
        self.messages = Messages()
        self._masks_of: object = None  # the project state the cached masks were combined from
        self._masks: np.ndarray | None = None  # (N, S, S) the expressive masks the artist sees
        self._count_lock = threading.Lock()  # the count is shown by the kernel's thread and the counting thread
        self.counter = Throttle(lambda: self.messages.run(self._recount, clear=False), hz=5.0)  # merge orders, aside
        self._drawing = False  # True while redraw() sets values (their observers must not edit)
        self.live_count = 0  # keyframes at the slider's τ (computed; the project is not edited)
        self._tau_seen: float | None = None  # the project's τ the slider last followed

        self.tau = w.FloatSlider(min=0.0, max=1.0, step=0.001, readout_format=".3f", description="τ",
                                 continuous_update=True)  # fmt: skip  # the browser snaps τ to the step
        self.count = w.Label()
        self.apply_tau = w.Button(description="Apply τ", tooltip="re-cluster the frames (hand edits are replaced)")
        self.strip = w.HBox(layout=w.Layout(overflow="auto", width="100%"))
        self.keyframe = w.Dropdown(description="keyframe")
        self.add = w.Button(description="Add at frame", icon="plus")
        self.remove = w.Button(description="Remove", icon="trash")
        self.move_to = w.Dropdown(description="move frame to")
        self.move = w.Button(description="Move frame")
        self.time = w.BoundedFloatText(min=0.0, max=1e6, step=0.1, description="time s")
        self.clock = w.Checkbox(description="the video's clock", value=True)
        self.set_time = w.Button(description="Set time")
        self.hold = w.Checkbox(description="hold")
        self.undo = w.Button(description="Undo", icon="undo")
        self.redo = w.Button(description="Redo", icon="repeat")
        self.frame_info = w.Label()

        self.tau.observe(lambda _: self.messages.run(self.update_count), names="value")
        self.apply_tau.on_click(lambda _: self.messages.run(self.state.edit, "recluster", tau=float(self.tau.value)))
        self.keyframe.observe(self._picked, names="value")
        self.add.on_click(lambda _: self.messages.run(self._add))
        self.remove.on_click(lambda _: self.messages.run(self.state.edit, "remove_keyframe", self.selected()))
        self.move.on_click(lambda _: self.messages.run(self._move))
        self.set_time.on_click(lambda _: self.messages.run(self._set_time))
        self.clock.observe(lambda ch: setattr(self.time, "disabled", ch["new"]), names="value")
        self.time.observe(self._round_time, names="value")
        self.hold.observe(self._held, names="value")
        self.undo.on_click(lambda _: self.messages.run(self.state.undo))
        self.redo.on_click(lambda _: self.messages.run(self.state.redo))

        keys = [(MASK_RGB, "expressive region"), *((rgb, f"frame: result {name}") for name, rgb in STATUS_RGB.items())]
        self.legend = legend(keys, then="a button selects its keyframe and frame in every tab")
        self.widget = w.VBox([
            title("Keyframes"),
            w.HBox([self.tau, self.count, self.apply_tau]),
            self.strip,
            self.legend,
            w.HBox([self.keyframe, self.hold, self.remove]),
            w.HBox([self.time, self.clock, self.set_time]),
            self.frame_info,
            w.HBox([self.add, self.move_to, self.move]),
            w.HBox([self.undo, self.redo]),
            self.messages.widget,
        ])  # fmt: skip
        self._stops = [state.on_change(self._changed)]
        self.redraw()

    def close(self) -> None:
        """Stop following the state (the widget stays as it is)."""
        for stop in self._stops:
            stop()
        self.counter.close(wait_s=5.0)

    # ---------------------------------------------------------------- reading the project
    def masks(self) -> np.ndarray:
        """The project's expressive masks ``(N, S, S)`` (paint included), combined once per project state."""
        s = self.state.project.state
        if self._masks_of is not s:
            self._masks, self._masks_of = combined_masks(s), s
        return self._masks

    def selected(self) -> int:
        """The keyframe id in view: the selection's, else the one the scrubber's frame plays."""
        p, sel = self.state.project, self.state.selection
        ids = [kf.id for kf in p.keyframes]
        if sel.keyframe in ids:
            return sel.keyframe
        return self.owner(sel.frame) if p.frames else ids[0]

    def owner(self, frame: int) -> int:
        """The id of the keyframe whose pose frame ``frame`` plays."""
        p = self.state.project
        return p.keyframes[int(p.assignment()[frame])].id

    def _time_range(self, kf: Keyframe) -> tuple[float, float]:
        times = [self.state.project.frames[m].time_s for m in kf.members]
        return min(times), max(times)

    # ---------------------------------------------------------------- drawing
    def _changed(self, what: str) -> None:
        if what in ("project", "selection"):
            self.redraw()

    def update_count(self) -> None:
        """The live count at the slider's τ (the project is not edited): at once from the project's merge orders, or,
        after an edit of what the clustering reads, "counting…" until the panel's thread has worked them out again."""
        with self._count_lock:
            orders = self.state.project.merge_orders(wait=False)
            if orders is not None:
                self._show_count(orders)
                return
            self.count.value = f"counting keyframes at τ {self.tau.value:.3f}…"
        self.counter()

    def _recount(self) -> None:
        """The project's merge orders as it is now (the counting thread: seconds for a long video)."""
        self.state.project.merge_orders()
        with self._count_lock:
            orders = self.state.project.merge_orders(wait=False)
            if orders is not None:  # else an edit meanwhile has asked for another count
                self._show_count(orders)

    def _show_count(self, orders: list) -> None:
        tau = float(self.tau.value)
        self.live_count = sum(o.count(tau) for o in orders)
        now = len(self.state.project.keyframes)
        self.count.value = f"{count(self.live_count, 'keyframe')} at τ {tau:.3f} (project: {now})"

    def _card(self, kf: Keyframe, chosen: bool, status: ProjectStatus) -> w.Widget:
        p = self.state.project
        rep = kf.representative
        pic = upscale(tint(grey_rgb(p.state.targets[rep]), self.masks()[rep], MASK_RGB, 0.6), CARD_PX)
        state = status.result_state(kf.id)
        colour = STATUS_RGB[state]
        pic[:FRAME_PX], pic[-FRAME_PX:], pic[:, :FRAME_PX], pic[:, -FRAME_PX:] = colour, colour, colour, colour
        when = span(*self._time_range(kf))
        extra = (" · hold" if kf.hold else "") + (f" · at {seconds(kf.time_s)}" if kf.time_s is not None else "")
        result = p.results.get(kf.id)
        scored = f" · loss {loss(result.loss.get('total'))}" if result is not None else ""
        if result is not None and result.awaits:  # a run stopped before it: "All stale" does it
            scored += f"<br>{html.escape(AWAITS[result.awaits])}"
        button = w.Button(description=f"k{kf.id}", button_style="info" if chosen else "",
                          layout=w.Layout(width=f"{CARD_PX}px"))  # fmt: skip
        button.on_click(lambda _, k=kf.id, r=rep: self.state.select(frame=r, keyframe=k))
        hex_colour = "#{:02x}{:02x}{:02x}".format(*colour)
        return w.VBox([
            w.Image(value=png(pic), format="png", width=CARD_PX, height=CARD_PX),
            button,
            w.HTML(f"<small>{count(len(kf.members), 'frame')}<br>{when}{extra}<br>"
                   f"<b style='color:{hex_colour}'>{state}</b>{scored}</small>"),
        ])  # fmt: skip

    def redraw(self) -> None:
        """Show the project's keyframes as they are now."""
        p = self.state.project
        self._drawing = True
        try:
            k = self.selected() if p.keyframes else None
            options = [(f"k{kf.id} ({count(len(kf.members), 'frame')})", kf.id) for kf in p.keyframes]
            self.keyframe.options = options
            self.move_to.options = options
            self.keyframe.value = k
            kf = p.state.keyframe(k) if k is not None else None
            if kf is not None:
                self.hold.value = kf.hold
                self.clock.value = kf.time_s is None
                self.time.value = self._rounded(kf.time_s if kf.time_s is not None else self._time_range(kf)[0])
                self.time.disabled = kf.time_s is None
            if p.frames:
                frame = frame_in_view(self.state)
                owner = self.owner(frame)
                self.frame_info.value = f"frame {frame} plays keyframe k{owner}"
                self.move_to.value = owner
            status = p.status()
            self.strip.children = [self._card(x, x.id == k, status) for x in p.keyframes]
            tau = p.state.clustering.tau
            if tau != self._tau_seen:  # the project's τ changed (applied, undone, redone, another panel): follow it
                self._tau_seen, self.tau.value = tau, tau
            self.undo.disabled, self.redo.disabled = not p.can_undo, not p.can_redo
        finally:
            self._drawing = False
        self.messages.run(self.update_count, clear=False)

    # ---------------------------------------------------------------- actions
    def _picked(self, change) -> None:
        if not self._drawing and change["new"] is not None:
            self.state.select(frame=frame_in_view(self.state), keyframe=change["new"])

    def _held(self, change) -> None:
        if not self._drawing:
            self.messages.run(self.state.edit, "set_hold", self.selected(), bool(change["new"]))

    @staticmethod
    def _rounded(t: float) -> float:
        return round(round(float(t) / TIME_STEP_S) * TIME_STEP_S, 6)

    def _round_time(self, change) -> None:
        """Keep the time box to the millisecond (a spinner's 0.7 + 0.1 is 0.7999999999999999 in binary)."""
        t = self._rounded(change["new"])
        if t != change["new"]:
            self.time.value = t

    def _add(self) -> int:
        frame = frame_in_view(self.state)
        k = self.state.edit("add_keyframe", frame)
        self.state.select(frame=frame, keyframe=k)
        return k

    def _move(self) -> None:
        self.state.edit("move_frame", frame_in_view(self.state), int(self.move_to.value))

    def _set_time(self) -> None:
        self.state.edit("set_keyframe_time", self.selected(), None if self.clock.value else float(self.time.value))


def keyframes_panel(state: StudioState) -> KeyframesPanel:
    """The Keyframes panel over ``state`` (its ``.widget`` is what the notebook shows; the studio closes it)."""
    return KeyframesPanel(state)
