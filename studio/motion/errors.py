"""Errors the motion planner reports: each says which keyframe or segment and what to do."""

from __future__ import annotations

import threading
from dataclasses import dataclass

from studio.errors import Cancelled, StudioError, count, stopped


class PlanError(StudioError):
    """Planning a show failed (bad keyframes file, colliding keyframe, no path, infeasible timing)."""


class PlanCancelled(Cancelled):
    """Planning stopped because its cancel event was set (half a plan is no show: nothing is returned). Not a
    :class:`PlanError`: nothing is wrong with the keyframes."""


def check_cancel(cancel: threading.Event | None) -> None:
    """Raise :class:`PlanCancelled` when ``cancel`` is set (the planner's loops call it between their steps)."""
    if stopped(cancel):
        raise PlanCancelled("planning the show was cancelled")


class KeyframeCollisionError(PlanError):
    """A keyframe pose itself is in self-collision; keyframes are never moved, so the artist must fix it."""


class PathError(PlanError):
    """No collision-free path was found between two keyframes."""


@dataclass(frozen=True)
class SegmentTiming:
    """A segment whose requested duration is shorter than the shortest feasible one."""

    index: int  # segment index: 0 is home → first keyframe (or first → second when the first is at t = 0)
    t_start: float  # requested start time, s
    t_end: float  # requested end time, s
    feasible: float  # shortest feasible duration, s, with the same boundary states and limits

    @property
    def requested(self) -> float:
        return self.t_end - self.t_start

    def describe(self) -> str:
        return (
            f"segment {self.index} ({self.t_start:.3f} s → {self.t_end:.3f} s) asks for {self.requested:.3f} s "
            f"but needs at least {self.feasible:.3f} s"
        )


class SegmentTooFastError(PlanError):
    """One or more segments cannot meet their keyframe times within the velocity/acceleration/jerk limits."""

    def __init__(self, segments: list[SegmentTiming]):
        self.segments = list(segments)
        lines = "; ".join(s.describe() for s in self.segments)
        super().__init__(
            f"{count(len(self.segments), 'segment')} too fast for the servo limits: {lines}. "
            "Give those keyframes more time, or allow late transitions to stretch them (later keyframes shift)"
        )


class MotionError(StudioError):
    """Ruckig could not step the online motion (limits too small to reach the target, or an invalid state)."""
