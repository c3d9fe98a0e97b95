"""The shadow rig and the fast exact shadow renderer: ``theta (B, 21)`` → ``(B, H, W)`` uint8, 1 = shadow.

The rig (DESIGN §1): a point light on the +z axis, the backdrop plane ``z = backdrop_z``, and a square image
window of the backdrop centred on the light axis. Row 0 of an image is the top (+y), column 0 the left (-x).
The renderer projects each convex piece of the hand's visual shell from the light onto the backdrop and fills
the convex outline at pixel centres (kernels in ``studio.sim.raster``); ``studio.sim.shadow_reference`` is its slow
PyBullet reference.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, replace

import numpy as np

from studio.sim.hand import Hand, load_hand


@dataclass(frozen=True)
class Rig:
    """Light, backdrop and image window, in metres in the world (palm-centre) frame."""

    light: tuple[float, float, float] = (0.0, 0.0, 3.0)  # point light position
    backdrop_z: float = -1.0  # the backdrop is the plane z = backdrop_z
    window: float = 0.6  # side of the square backdrop window imaged, centred on the light axis (0, 100]
    resolution: int = 256  # pixels per side of shadow images (8192² is 64 MB; 100000² would be 10 GB) [8, 8192]
    roll: float = 0.0  # mount roll about the light axis, rad, counter-clockwise as the audience sees the backdrop
    hand_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the mount moved from the origin, m (a calibrated rig)
    foam: float = 0.0  # foam shell thicker than the URDF's by this much, m (a calibrated rig; negative: thinner)

    def __post_init__(self) -> None:
        if not self.light[2] > self.backdrop_z:
            raise ValueError("the light must be in front of the backdrop (light z > backdrop_z)")
        if self.window <= 0 or self.resolution < 8:
            raise ValueError("window must be positive and resolution at least 8 pixels")
        if len(self.hand_offset) != 3 or not self.light[2] > self.hand_offset[2] > self.backdrop_z:
            raise ValueError("the hand must sit between the light and the backdrop (hand_offset is [x, y, z] m)")
        if not -0.005 <= self.foam <= 0.05:
            raise ValueError(f"foam must be within -5 mm and 50 mm of the URDF's shell, got {self.foam * 1000:g} mm")

    @property
    def pixel_size(self) -> float:
        """Metres of backdrop per pixel."""
        return self.window / self.resolution

    def with_resolution(self, resolution: int) -> Rig:
        return replace(self, resolution=int(resolution))

    def with_roll(self, roll: float) -> Rig:
        """This rig with the mount rolled by ``roll`` rad about the light axis."""
        return replace(self, roll=float(roll))

    def to_dict(self) -> dict:
        """The rig's fields; ``roll``, ``hand_offset`` and ``foam`` only where they differ from the paper rig (so
        the paper rig reads, and hashes, as it always did: caches keyed by the rig stay valid)."""
        d = asdict(self)
        d["light"], d["hand_offset"] = list(d["light"]), list(d["hand_offset"])
        for key, nominal in (("roll", 0.0), ("hand_offset", [0.0, 0.0, 0.0]), ("foam", 0.0)):
            if d[key] == nominal:
                del d[key]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Rig:
        """A rig from :meth:`to_dict`'s fields (a checkpoint's or a cache's record); missing fields are nominal."""
        known = {f: d[f] for f in cls.__dataclass_fields__ if f in d}
        for key in ("light", "hand_offset"):
            if key in known:
                known[key] = tuple(float(v) for v in known[key])
        return cls(**known)

    @property
    def T_world_mount(self) -> np.ndarray:
        """``(4, 4)``: the hand's root in the world, the mount moved by ``hand_offset`` and rolled by ``roll``."""
        T = roll_matrix(self.roll)
        T[:3, 3] = self.hand_offset
        return T

    @property
    def hash(self) -> str:
        """Short hash of the rig geometry (resolution included; roll only when non-zero)."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]

    def project(self, p_world: np.ndarray) -> np.ndarray:
        """Shadow of points ``(..., 3)`` on the backdrop, ``(..., 2)`` backdrop (x, y) in metres."""
        L = np.asarray(self.light)
        p = np.asarray(p_world, dtype=float)
        s = (L[2] - self.backdrop_z) / (L[2] - p[..., 2])
        return L[:2] + s[..., None] * (p[..., :2] - L[:2])

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Backdrop ``(..., 2)`` metres → continuous pixel coordinates ``(..., 2)`` as (u = col, v = row)."""
        half = self.window / 2
        k = self.resolution / self.window
        return np.stack([(xy[..., 0] + half) * k, (half - xy[..., 1]) * k], axis=-1)

    def pixel_centres(self) -> np.ndarray:
        """Backdrop (x, y) of every pixel centre, ``(H, W, 2)`` metres."""
        n, half, px = self.resolution, self.window / 2, self.pixel_size
        c = (np.arange(n) + 0.5) * px
        x = -half + c
        y = half - c
        return np.stack(np.meshgrid(x, y, indexing="xy"), axis=-1)


