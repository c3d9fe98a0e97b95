"""The rig in Rerun's 3D view: the hand loaded from its URDF, the point light, and the backdrop carrying the shadow.

World frame = the rig's (DESIGN §1: palm centre at the origin, +y up, the light on +z, the backdrop at
``z = backdrop_z``). The hand's links are the URDF's transform frames (Rerun's URDF loader names them after the
links); the root link's frame is the world's (``tf#/world``). Joint angles become one transform per joint
(``world/pose/<joint>``, parent link → child link, :class:`rerun.urdf.UrdfTree`), logged for many instants at once
as columns. The backdrop is the rig's square image window as a textured quad whose texture is the rendered shadow
(row 0 at +y, column 0 at -x, as the shadow images are: seen from the light).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
from rerun.urdf import UrdfTree

from studio.motion.show import Show
from studio.review.blueprint import (
    BACKDROP,
    HAND,
    LIGHT,
    POSE,
    SHOW_LOG,
    SHOW_TIME,
    WORLD,
    part,
    pose_path,
    set_time,
    time_column,
)
from studio.review.series import VersionedLog
from studio.review.sheets import tint
from studio.sim.hand import Hand
from studio.sim.shadow import Rig, ShadowRenderer

LIGHT_COLOR = (255, 210, 60)  # RGB of the light's marker and rays
EDGE_COLOR = (120, 120, 120)  # RGB of the backdrop window's outline


@dataclass(frozen=True)
class RigReview:
    """How the rig is drawn in a review."""

    texture: int = 128  # pixels per side of the backdrop's shadow texture (RGB, so 3·texture² bytes per instant)
    show_hz: float = 10.0  # backdrop textures per second of show (the hand's pose is logged at every show sample)
    light_radius: float = 0.04  # m, radius of the light's marker
    rays: bool = True  # draw the light's rays to the corners of the backdrop window


def urdf_tree(hand: Hand) -> UrdfTree:
    """Rerun's view of the hand's URDF (joint transforms by link-frame name)."""
    if hand.urdf_path.is_file() and hand.urdf_path.read_text() == hand.urdf_text:
        return UrdfTree.from_file_path(str(hand.urdf_path))
    with tempfile.TemporaryDirectory() as tmp:  # a hand parsed from text: give the parser a file
        path = Path(tmp) / "hand.urdf"
        path.write_text(hand.urdf_text)
        return UrdfTree.from_file_path(str(path))


def window_corners(rig: Rig) -> np.ndarray:
    """The backdrop window's corners ``(4, 3)`` m: top-left, top-right, bottom-right, bottom-left (seen from the
    light: +y up, +x right)."""
    h, z = rig.window / 2, rig.backdrop_z
    return np.array([[-h, h, z], [h, h, z], [h, -h, z], [-h, -h, z]])


def log_rig(rec: rr.RecordingStream, hand: Hand, rig: Rig, cfg: RigReview | None = None) -> None:
    """Log, static: the world's axes (+y up), the hand's URDF (shell and skeleton, its links as frames, the root link
    at the world origin), the light's marker and rays, and the backdrop window's outline."""
    cfg = cfg or RigReview()
    rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
    rec.log_file_from_contents("hand.urdf", hand.urdf_text.encode(), entity_path_prefix=HAND, static=True)
    log_mount(rec, hand, rig.roll)
    light = np.asarray(rig.light, dtype=float)
    rec.log(LIGHT, rr.Points3D([light], radii=cfg.light_radius, colors=LIGHT_COLOR, labels="light"), static=True)
    corners = window_corners(rig)
    if cfg.rays:
        rays = rr.LineStrips3D([[light, c] for c in corners], radii=0.002, colors=LIGHT_COLOR)
        rec.log(f"{LIGHT}/rays", rays, static=True)
    outline = rr.LineStrips3D([np.vstack([corners, corners[:1]])], radii=0.004, colors=EDGE_COLOR)
    rec.log(f"{BACKDROP}/edge", outline, static=True)


def log_mount(rec: rr.RecordingStream, hand: Hand, roll: float) -> None:
    """The hand's root link at the world origin, rolled by ``roll`` rad about the light (z) axis (static: the last
    logged mount is the one drawn)."""
    root = rr.Transform3D(translation=[0.0, 0.0, 0.0], rotation=rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0],
                          radians=float(roll)), parent_frame=f"tf#/{WORLD}", child_frame=hand.root)  # fmt: skip
    rec.log(f"{POSE}/{part(hand.root)}", root, static=True)


def log_poses(
    rec: rr.RecordingStream, hand: Hand, tree: UrdfTree, timeline: str, times: np.ndarray, theta: np.ndarray
) -> None:
    """The hand at joint angles ``theta (T, 21) rad`` (hand order) at ``times (T,)`` on ``timeline`` (steps on
    ``frame``/``opt_step``, seconds on the others): one column of transforms per joint."""
    theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
    if theta.shape != (len(times), hand.dof):
        raise ValueError(f"theta must be ({len(times)}, {hand.dof}) for {len(times)} times; got {theta.shape}")
    index = [time_column(timeline, times)]
    for j, name in enumerate(hand.joint_names):
        joint = tree.get_joint_by_name(name)
        if joint is None:
            raise ValueError(f"joint {name} is not in the URDF Rerun read ({tree.name})")
        cols = joint.compute_transform_columns(theta[:, j].tolist(), clamp=False)
        rec.send_columns(pose_path(name), indexes=index, columns=cols)


def backdrop(rig: Rig, shadow: np.ndarray) -> rr.Mesh3D:
    """The backdrop window as a quad textured with ``shadow (R, R)`` (1 = shadow), dark shadow on a grey backdrop."""
    texture = tint(np.asarray(shadow))
    return rr.Mesh3D(
        vertex_positions=window_corners(rig),
        triangle_indices=[[0, 3, 2], [0, 2, 1]],  # counter-clockwise seen from the light
        vertex_normals=[[0.0, 0.0, 1.0]] * 4,
        vertex_texcoords=[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],  # Rerun's uv origin is the top-left
        albedo_texture=texture,
    )


def show_instants(show: Show, hz: float) -> np.ndarray:
    """Times ``(K,)`` s at which the backdrop is textured: every ``1/hz`` s from 0, and the show's end."""
    t = np.arange(0.0, show.duration + 1e-9, 1.0 / hz)
    if show.duration - t[-1] > 1e-6:
        t = np.append(t, show.duration)
    return t + float(show.times[0])


