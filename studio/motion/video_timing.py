"""Show timing of a video: sampled frames and their keyframe assignment → the planner's keyframes (DESIGN §4).

Every sampled frame plays its cluster's keyframe pose, on the video's own clock (show time = source time):

- **Runs.** A run is a maximal stretch of consecutive frames assigned the same keyframe. Frame ``k`` stands for
  its source interval ``[t_k, t_{k+1})``. A run's pose is *reached* at the run's first frame time (the source time
  where the assignment changes), and a run of two or more frames *holds* it (at rest) until its last frame's time
  ``t_j``. So the transition from one run to the next moves in ``[t_j, t_{j+1}]``, the interval of the last frame
  before the change: the time the video gives it. A single-frame run is passed with the spline's velocity (it is
  shown, not held). A loop ``A→B→A→B`` stays a loop: each run is its own keyframe, in time order.
- **The end.** The last run holds its pose to the show's end: the last frame's time plus one sample period
  ``1 / hz``, or the source's end when that comes first (``end_s``). So the show lasts as long as the sampled video.
- **The start (home).** The show's first pose is the first frame's pose, at the first frame's time. With the
  first sampled frame at ``t = 0`` (every source read from its start) there is no home move inside the show: the
  show starts at that pose, and the player brings the hand there before show time 0 (``hardware.player`` ramps to
  a show's first sample), so the show clock never leaves the video's. When the first kept frame is later than 0 (a
  leading frame skipped), the planner's home move (rest pose at ``t = 0``, ``studio.motion.plan``) arrives at the
  first frame's time.

A transition the servos cannot make in the time the video gives is reported by the planner as a late segment
(``SegmentTooFastError``, or ``TimedTrajectory.late`` with ``allow_late``); :meth:`VideoTiming.late_transitions`
names its frames and the needed versus given seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from studio.motion.errors import PlanError, SegmentTiming
from studio.motion.plan import Keyframes


@dataclass
class VideoTiming:
    """The planner's keyframes of a video and where each came from (arrays over the M planner keyframes)."""

    keyframes: Keyframes  # times (M,) s on the video's clock, poses (M, 21) rad, hold (M,)
    frame: np.ndarray  # (M,) int, sampled frame each planner keyframe stands at (the run's first or last frame)
    cluster: np.ndarray  # (M,) int, keyframe (cluster) number of its pose
    runs: list[tuple[int, int]]  # (first, last) sampled frame of each run, in time order
    end_s: float  # the show's end, s (the last planner keyframe's time)
    frame_times: np.ndarray | None = None  # (N,) s, the show time of every sampled frame (None: not computed)

    def late_transitions(self, segments: Sequence[SegmentTiming], home_added: bool) -> list[dict]:
        """The planner's late ``segments`` as video transitions: frames, clusters, needed versus given seconds.

        ``home_added``: the planner prepended home at t = 0 (:class:`~studio.motion.plan.PlanResult`), so its
        segment 0 is home → the first frame (``from_frame`` None)."""
        out = []
        for s in segments:
            a = s.index - 1 if home_added else s.index  # planner keyframe the segment leaves (-1: home)
            b = a + 1
            out.append({
                "from_frame": None if a < 0 else int(self.frame[a]),
                "to_frame": int(self.frame[b]),
                "from_keyframe": None if a < 0 else int(self.cluster[a]),
                "to_keyframe": int(self.cluster[b]),
                "t_start": round(float(s.t_start), 6),
                "t_end": round(float(s.t_end), 6),
                "given_s": round(float(s.requested), 6),
                "needed_s": round(float(s.feasible), 6),
            })  # fmt: skip
        return out


