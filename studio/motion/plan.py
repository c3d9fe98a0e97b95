"""Motion planning: keyframes → collision-free path → jerk-limited timed trajectory → show (DESIGN §4 "Motion").

Keyframes file (``POSES.json``, as ``imitate``/``imitate-video`` write it)::

    {"keyframes": [{"t": 1.5, "pose": {"wrist": 0.1, ...}, "hold": false,            # t in s, angles in rad
                    "source_frame": 12, "target": "frames/012.png", "loss": 0.21}, ...],
     "title": "...", "loss_weights": {...}}                                           # optional

**Home.** A show starts at rest: when the first keyframe is later than t = 0, the hand's rest pose
(``hand.rest_pose()``) is prepended as a held keyframe at t = 0 (the "home" keyframe); when the first keyframe is at
t = 0 it is the start pose instead. The first and last keyframes are passed at rest (zero velocity), as are keyframes
marked ``"hold": true``; every other keyframe is passed with the spline's velocity. So a single keyframe at t = 0 (what
``imitate --at 0`` writes) plans to a show of one sample that holds that pose: there is no home move to time, and a
player brings the hand to a show's first pose before playing it (``hardware.player`` ramps there). A single keyframe
at t > 0 is reached from home by then.

**How the passes enter the trajectory.** ``studio.motion.path`` builds a collision-free path (spline, repair, fingertip
refinement); ``studio.motion.timing`` times keyframe to keyframe with Ruckig and threads repaired/refined path points as
via-points wherever the direct motion would collide, then checks the result at 4× the show rate. So the final
trajectory hits every keyframe exactly at its time, stays within every limit, and is collision-free at every check.
"""

from __future__ import annotations

import json
import logging
import math
import threading
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path as FilePath
from typing import Any

import numpy as np

from studio.atomic import JsonFileError, read_json
from studio.errors import ProgressFn, count, plural, report
from studio.motion.bounds import MAX_KEYFRAMES, MAX_SHOW_S, MAX_SOURCE_FRAME, fmt, is_number, number_problem
from studio.motion.errors import KeyframeCollisionError, PlanError, check_cancel
from studio.motion.limits import JointLimits, LimitsConfig
from studio.motion.path import Path, PathConfig, build_path
from studio.motion.show import KeyframeMarker, Show
from studio.motion.spline import keyframe_spline
from studio.motion.timing import TimedTrajectory, TimingConfig, time_path
from studio.sim.hand import Hand
from studio.sim.physics import CollisionWorld
from studio.sim.roll import file_deg

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PlanConfig:
    """Everything the planner needs besides the keyframes."""

    path: PathConfig = field(default_factory=PathConfig)  # spline, repair and fingertip passes
    timing: TimingConfig = field(default_factory=TimingConfig)  # Ruckig timing and checking
    limits: LimitsConfig = field(default_factory=LimitsConfig)  # velocity/acceleration/jerk limits
    min_segment_s: float = 1e-3  # keyframes closer in time than this are an error


@dataclass
class Keyframes:
    """Artist keyframes: ``times (K,) s`` strictly increasing, ``poses (K, 21) rad``, ``hold (K,) bool``."""

    times: np.ndarray
    poses: np.ndarray
    hold: np.ndarray
    source_frame: list[int | None]  # video/target frame of each keyframe, if known
    target: list[str | None]  # target reference of each keyframe, if known
    extra: dict[str, Any] = field(default_factory=dict)  # title, loss_weights, per-keyframe losses

    @classmethod
    def at(
        cls, times: Sequence[float], poses: Sequence[np.ndarray] | np.ndarray, hold: bool = True, roll: float = 0.0
    ) -> Keyframes:
        """Keyframes from ``times (K,) s`` and ``poses (K, 21) rad`` (held at rest unless ``hold=False``), chosen for
        a mount rolled by ``roll`` rad (``ImitationResult.roll``; the planned show records it, 0: upright)."""
        times_a = np.asarray(times, dtype=float).reshape(-1)
        poses_a = np.asarray(poses, dtype=float).reshape(len(times_a), -1)
        if len(times_a) == 0 or not np.isfinite(times_a).all() or (times_a < 0).any():
            raise PlanError("keyframe times must be finite seconds ≥ 0, at least one")
        if (np.diff(times_a) <= 0).any():
            raise PlanError(f"keyframe times must increase strictly: {times_a.tolist()}")
        n = len(times_a)
        if not math.isfinite(roll):
            raise PlanError(f"the mount roll must be finite radians, not {roll!r}")
        extra = {"roll_deg": file_deg(roll)} if roll else {}
        return cls(times_a, poses_a, np.full(n, bool(hold)), [None] * n, [None] * n, extra)


