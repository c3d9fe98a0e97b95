"""A project's keyframes on the show clock: the planner's :class:`~studio.motion.plan.Keyframes` of a project.

Sources play one after another, in the project's order, each in its own span of the show clock:

- **A video** (a video file, a GIF, a frame folder) plays at its own clock (:mod:`studio.motion.video_timing`): its
  sampled frames at their source times plus the span's start, every frame playing its keyframe's pose, the span
  ending one sample period after the last frame (or at the source's end).
- **A still** is one keyframe, reached at the span's start and held for :attr:`ShowLayout.still_hold_s`.
- **Between sources** the hand has :attr:`ShowLayout.gap_s` to move from one source's last pose to the next one's
  first. The first source starts at t = 0: its first pose is the show's first pose (the player brings the hand
  there before show time 0), as for a single video.

The artist's keyframe settings (:meth:`~studio.project.project.Project.set_keyframe_time`, ``set_hold``):

- ``time_s`` is a show time. A still's keyframe is then reached at ``time_s`` (its span starts there, and the
  following sources follow it); a video keyframe's first appearance (its first run's start) moves to ``time_s``,
  the rest of the video staying on its clock. A time that falls before the previous planner keyframe or after the
  next is a :class:`~studio.project.state.ProjectError` naming the keyframe.
- ``hold`` makes the hand come to rest at every appearance of that keyframe's pose.

Every keyframe needs a current result (its pose): a missing or stale one is a
:class:`~studio.project.state.ResultsNeeded` error naming them. The returned
:class:`~studio.motion.video_timing.VideoTiming` names, for each planner keyframe, the project frame it stands at and
the keyframe *id* it plays, so ``late_transitions`` names the frames and keyframes of a transition too fast for the
servos.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from studio.motion.limits import JointLimits, LimitsConfig
from studio.motion.plan import Keyframes
from studio.motion.reach import distance_box, reach_distances, rest_to_rest_time
from studio.motion.video_timing import VideoTiming, runs_of, video_end, video_keyframes
from studio.motion.video_timing import transition_times as clock_of
from studio.project.state import ProjectError, ProjectState, ResultsNeeded
from studio.project.status import ProjectStatus
from studio.sim.hand import load_hand


@dataclass(frozen=True)
class ShowLayout:
    """How a project's sources share the show clock (module doc)."""

    still_hold_s: float = 2.0  # seconds a still's pose is held on the show clock (0, 3600]
    gap_s: float = 1.5  # seconds between one source's end and the next source's start: the move between them [0, 3600]

    def __post_init__(self) -> None:
        if not self.still_hold_s > 0 or not self.gap_s >= 0:
            raise ValueError(f"a still is held > 0 s and sources are ≥ 0 s apart, not {self}")


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _poses(s: ProjectState, status: ProjectStatus, joint_names: list[str]) -> dict[int, np.ndarray]:
    """Keyframe id → its result's pose ``(21,)`` rad; a ProjectError naming missing or stale results."""
    missing, stale = list(status.missing), list(status.stale)
    if missing or stale:
        kf = lambda ids: "keyframe" if len(ids) == 1 else "keyframes"  # noqa: E731
        parts = ([f"no result for {kf(missing)} {missing}"] if missing else []) + (
            [f"{'a stale result' if len(stale) == 1 else 'stale results'} for {kf(stale)} {stale}"] if stale else []
        )
        them = "it" if len(missing) + len(stale) == 1 else "them"
        raise ResultsNeeded(f"{status.path}: cannot time a show: {' and '.join(parts)}; optimise {them} first")
    return {k: r.theta(joint_names) for k, r in s.results.items()}


