"""Self-collision of the hand's skeleton in one reused PyBullet DIRECT world (DESIGN §4 "Motion").

``S_col = w_contact·(Σ max(0, −d_i) + max(0, p_soft − d_min)) + w_force·max(0, F_max − F_soft)``, 0 when no
non-adjacent pair of links is within ``p_soft``. ``d_i`` are the signed distances of the contact pairs (negative
= penetration). Poses are set kinematically (no simulation step), where PyBullet reports no contact forces, so
``F_i = contact_stiffness · max(0, −d_i)`` (a linear penalty spring) stands in for the normal force.

Parent–child link pairs are excluded (they touch at every joint by design); the fast path is PyBullet's
contact query with its breaking threshold set to ``p_soft``; ``closest_pairs_reference`` is the slow
all-pairs ``getClosestPoints`` reference that tests hold it against.
"""

from __future__ import annotations

import os
import sys
import threading
from dataclasses import dataclass

import numpy as np

from studio.errors import ClosedError
from studio.sim.hand import Hand, load_hand

_import_lock = threading.Lock()


def pybullet_module():
    """``pybullet``, imported with stderr silenced the first time: its import prints a "build time" banner there,
    which would turn every one-line CLI error after it into two lines. Import pybullet only through this."""
    with _import_lock:
        if "pybullet" not in sys.modules:
            sys.stderr.flush()
            saved = os.dup(2)
            try:
                with open(os.devnull, "w") as null:
                    os.dup2(null.fileno(), 2)
                    import pybullet  # noqa: F401
            finally:
                os.dup2(saved, 2)
                os.close(saved)
        return sys.modules["pybullet"]


def connect_direct() -> int:
    """A new PyBullet DIRECT client (physics server in this process)."""
    p = pybullet_module()
    return p.connect(p.DIRECT)


class PyBulletClient:
    """Owns one PyBullet DIRECT client (``self.p``, ``self.client``): ``close()`` disconnects it (idempotent), also at
    the end of a ``with`` block and at garbage collection. Subclasses add their own clean-up in ``_release``."""

    p = None
    client: int | None = None

    def _release(self) -> None:
        """Extra clean-up after the client is gone (none here)."""

    def close(self) -> None:
        """Disconnect the PyBullet client and release what the subclass holds (idempotent)."""
        if self.client is not None:
            self.p.disconnect(self.client)
            self.client = None
        self._release()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may already be gone
            pass


@dataclass(frozen=True)
class CollisionConfig:
    """Weights and thresholds of the collision score."""

    p_soft: float = 0.002  # m; pairs closer than this are penalised even without contact
    F_soft: float = 1.0  # N; normal force tolerated before it is penalised
    contact_stiffness: float = 2000.0  # N/m; penalty spring turning penetration depth into a normal force
    w_contact: float = 500.0  # weight of penetration and proximity (paper: 500)
    w_force: float = 0.2  # weight of excess normal force (paper: 0.2)
    penetration_tol: float = 0.0  # m; a pose is "in collision" when some pair penetrates deeper than this


@dataclass(frozen=True)
class Contact:
    """One close pair of non-adjacent links."""

    link_a: str  # link name
    link_b: str  # link name
    distance: float  # signed distance, m (negative = penetration)