@dataclass(frozen=True)
class PieceTable:
    """Every light-blocking piece as a hull of spheres in its link frame (flat arrays for the kernels)."""

    link: np.ndarray  # (P,) int64 index into hand.link_names
    points: np.ndarray  # (P, 8, 3) sphere centres / box corners in the link frame, metres
    count: np.ndarray  # (P,) int64 number of valid points per piece
    radius: np.ndarray  # (P,) float64 sphere radius (0 for boxes)


def piece_table(hand: Hand, which: str = "visual", grow: float = 0.0) -> PieceTable:
    """Flatten the hand's ``visual`` (shell) or ``collision`` (skeleton) geometry into a :class:`PieceTable`, every
    piece grown by ``grow`` m (capsules and spheres in radius, boxes on each face: a thicker or thinner foam)."""
    geoms = hand.visuals if which == "visual" else hand.collisions
    links, pts, counts, radii = [], [], [], []
    for li, name in enumerate(hand.link_names):
        for g in geoms.get(name, ()):
            local = np.zeros((8, 3))
            if g.kind == "capsule":
                c = np.array([[0, 0, -g.length / 2], [0, 0, g.length / 2]])
                n, r = 2, max(g.radius + grow, 0.0)
            elif g.kind == "sphere":
                c, n, r = np.zeros((1, 3)), 1, max(g.radius + grow, 0.0)
            else:  # box
                sx, sy, sz = (max(v / 2 + grow, 0.0) for v in g.size)
                c = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
                n, r = 8, 0.0
            local[:n] = c @ g.T_link_geom[:3, :3].T + g.T_link_geom[:3, 3]
            links.append(li)
            pts.append(local)
            counts.append(n)
            radii.append(r)
    return PieceTable(np.array(links, np.int64), np.array(pts), np.array(counts, np.int64), np.array(radii))


@dataclass(frozen=True)
class JointTable:
    """The kinematic chain as flat arrays for the compiled FK."""

    parent: np.ndarray  # (J,) int64 index of each joint's parent link in hand.link_names
    T_origin: np.ndarray  # (J, 4, 4) joint origin in the parent link frame
    axis: np.ndarray  # (J, 3) unit joint axis


def joint_table(hand: Hand) -> JointTable:
    index = {n: i for i, n in enumerate(hand.link_names)}
    return JointTable(
        np.array([index[j.parent] for j in hand.joints], np.int64),
        np.stack([j.T_parent_joint for j in hand.joints]),
        np.stack([j.axis for j in hand.joints]),
    )


def roll_matrix(roll: float) -> np.ndarray:
    """``R_z(roll)`` as a ``(4, 4)`` transform: the mount rolled about the light (z) axis by ``roll`` rad."""
    c, s = np.cos(roll), np.sin(roll)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def mounted_joints(table: JointTable, T_world_mount: np.ndarray) -> JointTable:
    """``table`` with the root link placed at ``T_world_mount (4, 4)``: joints hung on the root get
    ``T_world_mount @ T_origin``."""
    if np.array_equal(T_world_mount, np.eye(4)):
        return table
    T = table.T_origin.copy()
    on_root = table.parent == 0
    T[on_root] = T_world_mount @ T[on_root]
    return JointTable(table.parent, T, table.axis)


