"""Review in Rerun: the only module that imports ``rerun`` (DESIGN §5.6).

Entity layout: ``world/hand/<link>/<child link>/...`` follows the kinematic tree (each link's transform relative to
its parent, the shell geometry logged once, static, under ``.../shell``); ``images/*`` are shadows in display
convention (dark shadow on a light backdrop); ``loss/*`` are scalar curves. Timelines: ``opt_step`` (search then
refinement steps), ``frame`` and ``show_time`` (sequences and shows). The viewer layout is declared in code.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "inline")  # notebooks must not fetch the viewer from the internet

import rerun as rr  # noqa: E402
import rerun.blueprint as rrb  # noqa: E402

from studio.sim.hand import Hand  # noqa: E402
from studio.sim.kinematics import axis_angle_matrices  # noqa: E402

HAND_ROOT = "world/hand"
SHELL_COLOR = (40, 40, 40, 255)


def link_paths(hand: Hand, root: str = HAND_ROOT) -> dict[str, str]:
    """Entity path of every link, nested along the kinematic tree."""
    paths = {hand.root: f"{root}/{hand.root}"}
    for j in hand.joints:
        paths[j.child] = f"{paths[j.parent]}/{j.child}"
    return paths


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()  # scipy's order is (x, y, z, w), as Rerun expects


def log_hand_model(rec: rr.RecordingStream, hand: Hand, root: str = HAND_ROOT) -> None:
    """The light-blocking shell of every link, static, in its link frame."""
    paths = link_paths(hand, root)
    for link, path in paths.items():
        caps_len, caps_r, caps_t, caps_q, box_h, box_c, box_q = [], [], [], [], [], [], []
        for g in hand.visuals.get(link, ()):
            R, c = g.T_link_geom[:3, :3], g.T_link_geom[:3, 3]
            if g.kind in ("capsule", "sphere"):
                # Rerun capsules start at their translation and extend along their local +z by ``length``
                caps_len.append(g.length)
                caps_r.append(g.radius)
                caps_t.append(c - R @ np.array([0.0, 0.0, g.length / 2]))
                caps_q.append(_quat_xyzw(R))
            else:
                box_h.append(np.array(g.size) / 2)
                box_c.append(c)
                box_q.append(_quat_xyzw(R))
        if caps_len:
            caps = rr.Capsules3D(
                lengths=caps_len, radii=caps_r, translations=caps_t, quaternions=caps_q, colors=SHELL_COLOR
            )
            rec.log(f"{path}/shell/capsules", caps, static=True)
        if box_h:
            boxes = rr.Boxes3D(
                half_sizes=box_h, centers=box_c, quaternions=box_q, colors=SHELL_COLOR, fill_mode="solid"
            )
            rec.log(f"{path}/shell/boxes", boxes, static=True)


def log_pose(rec: rr.RecordingStream, hand: Hand, theta: np.ndarray, root: str = HAND_ROOT) -> None:
    """Each link's transform relative to its parent for joint angles ``theta (21,)`` at the current time."""
    paths = link_paths(hand, root)
    for j, joint in enumerate(hand.joints):
        T = joint.T_parent_joint.copy()
        T[:3, :3] = T[:3, :3] @ axis_angle_matrices(joint.axis, np.array([theta[j]]))[0]
        rec.log(paths[joint.child], rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))


def display(mask: np.ndarray) -> np.ndarray:
    """Shadow probabilities/mask ``(H, W)`` (1 = shadow) → uint8 image, dark shadow on a light backdrop."""
    return (255 * (1.0 - np.clip(np.asarray(mask, dtype=float), 0, 1))).astype(np.uint8)


def overlay(target: np.ndarray, shadow: np.ndarray, aligned: bool = True) -> np.ndarray:
    """RGB ``(H, W, 3)``: both = black, target only = red, shadow only = blue, neither = white.

    ``aligned``: compare the bounding-box crops the losses compare (position and scale removed), as the
    optimiser sees them, at the target's resolution."""
    if aligned:
        from studio.sim.crop import align

        size = target.shape[-1]
        t = align(np.asarray(target, np.float32), size)[0][0].numpy() > 0.5
        s = align(np.asarray(shadow, np.float32), size)[0][0].numpy() > 0.5
    else:
        t, s = target.astype(bool), shadow.astype(bool)
    img = np.full(t.shape + (3,), 255, np.uint8)
    img[t & ~s] = (220, 40, 40)
    img[s & ~t] = (40, 90, 220)
    img[t & s] = (0, 0, 0)
    return img


