"""The geometric path through the keyframes: the paper's three passes (DESIGN §4 "Motion").

1. **Spline**: the keyframe spline (:mod:`studio.motion.spline`, also the source of the keyframe velocities): a
   not-a-knot cubic through home + keyframes at their times, sampled at ``path_rate_hz``; a joint whose cubic leaves
   its limits (or a show with fewer than 3 poses) is interpolated linearly instead.
2. **Repair by noise recovery**: walking each segment, a point whose collision score exceeds ``threshold`` (or
   whose motion from the last accepted point collides) is replaced by the best of ``n_candidates`` uniform
   ±``noise_deg`` perturbations of the last accepted point: the best ``best_k`` by collision cost toward the next
   target, the tie broken by one-step look-ahead (the score of a further step toward the target). Keyframes are
   never perturbed; after the nominal points the walk keeps stepping until it reaches the segment's keyframe, and
   when that stalls (a finger must go around its neighbour, not through it) a detour is found with RRT-Connect
   (``studio.motion.detour``).
3. **Fingertip (DIP) refinement**: each non-keyframe point tries ``tip_candidates`` moves of its five DIP joints
   a random 5–25 % toward the nearest keyframe's DIP angles, ± ``tip_noise_deg``; a move is kept only if it is
   collision-free and brings the DIP angles closer (L1) to that keyframe's.

The result is a list of collision-free points with nominal times; ``studio.motion.timing`` turns it into a jerk-limited
trajectory (the points are the pool of via-points it threads where a direct keyframe-to-keyframe motion would
collide).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from studio.errors import ProgressFn, report
from studio.motion.detour import DetourConfig, rrt_connect
from studio.motion.errors import PathError, check_cancel
from studio.motion.spline import spline_path
from studio.sim.hand import Hand
from studio.sim.physics import CollisionWorld


@dataclass(frozen=True)
class PathConfig:
    """Thresholds of the three path passes (paper values as defaults)."""

    path_rate_hz: float = 40.0  # nominal density of path points between keyframes
    threshold: float = 0.5  # collision score above which a path point is repaired (1.0 = touching, 0 = 2 mm gap)
    n_candidates: int = 50  # perturbations tried per repaired point (paper: 50)
    noise_deg: float = 5.0  # half-width of the uniform perturbation, degrees (paper: ±5°)
    best_k: int = 3  # candidates kept by collision cost toward the next target (paper: 3)
    goal_weight: float = 2.0  # weight of the L2 distance (rad) to the next target in the collision cost
    max_extra_steps: int = 40  # recovery steps after the nominal points before a detour to the segment's keyframe
    check_step_deg: float = 2.0  # the motion between consecutive points is collision-checked at this spacing
    tip_candidates: int = 20  # fingertip candidates per point (paper: 20)
    tip_fraction: tuple[float, float] = (0.05, 0.25)  # step toward the nearest keyframe's DIP angles (paper: 5–25 %)
    tip_noise_deg: float = 2.0  # DIP noise, degrees (paper: ±2°)
    seed: int = 0  # random seed of both passes (plans are reproducible) [0, 4294967295]
    detour: DetourConfig = field(default_factory=DetourConfig)  # RRT-Connect when noise recovery stalls


@dataclass
class Path:
    """Collision-free path points with nominal times.

    ``times (M,) s``, ``poses (M, 21) rad``; ``key_index (K,)`` indexes the keyframes (home first);
    ``repaired``/``refined (M,) bool`` mark points changed by pass 2/3. Nominal times split each segment's duration
    half by joint-space arc length, half evenly by point count (strictly increasing even where the walk waits).
    """

    times: np.ndarray
    poses: np.ndarray
    key_index: np.ndarray
    repaired: np.ndarray
    refined: np.ndarray
    corner: np.ndarray  # (M,) bool: points kept by string-pulling; straight motions between corners are free
    collision_checks: int = 0  # poses scored or checked while building the path


class _Walker:
    """Pass 2 state: one collision world, a random generator, a check counter and the cancel event (every collision
    query first raises :class:`~studio.motion.errors.PlanCancelled` once it is set)."""

    def __init__(self, hand: Hand, world: CollisionWorld, cfg: PathConfig, rng: np.random.Generator, cancel=None):
        self.hand, self.world, self.cfg, self.rng, self.cancel = hand, world, cfg, rng, cancel
        self.checks = 0

    def score(self, q: np.ndarray) -> np.ndarray:
        check_cancel(self.cancel)
        q = np.atleast_2d(q)
        self.checks += len(q)
        return self.world.collision_score(q, check=False)

    def motion_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when the straight joint-space motion a → b is penetration-free (checked every check_step_deg)."""
        check_cancel(self.cancel)
        n = int(np.ceil(np.abs(b - a).max() / np.radians(self.cfg.check_step_deg)))
        if n <= 1:
            return True
        s = np.linspace(0, 1, n + 1)[1:-1, None]
        self.checks += len(s)
        return not self.world.in_collision(a + s * (b - a), check=False).any()

    def free_step(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when ``b`` and the straight motion a → b are penetration-free (the detour's edge test)."""
        check_cancel(self.cancel)
        self.checks += 1
        return not self.world.in_collision(b, check=False)[0] and self.motion_free(a, b)

    def ok(self, prev: np.ndarray, q: np.ndarray, s: float) -> bool:
        return s <= self.cfg.threshold and self.motion_free(prev, q)

    def recover(self, prev: np.ndarray, target: np.ndarray) -> np.ndarray | None:
        """One noise-recovery step from ``prev`` toward ``target``; None when no candidate is acceptable."""
        cfg, h = self.cfg, self.hand
        noise = np.radians(cfg.noise_deg)
        step = np.clip(target - prev, -noise, noise)
        cand = prev + step + self.rng.uniform(-noise, noise, (cfg.n_candidates, h.dof))
        cand = np.clip(cand, h.lower, h.upper)
        cost = self.score(cand) + cfg.goal_weight * np.linalg.norm(cand - target, axis=1)
        best = np.argsort(cost)[: cfg.best_k]
        ahead = np.clip(cand[best] + np.clip(target - cand[best], -noise, noise), h.lower, h.upper)
        look = self.score(ahead) + cfg.goal_weight * np.linalg.norm(ahead - target, axis=1)
        for i in best[np.lexsort((cost[best], look))]:  # look-ahead first, then the candidate's own cost
            s = cost[i] - cfg.goal_weight * np.linalg.norm(cand[i] - target)
            if self.ok(prev, cand[i], s):
                return cand[i]
        return None

    def segment(self, targets: np.ndarray, key: np.ndarray, t0: float, t1: float) -> tuple[list, list]:
        """Walk nominal ``targets (n, 21)`` (the keyframe excluded) from the last keyframe to ``key``."""
        out, rep = [targets[0]], [False]  # the segment's starting keyframe, never perturbed
        prev = targets[0]
        scores = self.score(targets[1:]) if len(targets) > 1 else []  # one batched call
        for q, sc in zip(targets[1:], scores):
            if self.ok(prev, q, float(sc)):
                nxt = q
            else:
                nxt = self.recover(prev, q)
                if nxt is None:
                    continue  # wait at prev: this nominal point is skipped
            out.append(nxt)
            rep.append(nxt is not q)
            prev = nxt
        for _ in range(self.cfg.max_extra_steps):
            if self.motion_free(prev, key):
                return out, rep
            nxt = self.recover(prev, key)
            if nxt is not None:
                out.append(nxt)
                rep.append(True)
                prev = nxt
        detour = rrt_connect(prev, key, self.hand.lower, self.hand.upper, self.free_step, self.rng, self.cfg.detour)
        if detour is not None:
            return out + list(detour[1:-1]), rep + [True] * (len(detour) - 2)
        raise PathError(
            f"no collision-free path found from t = {t0:.3f} s to the keyframe at t = {t1:.3f} s; "
            "move one of the two keyframes or add a keyframe in between"
        )


def refine_fingertips(
    walker: _Walker, poses: np.ndarray, key_mask: np.ndarray, nearest_key: np.ndarray, dip: list[int]
) -> np.ndarray:
    """Pass 3 on ``poses (M, 21)`` in place; returns ``refined (M,) bool``.

    Candidates of every point are drawn and scored in one batch (the 3 closest of each); acceptance then runs in
    order along the path, so each accepted point's motion to its (possibly refined) neighbours is checked."""
    cfg, rng, h = walker.cfg, walker.rng, walker.hand
    refined = np.zeros(len(poses), dtype=bool)
    idx = np.flatnonzero(~key_mask)
    if idx.size == 0:
        return refined
    n, c, noise = len(idx), cfg.tip_candidates, np.radians(cfg.tip_noise_deg)
    goal, cur = nearest_key[idx][:, dip], poses[idx][:, dip]
    gap = np.abs(cur - goal).sum(axis=1)
    frac = rng.uniform(*cfg.tip_fraction, (n, c, 1))
    step = frac * (goal - cur)[:, None] + rng.uniform(-noise, noise, (n, c, len(dip)))
    cand = np.clip(cur[:, None] + step, h.lower[dip], h.upper[dip])  # (n, c, 5) DIP angles
    dist = np.abs(cand - goal[:, None]).sum(axis=2)
    dist[dist >= gap[:, None]] = np.inf  # only moves that bring the tips closer
    top = np.argsort(dist, axis=1)[:, :3]
    full = np.repeat(poses[idx][:, None], top.shape[1], axis=1)
    full[:, :, dip] = np.take_along_axis(cand, top[:, :, None], axis=1)
    closer = np.isfinite(np.take_along_axis(dist, top, axis=1))
    ok = np.zeros_like(closer)
    if closer.any():
        ok[closer] = walker.score(full[closer]) <= cfg.threshold
    for r, i in enumerate(idx):
        for q in full[r][ok[r]]:
            nbrs = [poses[k] for k in (i - 1, i + 1) if 0 <= k < len(poses)]
            if all(walker.motion_free(nb, q) for nb in nbrs):
                poses[i], refined[i] = q, True
                break
    return refined


def string_pull(n: int, free: Callable[[int, int], bool]) -> list[int]:
    """Indices ``0 … n−1`` to keep so that each straight jump between kept points is ``free`` (greedy, doubling
    then bisecting the reach from each kept point; assumes consecutive points are joined freely)."""
    keep, i = [0], 0
    while i < n - 1:
        good, step = i + 1, 1
        while good + step < n and free(i, good + step):  # gallop
            good += step
            step *= 2
        bad = min(good + step, n)
        while bad - good > 1:  # bisect between the farthest reach found and the first miss
            mid = (good + bad) // 2
            good, bad = (mid, bad) if free(i, mid) else (good, mid)
        keep.append(good)
        i = good
    return keep


def build_path(
    hand: Hand, world: CollisionWorld, key_times: np.ndarray, key_poses: np.ndarray, cfg: PathConfig | None = None,
    progress: ProgressFn | None = None, cancel: threading.Event | None = None,
) -> Path:  # fmt: skip
    """Run the three passes on ``key_poses (K, 21)`` at ``key_times (K,)`` (home included, first at 0).

    Stage "path": step ``s + 1`` of ``K + 1`` after segment ``s`` is walked, ``K`` after the fingertip pass, ``K + 1``
    after the corners. Raises :class:`~studio.motion.errors.PlanCancelled` within one collision query of ``cancel``
    being set."""
    cfg = cfg or PathConfig()
    walker = _Walker(hand, world, cfg, np.random.default_rng(cfg.seed), cancel)
    times, poses, key_index = spline_path(hand, key_times, key_poses, cfg.path_rate_hz)
    out_t, out_q, out_rep, out_key = [], [], [], []
    steps = len(key_index) + 1  # K − 1 segments, the fingertip pass, the corners
    for s in range(len(key_index) - 1):
        a, b = key_index[s], key_index[s + 1]
        seg, rep = walker.segment(poses[a:b], key_poses[s + 1], times[a], times[b])
        pts = np.array(seg + [key_poses[s + 1]])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        frac = 0.5 * arc / max(arc[-1], 1e-12) + 0.5 * np.arange(len(pts)) / (len(pts) - 1)  # strictly increasing
        t = list(times[a] + (times[b] - times[a]) * frac[:-1])
        out_key.append(len(out_q))
        out_t += t
        out_q += seg
        out_rep += rep
        report(progress, "path", s + 1, steps)
    out_key.append(len(out_q))
    out_t.append(times[-1])
    out_q.append(key_poses[-1])
    out_rep.append(False)
    q = np.array(out_q)
    key_index = np.array(out_key)
    key_mask = np.zeros(len(q), dtype=bool)
    key_mask[key_index] = True
    t = np.array(out_t)
    kt = t[key_index]
    nearest = key_index[np.argmin(np.abs(t[:, None] - kt[None]), axis=1)]
    dip = [i for i, n in enumerate(hand.joint_names) if n.endswith("_dip")]
    refined = refine_fingertips(walker, q, key_mask, q[nearest].copy(), dip)
    report(progress, "path", steps - 1, steps)
    corner = key_mask.copy()
    for a, b in zip(key_index, key_index[1:]):
        keep = string_pull(b - a + 1, lambda i, j, a=a: walker.motion_free(q[a + i], q[a + j]))
        corner[a + np.array(keep)] = True
    report(progress, "path", steps, steps)
    return Path(t, q, key_index, np.array(out_rep), refined, corner, walker.checks)
