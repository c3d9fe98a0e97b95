"""A project's frames and keyframes on the ``frame`` timeline (plain data in).

:func:`log_frames` takes arrays and :class:`KeyframeReview` s (no Project needed): at frame k the target, its
expressive mask, which keyframe it plays and that keyframe's self-model and rendered shadows, losses, and (given the
hand and rig) the hand at that keyframe's pose with the backdrop carrying its shadow. A keyframe's images and pose
are logged only where the frame's keyframe changes (Rerun shows the latest row at or before the time), so a long
clip of few keyframes stays small; where the new keyframe has none yet, the old ones are cleared (the hand rests).
The keyframe per frame, the losses and the keyframes' log lines are logged whole (:func:`log_frame_series`),
replacing what was logged before, on ``show_time`` too when the show is current: a plot drawn under the show player
follows the show.
A job's progress on ``opt_step``: :mod:`studio.review.job_progress`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from studio.review.blueprint import (
    BACKDROP,
    EXPRESSIVE,
    FRAME,
    FRAME_LOSS,
    KEYFRAME_OF_FRAME,
    KEYFRAMES_LOG,
    RENDERED,
    SELF_MODEL,
    SHOW_TIME,
    SOURCE,
    TARGET,
    part,
    set_time,
    time_column,
)
from studio.review.rig3d import RigReview, backdrop, log_poses, urdf_tree
from studio.review.series import VersionedLog, digest
from studio.review.sheets import display, tint
from studio.sim.hand import Hand
from studio.sim.shadow import Rig, ShadowRenderer


@dataclass(frozen=True, eq=False)
class KeyframeReview:
    """One keyframe as a review shows it (plain data; a Project's keyframe with its result)."""

    id: int  # the keyframe's stable id
    representative: int  # the frame whose target its pose imitates
    members: tuple[int, ...]  # the frames that play its pose
    theta: np.ndarray | None = None  # (21,) rad, its optimised pose (None: not optimised yet)
    shadow: np.ndarray | None = None  # (R, R) uint8 {0, 1}, the rendered shadow of that pose (rig window)
    self_model: np.ndarray | None = None  # (R, R) float in [0, 1], the self-model's shadow of that pose
    loss: Mapping[str, float] = field(default_factory=dict)  # loss components (NaN: not computed)
    stale: bool = False  # the result was computed from inputs that have changed since


def assignment(keyframes: Sequence[KeyframeReview], n: int) -> np.ndarray:
    """``(n,)`` int: each frame's keyframe as its position in ``keyframes`` (-1 for a frame in none)."""
    out = np.full(n, -1, dtype=np.int64)
    for i, kf in enumerate(keyframes):
        out[list(kf.members)] = i
    return out


def _changes(a: np.ndarray) -> np.ndarray:
    """Indices where ``a (N,)`` differs from its previous entry (0 always)."""
    return np.flatnonzero(np.r_[True, a[1:] != a[:-1]]) if len(a) else np.zeros(0, dtype=np.int64)


def _finite(loss: Mapping[str, float]) -> dict[str, float]:
    return {k: float(v) for k, v in loss.items() if v is not None and math.isfinite(float(v))}


def log_frames(
    rec: rr.RecordingStream,
    targets: np.ndarray,
    expressive: np.ndarray,
    keyframes: Sequence[KeyframeReview],
    sources: Sequence[np.ndarray | None] | None = None,
    times: np.ndarray | None = None,
    hand: Hand | None = None,
    rig: Rig | None = None,
    cfg: RigReview | None = None,
    versions: VersionedLog | None = None,
    show_times: np.ndarray | None = None,
    logged: FramesLogged | None = None,
) -> np.ndarray:
    """Frames ``targets (N, S, S)`` (1 = shadow) with their ``expressive (N, S, S)`` masks, RGB ``sources`` (one
    ``(H, W, 3)`` image or None per frame) when given, and their ``keyframes`` (first-appearance order), on ``frame``
    (module doc). ``times (N,)`` s, when given, go into the keyframes' log lines. With ``hand`` and ``rig`` the 3D
    rig shows each frame's keyframe pose, the backdrop its shadow (rendered at ``cfg.texture`` when a keyframe has a
    pose but no shadow). The keyframe per frame, the losses and the keyframes' lines are logged whole
    (:func:`log_frame_series`, through ``versions``: the recording's, so that they replace what it logged before;
    given ``show_times (N,)``, on ``show_time`` too). ``logged``: what earlier calls logged on this recording (the
    recording's; updated): a keyframe's images, pose and backdrop are logged where the frame's keyframe changes *and*
    wherever an earlier call logged them, since Rerun would otherwise show an earlier keyframe's row from there on
    (after the keyframes change, frames 5-9 kept showing the old keyframe of frame 5); frames an earlier call had
    beyond the last one now are cleared. Returns the assignment ``(N,)`` (:func:`assignment`)."""
    n = len(targets)
    if expressive.shape != targets.shape:
        raise ValueError(f"expressive masks {expressive.shape} must match the targets {targets.shape}")
    which = assignment(keyframes, n)
    logged = logged or FramesLogged()
    rows = sorted(set(_changes(which).tolist()) | {k for k in logged.keyframe_rows if k < n})
    drawn = {k: _keyframe_row(keyframes[which[k]] if which[k] >= 0 else None, rig) for k in rows}
    at = [k for k in rows if logged.keyframe_rows.get(k) != drawn[k]]  # only where it would draw something else
    for k in range(n):  # each image only when it differs from what an earlier call logged at that frame
        set_time(rec, frame=k)
        if logged.fresh(TARGET, k, targets[k]):
            rec.log(TARGET, rr.Image(display(targets[k])))
        if logged.fresh(EXPRESSIVE, k, targets[k], expressive[k]):
            rec.log(EXPRESSIVE, rr.Image(tint(targets[k], expressive[k])))
        if sources is not None and logged.fresh(SOURCE, k, sources[k]):  # a frame without one clears an earlier's
            rec.log(SOURCE, rr.Clear(recursive=False) if sources[k] is None else rr.Image(np.asarray(sources[k])))
    for k in at:  # a keyframe without them (or a frame in none) clears the previous keyframe's images
        set_time(rec, frame=k)
        kf = keyframes[which[k]] if which[k] >= 0 else None
        for entity, image in ((RENDERED, None if kf is None else kf.shadow),
                              (SELF_MODEL, None if kf is None else kf.self_model)):  # fmt: skip
            rec.log(entity, rr.Clear(recursive=False) if image is None else rr.Image(display(image)))
    for k in range(n, logged.count):  # frames an earlier call had and this one has not
        set_time(rec, frame=k)
        for entity in (TARGET, EXPRESSIVE, SOURCE, RENDERED, SELF_MODEL, BACKDROP):
            rec.log(entity, rr.Clear(recursive=False))
            logged.images.pop((entity, k), None)
    log_frame_series(versions or VersionedLog(rec), keyframes, which, times, show_times)
    if hand is not None and rig is not None:
        gone = np.arange(n, logged.count)  # ... where the hand rests
        _log_frame_rig(rec, hand, rig, keyframes, which, cfg or RigReview(), at)
        if len(gone):
            log_poses(rec, hand, urdf_tree(hand), FRAME, gone, np.repeat(hand.rest_pose()[None], len(gone), 0))
    cleared = {k: b"cleared" for k in range(n, logged.count)}  # logged again when such a frame comes back
    logged.keyframe_rows = {**{k: v for k, v in logged.keyframe_rows.items() if k >= n}, **cleared, **drawn}
    logged.count = n
    rec.reset_time()
    return which


@dataclass
class FramesLogged:
    """What :func:`log_frames` logged on one recording so far (it updates it)."""

    count: int = 0  # frames logged
    # frame → a digest of the keyframe images, pose and backdrop logged there (where a frame's keyframe changes)
    keyframe_rows: dict[int, bytes] = field(default_factory=dict)
    images: dict[tuple[str, int], bytes] = field(default_factory=dict)  # (entity, frame) → digest of what it shows

    def fresh(self, entity: str, frame: int, *arrays: np.ndarray | None) -> bool:
        """Whether the image made from ``arrays`` differs from the one logged at ``frame`` on ``entity`` (then it
        is remembered as logged): the notebook logs the whole project after every edit, most frames unchanged."""
        key = digest(*arrays)
        if self.images.get((entity, frame)) == key:
            return False
        self.images[(entity, frame)] = key
        return True


def _keyframe_row(kf: KeyframeReview | None, rig: Rig | None) -> bytes:
    """A digest of what :func:`log_frames` draws at a row where ``kf`` starts to play (None: a frame in none)."""
    if kf is None:
        return b"none"
    pose = None if kf.theta is None else np.asarray(kf.theta, np.float64)
    roll = np.array([np.nan if rig is None else rig.roll])
    return digest(kf.shadow, kf.self_model, pose, roll)


def log_frame_series(
    versions: VersionedLog,
    keyframes: Sequence[KeyframeReview],
    which: np.ndarray,
    times: np.ndarray | None = None,
    show_times: np.ndarray | None = None,
) -> None:
    """Which keyframe each frame plays (``which (N,)``, -1: none) on ``frames/keyframe``, the loss components of
    each frame's keyframe result on ``loss/frame/<component>`` (frames without one left out) and each keyframe's
    line on ``log/keyframes`` at its representative frame (``times (N,)`` s, when given, in the lines), on ``frame``
    and, given ``show_times (N,)`` s (where each frame starts to play in a current show), on ``show_time`` too; each
    replaces what was logged there before (:mod:`studio.review.series`)."""
    n = len(which)
    if show_times is not None and np.shape(show_times) != (n,):
        raise ValueError(f"{n} frames need as many show times, not {np.shape(show_times)}")

    def index(rows) -> list[rr.TimeColumn]:
        rows = np.asarray(rows, dtype=np.int64)
        cols = [time_column(FRAME, rows)]
        return cols if show_times is None else [*cols, time_column(SHOW_TIME, np.asarray(show_times, float)[rows])]

    versions.scalars(KEYFRAME_OF_FRAME, index(np.arange(n)), which.astype(np.float64), name="keyframe", points=True)
    losses: dict[str, list[tuple[int, float]]] = {}
    for k in range(n):
        if which[k] >= 0:
            for name, value in _finite(keyframes[which[k]].loss).items():
                losses.setdefault(part(name), []).append((k, value))
    for name in sorted(set(losses) | _loss_names(versions)):
        rows = [k for k, _ in losses.get(name, [])]
        versions.scalars(f"{FRAME_LOSS}/{name}", index(rows), np.array([v for _, v in losses.get(name, [])]))
    lines = sorted((kf.representative, _keyframe_line(pos, kf, times)) for pos, kf in enumerate(keyframes)
                   if 0 <= kf.representative < n and which[kf.representative] == pos)  # fmt: skip
    versions.text(KEYFRAMES_LOG, index([k for k, _ in lines]), [line for _, line in lines])


def _loss_names(versions: VersionedLog) -> set[str]:
    """The loss components with a series on show (a component no result has now is hidden)."""
    prefix = f"{FRAME_LOSS}/"
    return {path[len(prefix) :] for path in versions.paths() if path.startswith(prefix) and versions.shown(path)}


def _keyframe_line(pos: int, kf: KeyframeReview, times: np.ndarray | None) -> str:
    at = "" if times is None else f" at {float(times[kf.representative]):.2f} s"
    loss = _finite(kf.loss).get("total")
    result = "no result yet" if kf.theta is None else f"loss {loss:.3f}" if loss is not None else "optimised"
    stale = ", stale: its inputs changed since" if kf.stale else ""
    plays = f"plays {len(kf.members)} frames"
    return f"keyframe {pos} (id {kf.id}): frame {kf.representative}{at}, {plays}; {result}{stale}"


def _log_frame_rig(rec, hand: Hand, rig: Rig, keyframes, which: np.ndarray, cfg: RigReview, at: list[int]) -> None:
    """The hand and the backdrop on ``frame`` at the frames ``at`` (where the frame's keyframe changes, and where
    they were logged before): its pose and shadow, or the rest pose and a bare backdrop for a keyframe not optimised
    yet or a frame in none."""
    if not at:
        return
    chosen = [keyframes[which[k]] if which[k] >= 0 else None for k in at]
    rest = hand.rest_pose()
    theta = np.stack([rest if kf is None or kf.theta is None else np.asarray(kf.theta, np.float64) for kf in chosen])
    log_poses(rec, hand, urdf_tree(hand), FRAME, np.array(at), theta)
    renderer = None
    for k, kf, th in zip(at, chosen, theta):
        set_time(rec, frame=k)
        if kf is None or kf.theta is None:
            rec.log(BACKDROP, rr.Clear(recursive=False))
            continue
        shadow = kf.shadow
        if shadow is None:
            renderer = renderer or ShadowRenderer(hand, rig.with_resolution(cfg.texture))
            shadow = renderer.render_one(th)
        rec.log(BACKDROP, backdrop(rig, shadow))
