"""What a project run did (plain data): :class:`RunReport`, the CLI's JSON summary and the notebook's message, and
:class:`TooFast`, what the plan step returns when a transition is too fast for the servos; the words its messages
count in (:func:`counted`) and the run's last step (:meth:`RunReport.finish`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from studio.errors import count
from studio.jobs.events import JobError
from studio.project.summary import mount_apart, project_transitions
from studio.sim.roll import mount_text, roll_deg

if TYPE_CHECKING:
    from studio.imitate.transitions import TransitionConfig
    from studio.project.status import ProjectHandle


@dataclass
class TooFast:
    """What the plan step returns when a transition is too fast for the servos and ``allow_late`` is off."""

    segments: list  # studio.motion.errors.SegmentTiming of every late segment
    home_added: bool  # the planner prepended home at t = 0
    message: str  # the planner's message


@dataclass
class RunReport:
    """What a run did (plain data; :meth:`summary` is the CLI's JSON)."""

    project: str  # the project folder
    optimised: list[int] = field(default_factory=list)  # keyframe ids computed and saved by this run, in order
    skipped: list[int] = field(default_factory=list)  # keyframe ids already current (not recomputed)
    refined: list[int] = field(default_factory=list)  # keyframe ids refined together (studio.project.run_together)
    show: str | None = None  # "planned" (by this run), "current" (kept), or None (no show: see message)
    show_seconds: float | None = None  # the show's duration, s
    late: list[dict] = field(default_factory=list)  # transitions too fast for the servos (frames, needed vs given s)
    transitions: dict = field(default_factory=dict)  # success, transitions, rate (per source, summed): L_base ≤ 0.35
    transitions_literal: dict = field(default_factory=dict)  # the same, the paper's literal reading: L_base + L_expr
    cancelled: bool = False  # the cancel event stopped the run
    error: JobError | None = None  # why a job failed (nothing of it was applied)
    message: str = ""  # one line: what happened
    too_fast: bool = False  # no show because transitions are too fast for the servos (``late`` lists them)
    roll: float = 0.0  # the mount roll the keyframes are optimised for, rad
    roll_chosen: bool = False  # this run chose it (``--roll auto``)
    apart: list[dict] = field(default_factory=list)  # keyframes another roll would cast clearly better (mount_apart)
    seconds: float = 0.0  # wall time of the run

    @property
    def ok(self) -> bool:
        """Every keyframe current and a show planned (or kept)."""
        return not self.cancelled and self.error is None and self.show is not None

    def summary(self) -> dict:
        rate = self.transitions.get("rate")
        return {
            "project": self.project, "keyframes_optimised": self.optimised, "keyframes_skipped": self.skipped,
            "keyframes_refined_together": self.refined,
            "show": self.show, "show_seconds": self.show_seconds, "late_transitions": self.late,
            "transition_success": rate, "transitions_ok": self.transitions.get("success", 0),
            "transition_success_literal": self.transitions_literal.get("rate"),
            "transitions_ok_literal": self.transitions_literal.get("success", 0),
            "transitions": self.transitions.get("transitions", 0), "cancelled": self.cancelled,
            "error": None if self.error is None else str(self.error), "message": self.message,
            "roll_deg": roll_deg(self.roll), "mount": mount_text(self.roll), "mount_apart": self.apart,
            "seconds": round(self.seconds, 2),
        }  # fmt: skip

    def finish(self, project: ProjectHandle, transitions: TransitionConfig, t0: float) -> RunReport:
        """The run's last step: the roll, the show's length, both readings of transition success (in the message
        too) and the wall time since ``t0`` (``time.perf_counter()``)."""
        self.roll = project.mount.roll
        self.apart = mount_apart(project.state)
        if self.roll_chosen:
            self.message = f"chose the mount roll {roll_deg(self.roll):+.1f}° (auto); {self.message}"
        if project.show is not None and self.show is not None:
            self.show_seconds = round(project.show.duration, 4)
        self.transitions = project_transitions(project.state, transitions)
        self.transitions_literal = project_transitions(project.state, replace(transitions, total="image"))
        n = self.transitions.get("transitions", 0)
        if n and self.show is not None:
            self.message += (f"; transitions {self.transitions['success']}/{n} (L_base), "
                             f"{self.transitions_literal['success']}/{n} (L_base + L_expr, the paper's)")  # fmt: skip
        self.seconds = time.perf_counter() - t0
        return self

    def nothing_done(self) -> str:
        """The message of a run that planned no show because the show is current."""
        if self.optimised:
            return f"optimised {count(len(self.optimised), 'keyframe')}; the show is current"
        every = "all " if len(self.skipped) > 1 else ""
        return f"nothing to do: {every}{count(len(self.skipped), 'keyframe')} and the show are current"


def late_transitions(timing, show) -> list[dict]:
    """The late transitions a planned show was stretched by (its planner provenance), named by frame."""
    from studio.motion.errors import SegmentTiming

    late = [SegmentTiming(**d) for d in show.provenance.get("late_segments", [])]
    return timing.late_transitions(late, bool(show.provenance.get("home_added", False)))