def mounted_pieces(table: PieceTable, T_world_mount: np.ndarray) -> PieceTable:
    """``table`` with the root link's own pieces placed at ``T_world_mount (4, 4)`` (the others ride on the
    joints)."""
    if np.array_equal(T_world_mount, np.eye(4)):
        return table
    pts = table.points.copy()
    on_root = table.link == 0
    pts[on_root] = pts[on_root] @ T_world_mount[:3, :3].T + T_world_mount[:3, 3]
    return PieceTable(table.link, pts, table.count, table.radius)


class ShadowRenderer:
    """Fast exact batched renderer of the hand's shadow for one rig.

    ``render(theta (B, 21) or (21,)) -> (B, H, W) uint8`` (1 = shadow). Invalid poses raise ``ValueError``. A rig
    with a mount roll or a moved mount renders that hand exactly: ``T_world_mount`` (offset and roll ``R_z``) is
    folded into the root's joints and pieces, so ``fk`` gives the mounted frames too; a calibrated ``foam`` grows
    every piece of the shell.
    """

    def __init__(self, hand: Hand | None = None, rig: Rig | None = None, ring_points: int = 16):
        self.hand = hand or load_hand()
        self.rig = rig or Rig()
        self.ring_points = ring_points  # points per projected sphere outline (area-preserving polygon)
        T_world_mount = self.rig.T_world_mount
        self.joints = mounted_joints(joint_table(self.hand), T_world_mount)
        self.pieces = mounted_pieces(piece_table(self.hand, "visual", self.rig.foam), T_world_mount)
        self._light = np.asarray(self.rig.light, dtype=np.float64)

    def render(self, theta: np.ndarray, check: bool = True) -> np.ndarray:
        """Shadows of poses ``theta (B, 21)`` rad → ``(B, H, W)`` uint8. ``check=False`` skips validation
        (callers that sampled within limits themselves)."""
        from studio.sim.raster import SERIAL_BELOW, render_into, render_into_serial

        th = self.hand.check_theta(theta) if check else np.atleast_2d(np.asarray(theta, np.float64))
        th = np.ascontiguousarray(th, dtype=np.float64)
        jt, pc, rig = self.joints, self.pieces, self.rig
        # numpy's allocator (huge pages for big batches); the kernel zeroes each image in the thread drawing it
        out = np.empty((len(th), rig.resolution, rig.resolution), dtype=np.uint8)
        kernel = render_into_serial if len(th) < SERIAL_BELOW else render_into
        return kernel(
            out, th, jt.parent, jt.T_origin, jt.axis, pc.link, pc.points, pc.count, pc.radius,
            self._light, float(rig.backdrop_z), rig.window / 2, self.ring_points,
        )  # fmt: skip

    def render_one(self, theta: np.ndarray) -> np.ndarray:
        """Shadow of one pose ``(21,)`` → ``(H, W)`` uint8."""
        return self.render(np.asarray(theta)[None])[0]

    def fk(self, theta: np.ndarray) -> np.ndarray:
        """Compiled FK: ``theta (B, 21)`` → ``T_world_link (B, L, 4, 4)``."""
        from studio.sim.raster import SERIAL_BELOW, fk_batch, fk_batch_serial

        th = np.ascontiguousarray(np.atleast_2d(theta), dtype=np.float64)
        kernel = fk_batch_serial if len(th) < SERIAL_BELOW else fk_batch
        return kernel(th, self.joints.parent, self.joints.T_origin, self.joints.axis)


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of binary masks over the last two axes; two empty masks count as IoU 1."""
    a, b = a.astype(bool), b.astype(bool)
    inter = (a & b).sum(axis=(-2, -1))
    union = (a | b).sum(axis=(-2, -1))
    return np.where(union == 0, 1.0, inter / np.maximum(union, 1))
