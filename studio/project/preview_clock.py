"""What a project's show preview plays when (:class:`~studio.review.preview.PreviewClock`, plain data; no pixels).

The preview runs on the **show clock** at ``fps``:

- **A current show** (planned from the project as it is now): the pose at each preview time is the show's own
  40 Hz samples interpolated (:meth:`~studio.motion.show.Show.sample`). A planner that stretched a late transition
  moved the keyframes after it, so the frame in view follows the show: show time maps to the project's clock
  through the keyframe markers (:func:`~studio.review.preview.show_clock_map`), then to the frame being played
  then (:func:`~studio.review.video_review.frame_at`). Given ``home`` (rad/s, the player's ramp speed), a show that
  starts with a still is preceded by the move from home (the rest pose) to its pose, on negative show times.
- **No current show** (not planned yet, or stale): each frame plays its keyframe's pose (stale results included;
  a keyframe with no result leaves the shadow blank) on the project's clock (:func:`.show_timing.project_timing`).

Ticks mark where each keyframe's pose is reached, coloured by its result's status (missing, stale, current); the
late transitions are the run report's (:func:`studio.project.run_report.late_transitions`), on the show clock.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from studio.errors import count
from studio.motion.show import Show
from studio.motion.video_timing import VideoTiming
from studio.project.show_timing import project_timing
from studio.project.state import ProjectState
from studio.project.status import ProjectStatus
from studio.review.preview import PreviewClock, PreviewTick, home_move, remap, show_clock_map
from studio.review.video_review import frame_at, video_times


@dataclass(frozen=True, eq=False)
class PreviewInputs:
    """What a preview is made from: a snapshot of the project (plain data, read on the caller's thread)."""

    path: Path  # the project folder (its sources are read from beside it)
    state: ProjectState  # the project's state (immutable)
    status: ProjectStatus  # where it stood
    masks: np.ndarray  # (N, S, S) uint8, the artist's expressive masks (automatic + paint)
    joint_names: tuple[str, ...]  # the hand's joint order (of the poses)
    rest: np.ndarray  # (21,) rad, the hand's rest pose (home)


def preview_inputs(project) -> PreviewInputs:
    """The :class:`PreviewInputs` of an open :class:`~studio.project.project.Project` as it is now."""
    from studio.sim.hand import load_hand

    hand = load_hand()
    return PreviewInputs(project.path, project.state, project.status(), np.asarray(project.combined_masks()),
                         tuple(hand.joint_names), hand.rest_pose())  # fmt: skip


def _ticks(timing: VideoTiming, status: ProjectStatus, times: np.ndarray) -> list[PreviewTick]:
    """A tick where each keyframe's pose is reached (the planner keyframe where the pose changes), at ``times``."""
    out, last = [], None
    for j, k in enumerate(timing.cluster.tolist()):
        if k != last:
            out.append(PreviewTick(float(times[j]), int(k), int(timing.frame[j]), status.result_state(int(k))))
        last = k
    return out


def _frames_at(timing: VideoTiming, clock_t: np.ndarray) -> np.ndarray:
    """Project frame ``(M,)`` played at project-clock times ``clock_t (M,)``."""
    order = np.argsort(timing.frame_times, kind="stable")
    return order[frame_at(timing.frame_times[order], clock_t)]


def preview_clock(inp: PreviewInputs, fps: float, home: float | None = None) -> PreviewClock:
    """The preview's clock of the project ``inp`` at ``fps`` (module doc); ``home``: rad/s of the move from home
    shown before a show that starts with a still (None: not shown). A
    :class:`~studio.project.state.ProjectError` when the artist's keyframe times do not fit together."""
    from studio.project.run_report import late_transitions  # the run report's: one way to name them

    s, status = inp.state, inp.status
    names = list(inp.joint_names)
    show = _current_show(s, status)
    if show is None or list(show.joint_names) != names:
        return _keyframe_clock(inp, fps, home)
    timing = project_timing(s, status, names)
    marks, asked = show_clock_map(show)
    t = video_times(show.duration, fps) + float(show.times[0])
    theta = show.sample(t)
    t, theta = _from_home(inp, t, theta, fps, home)
    frame = _frames_at(timing, remap(np.maximum(t, 0.0), marks, asked))
    ticks = _ticks(timing, status, remap(timing.keyframes.times, asked, marks))
    late = [(float(remap(d["t_start"], asked, marks)), float(remap(d["t_end"], asked, marks)))
            for d in late_transitions(timing, show)]  # fmt: skip
    note = "the planned show" + (f", after the move from home ({-t[0]:.2f} s)" if t[0] < 0 else "")
    if late:
        note += f"; {count(len(late), 'late transition')}, stretched (shaded red)"
    return PreviewClock(t, frame, theta, float(t[0]), float(show.times[-1]), fps, True, ticks, late, note)


def _current_show(s: ProjectState, status: ProjectStatus) -> Show | None:
    """The project's show when it is current (planned from the project as it is now), else None."""
    return s.show if s.show is not None and not status.show_stale and not status.pending else None


def frame_show_times(s: ProjectState, status: ProjectStatus) -> np.ndarray | None:
    """Show time ``(N,)`` s at which each project frame starts to play in the current show, on the clock the
    preview plays (a stretched late transition moves the frames after it); None without a current show."""
    show = _current_show(s, status)
    if show is None:
        return None
    marks, asked = show_clock_map(show)
    return remap(project_timing(s, status, list(show.joint_names)).frame_times, asked, marks)


def _from_home(inp: PreviewInputs, t: np.ndarray, theta: np.ndarray, fps: float, home: float | None):
    """``(t, theta)`` preceded by the move from home when the show starts with a still at t = 0 and ``home`` is
    given (rad/s) and the first pose is known."""
    s = inp.state
    if home is None or s.sources[s.frames[0].source].kind != "still" or t[0] != 0 or np.isnan(theta[0]).any():
        return t, theta
    lead_t, lead_q = home_move(inp.rest, theta[0], fps, home)
    return np.r_[lead_t, t], np.concatenate([lead_q, theta])


def _keyframe_clock(inp: PreviewInputs, fps: float, home: float | None) -> PreviewClock:
    """No current show: each frame plays its keyframe's pose (stale included) on the project's clock."""
    s, status = inp.state, inp.status
    dof = len(inp.joint_names)
    timing = project_timing(s, None, [], poses={kf.id: np.zeros(dof) for kf in s.keyframes})
    t = video_times(timing.end_s, fps)
    frame = _frames_at(timing, t)
    pose = {k: r.theta(list(inp.joint_names)) for k, r in s.results.items()}
    owner = {m: kf.id for kf in s.keyframes for m in kf.members}
    blank = np.full(dof, np.nan)
    theta = np.stack([pose.get(owner[int(i)], blank) for i in frame])
    t, theta = _from_home(inp, t, theta, fps, home)
    frame = np.r_[np.full(len(t) - len(frame), frame[0]), frame]
    ticks = _ticks(timing, status, timing.keyframes.times)
    why = "the show is stale: plan it again" if s.show is not None else "no show planned yet"
    if status.pending:
        why = f"{count(len(status.pending), 'keyframe')} to optimise before the show"
    note = f"{why}; each frame plays its keyframe's pose" + (", after the move from home" if t[0] < 0 else "")
    return PreviewClock(t, frame, theta, float(t[0]), float(timing.end_s), fps, False, ticks, [], note)