def parse_keyframes(doc: Any, hand: Hand) -> Keyframes:
    """Validate a POSES.json document; raises ``PlanError`` saying which keyframe is wrong.

    Every field has its JSON type (``"t": "2.5"`` and ``"hold": "false"`` are refused, never read as 2.5 and True) and
    its bounds (:mod:`studio.motion.bounds`): at most ``MAX_KEYFRAMES`` keyframes, times in ``[0, MAX_SHOW_S]``."""
    if not isinstance(doc, dict) or not isinstance(doc.get("keyframes"), list) or not doc["keyframes"]:
        raise PlanError('a keyframes file must be {"keyframes": [{"t": seconds, "pose": {joint: rad}}, ...]}')
    if len(doc["keyframes"]) > MAX_KEYFRAMES:
        raise PlanError(
            f"the file has {len(doc['keyframes'])} keyframes; a show is planned through at most {MAX_KEYFRAMES} "
            "(split it into several shows)"
        )
    times, poses, hold, frames, targets, losses = [], [], [], [], [], []
    for i, k in enumerate(doc["keyframes"]):
        if not isinstance(k, dict) or "t" not in k or not isinstance(k.get("pose"), dict):
            raise PlanError(f'keyframe {i} needs "t" (seconds) and "pose" ({{joint: rad}})')
        problem = _keyframe_field_problem(k)
        if problem:
            raise PlanError(f"keyframe {i}: {problem}")
        try:
            q = hand.pose_from_dict(k["pose"])
            hand.check_theta(q)
        except (TypeError, ValueError) as e:
            raise PlanError(f"keyframe {i} (t = {fmt(k['t'])}): {e}") from None
        times.append(float(k["t"]))
        poses.append(q)
        hold.append(k.get("hold", False))
        frames.append(None if k.get("source_frame") is None else int(k["source_frame"]))
        targets.append(k.get("target"))
        losses.append(k.get("loss", k.get("losses")))
    times_a = np.array(times)
    if (np.diff(times_a) <= 0).any():
        i = int(np.flatnonzero(np.diff(times_a) <= 0)[0]) + 1
        raise PlanError(
            f"keyframe {i} (t = {fmt(times[i])}) is not after keyframe {i - 1} (t = {fmt(times[i - 1])}); "
            "keyframe times must increase"
        )
    for where, entries in (("keyframes", doc["keyframes"]), ("poses", doc.get("poses") or [])):
        ids = [e.get("id") for e in entries if isinstance(e, dict) and e.get("id") is not None]
        repeated = sorted({x for x in ids if ids.count(x) > 1}, key=str)
        if repeated:
            raise PlanError(f"{where}: keyframe id {repeated[0]!r} appears more than once; each id names one keyframe")
    extra = {k: doc[k] for k in ("title", "loss_weights", "media", "calibration", "roll_deg") if k in doc}
    if "roll_deg" in extra and number_problem("roll_deg", extra["roll_deg"], -180, 180, "of degrees"):
        raise PlanError(f"{number_problem('roll_deg', extra['roll_deg'], -180, 180, 'of degrees')} (the mount roll)")
    for key in ("title", "calibration"):
        if extra.get(key) is not None and not isinstance(extra[key], str):
            raise PlanError(f"{key} must be a string, not {extra[key]!r}")
    if any(x is not None for x in losses):
        extra["keyframe_losses"] = losses
    return Keyframes(times_a, np.array(poses), np.array(hold, dtype=bool), frames, targets, extra)


