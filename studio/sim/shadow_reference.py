"""Slow reference for the shadow renderer: PyBullet's own camera at the light, looking at the backdrop.

What a pinhole camera at the point light sees of the hand is exactly the shadow's silhouette: its hand
segmentation mask, with the camera's image plane mapped onto the backdrop window, is the shadow. PyBullet draws
URDF capsules as coarse faceted prisms, so the reference loads a *mesh twin* of the URDF (every capsule and
sphere of the visual shell replaced by a finely tessellated mesh, generated from the URDF's own numbers) and
renders with a frustum shifted by half a pixel, so its pixels sample at pixel centres like ours.
"""

from __future__ import annotations

import math
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from studio.errors import ClosedError
from studio.sim.hand import Hand
from studio.sim.physics import PyBulletClient, connect_direct, pybullet_module
from studio.sim.shadow import Rig


def capsule_obj(radius: float, length: float, segments: int = 64, rings: int = 16) -> str:
    """Wavefront OBJ text of a capsule along z centred at the origin (cylinder ``length`` + two caps)."""
    verts: list[tuple[float, float, float]] = []
    # latitude rings from the bottom pole to the top pole; the cylinder is the gap between the two equators
    lats = [(-length / 2, -math.pi / 2 + math.pi / 2 * k / rings) for k in range(rings + 1)]
    lats += [(length / 2, math.pi / 2 * k / rings) for k in range(rings + 1)]
    for zc, phi in lats:
        for s in range(segments):
            a = 2 * math.pi * s / segments
            verts.append((radius * math.cos(phi) * math.cos(a), radius * math.cos(phi) * math.sin(a),
                          zc + radius * math.sin(phi)))  # fmt: skip
    faces = []
    for r in range(len(lats) - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            c, d = a + segments, b + segments
            faces.append((a, b, d))
            faces.append((a, d, c))
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def mesh_twin_urdf(hand: Hand, folder: Path, foam: float = 0.0) -> Path:
    """Write a copy of the hand's URDF whose visual capsules/spheres are fine meshes, every visual piece grown by
    ``foam`` m (boxes by ``foam`` on each face: square edges where the renderer's are rounded); returns its path."""
    root = ET.fromstring(hand.urdf_text)
    n = 0
    for link in root.findall("link"):
        for vis in link.findall("visual"):
            geom = vis.find("geometry")
            shape = geom[0]
            if shape.tag == "capsule":
                r, length = float(shape.get("radius")), float(shape.get("length"))
            elif shape.tag == "sphere":
                r, length = float(shape.get("radius")), 0.0
            else:
                if foam and shape.tag == "box":
                    size = [float(v) + 2 * foam for v in shape.get("size").split()]
                    shape.set("size", " ".join(f"{v:.7f}" for v in size))
                continue
            r += foam
            obj = folder / f"piece_{n}.obj"
            obj.write_text(capsule_obj(r, length))
            n += 1
            geom.remove(shape)
            ET.SubElement(geom, "mesh", filename=str(obj))
    out = folder / "hand_mesh_twin.urdf"
    out.write_text(ET.tostring(root, encoding="unicode"))
    return out


class PyBulletShadowCamera(PyBulletClient):
    """``render(theta (21,)) -> (H, W) uint8``: the shadow as PyBullet's TinyRenderer sees it from the light.

    Holds a PyBullet DIRECT client and a temporary folder with the mesh twin; ``close()`` (or the end of a ``with``
    block) releases both, after which ``render`` raises :class:`~studio.errors.ClosedError`.
    """

    def __init__(self, hand: Hand, rig: Rig, half_pixel_shift: bool = True):
        p = pybullet_module()
        self.p, self.hand, self.rig = p, hand, rig
        self._tmp = tempfile.TemporaryDirectory(prefix="shadow_ref_")
        self.client = connect_direct()
        try:
            self._load(half_pixel_shift)
        except BaseException:
            self.close()
            raise

    def _load(self, half_pixel_shift: bool) -> None:
        p, hand, rig = self.p, self.hand, self.rig
        urdf = mesh_twin_urdf(hand, Path(self._tmp.name), rig.foam)
        roll = p.getQuaternionFromEuler([0.0, 0.0, rig.roll])
        self.body = p.loadURDF(str(urdf), list(rig.hand_offset), roll, useFixedBase=True, physicsClientId=self.client)
        names = [p.getJointInfo(self.body, i, physicsClientId=self.client)[1].decode() for i in range(hand.dof)]
        if names != hand.joint_names:
            raise ValueError("PyBullet joint order differs from the URDF order")
        L = np.asarray(rig.light)
        dist = L[2] - rig.backdrop_z
        self.near, self.far = 0.05, dist + 1.0
        self.view = p.computeViewMatrix(L.tolist(), [L[0], L[1], rig.backdrop_z], [0, 1, 0])
        # The frustum at the near plane spans the window scaled by near/dist; shift it by half a pixel.
        h = rig.window / 2 * self.near / dist
        px = rig.window / rig.resolution * self.near / dist
        sh = px / 2 if half_pixel_shift else 0.0
        self.proj = p.computeProjectionMatrix(-h + sh, h + sh, -h + sh, h + sh, self.near, self.far)

    def render(self, theta: np.ndarray) -> np.ndarray:
        if self.client is None:
            raise ClosedError("this PyBulletShadowCamera was closed; make a new one (or render in its `with` block)")
        p, n = self.p, self.rig.resolution
        theta = self.hand.check_theta(theta)[0]
        for i, q in enumerate(theta):
            p.resetJointState(self.body, i, float(q), physicsClientId=self.client)
        _, _, _, _, seg = p.getCameraImage(
            n, n, self.view, self.proj, renderer=p.ER_TINY_RENDERER, physicsClientId=self.client
        )
        seg = np.asarray(seg).reshape(n, n)
        return (seg >= 0).astype(np.uint8)

    def _release(self) -> None:
        """Delete the mesh twin's folder (after the client is disconnected)."""
        if hasattr(self, "_tmp"):
            self._tmp.cleanup()  # idempotent itself
