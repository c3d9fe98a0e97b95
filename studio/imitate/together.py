"""How a keyframe's pose is scored, and a show's keyframes refined together on the show's clock (engine side).

:func:`score_keyframe` is the one way a keyframe's final pose becomes its shadow and loss components: what its row
optimised (``loss``) and the common measure (``evaluation``; :mod:`studio.imitate.sequence`). :func:`refine_together`
refines the poses of keyframes already optimised one after another (:mod:`studio.imitate.joint_refine`), as the
mount (rolled or not) casts them, and scores each again. Both faces reach it: a sequence within one call
(:meth:`SequenceImitator.imitate <studio.imitate.sequence.SequenceImitator.imitate>` given the clock's ``pairs``)
and a project's keyframes after its run (:func:`studio.jobs.engine.refine_together_job`), both through
:func:`refine_show`.

Which keyframe is posed first matters: each is kept within the servos' reach of those posed before it, so the first
one, posed for its own target alone, decides where the others can go. With ``cfg.joint.both_orders``
:func:`refine_show` poses the keyframes again last to first (:func:`pose_backwards`), each within reach of those
after it, and the refinement starts from whichever order's sum is lower. Measured on Table 2's studio row (six DAVIS
sequences, 13 keyframes): L_base + L_expr 0.349 → 0.325, the paper's literal reading 2/7 → 3/7 transitions, at about
twice a sequence's time (the reverse order kept on bear, cows, dog and flamingo).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from studio.errors import ProgressFn
from studio.imitate.config import COMPONENTS, SequenceConfig
from studio.imitate.joint_refine import JointResult, posed_box, refine_jointly
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.still import Imitator

Box = tuple[np.ndarray, np.ndarray]  # (lower (21,), upper (21,)) rad


@dataclass(frozen=True)
class Stretch:
    """Keyframes of a show on its clock: what posing them again and refining them together needs besides their
    poses and the sequence's config."""

    masks: np.ndarray  # (K, S, S) keyframe targets in show order, as the audience sees them, 1 = shadow
    expressive: np.ndarray | None  # (K, S, S) their expressive regions, or None
    pairs: Mapping[tuple[int, int], np.ndarray]  # (i, j) → (21,) rad: the most keyframes i and j may differ per joint
    box_of: Callable[[int], Box | None] | None = None  # keyframe k's box from poses outside these (None: the limits)
    previous: np.ndarray | None = None  # (21,) rad: the pose before keyframe 0 (None: none)
    roll: float = 0.0  # the mount's roll about the light axis, rad
    ids: Sequence[int] | None = None  # the keyframes' own ids (a project's), for stage names; None: their places

    def __len__(self) -> int:
        return len(self.masks)

    def expressive_of(self, k: int) -> np.ndarray | None:
        """Keyframe ``k``'s expressive region ``(S, S)``, or None."""
        return None if self.expressive is None else self.expressive[k]

    def box(self, k: int) -> Box | None:
        """Keyframe ``k``'s box from the poses outside the stretch (None: the joint limits)."""
        return None if self.box_of is None else self.box_of(k)


@dataclass
class KeyframeScore:
    """A keyframe's pose as its shadow and losses (plain data)."""

    theta: np.ndarray  # (21,) rad
    shadow: np.ndarray  # (R, R) uint8 rendered shadow, as the mount casts it, 1 = shadow
    loss: dict[str, float]  # components of what its row optimises (NaN = not computed)
    evaluation: dict[str, float]  # components under the common measure
    collision_free: bool  # the pose does not penetrate itself


def score_keyframe(
    refiner: Refiner, loss_fn: ImageLoss, eval_fn: ImageLoss, theta: np.ndarray, prev_t: np.ndarray | None,
    prev: np.ndarray | None,
) -> KeyframeScore:  # fmt: skip
    """``theta (21,)`` rad rendered by ``refiner`` (the mount as it is rolled) and scored: ``loss_fn`` with the
    temporal term against ``prev_t`` (the row's θ*_{k−1}, None: without it), ``eval_fn`` against ``prev`` (the
    common measure's: the previous keyframe's pose whatever the row)."""
    theta = np.asarray(theta, dtype=np.float64)
    _, comps = refiner.score(loss_fn, theta[None], prev_t)
    _, evaluation = refiner.score(eval_fn, theta[None], prev)
    return KeyframeScore(
        theta, refiner.renderer.render_one(theta), {k: float(comps[k][0]) for k in COMPONENTS},
        {k: float(evaluation[k][0]) for k in COMPONENTS}, not bool(refiner.world.in_collision(theta)[0]),
    )  # fmt: skip


def eval_loss(imitator: Imitator, loss_fn: ImageLoss, target: np.ndarray, expressive: np.ndarray | None,
              cfg: SequenceConfig) -> ImageLoss:  # fmt: skip
    """The common measure's loss of a keyframe: its row's own when that row optimises the expressive term (or there
    is no expressive mask), else the target's with the expressive term."""
    if expressive is None or cfg.expressive:
        return loss_fn
    return ImageLoss(target, imitator.loss_cfg, imitator.clip, expressive)