def _keyframe_field_problem(k: dict[str, Any]) -> str | None:
    """What is wrong with the fields of one keyframe entry besides its pose (None when nothing is)."""
    problem = number_problem("t", k["t"], 0.0, MAX_SHOW_S, "of seconds")
    if problem:
        return problem
    if "hold" in k and not isinstance(k["hold"], bool):
        return f'"hold" is {k["hold"]!r}; it must be true or false (JSON booleans, not strings or numbers)'
    frame = k.get("source_frame")
    if frame is not None and (not is_number(frame) or not 0 <= frame <= MAX_SOURCE_FRAME or frame != int(frame)):
        return f'"source_frame" is {frame!r}; it must be a frame index in [0, {MAX_SOURCE_FRAME}] or null'
    if k.get("target") is not None and not isinstance(k["target"], str):
        return f'"target" is {k["target"]!r}; it must be a string (a path or id) or null'
    return None


def load_keyframes(path: str | FilePath, hand: Hand) -> Keyframes:
    """Read and validate a POSES.json file (:func:`parse_keyframes`); a bad file is a ``PlanError`` naming it."""
    path = FilePath(path)
    if not path.is_file():
        raise FileNotFoundError(f"keyframes file not found: {path}")
    try:
        doc = read_json(path, what="keyframes file")
    except JsonFileError as e:
        raise PlanError(str(e)) from None
    try:
        return parse_keyframes(doc, hand)
    except PlanError as e:
        raise PlanError(f"{path}: {e}") from None


def with_home(hand: Hand, kf: Keyframes) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """``(times, poses, at_rest, home_added)``: home (rest pose, t = 0) prepended unless a keyframe is at t = 0."""
    at_rest = kf.hold.copy()
    at_rest[[0, -1]] = True
    if kf.times[0] == 0.0:
        return kf.times, kf.poses, at_rest, False
    return (
        np.concatenate([[0.0], kf.times]),
        np.concatenate([hand.rest_pose()[None], kf.poses]),
        np.concatenate([[True], at_rest]),
        True,
    )


def keyframe_velocities(times: np.ndarray, poses: np.ndarray, at_rest: np.ndarray, hand: Hand) -> np.ndarray:
    """(K, 21) rad/s: the keyframe spline's velocity at each keyframe (``studio.motion.spline.keyframe_spline``, the
    spline the path follows); 0 where at rest or where that joint falls back to linear interpolation."""
    v = keyframe_spline(times, poses, hand.lower, hand.upper).key_velocities()
    v[at_rest] = 0.0
    return v


@dataclass
class PlanResult:
    """What ``plan_show`` returns: the show plus everything needed to inspect how it was made."""

    show: Show
    trajectory: TimedTrajectory
    path: Path
    home_added: bool  # True when the rest pose was prepended at t = 0
    collision_checks: int  # poses scored/checked by the passes and along the trajectory
    max_jerk_ratio: float  # largest |jerk| used / its limit (≤ 1)


def check_keyframes(world: CollisionWorld, poses: np.ndarray, times: np.ndarray) -> None:
    """Raise ``KeyframeCollisionError`` naming each keyframe in self-collision and its touching links."""
    bad = np.flatnonzero(world.in_collision(poses))
    if bad.size:
        parts = []
        for i in bad:
            touching = ", ".join(f"{c.link_a}–{c.link_b}" for c in world.contacts(poses[i]) if c.distance < 0)
            parts.append(f"t = {times[i]:.3f} s ({touching})")
        raise KeyframeCollisionError(
            f"{count(bad.size, 'keyframe')} {plural('is', bad.size)} in self-collision: {'; '.join(parts)}. Keyframes "
            "are never moved: optimise those keyframes again or edit their poses"
        )


