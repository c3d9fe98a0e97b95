"""The Weights panel: a slider per loss weight (MAE, IoU, CLIP, Exp. IoU, Exp. CLIP, temporal) with the paper's
defaults (:class:`studio.imitate.config.LossConfig`), and a reset button. Every change is one project edit
(``project.set_weights``, undoable); a slider applies when it is released (``continuous_update=False``), so a drag
is one edit, not fifty.

    panel = WeightsPanel(state)      # panel.widget goes in the notebook; tests set slider values and .click()

The CLIP sliders are disabled, with the reason beside them, while no local CLIP weights are configured: the studio
never downloads them (DESIGN §6). The one CLIP rule of every face holds here (:func:`studio.imitate.clip_loss.
find_clip`): weights the artist gives (the panel's "CLIP weights file" box, kept in ``state.extras["clip_weights"]``)
or weights in the open_clip / Hugging Face cache turn the terms on.
"""

from __future__ import annotations

import html
import logging
import threading
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import ipywidgets as w

from studio.imitate.config import LossConfig
from widgets.app import CLIP_ENV
from widgets.images import Messages, background, title
from widgets.state import StudioState

log = logging.getLogger(__name__)

CLIP_MODEL = "ViT-B-32"  # the open_clip model whose cached weights count as configured
CLIP_FIELDS = ("w_clip", "w_exp_clip")  # the weights that need a CLIP model


@dataclass(frozen=True)
class WeightSlider:
    """One slider of the panel."""

    field: str  # the LossConfig field it sets
    label: str  # what the artist reads
    maximum: float  # the slider's upper end (the default is well inside)
    step: float  # the slider's resolution


SLIDERS = (
    WeightSlider("w_mae", "MAE", 0.5, 0.005),
    WeightSlider("w_iou", "IoU", 2.0, 0.01),
    WeightSlider("w_clip", "CLIP", 0.2, 0.002),
    WeightSlider("w_exp_iou", "Exp. IoU", 3.0, 0.01),
    WeightSlider("w_exp_clip", "Exp. CLIP", 0.5, 0.005),
    WeightSlider("w_temporal", "temporal", 1.0, 0.01),
)  # in the paper's order (DESIGN §4 "Losses")


def paper_weights() -> dict[str, float]:
    """The paper's default of every weight of :data:`SLIDERS` (``LossConfig``'s field defaults)."""
    defaults = {f.name: f.default for f in fields(LossConfig)}
    return {s.field: float(defaults[s.field]) for s in SLIDERS}


def clip_encoder(state: StudioState) -> Any:
    """The studio's CLIP encoder by the one CLIP rule (:func:`studio.imitate.clip_loss.find_clip`): the weights file
    the artist gave (``state.extras["clip_weights"]``), else weights in a local cache; None when there are none (the
    CLIP terms are then left out). Loaded once and kept in ``state.extras["clip"]``."""
    if state.extras.get("clip") is None:
        from studio.imitate.clip_loss import find_clip

        clip, line = find_clip(state.extras.get("clip_weights"))
        state.extras["clip"], state.extras["clip_line"] = clip, line
        log.info(line)
    return state.extras.get("clip")


def missing_weights(given: str | Path) -> str | None:
    """Why the CLIP weights file ``given`` cannot be used before it is read (None: it is a file)."""
    path = Path(given).expanduser()
    return None if path.is_file() else f"the CLIP weights file {path} does not exist: give another in the box below"


def clip_unavailable(state: StudioState) -> str | None:
    """Why the CLIP terms cannot be used in this studio (None: local CLIP weights are configured)."""
    if state.extras.get("clip") is not None:
        return None
    given = state.extras.get("clip_weights")
    if given:
        return missing_weights(given)
    try:
        from studio.imitate.clip_files import cache_candidates

        if any(p.is_file() for p in cache_candidates(CLIP_MODEL, "openai")):
            return None
    except Exception as e:  # open_clip missing or its tables changed: the terms stay off, and we say why
        log.debug("cannot look for cached CLIP weights: %s", e)
    return (
        "no local CLIP weights on this machine (they are never downloaded): type the path of an open_clip "
        f"{CLIP_MODEL} checkpoint file in the box below and press 'Use these weights' (or start the studio with "
        f"{CLIP_ENV} set to it); until then the CLIP terms are left out"
    )


