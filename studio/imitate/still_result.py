"""What one still imitation gives (plain data, :class:`ImitationResult`): the searched pose and the final one, their
shadows as the mount casts them, their losses and timings. Made by :meth:`studio.imitate.still.Imitator.imitate`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from studio.imitate.refine import RefineResult
from studio.imitate.retrieval import Retrieved
from studio.imitate.search import SearchResult

__all__ = ["ImitationResult"]


@dataclass
class ImitationResult:
    """Everything one imitation produced (plain data)."""

    target: np.ndarray  # (R, R) uint8 target mask at the model's resolution, as the audience sees it, 1 = shadow
    search: SearchResult  # gradient search through the self-model
    predicted: np.ndarray  # (R, R) float self-model image of the searched pose (the upright hand's frame)
    unrefined_theta: np.ndarray  # (21,) rad the pose before refinement (ImitateConfig.select: how it is picked)
    unrefined_shadow: np.ndarray  # (R, R) uint8 rendered shadow of the searched pose (as the mount casts it)
    unrefined_loss: dict[str, float]  # rendered-shadow loss components of the searched pose
    unrefined_collides: bool  # the searched pose penetrates itself
    refine: RefineResult | None  # hill climbing (None when skipped)
    theta: np.ndarray  # (21,) rad final pose (refined when refinement ran and found a free pose)
    shadow: np.ndarray  # (R, R) uint8 rendered shadow of the final pose (as the mount, rolled or not, casts it)
    loss: dict[str, float]  # rendered-shadow loss components of the final pose
    collision_free: bool  # the final pose does not penetrate itself
    seconds: float  # wall time of search + refinement
    timings: dict[str, float] = field(default_factory=dict)  # seconds: index, first_answer, sweep, search, refine
    cancelled: bool = False  # the cancel event stopped the search or refinement: the best pose found so far
    first: Retrieved | None = None  # the retrieval's distinct best poses (first answer: row 0); None when off
    swept: Retrieved | None = None  # those poses after the block sweep, best first (seconds: the sweep's); None: off
    roll: float = 0.0  # rad, the mount roll the pose was chosen for (its show must be played on a mount so rolled)