def plan_show(
    hand: Hand,
    keyframes: Keyframes,
    cfg: PlanConfig | None = None,
    world: CollisionWorld | None = None,
    progress: ProgressFn | None = None,
    title: str | None = None,
    cancel: threading.Event | None = None,
) -> PlanResult:
    """Plan a show through ``keyframes``. Raises ``KeyframeCollisionError``, ``PathError``, ``SegmentTooFastError``.

    Reports stages "keyframes" (0 of K at once, K of K when every keyframe is checked for collisions), "path"
    (:func:`~studio.motion.path.build_path`: a step per segment walked and repaired, then the fingertip pass and the
    corners), "timing" (:func:`~studio.motion.timing.time_path`: a step per segment timed and
    collision-checked along the trajectory) and "show" (1 of 1: sampled). Setting ``cancel`` raises
    :class:`~studio.motion.errors.PlanCancelled` (a :class:`~studio.errors.Cancelled`, not a ``PlanError``) between
    the stages and within one collision query or timing round inside them: half a plan is no show, so there is
    nothing to return."""
    cfg = cfg or PlanConfig()
    own_world = world is None
    world = world or CollisionWorld(hand)
    try:
        times, poses, at_rest, home = with_home(hand, keyframes)
        if (np.diff(times) < cfg.min_segment_s).any():
            raise PlanError(f"keyframes must be at least {cfg.min_segment_s} s apart (home is at t = 0)")
        check_cancel(cancel)
        report(progress, "keyframes", 0, len(poses))  # shown at once: checking thousands of keyframes takes seconds
        check_keyframes(world, poses, times)
        report(progress, "keyframes", len(poses), len(poses))
        limits = JointLimits.from_hand(hand, cfg.limits)
        path = build_path(hand, world, times, poses, cfg.path, progress, cancel)
        check_cancel(cancel)
        kv = keyframe_velocities(times, poses, at_rest, hand)
        traj = time_path(path, kv, limits, world, cfg.timing, progress, cancel)
        check_cancel(cancel)
        show = sample_show(hand, traj, keyframes, home, limits, cfg, title)
        report(progress, "show", 1, 1)
    finally:
        if own_world:
            world.close()
    return PlanResult(show, traj, path, home, traj.collision_checks, traj.max_jerk_ratio(limits.jerk))


def sample_show(
    hand: Hand, traj: TimedTrajectory, kf: Keyframes, home: bool, limits: JointLimits, cfg: PlanConfig, title
) -> Show:
    """Sample ``traj`` on the 40 Hz grid plus every keyframe time (so keyframes are samples) into a show."""
    rate = cfg.timing.rate_hz
    grid = np.arange(int(np.floor(traj.duration * rate + 1e-9)) + 1) / rate
    times = np.union1d(grid, traj.key_times)
    times = times[np.concatenate([[True], np.diff(times) > 1e-9])]
    times[np.searchsorted(times, traj.key_times - 1e-9)] = traj.key_times  # snap near-duplicates onto keyframes
    positions = np.clip(traj.state(times)[0], hand.lower, hand.upper)
    key_t = traj.key_times[1:] if home else traj.key_times
    markers = [
        KeyframeMarker(float(t), kf.source_frame[i], kf.target[i], bool(kf.hold[i])) for i, t in enumerate(key_t)
    ]
    extra = dict(kf.extra)
    provenance = {
        "planner": "studio.motion.plan",
        "home_added": home,
        "requested_times": kf.times.tolist(),
        "late_segments": [asdict(s) for s in traj.late],
        "config": json.loads(json.dumps(asdict(cfg), default=str)),
    }
    for key in ("loss_weights", "keyframe_losses"):
        if key in extra:
            provenance[key] = extra[key]
    return Show.from_samples(
        hand, times, positions, title=title or extra.get("title", "untitled"), keyframes=markers, limits=limits,
        calibration=extra.get("calibration"), provenance=provenance,
        roll=math.radians(float(extra.get("roll_deg", 0.0))),  # the mount the poses were chosen for
    )  # fmt: skip
