"""The hand as read from its URDF: ordered joints, limits, rest pose, link geometry and a content hash.

``assets/hand.urdf`` is the single source of truth; this module parses it once (no re-typed numbers) and
everything else (FK, renderer, PyBullet, servo map) takes a :class:`Hand`.
"""

from __future__ import annotations

import hashlib
import numbers
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from studio.assets import asset

DEFAULT_URDF = asset("hand.urdf")  # the shipped hand, the single source of truth


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw → rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll), (3, 3)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def make_transform(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """A (4, 4) homogeneous transform from a URDF ``<origin>``."""
    T = np.eye(4)
    T[:3, :3] = rpy_to_matrix(rpy)
    T[:3, 3] = xyz
    return T


@dataclass(frozen=True)
class Geometry:
    """One convex piece of a link, in the link frame."""

    kind: str  # "capsule" (segment along the piece's local z), "box" or "sphere"
    T_link_geom: np.ndarray  # (4, 4) pose of the piece in its link frame
    radius: float  # capsule/sphere radius, metres (0 for boxes)
    length: float  # capsule cylinder length, metres (0 otherwise)
    size: tuple[float, float, float]  # box full size, metres ((0, 0, 0) otherwise)


@dataclass(frozen=True)
class Joint:
    """A revolute joint: ``T_parent_child(q) = T_parent_joint · Rot(axis, q)``."""

    name: str  # e.g. "index_mcp_flex"
    parent: str  # parent link name
    child: str  # child link name
    T_parent_joint: np.ndarray  # (4, 4) fixed origin of the joint in the parent link frame
    axis: np.ndarray  # (3,) unit rotation axis in the joint frame
    lower: float  # lower limit, rad
    upper: float  # upper limit, rad
    velocity: float  # velocity limit, rad/s


@dataclass(frozen=True)
class Hand:
    """The parsed hand. Joints are in URDF order, which is also the order of every ``theta (B, 21)``."""

    urdf_path: Path  # file it was read from
    urdf_text: str  # the file's exact text (for PyBullet and pytorch_kinematics)
    root: str  # name of the fixed base link
    joints: tuple[Joint, ...]  # the 21 revolute joints, in order
    link_names: tuple[str, ...]  # every link: root first, then each joint's child in joint order
    visuals: dict[str, tuple[Geometry, ...]]  # light-blocking shell pieces per link
    collisions: dict[str, tuple[Geometry, ...]]  # collision skeleton pieces per link

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def lower(self) -> np.ndarray:
        """(21,) lower joint limits, rad."""
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        """(21,) upper joint limits, rad."""
        return np.array([j.upper for j in self.joints])

    @property
    def hash(self) -> str:
        """Short content hash of the URDF without its XML comments, stored in shards, checkpoints and show files.

        Comments (the generator's note) are left out so that only links, joints, limits and geometry count.
        """
        return hashlib.sha256(re.sub(r"<!--.*?-->", "", self.urdf_text, flags=re.S).encode()).hexdigest()[:16]

    def rest_pose(self) -> np.ndarray:
        """(21,) rest pose: every joint at 0 rad clipped into its limits (open flat hand facing the light)."""
        return np.clip(np.zeros(self.dof), self.lower, self.upper)

    def pose_from_dict(self, pose: dict[str, float]) -> np.ndarray:
        """(21,) angles from ``{joint_name: rad}``; unknown or missing names raise ``ValueError``."""
        names = self.joint_names
        unknown = sorted(set(pose) - set(names))
        missing = [n for n in names if n not in pose]
        if unknown or missing:
            raise ValueError(f"pose does not match the hand's joints: unknown {unknown}, missing {missing}")
        bad = next((n for n in names if isinstance(pose[n], bool) or not isinstance(pose[n], numbers.Real)), None)
        if bad is not None:  # "0.5" and true are not angles (float() would read them as 0.5 and 1.0)
            raise ValueError(f"joint {bad} is {pose[bad]!r}; every angle must be a number of radians")
        return np.array([float(pose[n]) for n in names])

    def pose_to_dict(self, theta: np.ndarray) -> dict[str, float]:
        """``{joint_name: rad}`` from (21,) angles."""
        return {n: float(v) for n, v in zip(self.joint_names, np.asarray(theta, dtype=float).ravel())}

    def check_theta(self, theta: np.ndarray, tol: float = 1e-6) -> np.ndarray:
        """Validate joint angles: shape (21,) or (B, 21), finite, within limits (± tol). Returns (B, 21) float64.

        Raises ``ValueError`` saying which pose and joint is wrong.
        """
        a = np.asarray(theta, dtype=np.float64)
        if a.ndim == 1:
            a = a[None]
        if a.ndim != 2 or a.shape[1] != self.dof:
            raise ValueError(f"joint angles must have shape (21,) or (B, 21); got {np.shape(theta)}")
        bad = ~np.isfinite(a)
        if bad.any():
            b, j = np.argwhere(bad)[0]
            raise ValueError(f"joint angles contain NaN/inf: pose {b}, joint {self.joints[j].name}")
        out = (a < self.lower - tol) | (a > self.upper + tol)
        if out.any():
            b, j = np.argwhere(out)[0]
            jt = self.joints[j]
            raise ValueError(
                f"pose {b}: {jt.name} = {a[b, j]:.4f} rad is outside its limits [{jt.lower:.4f}, {jt.upper:.4f}]"
            )
        return a


def _floats(text: str | None, n: int, default: float = 0.0) -> np.ndarray:
    if text is None:
        return np.full(n, default)
    vals = [float(v) for v in text.split()]
    if len(vals) != n:
        raise ValueError(f"expected {n} numbers, got {text!r}")
    return np.array(vals)


def _origin(el: ET.Element | None) -> np.ndarray:
    if el is None:
        return np.eye(4)
    return make_transform(_floats(el.get("xyz"), 3), _floats(el.get("rpy"), 3))


def _geometry(el: ET.Element) -> Geometry:
    T = _origin(el.find("origin"))
    g = el.find("geometry")
    if g is None or len(g) != 1:
        raise ValueError("each visual/collision needs exactly one geometry")
    shape = g[0]
    if shape.tag == "capsule":
        return Geometry("capsule", T, float(shape.get("radius")), float(shape.get("length")), (0.0, 0.0, 0.0))
    if shape.tag == "sphere":
        return Geometry("sphere", T, float(shape.get("radius")), 0.0, (0.0, 0.0, 0.0))
    if shape.tag == "box":
        size = tuple(float(v) for v in _floats(shape.get("size"), 3))
        return Geometry("box", T, 0.0, 0.0, size)  # type: ignore[arg-type]
    raise ValueError(f"unsupported geometry <{shape.tag}>: the hand uses capsules, spheres and boxes")


def parse_urdf(text: str, path: Path | None = None) -> Hand:
    """Parse URDF text into a :class:`Hand` (revolute chain, convex pieces only)."""
    root_el = ET.fromstring(text)
    visuals: dict[str, tuple[Geometry, ...]] = {}
    collisions: dict[str, tuple[Geometry, ...]] = {}
    for link in root_el.findall("link"):
        name = link.get("name")
        visuals[name] = tuple(_geometry(v) for v in link.findall("visual"))
        collisions[name] = tuple(_geometry(c) for c in link.findall("collision"))
    joints = []
    for j in root_el.findall("joint"):
        if j.get("type") != "revolute":
            raise ValueError(f"joint {j.get('name')}: only revolute joints are supported")
        lim = j.find("limit")
        axis = _floats(j.find("axis").get("xyz"), 3)
        joints.append(
            Joint(
                name=j.get("name"),
                parent=j.find("parent").get("link"),
                child=j.find("child").get("link"),
                T_parent_joint=_origin(j.find("origin")),
                axis=axis / np.linalg.norm(axis),
                lower=float(lim.get("lower")),
                upper=float(lim.get("upper")),
                velocity=float(lim.get("velocity", "0")),
            )
        )
    children = {j.child for j in joints}
    roots = [n for n in visuals if n not in children]
    if len(roots) != 1:
        raise ValueError(f"the URDF must have exactly one root link, found {roots}")
    seen = {roots[0]}
    for j in joints:  # parents must come before children so FK can run in joint order
        if j.parent not in seen:
            raise ValueError(f"joint {j.name}: parent {j.parent} appears after its child in the URDF")
        seen.add(j.child)
    link_names = (roots[0],) + tuple(j.child for j in joints)
    return Hand(path or Path("<string>"), text, roots[0], tuple(joints), link_names, visuals, collisions)


@lru_cache(maxsize=8)
def _load_cached(path: str, mtime: float) -> Hand:
    return parse_urdf(Path(path).read_text(), Path(path))


def load_hand(path: str | Path | None = None) -> Hand:
    """Load the hand from ``path`` (default: the shipped ``assets/hand.urdf``); cached per file version."""
    p = Path(path) if path is not None else DEFAULT_URDF
    if not p.is_file():
        raise FileNotFoundError(f"hand URDF not found: {p}")
    return _load_cached(str(p.resolve()), p.stat().st_mtime)
