"""A target on a rolled mount (DESIGN §1): which loss scores what, so the audience's shadow is what is optimised.

A roll turns every shadow about the image centre. The self-model's images and the retrieval index's crops are the
upright hand's, so the self-model's search and the index's ranking see the target turned into the hand's frame
(:func:`studio.sim.roll.into_hand_frame`). Every rendered score (the index's shortlist, the block sweep, the
refinement pool, the refinement and the result) renders the pose with the rolled rig itself and compares it with
the target as it is: a hole or a thin part that turning a 128² target would blur is judged as the audience will
see it (on 12 rolled reachable targets this took the IoU loss from 0.146 to 0.112, and Total from 0.415 to 0.207).

Pure compute over a refiner (renderer + collision world) and a loss factory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.sim.roll import into_hand_frame


@dataclass
class Framed:
    """One target on a mount rolled by ``roll`` (the audience sees the target as it is): what scores it where.

    Every rendered score (retrieval's shortlist, sweep, pool, refinement, the result) renders the pose as the
    rolled mount casts it and compares it with the target as it is, so a hole or a thin part that turning the
    target would blur is judged as the audience sees it; only the self-model (whose images are the upright hand's)
    and the retrieval index's ranking see the target turned into the hand's frame."""

    refiner: Refiner  # renders as the rolled mount casts (the imitator's own at roll 0)
    exact: ImageLoss  # the target as it is: every rendered score
    model: ImageLoss  # the target turned into the hand's frame: the self-model's search (``exact`` at roll 0)
    ranking: np.ndarray  # (R, R) uint8 the turned target the retrieval index ranks by


class Framer:
    """Frames targets for one imitator: ``framer(target, expressive, roll)`` → :class:`Framed`, keeping the rolled
    refiner of the last roll asked for (a show's keyframes share one)."""

    def __init__(self, refiner: Refiner, loss_fn: Callable[[np.ndarray, np.ndarray | None], ImageLoss]):
        self.refiner, self.loss_fn = refiner, loss_fn
        self._rolled: tuple[float, Refiner] | None = None  # (roll rad, the refiner at that roll)

    def __call__(self, target: np.ndarray, expressive: np.ndarray | None, roll: float) -> Framed:
        exact = self.loss_fn(target, expressive)
        if not roll:
            return Framed(self.refiner, exact, exact, np.asarray(target))
        turned, turned_exp = into_hand_frame(target, expressive, roll)
        if self._rolled is None or self._rolled[0] != roll:
            self._rolled = (roll, self.refiner.with_roll(roll))
        refiner = self._rolled[1]
        refiner.box = self.refiner.box  # the box the caller set on the imitator's refiner (a keyframe's reach)
        return Framed(refiner, exact, self.loss_fn(turned, turned_exp), turned)