class WeightsPanel:
    """The Weights panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState):
        self.state = state
        self.messages = Messages()
        self._syncing = False
        self.sliders: dict[str, w.FloatSlider] = {}
        for s in SLIDERS:
            slider = w.FloatSlider(
                description=s.label, min=0.0, max=s.maximum, step=s.step, readout_format=".3f",
                continuous_update=False, style={"description_width": "80px"}, layout=w.Layout(width="420px"),
            )  # fmt: skip
            slider.observe(self._on_slider, names="value")
            self.sliders[s.field] = slider
        self.reset = w.Button(description="Reset to paper defaults", icon="undo", layout=w.Layout(width="220px"))
        self.reset.on_click(lambda _: self.reset_defaults())
        self.clip_reason = w.HTML("")
        self.clip_path = w.Text(placeholder="/path/to/open_clip_model.safetensors", description="CLIP weights file",
                                style={"description_width": "120px"}, layout=w.Layout(width="520px"))  # fmt: skip
        self.clip_use = w.Button(description="Use these weights", icon="check", layout=w.Layout(width="180px"))
        self.clip_use.on_click(lambda _: self.load_clip_aside(self.clip_path.value))
        self.loading: threading.Thread | None = None  # the button's load of CLIP weights, while it runs
        self.clip_path.value = str(state.extras.get("clip_weights") or "")  # given when the studio opened
        self.sync()
        self._stop = state.on_change(self._on_change)
        defaults = ", ".join(f"{s.label} {v:g}" for s, v in zip(SLIDERS, paper_weights().values(), strict=True))
        self.widget = w.VBox([
            title("Weights"),
            w.HTML(f"<span style='color:#555'>paper defaults: {html.escape(defaults)}</span>"),
            *self.sliders.values(), self.clip_reason, w.HBox([self.clip_path, self.clip_use]), self.reset,
            self.messages.widget,
        ])  # fmt: skip

    # ---------------------------------------------------------------- project → widgets
    def sync(self) -> None:
        """Show the project's weights (after an undo, say) and whether the CLIP sliders can be used."""
        weights = self.state.project.weights
        self._syncing = True
        try:
            for name, slider in self.sliders.items():
                value = float(getattr(weights, name))
                slider.max = max(slider.max, value)
                slider.value = value
        finally:
            self._syncing = False
        reason = clip_unavailable(self.state)
        self.clip_disabled_reason = reason  # None: the CLIP sliders are usable
        for name in CLIP_FIELDS:
            self.sliders[name].disabled = reason is not None
        why = "" if reason is None else f"<span style='color:#a60'>CLIP: {html.escape(reason)}</span>"
        self.clip_reason.value = why

    def _on_change(self, what: str) -> None:
        if what == "project":
            self.sync()

    # ---------------------------------------------------------------- widgets → project
    def _on_slider(self, change: dict) -> None:
        if self._syncing:
            return
        name = next(n for n, s in self.sliders.items() if s is change["owner"])
        if float(getattr(self.state.project.weights, name)) == float(change["new"]):
            return
        self.messages.run(self.state.edit, "set_weights", **{name: float(change["new"])})
        if float(getattr(self.state.project.weights, name)) != float(change["new"]):  # refused: show what holds
            self.sync()

    def load_clip_aside(self, path: str) -> None:
        """ "Use these weights": an empty box or a missing file is answered at once; a file is loaded (torch and
        open_clip: seconds) in a thread of the panel's, the button resting and the panel saying so meanwhile."""
        given = Path(path.strip()).expanduser()
        if not path.strip() or not given.is_file():
            self.use_clip_weights(path)  # says what is wrong, without loading anything
            return
        self.clip_use.disabled = True
        self.messages.say(f"loading the CLIP weights {given.name} (the first time in a session takes a few seconds)")

        def load() -> None:
            try:
                self.use_clip_weights(path)
            finally:
                self.clip_use.disabled = False

        self.loading = background(load, "clip-load")

    def use_clip_weights(self, path: str) -> bool:
        """Load the CLIP weights file at ``path`` for this studio (the CLIP terms then count); a message says what
        is wrong with a file that cannot be used, and nothing changes. True when loaded."""
        from studio.imitate.clip_loss import find_clip

        path = path.strip()
        if not path:
            self.messages.say("type the path of a CLIP weights file first", error=True)
            return False
        if (missing := missing_weights(path)) is not None:
            self.messages.say(missing, error=True)
            return False
        try:
            clip, line = find_clip(Path(path).expanduser())
        except Exception as e:  # an unreadable file: say why, keep what was there
            self.messages.say(str(e), error=True)
            return False
        self.state.extras |= {"clip_weights": str(Path(path).expanduser()), "clip": clip, "clip_line": line}
        self.messages.say(line)
        self.sync()
        return True

    def reset_defaults(self) -> None:
        """Every weight back to the paper's default (one edit; nothing when they already are)."""
        self.messages.run(self.state.edit, "set_weights", **paper_weights())

    def close(self) -> None:
        """Stop following the project."""
        self._stop()


def weights_panel(state: StudioState) -> WeightsPanel:
    """The Weights panel over ``state`` (its ``.widget`` is what the notebook shows)."""
    return WeightsPanel(state)