def imitation_blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Horizontal(
                    rrb.Spatial2DView(origin="images/target", name="target"),
                    rrb.Spatial2DView(origin="images/self_model", name="self-model"),
                    rrb.Spatial2DView(origin="images/rendered", name="rendered"),
                    rrb.Spatial2DView(origin="images/overlay", name="overlay"),
                ),
                rrb.TimeSeriesView(origin="loss", name="loss"),
            ),
            rrb.Spatial3DView(origin="world", name="hand"),
            column_shares=[2, 1],
        ),
        collapse_panels=True,
    )


def log_imitation(path: Path, result, hand: Hand, name: str = "target", notes: str = "") -> Path:
    """Write an ``.rrd`` reviewing one imitation (``studio.imitate.still.ImitationResult``); returns the path."""
    path = Path(path)
    rec = rr.RecordingStream("shadow_studio", recording_id=f"imitate-{name}")
    rec.save(str(path), default_blueprint=imitation_blueprint())
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
    log_hand_model(rec, hand)
    rec.log("images/target", rr.Image(display(result.target)), static=True)
    if notes:
        rec.log("notes", rr.TextDocument(notes), static=True)
    rec.set_time("opt_step", sequence=0)
    log_pose(rec, hand, result.search.batch_theta[0])
    for step, best, mean in result.search.curve:
        rec.set_time("opt_step", sequence=step)
        rec.log("loss/search/best", rr.Scalars(best))
        rec.log("loss/search/mean", rr.Scalars(mean))
    n = result.search.iterations
    rec.set_time("opt_step", sequence=n)
    log_pose(rec, hand, result.unrefined_theta)
    rec.log("images/self_model", rr.Image(display(result.predicted)))
    rec.log("images/rendered", rr.Image(display(result.unrefined_shadow)))
    rec.log("images/overlay", rr.Image(overlay(result.target, result.unrefined_shadow)))
    rec.log("loss/rendered/total", rr.Scalars(result.unrefined_loss["total"]))
    if result.refine is not None:
        for step, best in result.refine.curve:
            if np.isfinite(best):
                rec.set_time("opt_step", sequence=n + step)
                rec.log("loss/refine/best", rr.Scalars(best))
        rec.set_time("opt_step", sequence=n + (result.refine.curve[-1][0] if result.refine.curve else 0))
        log_pose(rec, hand, result.theta)
        rec.log("images/rendered", rr.Image(display(result.shadow)))
        rec.log("images/overlay", rr.Image(overlay(result.target, result.shadow)))
        rec.log("loss/rendered/total", rr.Scalars(result.loss["total"]))
    rec.flush()
    rec.disconnect()
    return path


def video_blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Horizontal(
                    rrb.Spatial2DView(origin="video/source", name="source"),
                    rrb.Spatial2DView(origin="video/target", name="target"),
                    rrb.Spatial2DView(origin="video/expressive", name="expressive"),
                    rrb.Spatial2DView(origin="video/shadow", name="keyframe shadow"),
                    rrb.Spatial2DView(origin="video/overlay", name="overlay"),
                ),
                rrb.TimeSeriesView(origin="loss", name="loss per frame"),
            ),
            rrb.Vertical(
                rrb.Spatial3DView(origin="world", name="hand (show_time)"),
                rrb.Spatial2DView(origin="show/shadow", name="show shadow"),
            ),
            column_shares=[2, 1],
        ),
        collapse_panels=True,
    )