class CollisionWorld(PyBulletClient):
    """A PyBullet DIRECT world holding the hand's collision skeleton with self-collision on.

    One world per instance, reused for every query (not thread-safe: one per thread or process). ``close()`` (or
    the end of a ``with`` block) disconnects it; a closed world raises :class:`~studio.errors.ClosedError`.
    """

    def __init__(self, hand: Hand | None = None, cfg: CollisionConfig | None = None):
        p = pybullet_module()
        self.p = p
        self.hand = hand or load_hand()
        self.cfg = cfg or CollisionConfig()
        self.client = connect_direct()
        try:
            self._load()
        except BaseException:
            self.close()
            raise

    def _load(self) -> None:
        p = self.p
        p.setPhysicsEngineParameter(contactBreakingThreshold=self.cfg.p_soft, physicsClientId=self.client)
        self.body = p.loadURDF(
            str(self.hand.urdf_path), useFixedBase=True, flags=p.URDF_USE_SELF_COLLISION,
            physicsClientId=self.client,
        )  # fmt: skip
        n = p.getNumJoints(self.body, physicsClientId=self.client)
        names = [p.getJointInfo(self.body, i, physicsClientId=self.client)[1].decode() for i in range(n)]
        if names != self.hand.joint_names:
            raise ValueError("PyBullet joint order differs from the URDF order")
        # PyBullet link index i is joint i's child; -1 is the base.
        self._link_name = {-1: self.hand.root} | {i: j.child for i, j in enumerate(self.hand.joints)}
        index = {name: i for i, name in self._link_name.items()}
        self._adjacent = set()
        for j in self.hand.joints:
            a, b = index[j.parent], index[j.child]
            self._adjacent |= {(a, b), (b, a)}
        self._joint_ids = list(range(self.hand.dof))
        self._init_bounds()

    def _init_bounds(self) -> None:
        """Bounding sphere of each link's collision pieces (link frame) for the pair prefilter."""
        from studio.sim.shadow import ShadowRenderer, piece_table

        pieces = piece_table(self.hand, "collision")
        links, centres, radii = [], [], []
        for li in np.unique(pieces.link):
            pts = [(pieces.points[k, : pieces.count[k]], pieces.radius[k]) for k in np.flatnonzero(pieces.link == li)]
            allp = np.concatenate([p for p, _ in pts])
            c = allp.mean(axis=0)
            r = max(np.linalg.norm(p - c, axis=1).max() + rad for p, rad in pts)
            links.append(li)
            centres.append(c)
            radii.append(r + 1e-4)
        self._sphere_link = np.array(links)
        self._sphere_c = np.array(centres)
        self._sphere_r = np.array(radii)
        bullet = self._sphere_link - 1
        ok = np.array([[a < b and (a, b) not in self._adjacent for b in bullet] for a in bullet])
        self._pair_ok = ok
        self._fk = ShadowRenderer(self.hand).fk

    # -- queries ---------------------------------------------------------------------------------------
    def _set(self, q: np.ndarray) -> None:
        if self.client is None:  # every query sets the pose first
            raise ClosedError("this CollisionWorld was closed; make a new one (or use it inside its `with` block)")
        self.p.resetJointStatesMultiDof(
            self.body, self._joint_ids, [[float(v)] for v in q], physicsClientId=self.client
        )

    def _candidates(self, T: np.ndarray) -> np.ndarray:
        """(K, 2) PyBullet link index pairs whose bounding spheres come within p_soft (non-adjacent).

        ``T (L, 4, 4)``: link poses in hand order (= PyBullet link index + 1)."""
        centre = np.einsum("lij,lj->li", T[self._sphere_link, :3, :3], self._sphere_c) + T[self._sphere_link, :3, 3]
        gap = np.linalg.norm(centre[:, None] - centre[None], axis=-1) - self._sphere_r[:, None] - self._sphere_r[None]
        a, b = np.nonzero((gap < self.cfg.p_soft) & self._pair_ok)
        return np.stack([self._sphere_link[a] - 1, self._sphere_link[b] - 1], axis=1)

    def _pairs(self, q: np.ndarray, T: np.ndarray | None = None) -> list[tuple[int, int, float]]:
        """(link a, link b, signed distance) of every non-adjacent pair within p_soft (fast path).

        Bounding spheres pick the candidate pairs, then PyBullet's closest points per pair give the distance.
        """
        p = self.p
        self._set(q)
        out = []
        for a, b in self._candidates(self._fk(q[None])[0] if T is None else T):
            pts = p.getClosestPoints(self.body, self.body, self.cfg.p_soft, int(a), int(b), physicsClientId=self.client)
            if pts:
                out.append((int(a), int(b), min(c[8] for c in pts)))
        return [t for t in out if t[2] < self.cfg.p_soft]

    def closest_pairs_reference(self, theta: np.ndarray) -> list[tuple[int, int, float]]:
        """Slow reference of ``_pairs``: every link pair via ``getClosestPoints``, adjacency filtered here."""
        q = self.hand.check_theta(theta)[0]
        self._set(q)
        out = []
        for c in self.p.getClosestPoints(self.body, self.body, self.cfg.p_soft, physicsClientId=self.client):
            a, b, d = c[3], c[4], c[8]
            if a < b and (a, b) not in self._adjacent and d < self.cfg.p_soft:
                out.append((a, b, d))
        return out

    def score_from_distances(self, distances: np.ndarray) -> float:
        """S_col from the signed distances of the close pairs (empty → 0)."""
        cfg = self.cfg
        d = np.asarray(distances, dtype=float)
        if d.size == 0:
            return 0.0
        pen = np.maximum(0.0, -d)
        f_max = cfg.contact_stiffness * pen.max()
        s = cfg.w_contact * (pen.sum() + max(0.0, cfg.p_soft - d.min())) + cfg.w_force * max(0.0, f_max - cfg.F_soft)
        return float(s)

    def collision_score(self, theta: np.ndarray, check: bool = True) -> np.ndarray:
        """``theta (B, 21)`` or ``(21,)`` → S_col ``(B,)`` (0 for a pose with no close pair)."""
        th = self.hand.check_theta(theta) if check else np.atleast_2d(theta)
        out = np.empty(len(th))
        T_all = self._fk(th)
        for b, q in enumerate(th):
            d = np.array([d for _, _, d in self._pairs(q, T_all[b])])
            out[b] = self.score_from_distances(d)
        return out

    def in_collision(self, theta: np.ndarray, check: bool = True) -> np.ndarray:
        """``theta (B, 21)`` or ``(21,)`` → ``(B,)`` bool: some non-adjacent pair penetrates."""
        th = self.hand.check_theta(theta) if check else np.atleast_2d(theta)
        tol = -self.cfg.penetration_tol
        p, out = self.p, np.zeros(len(th), dtype=bool)
        for b, q in enumerate(th):
            # penetration is exactly what PyBullet's contact query reports (parent-child pairs skipped by it)
            self._set(q)
            p.performCollisionDetection(physicsClientId=self.client)
            for c in p.getContactPoints(self.body, self.body, physicsClientId=self.client):
                if c[8] < tol and c[3] != c[4] and (c[3], c[4]) not in self._adjacent:
                    out[b] = True
                    break
        return out

    def contacts(self, theta: np.ndarray) -> list[Contact]:
        """The close pairs of one pose, by link name (for review and error messages)."""
        q = self.hand.check_theta(theta)[0]
        return [Contact(self._link_name[a], self._link_name[b], d) for a, b, d in self._pairs(q)]
