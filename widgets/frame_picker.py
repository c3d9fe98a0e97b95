"""The frame picker the panels share: a slider over the project's frames that *is* the studio-wide selection.

    picker, stop = frame_picker(state)     # picker goes in a panel; stop() when the panel closes

Moving it selects that frame in every tab (``StudioState.select``, as a click on Review's strip does); a selection
made anywhere else (the strip, the player, another panel's picker or scrubber, an edit that changes the frames)
moves it there, so every picker in the studio shows the same frame.
"""

from __future__ import annotations

from collections.abc import Callable

import ipywidgets as w

from widgets.images import frame_in_view
from widgets.state import StudioState


def frame_picker(state: StudioState, description: str = "frame") -> tuple[w.IntSlider, Callable[[], None]]:
    """A slider over ``state.project.frames`` that follows and sets ``state.selection.frame`` → (the slider, a
    function that stops it following the state)."""
    slider = w.IntSlider(min=0, max=0, description=description)

    def follow(what: str = "selection") -> None:
        if what not in ("project", "selection"):
            return
        with slider.hold_trait_notifications():  # no clamped value in between
            slider.max, slider.value = max(0, len(state.project.frames) - 1), frame_in_view(state)

    def picked(change: dict) -> None:
        if change["new"] != state.selection.frame:
            state.select(frame=change["new"])

    follow()
    slider.observe(picked, names="value")
    return slider, state.on_change(follow)