def refine_together(
    imitator: Imitator,
    stretch: Stretch,
    theta: np.ndarray,
    cfg: SequenceConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    alternatives: Sequence[np.ndarray] = (),
) -> tuple[list[KeyframeScore], JointResult]:
    """The ``stretch``'s keyframes posed at ``theta (K, 21)`` rad in show order, refined together by ``cfg.joint``
    within its ``pairs`` and boxes → each keyframe scored again (:func:`score_keyframe`) and what the refinement
    gave. ``alternatives``: other poses ``(K, 21)`` of the same keyframes; the refinement starts from the one of all
    with the lowest sum (``JointResult.chosen``). Stage "together"; ``cancel`` keeps the best poses found before it."""
    hand, masks, n = imitator.hand, stretch.masks, len(stretch)
    exp = [stretch.expressive_of(k) for k in range(n)]
    framed = [imitator.framed(masks[k], exp[k] if cfg.expressive else None, stretch.roll) for k in range(n)]
    refiner = framed[0].refiner  # every keyframe's: one mount
    boxes = []
    for k in range(n):
        box = stretch.box(k)
        boxes.append((hand.lower, hand.upper) if box is None else box)
    scorers = [lambda poses, f=f: refiner.score(f.exact, poses)[0] for f in framed]
    w_temporal = imitator.loss_cfg.w_temporal if cfg.temporal else 0.0
    previous = stretch.previous
    got = refine_jointly(scorers, theta, stretch.pairs, boxes, refiner.world.in_collision, cfg.joint, previous,
                         w_temporal, progress, cancel, alternatives)  # fmt: skip
    out = []
    for k, f in enumerate(framed):
        prev = got.theta[k - 1] if k else previous
        out.append(score_keyframe(refiner, f.exact, eval_loss(imitator, f.exact, masks[k], exp[k], cfg), got.theta[k],
                                  prev if cfg.temporal else None, prev))  # fmt: skip
    return out, got


def pose_backwards(
    seq: Any,
    stretch: Stretch,
    cfg: SequenceConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    best_pose: Callable[[np.ndarray], None] | None = None,
) -> np.ndarray | None:
    """The ``stretch``'s keyframes posed last to first by ``seq`` (a
    :class:`~studio.imitate.sequence.SequenceImitator`, as ``cfg``): the last one as a first keyframe is, each earlier
    one from the pose after it, within its box and the ``pairs`` distance of every keyframe after it → ``(K, 21)``
    rad in show order; None when ``cancel`` stopped it. Stages "last to first: keyframe k/K: ..." (k: the keyframe's
    place in the show, K first; given the keyframes' ``ids``, a project's: "last to first: keyframe 7 (3 of 3): ...",
    each report's ``item`` the id, "7"); ``best_pose(θ (21,) rad)`` gets each keyframe's improving collision-free
    poses (live previews, as ``SequenceImitator.imitate``)."""
    n, ids, pairs = len(stretch), stretch.ids, stretch.pairs
    hand = seq.imitator.hand

    def box_for(j: int, done: list) -> Box | None:  # j: posed j-th, keyframe n − 1 − j; done: n − 1, n − 2, ...
        k = n - 1 - j
        own = stretch.box(k)
        posed = {n - 1 - i: theta for i, theta in enumerate(done)}
        if own is None and not any(a in posed or b in posed for a, b in pairs if k in (a, b)):
            return None  # nothing holds it: the joint limits
        lower, upper = (hand.lower, hand.upper) if own is None else own
        return posed_box(k, posed, pairs, lower, upper)

    flip = None if stretch.expressive is None else np.ascontiguousarray(stretch.expressive[::-1])
    if ids is not None and len(ids) != n:
        raise ValueError(f"{len(ids)} keyframe ids for {n} keyframes")
    places = [n - j for j in range(n)]  # the j-th posed is the show's keyframe n − j (1-based)
    labels = [f"last to first: keyframe {k}/{n}" if ids is None else f"last to first: keyframe {ids[k - 1]} ({k} of "
              f"{n})" for k in places]  # fmt: skip
    items = None if ids is None else [str(ids[k - 1]) for k in places]  # each report names its keyframe's id
    got = seq.imitate(np.ascontiguousarray(stretch.masks[::-1]), flip, progress, cancel, cfg=cfg, box_for=box_for,
                      roll=stretch.roll, best_pose=best_pose, labels=labels, items=items)  # fmt: skip
    return None if got.cancelled else got.thetas[::-1].copy()


def refine_show(
    seq: Any,
    stretch: Stretch,
    theta: np.ndarray,
    cfg: SequenceConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    best_pose: Callable[[np.ndarray], None] | None = None,
) -> tuple[list[KeyframeScore], JointResult]:
    """The ``stretch``'s keyframes posed first to last at ``theta (K, 21)`` rad, posed again last to first when
    ``cfg.joint.both_orders`` (:func:`pose_backwards`), then refined together from the order with the lower sum
    (:func:`refine_together`; ``seq`` a :class:`~studio.imitate.sequence.SequenceImitator`). The result's
    ``seconds`` include the second order's posing; ``chosen`` is 1 when it was kept. A cancel while posing backwards
    refines nothing and keeps ``theta``. ``best_pose``: as :func:`pose_backwards`'s."""
    t0 = time.perf_counter()
    alternatives = []
    if cfg.joint.both_orders and len(stretch) > 1:
        back = pose_backwards(seq, stretch, cfg, progress, cancel, best_pose)
        if back is not None:
            alternatives.append(back)
    scored, got = refine_together(seq.imitator, stretch, theta, cfg, progress, cancel, alternatives)
    return scored, replace(got, seconds=time.perf_counter() - t0)
