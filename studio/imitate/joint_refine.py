"""A show's keyframes refined together, within the servos' reach of one another on the show's clock.

Sequential optimisation poses keyframe ``k`` knowing only the keyframes before it, and the clock keeps it within
the servos' reach of those (:mod:`studio.motion.reach`: at 4 Hz a transition has 0.25 s, about 0.1 rad a finger
joint). So the first keyframe's pose, chosen for its own target alone, fixes where every later one can go. Refined
together, a first pose a little worse for its own target can let the next ones reach theirs.

CMA-ES (:class:`~studio.imitate.cmaes.CMAES`) over the poses of a window of ``window`` consecutive keyframes
(``window × 21`` numbers; a longer show is refined window by window, each overlapping the last by one keyframe).
Every candidate is first repaired into the reach constraints:

* the distance every pair of keyframes may keep per joint (``pairs``: :func:`~studio.motion.reach.reach_distances`
  on the show's clock), between two keyframes of the window and from one in it to one outside it (held);
* each keyframe's own box (``boxes``: the joint limits and the poses of keyframes outside the show).

The repair alternates projections onto each pair's slab and the boxes (a convex set, which holds the start). The
objective is the sum of the window's image losses plus the temporal term between neighbours (``w_temporal``).
A candidate still outside the constraints or in collision is never kept. The result is the best kept candidate,
and only when it lowers the sum, so it is never worse than the start. Measured on the six DAVIS sequences
(Table 2's studio row, 13 keyframes, 200 generations of 32): the mean L_base + L_expr 0.393 → 0.349, transitions
passing the paper's literal reading 1/7 → 2/7, at 1.5–2.5 s a sequence (a start step 0.05 rad gave 0.360, 400
generations of it 0.356).

Pure compute: the caller gives the scorers (rendered shadow → image loss, as the rolled mount casts it) and the
collision check.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from studio.errors import ProgressFn, report, stopped
from studio.imitate.cmaes import CMAES
from studio.imitate.config import JointConfig
from studio.sim.joint_box import box_near

Scorer = Callable[[np.ndarray], np.ndarray]  # poses (B, 21) rad → (B,) image losses (no temporal term)
TOL = 1e-6  # rad a repaired candidate may stay outside a constraint (the clock's margin leaves far more room)
REPAIRS = 30  # alternating projections per candidate


@dataclass
class JointResult:
    """What refining together gave (plain data)."""

    theta: np.ndarray  # (K, 21) rad, the poses (the start's where nothing better was kept)
    loss: float  # the objective at ``theta``: image losses + the temporal term
    start_loss: float  # the objective at the start
    seconds: float  # wall time
    cancelled: bool = False  # the cancel event stopped it: the best poses kept before it
    chosen: int = 0  # the start refined: 0 the poses given, i ≥ 1 the alternative i − 1


def windows(k: int, width: int) -> list[list[int]]:
    """Keyframe indices of each window of at most ``width`` consecutive keyframes of ``k``, each overlapping the last
    by one, together covering all."""
    if k <= width:
        return [list(range(k))]
    starts = list(range(0, k - width + 1, width - 1))
    if starts[-1] != k - width:
        starts.append(k - width)
    return [list(range(s, s + width)) for s in starts]


def objective(theta: np.ndarray, image: np.ndarray, previous: np.ndarray | None, w_temporal: float) -> np.ndarray:
    """Sum over keyframes of ``image (B, K)`` losses + ``w_temporal · ‖θ_k − θ_{k−1}‖²`` over neighbours of
    ``theta (B, K, 21)`` (θ_{−1}: ``previous (21,)``, when given) → ``(B,)``."""
    total = image.sum(axis=1)
    if w_temporal:
        total = total + w_temporal * ((theta[:, 1:] - theta[:, :-1]) ** 2).sum(axis=(1, 2))
        if previous is not None:
            total = total + w_temporal * ((theta[:, 0] - previous) ** 2).sum(axis=-1)
    return total


def posed_box(
    k: int, posed: Mapping[int, np.ndarray], pairs: Mapping[tuple[int, int], np.ndarray], lower: np.ndarray,
    upper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The box ``(lower (21,), upper (21,))`` rad keyframe ``k`` keeps: ``[lower, upper]`` within the ``pairs``
    distance of every keyframe ``posed`` (index → ``(21,)`` rad), by the one rule of
    :func:`studio.sim.joint_box.box_near` (crossed bounds pinned to their middle)."""
    near = []
    for (a, b), d in pairs.items():
        other = b if a == k else a if b == k else None
        if other is not None and other in posed:
            near.append((posed[other], d))
    return box_near(lower, upper, near)