def runs_of(assignment: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` frame of each maximal run of equal values in ``assignment (N,)``, in order."""
    a = np.asarray(assignment).reshape(-1)
    if len(a) == 0:
        return []
    starts = np.concatenate([[0], np.flatnonzero(a[1:] != a[:-1]) + 1])
    ends = np.concatenate([starts[1:] - 1, [len(a) - 1]])
    return [(int(i), int(j)) for i, j in zip(starts, ends)]


def video_end(times: np.ndarray, hz: float, duration_s: float | None = None) -> float:
    """The end of a sampled video, s: the last frame's time ``times[-1]`` plus one sample period ``1 / hz``, or the
    source's end ``duration_s`` when it is sooner (and after the last frame)."""
    last = float(np.asarray(times)[-1])
    end = last + 1.0 / hz
    if duration_s is not None and last < duration_s < end:
        end = float(duration_s)
    return end


def video_keyframes(
    times: np.ndarray,
    assignment: np.ndarray,
    poses: np.ndarray,
    end_s: float,
    source_frames: np.ndarray | None = None,
    targets: Sequence[str | None] | None = None,
    losses: Sequence[float | None] | None = None,
) -> VideoTiming:
    """Planner keyframes for sampled frames at source ``times (N,) s`` assigned ``assignment (N,)`` (keyframe numbers
    into ``poses (K, 21) rad``), the show ending at ``end_s`` (:func:`video_end`); rules in the module doc.

    ``source_frames (N,)`` (source frame index of each sampled frame) and ``targets (K,)`` fill the keyframes'
    ``source_frame`` and ``target``; ``losses (K,)`` become their per-keyframe losses. Raises ``PlanError`` for
    times that do not increase, an assignment outside ``poses`` or an end before the last frame.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    a = np.asarray(assignment, dtype=np.int64).reshape(-1)
    q = np.asarray(poses, dtype=np.float64)
    if len(t) == 0 or a.shape != t.shape:
        raise PlanError(f"need one assignment per frame time, got {len(a)} for {len(t)} frames")
    if not np.isfinite(t).all() or (t < 0).any() or (np.diff(t) <= 0).any():
        raise PlanError(f"frame times must be finite seconds ≥ 0, strictly increasing: {t.tolist()}")
    if q.ndim != 2 or a.min() < 0 or a.max() >= len(q):
        raise PlanError(f"the assignment names keyframes 0–{a.max()} but {len(q)} poses were given")
    if not end_s > t[-1]:
        raise PlanError(f"the show's end ({end_s} s) must come after the last frame ({t[-1]} s)")
    runs = runs_of(a)
    kt, kframe, kcluster, khold = [], [], [], []
    for r, (i, j) in enumerate(runs):
        last = r == len(runs) - 1
        held = j > i or last
        kt.append(t[i])
        kframe.append(i)
        khold.append(held)
        if j > i and not last:  # hold to the run's last frame, then move during that frame's interval
            kt.append(t[j])
            kframe.append(j)
            khold.append(True)
        if last:
            kt.append(float(end_s))
            kframe.append(j)
            khold.append(True)
        kcluster += [int(a[i])] * (len(kt) - len(kcluster))
    kframe_a, kcluster_a = np.array(kframe), np.array(kcluster)
    kf = Keyframes.at(kt, q[kcluster_a])
    kf.hold = np.array(khold)
    if source_frames is not None:
        sf = np.asarray(source_frames).reshape(-1)
        kf.source_frame = [int(sf[i]) for i in kframe_a]
    if targets is not None:
        kf.target = [targets[c] for c in kcluster_a]
    if losses is not None:
        kf.extra["keyframe_losses"] = [None if losses[c] is None else float(losses[c]) for c in kcluster_a]
    return VideoTiming(kf, kframe_a, kcluster_a, runs, float(end_s), t.copy())


def transition_times(timing: VideoTiming) -> dict[tuple[int, int], float]:
    """Every pair of clusters (keyframes) the show moves between, either way (A → B → A counts both moves) → the
    shortest time the clock gives such a move, s: what the sequence optimisation keeps each transition within
    (:func:`studio.motion.reach.reach_distances`)."""
    t, c = timing.keyframes.times, timing.cluster
    out: dict[tuple[int, int], float] = {}
    for m in range(len(t) - 1):
        a, b = int(c[m]), int(c[m + 1])
        if a != b:
            key = (min(a, b), max(a, b))
            out[key] = min(out.get(key, float("inf")), float(t[m + 1] - t[m]))
    return out