def log_video(
    path: Path,
    hand: Hand,
    masks: np.ndarray,
    expressive: np.ndarray,
    shadows: np.ndarray,
    frames: np.ndarray | None = None,
    keyframe: np.ndarray | None = None,
    losses: np.ndarray | None = None,
    show=None,
    show_shadows: np.ndarray | None = None,
    name: str = "video",
    notes: str = "",
) -> Path:
    """Write an ``.rrd`` reviewing a video's imitation and its show; returns the path.

    On the ``frame`` timeline (sampled frame k): ``video/source`` (RGB ``frames (N, S, S, 3)``, if given),
    ``video/target`` (``masks (N, S, S)``), ``video/expressive`` (``expressive (N, S, S)``), ``video/shadow``
    (``shadows (N, R, R)``: each frame's keyframe shadow), ``video/overlay``, and the scalars ``video/keyframe``
    (``keyframe (N,)``, its keyframe number) and ``loss/total`` (``losses (N,)``). On ``show_time`` (s): the hand
    of ``show`` (a ``studio.motion.show.Show``) at every sample under ``world/hand``, ``show/shadow`` (the rendered
    ``show_shadows (T, R, R)``, one per show sample) and its keyframe markers in ``show/keyframes``."""
    path = Path(path)
    rec = rr.RecordingStream("shadow_studio", recording_id=f"imitate-video-{name}")
    rec.save(str(path), default_blueprint=video_blueprint())
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
    log_hand_model(rec, hand)
    if notes:
        rec.log("notes", rr.TextDocument(notes), static=True)
    for k in range(len(masks)):
        rec.set_time("frame", sequence=k)
        if frames is not None:
            rec.log("video/source", rr.Image(frames[k]))
        rec.log("video/target", rr.Image(display(masks[k])))
        rec.log("video/expressive", rr.Image(display(expressive[k])))
        rec.log("video/shadow", rr.Image(display(shadows[k])))
        if shadows[k].shape == masks[k].shape and masks[k].any() and shadows[k].any():
            rec.log("video/overlay", rr.Image(overlay(masks[k], shadows[k])))
        if keyframe is not None:
            rec.log("video/keyframe", rr.Scalars(float(keyframe[k])))
        if losses is not None and np.isfinite(losses[k]):
            rec.log("loss/total", rr.Scalars(float(losses[k])))
    if show is not None:
        rec.reset_time()  # the show's entities live on show_time only, not at the last frame
        for m in show.keyframes:
            rec.set_time("show_time", duration=float(m.t))
            rec.log("show/keyframes", rr.TextLog(f"keyframe at {m.t:.3f} s (source frame {m.source_frame})"))
        for i, t in enumerate(show.times):
            rec.set_time("show_time", duration=float(t))
            log_pose(rec, hand, show.positions[i])
            if show_shadows is not None:
                rec.log("show/shadow", rr.Image(display(show_shadows[i])))
    rec.flush()
    rec.disconnect()
    return path


def read_recording(path: Path) -> dict[str, dict]:
    """Read an ``.rrd`` back: ``{entity_path: {"static": bool, "rows": int, "columns": [...], "timelines": [...]}}``.

    For tests and tools that check what a recording holds (reads Rerun's own file format).
    """
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # a stream saved by `rerun --save` has no footer: read it whole (below)
        warnings.filterwarnings("ignore", message=".*no footer.*")
        reader = RrdReader(str(path))
    try:
        chunks = reader.store().stream()
    except RuntimeError:  # no footer/manifest (a live stream's file): scan the whole file
        chunks = reader.stream()
    out: dict[str, dict] = {}
    for chunk in chunks:
        batch = chunk.to_record_batch()
        entry = out.setdefault(
            chunk.entity_path, {"static": chunk.is_static, "rows": 0, "columns": set(), "timelines": set()}
        )
        entry["rows"] += chunk.num_rows
        entry["columns"] |= set(batch.schema.names)
        entry["timelines"] |= set(chunk.timeline_names)
        entry.setdefault("batches", []).append(batch)
    return out


def scalar_series(recording: dict[str, dict], entity: str, timeline: str = "opt_step") -> list[tuple[float, float]]:
    """``(time, value)`` pairs of a ``Scalars`` entity read by :func:`read_recording`: steps (int) on sequence
    timelines, seconds (float) on duration timelines; rows without ``timeline`` are left out."""
    import pyarrow as pa

    values: list[tuple[float, float]] = []
    for batch in recording.get(entity, {}).get("batches", []):
        if timeline not in batch.schema.names or "Scalars:scalars" not in batch.schema.names:
            continue
        column = batch.column(timeline)
        seconds = pa.types.is_duration(column.type)
        times = column.cast(pa.int64()).to_pylist()  # steps, or nanoseconds on a duration timeline
        for t, v in zip(times, batch.column("Scalars:scalars").to_pylist()):
            if t is not None and v is not None:
                values.append((t / 1e9 if seconds else int(t), float(v[0])))
    return sorted(values)