def project_timing(
    s: ProjectState, status: ProjectStatus | None, joint_names: list[str], layout: ShowLayout | None = None,
    poses: dict[int, np.ndarray] | None = None,
) -> VideoTiming:  # fmt: skip
    """The planner keyframes of a project (its state ``s`` and ``status``) on the show clock (module doc), poses in
    ``joint_names``' order (``poses``: keyframe id → pose to use instead of the results, e.g. placeholders when only
    the clock is wanted, :func:`transition_times`).

    ``frame`` of the result is a project frame index, ``cluster`` a keyframe id; ``runs`` are project frame
    indices; ``end_s`` is the show's end (the last source's end)."""
    layout = layout or ShowLayout()
    poses = poses if poses is not None else _poses(s, status, joint_names)
    owner = {m: kf for kf in s.keyframes for m in kf.members}
    hz = s.video.hz
    times: list[float] = []
    frame: list[int] = []
    cluster: list[int] = []
    hold: list[bool] = []
    source_frame: list[int | None] = []
    target: list[str | None] = []
    losses: list[float | None] = []
    runs: list[tuple[int, int]] = []
    frame_times = np.zeros(len(s.frames))
    start = 0.0  # the next source's span starts here
    for i, src in enumerate(s.sources):
        idx = np.array([n for n, f in enumerate(s.frames) if f.source == i])
        if len(idx) == 0:
            continue
        ids = [owner[int(n)].id for n in idx]
        order = list(dict.fromkeys(ids))  # this source's keyframe ids, first appearance first
        local = np.array([order.index(k) for k in ids])
        t_src = np.array([s.frames[int(n)].time_s for n in idx])
        if src.kind == "still":
            kf = owner[int(idx[0])]
            start = start if kf.time_s is None else float(kf.time_s)
            t_src, end = t_src[:1] - t_src[0], layout.still_hold_s
        else:
            end = video_end(t_src, hz, src.duration_s or None)
        vt = video_keyframes(
            t_src + start, local, np.stack([poses[k] for k in order]), end + start,
            source_frames=np.array([s.frames[int(n)].source_frame for n in idx]),
            targets=[f"{Path(src.path).name}#{s.frames[s.keyframe(k).representative].source_frame}" for k in order],
            losses=[_finite(s.results[k].loss.get("total")) if k in s.results else None for k in order],
        )  # fmt: skip
        k_times = vt.keyframes.times.copy()
        k_hold = vt.keyframes.hold.copy()
        for c, k in enumerate(order):
            kf = s.keyframe(k)
            mine = vt.cluster == c
            if kf.hold:
                k_hold[mine] = True
            if kf.time_s is not None and src.kind != "still":
                first = int(np.flatnonzero(mine)[0])  # the first run's start: where the pose is reached
                k_times[first] = float(kf.time_s)
        times += k_times.tolist()
        frame += idx[vt.frame].tolist()
        cluster += [order[c] for c in vt.cluster]
        hold += k_hold.tolist()
        source_frame += list(vt.keyframes.source_frame)
        target += list(vt.keyframes.target)
        losses += list(vt.keyframes.extra["keyframe_losses"])
        runs += [(int(idx[a]), int(idx[b])) for a, b in runs_of(local)]
        frame_times[idx] = t_src + start
        start = float(k_times[-1]) + layout.gap_s
    t = np.array(times)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        j = int(bad[0]) + 1
        raise ProjectError(
            f"{status.path}: keyframe {cluster[j]} would be at {t[j]:.3f} s, not after keyframe {cluster[j - 1]} at "
            f"{t[j - 1]:.3f} s: change or clear its time"
        )
    planner = Keyframes(t, np.stack([poses[k] for k in cluster]), np.array(hold), source_frame, target,
                        {"title": s.title, "loss_weights": s.weights.to_dict(), "keyframe_losses": losses})  # fmt: skip
    return VideoTiming(planner, np.array(frame), np.array(cluster), runs, float(t[-1]), frame_times)


def transition_times(s: ProjectState, layout: ShowLayout | None = None) -> dict[tuple[int, int], float]:
    """Every pair of keyframe ids the show moves between (either way; A → B → A counts both moves) → the shortest
    time the show clock gives such a move, s (whatever the poses: the clock alone). Empty when the artist's keyframe
    times do not fit together (the planner says so)."""
    dof = len(load_hand().joint_names)
    try:
        vt = project_timing(s, None, [], layout, poses={kf.id: np.zeros(dof) for kf in s.keyframes})
    except ProjectError:
        return {}
    return clock_of(vt)