class _Window:
    """One window's constraints: each member's box (own box ∩ reach of the held keyframes) and the pairs inside."""

    def __init__(self, members: list[int], theta: np.ndarray, pairs: Mapping, boxes: Sequence):
        self.members = members
        lo = np.stack([np.asarray(boxes[i][0], float) for i in members])
        hi = np.stack([np.asarray(boxes[i][1], float) for i in members])
        inside: list[tuple[int, int, np.ndarray]] = []
        for (i, j), d in pairs.items():
            a, b = (i, j) if i in members else (j, i)
            if a not in members:
                continue
            d = np.maximum(np.asarray(d, float), np.abs(theta[i] - theta[j]))  # a start outside it keeps its distance
            if b in members:
                inside.append((members.index(a), members.index(b), d))
            else:  # held: a box about its pose
                m = members.index(a)
                lo[m], hi[m] = np.maximum(lo[m], theta[b] - d), np.minimum(hi[m], theta[b] + d)
        start = theta[members]
        self.lo, self.hi = np.minimum(lo, start), np.maximum(hi, start)  # the start always inside
        self.inside = inside

    def repair(self, x: np.ndarray) -> np.ndarray:
        """Candidates ``(B, W, 21)`` moved into the constraints (alternating projections)."""
        x = np.clip(x, self.lo, self.hi)
        for _ in range(REPAIRS if self.inside else 0):
            for a, b, d in self.inside:
                diff = x[:, b] - x[:, a]
                excess = np.maximum(np.abs(diff) - d, 0.0) * np.sign(diff) / 2.0
                x[:, a] += excess
                x[:, b] -= excess
            x = np.clip(x, self.lo, self.hi)
        return x

    def violation(self, x: np.ndarray) -> np.ndarray:
        """How far ``(B, W, 21)`` candidates are outside the pairs' distances, rad summed → ``(B,)``."""
        v = np.zeros(len(x))
        for a, b, d in self.inside:
            v += np.maximum(np.abs(x[:, b] - x[:, a]) - d, 0.0).sum(axis=-1)
        return v


def refine_jointly(
    scorers: Sequence[Scorer],
    theta: np.ndarray,
    pairs: Mapping[tuple[int, int], np.ndarray],
    boxes: Sequence[tuple[np.ndarray, np.ndarray]],
    collides: Callable[[np.ndarray], np.ndarray],
    cfg: JointConfig,
    previous: np.ndarray | None = None,
    w_temporal: float = 0.0,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    alternatives: Sequence[np.ndarray] = (),
) -> JointResult:
    """Refine the poses ``theta (K, 21)`` rad of a show's keyframes (in show order) together (module doc), or
    whichever of them and ``alternatives`` (each ``(K, 21)`` rad, within the same constraints; e.g. the keyframes
    posed in the other order) has the lowest objective (the first on a tie; ``JointResult.chosen``).

    ``scorers[k]``: keyframe ``k``'s image loss of poses; ``pairs``: ``(i, j) → (21,)`` rad the most keyframes ``i``
    and ``j`` may differ per joint; ``boxes[k]``: ``(lower (21,), upper (21,))`` rad keyframe ``k`` keeps;
    ``collides(poses (B, 21)) → (B,)`` bool; ``previous (21,)``: the pose before keyframe 0 (the temporal term's,
    held). Stage "together" after every generation (step: generations done of all windows', best: the objective of
    the best poses so far);
    ``cancel`` stops between generations, keeping the best poses found before it."""
    t0 = time.perf_counter()
    starts = [np.array(t, dtype=np.float64) for t in (theta, *alternatives)]
    if any(t.shape != starts[0].shape for t in starts):
        raise ValueError(f"every start must be (K, 21) like the poses {starts[0].shape}")
    theta = starts[0]
    k, dof = theta.shape

    def score(x: np.ndarray, members: list[int]) -> np.ndarray:  # candidates (B, W, 21) of a window → (B,)
        full = np.repeat(theta[None], len(x), axis=0)
        full[:, members] = x
        image = np.zeros((len(x), k))
        image[:, members] = np.stack([scorers[m](x[:, i]) for i, m in enumerate(members)], axis=1)  # held: 0
        return objective(full, image, previous, w_temporal)

    at_start = [float(score(t[None, :], list(range(k)))[0]) for t in starts]
    chosen = int(np.argmin(at_start))
    theta, start = starts[chosen].copy(), at_start[chosen]
    own = np.array([float(scorers[i](theta[i : i + 1])[0]) for i in range(k)])  # each keyframe's image loss now
    wins = windows(k, cfg.window) if k > 1 else []
    total, done, cancelled = len(wins) * cfg.generations, 0, False
    for n, members in enumerate(wins):
        win = _Window(members, theta, pairs, boxes)
        best_x, best = theta[members].copy(), float(score(theta[None, members], members)[0])
        held = float(own.sum() - own[members].sum())  # the image losses outside the window: the same throughout
        es = CMAES(best_x.reshape(-1), cfg.sigma0, win.lo.reshape(-1), win.hi.reshape(-1), cfg.popsize,
                   np.random.default_rng((cfg.seed, n)))  # fmt: skip
        for _ in range(cfg.generations):
            if stopped(cancel):
                cancelled = True
                break
            x = win.repair(es.ask().reshape(-1, len(members), dof))
            f = score(x, members)
            bad = win.violation(x) > TOL
            for i in range(len(members)):
                bad |= np.asarray(collides(x[:, i]), dtype=bool)
            f = np.where(bad, f + 1e3, f)  # never kept; still ordered for CMA-ES
            es.tell(x.reshape(len(x), -1), f)
            i = int(np.argmin(f))
            if not bad[i] and f[i] < best - 1e-12:
                best_x, best = x[i].copy(), float(f[i])
            done += 1
            report(progress, "together", done, total, best + held)
        theta[members] = best_x
        own[members] = [float(scorers[m](best_x[i : i + 1])[0]) for i, m in enumerate(members)]
        if cancelled:
            break
    final = float(score(theta[None, :], list(range(k)))[0])
    return JointResult(theta, final, start, time.perf_counter() - t0, cancelled, chosen)
