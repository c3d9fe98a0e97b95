"""The mount roll control of the Optimise tab: ``auto`` or degrees, and how the hand is to be mounted.

The roll is the project's (:attr:`Project.mount`): "auto" lets the next optimisation choose one roll for the whole
show (by the retrieval index, under a second a keyframe), a number fixes it (degrees, counter-clockwise as the
audience sees the backdrop; 0 is the paper's upright rig). A new roll makes every keyframe stale, since each pose is
chosen for its roll; the line under the box says what the project holds now, and, for a roll set by hand, which
keyframes it casts clearly worse than a roll of their own would (measured in the background as it is set).
"""

from __future__ import annotations

import html

import ipywidgets as w

from studio.jobs.job import Job
from studio.project.jobs import roll_check_job
from studio.project.state import ProjectError
from studio.project.summary import apart_text, mount_apart
from studio.sim.roll import mount_text, roll_deg
from widgets.state import StudioState


def mount_line(project) -> str:
    """One line: the roll the project holds and how to mount the hand (or that auto chooses it at the next run)."""
    m = project.mount
    if m.auto and not m.chosen:
        return "roll auto: chosen for the whole show when the keyframes are next optimised"
    chosen = " (chosen by auto)" if m.auto else ""
    gain = ""
    if m.auto and m.loss is not None and m.upright_loss is not None:
        gain = f"; first-answer outline loss {m.loss:.3f} vs {m.upright_loss:.3f} upright"
    apart = apart_text(mount_apart(project.state))
    return f"{mount_text(m.roll)}{chosen}{gain}" + (f"<br>{html.escape(apart)}" if apart else "")


class MountControl:
    """``widget``: the roll box ("auto" or degrees), a Set button and the project's mount line."""

    def __init__(self, state: StudioState, say):
        self.state = state
        self.say = say  # (text, error=False) → shown to the artist
        self.box = w.Text(
            description="mount roll", placeholder="auto or degrees", layout=w.Layout(width="220px"),
            tooltip="auto: the studio picks one roll for the whole show; or degrees (0: upright)",
        )  # fmt: skip
        self.set_button = w.Button(description="Set roll", icon="repeat",
                                   tooltip="every keyframe is optimised again for a new roll")  # fmt: skip
        self.line = w.HTML("")
        self.set_button.on_click(lambda _: self.apply())
        self.widget = w.VBox([w.HBox([self.box, self.set_button]), self.line])
        self.refresh()

    def refresh(self) -> None:
        """The box and the line as the project holds them (after an undo, a run or another face's edit)."""
        m = self.state.project.mount
        self.box.value = "auto" if m.auto else f"{roll_deg(m.roll):g}"
        self.line.value = mount_line(self.state.project)

    def apply(self) -> bool:
        """Set the project's roll from the box; a bad value is said, nothing changes."""
        text = self.box.value.strip() or "auto"
        try:
            self.state.project.set_roll(text)
        except ProjectError as e:
            self.say(str(e), error=True)
            return False
        self.say(f"mount roll set to {text}: the keyframes are stale until optimised for it")
        self.state.changed("project")
        self.refresh()
        self.measure()
        return True

    def measure(self) -> Job | None:
        """A roll set by hand for a show (not the paper's 0°): what it costs the keyframes, measured in the background
        (:func:`~studio.project.jobs.roll_check_job`, about a second once the index is loaded); the line says it
        when it lands. The job, or None when there is nothing to measure."""
        p = self.state.project
        if not p.mount.measurable(len(p.keyframes)):
            return None
        return self.state.queue.submit(roll_check_job(p, on_applied=self._measured))

    def _measured(self) -> None:
        """The costs of the roll set landed (the queue's thread): this line, then every panel."""
        self.refresh()
        self.state.changed("project")