def keyframe_box(
    s: ProjectState, status: ProjectStatus, k: int, margin: float = 0.9, layout: ShowLayout | None = None,
    limits: LimitsConfig | None = None, posed: Collection[int] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:  # fmt: skip
    """The joint box ``(lower (21,), upper (21,))`` rad keyframe ``k``'s pose must keep so that every move on the
    show's clock between it and a keyframe already posed (a current result; ``posed``: only these ids count), and
    every chain of moves through keyframes not posed yet, fits the time the clock gives it (:func:`reach_of` with
    ``margin``); None when no keyframe joined to it on the clock is posed yet."""
    hand = load_hand()
    current = {kf.id for kf in s.keyframes if kf.id in s.results and kf.id not in status.stale and kf.id != k}
    if posed is not None:
        current &= set(posed)
    poses = {n: s.results[n].theta(hand.joint_names) for n in current}
    lim = JointLimits.from_hand(hand, limits)
    return reach_of(reach_distances(transition_times(s, layout), lim, margin).get(k, {}), poses, lim)


def reach_of(
    far: Mapping[int, np.ndarray], poses: Mapping[int, np.ndarray], limits: JointLimits
) -> tuple[np.ndarray, np.ndarray] | None:
    """The joint box ``(lower (21,), upper (21,))`` rad a keyframe keeps from every posed keyframe: ``far`` id →
    ``(21,)`` rad its :func:`~studio.motion.reach.reach_distances` over the show clock's moves
    (:func:`transition_times`), ``poses`` id → ``(21,)`` rad of those that count as posed (the others are left
    out); None when none joined to it is posed. The one rule of :func:`keyframe_box`, :func:`seams_out_of_reach`
    and a spread run's workers (:mod:`studio.project.run_spread`), which hold poses but no project."""
    near = [(poses[n], d) for n, d in far.items() if n in poses]
    return distance_box(near, limits) if near else None


def seams_out_of_reach(
    s: ProjectState,
    optimised: Collection[int],
    layout: ShowLayout | None = None,
    limits: LimitsConfig | None = None,
    margin: float = 0.9,
) -> list[int]:
    """Keyframes of ``optimised`` (a run's) to optimise again, in keyframe order: one for each move the show makes
    between keyframes of *two sources* faster than the servos can move rest to rest
    (:func:`~studio.motion.reach.rest_to_rest_time`, every joint). A run keeps each keyframe within reach of its
    own source's posed keyframes and of those current before it, but not of another source's optimised in the same
    run (side by side in a spread run, so both faces follow one rule): a move between sources (a still, then a
    video) may ask for more than the clock gives it. Of the move's two keyframes (those of ``optimised``) the one
    named is one that every posed neighbour leaves room for (its :func:`reach_of` box, ``margin``, crosses on no
    joint: a still, held alone, rather than a video keyframe tied to the next), else the later; optimised again
    within that box, the move fits."""
    hand = load_hand()
    lim = JointLimits.from_hand(hand, limits)
    order = [kf.id for kf in s.keyframes]
    source = {kf.id: s.frames[kf.representative].source for kf in s.keyframes}
    poses = {k: r.theta(hand.joint_names) for k, r in s.results.items()}
    times = transition_times(s, layout)
    far = reach_distances(times, lim, margin)

    def room(k: int) -> bool:  # every posed neighbour of k leaves room on every joint
        box = reach_of(far.get(k, {}), {n: p for n, p in poses.items() if n != k}, lim)
        return box is None or not bool(np.any(box[1] - box[0] < 1e-9))

    again: set[int] = set()
    for (a, b), dt in times.items():
        if source[a] == source[b] or a not in poses or b not in poses:
            continue
        mine = [k for k in (a, b) if k in optimised]
        if mine and float(rest_to_rest_time(poses[a] - poses[b], lim).max()) > dt:
            again.add(max(mine, key=lambda k: (room(k), order.index(k))))
    return [k for k in order if k in again]