@dataclass
class ShowsLogged:
    """What :func:`log_show` logged on one recording so far (it updates it)."""

    show: Show | None = None  # the show logged last
    shadows: np.ndarray | None = None  # (K, R, R) uint8 its backdrop shadows
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (M,) s every show time a pose or backdrop has


def same_show(a: Show, b: Show) -> bool:
    """Whether two shows put the same hand at the same poses and times, with the same markers, roll and title
    (what :func:`log_show` draws)."""
    if a is b:
        return True
    same_arrays = np.array_equal(a.times, b.times) and np.array_equal(a.positions, b.positions)
    return same_arrays and (a.roll, a.title, a.keyframes) == (b.roll, b.title, b.keyframes)


def log_show(
    rec: rr.RecordingStream,
    hand: Hand,
    rig: Rig,
    show: Show,
    cfg: RigReview | None = None,
    tree: UrdfTree | None = None,
    renderer: ShadowRenderer | None = None,
    versions: VersionedLog | None = None,
    logged: ShowsLogged | None = None,
) -> np.ndarray:
    """The planned ``show`` on ``show_time``: the hand at every sample (mounted at the show's roll), the keyframe
    markers, and the backdrop textured with the rendered shadow of the show's pose every ``1/cfg.show_hz`` s, as
    that mount casts it. The show's log lines replace the last show's through ``versions`` (the recording's;
    :mod:`studio.review.series`). ``logged``: what earlier calls logged on this recording (the recording's; updated):
    the show logged last is not logged again (the notebook logs the project after every edit), and after a shorter
    show every time an earlier show reached shows this one's last pose and shadow (Rerun shows the latest row at or
    before the time in view, which there was the earlier show's). Returns the shadows ``(K, R, R)`` uint8 put on
    the backdrop, R = ``cfg.texture``, at :func:`show_instants`."""
    logged = logged or ShowsLogged()
    if logged.show is not None and same_show(logged.show, show):
        return logged.shadows
    cfg = cfg or RigReview()
    tree = tree or urdf_tree(hand)
    rig = rig.with_roll(show.roll)
    renderer = renderer or ShadowRenderer(hand, rig.with_resolution(cfg.texture))
    log_mount(rec, hand, show.roll)
    log_poses(rec, hand, tree, SHOW_TIME, show.times, show.positions)
    lines = [(float(show.times[0]), f"show {show.title!r}: {len(show.times)} samples, {show.duration:.2f} s")]
    for m in show.keyframes:
        where = "" if m.source_frame is None else f" (source frame {m.source_frame})"
        lines.append((float(m.t), f"keyframe at {m.t:.3f} s{where}{', held' if m.hold else ''}"))
    at = np.array([t for t, _ in lines])
    (versions or VersionedLog(rec)).text(SHOW_LOG, [time_column(SHOW_TIME, at)], [line for _, line in lines])
    instants = show_instants(show, cfg.show_hz)
    shadows = renderer.render(show.sample(instants), check=False)
    for t, shadow in zip(instants, shadows):
        set_time(rec, show_time=float(t))
        rec.log(BACKDROP, backdrop(rig, shadow))
    tail = logged.rows[logged.rows > float(show.times[-1]) + 1e-9]  # an earlier, longer show's times
    if len(tail):
        log_poses(rec, hand, tree, SHOW_TIME, tail, np.repeat(show.positions[-1:], len(tail), 0))
        for t in tail:
            set_time(rec, show_time=float(t))
            rec.log(BACKDROP, backdrop(rig, shadows[-1]))
    rec.reset_time()
    rows = np.unique(np.round(np.r_[logged.rows, show.times, instants], 9))  # ns: a sample and an instant are one
    logged.show, logged.shadows, logged.rows = show, shadows, rows
    return shadows
