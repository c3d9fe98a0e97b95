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
from dataclasses import asdict, dataclass

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

    def __post_init__(self) -> None:
        if not self.light[2] > self.backdrop_z:
            raise ValueError("the light must be in front of the backdrop (light z > backdrop_z)")
        if self.window <= 0 or self.resolution < 8:
            raise ValueError("window must be positive and resolution at least 8 pixels")

    @property
    def pixel_size(self) -> float:
        """Metres of backdrop per pixel."""
        return self.window / self.resolution

    def with_resolution(self, resolution: int) -> Rig:
        return Rig(self.light, self.backdrop_z, self.window, resolution, self.roll)

    def with_roll(self, roll: float) -> Rig:
        """This rig with the mount rolled by ``roll`` rad about the light axis."""
        return Rig(self.light, self.backdrop_z, self.window, self.resolution, float(roll))

    def to_dict(self) -> dict:
        """The rig's fields; ``roll`` only when the mount is rolled (so roll 0 reads, and hashes, as the paper rig
        always did: caches keyed by the rig stay valid)."""
        d = asdict(self)
        if not d["roll"]:
            del d["roll"]
        return d

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


def piece_table(hand: Hand, which: str = "visual") -> PieceTable:
    """Flatten the hand's ``visual`` (shell) or ``collision`` (skeleton) geometry into a :class:`PieceTable`."""
    geoms = hand.visuals if which == "visual" else hand.collisions
    links, pts, counts, radii = [], [], [], []
    for li, name in enumerate(hand.link_names):
        for g in geoms.get(name, ()):
            local = np.zeros((8, 3))
            if g.kind == "capsule":
                c = np.array([[0, 0, -g.length / 2], [0, 0, g.length / 2]])
                n, r = 2, g.radius
            elif g.kind == "sphere":
                c, n, r = np.zeros((1, 3)), 1, g.radius
            else:  # box
                sx, sy, sz = (v / 2 for v in g.size)
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


def rolled_joints(table: JointTable, roll: float) -> JointTable:
    """``table`` with the root link turned by ``roll`` rad about z: joints hung on the root get ``R_z @ T_origin``."""
    if not roll:
        return table
    T = table.T_origin.copy()
    on_root = table.parent == 0
    T[on_root] = roll_matrix(roll) @ T[on_root]
    return JointTable(table.parent, T, table.axis)


def rolled_pieces(table: PieceTable, roll: float) -> PieceTable:
    """``table`` with the root link's own pieces turned by ``roll`` rad about z (the others ride on the joints)."""
    if not roll:
        return table
    pts = table.points.copy()
    on_root = table.link == 0
    pts[on_root] = pts[on_root] @ roll_matrix(roll)[:3, :3].T
    return PieceTable(table.link, pts, table.count, table.radius)


class ShadowRenderer:
    """Fast exact batched renderer of the hand's shadow for one rig.

    ``render(theta (B, 21) or (21,)) -> (B, H, W) uint8`` (1 = shadow). Invalid poses raise ``ValueError``. A rig
    with a mount roll renders the rolled hand exactly: the roll ``R_z`` is folded into the root's joints and
    pieces (``T_world_root = R_z(roll)``), so ``fk`` gives the rolled frames too.
    """

    def __init__(self, hand: Hand | None = None, rig: Rig | None = None, ring_points: int = 16):
        self.hand = hand or load_hand()
        self.rig = rig or Rig()
        self.ring_points = ring_points  # points per projected sphere outline (area-preserving polygon)
        self.joints = rolled_joints(joint_table(self.hand), self.rig.roll)
        self.pieces = rolled_pieces(piece_table(self.hand, "visual"), self.rig.roll)
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
