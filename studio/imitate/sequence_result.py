"""What a sequence's imitation gives (plain data): each keyframe's pose, shadow and losses
(:class:`KeyframeResult`), and the sequence's (:class:`SequenceResult`), with the endpoint totals the transition
test reads (:mod:`studio.imitate.transitions`). Made by :class:`~studio.imitate.sequence.SequenceImitator`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from studio.imitate.config import SequenceConfig
from studio.imitate.transitions import TransitionConfig, TransitionReport, transition_success

__all__ = ["KeyframeResult", "SequenceResult"]


@dataclass
class KeyframeResult:
    """One keyframe's pose and how well its shadow imitates its target (plain data)."""

    index: int  # keyframe number k (first-appearance order)
    theta: np.ndarray  # (21,) rad, final pose (within the joint limits)
    shadow: np.ndarray  # (R, R) uint8 rendered shadow of the final pose, 1 = shadow
    loss: dict[str, float]  # components of the objective this row optimised (config.COMPONENTS; NaN = not computed)
    evaluation: dict[str, float]  # components under the common measure (module doc), total incl. temporal
    collision_free: bool  # the final pose does not penetrate itself
    search_loss: float  # the self-model loss of the searched pose
    seconds: float  # wall time of this keyframe's search + refinement
    timings: dict[str, float] = field(default_factory=dict)  # seconds per stage ("seed", "search", "refine")

    def total(self, reading: str = "base") -> float:
        """The endpoint total of the transition test (:mod:`studio.imitate.transitions`): ``"base"`` L_base,
        ``"image"`` L_base + L_expr (the expressive term when masks were given), ``"full"`` + L_temp (k ≥ 1)."""
        e = self.evaluation
        parts = {"base": ("base",), "image": ("base", "expr"), "full": ("base", "expr", "temporal")}[reading]
        return e["base"] + sum(0.0 if math.isnan(e[p]) else e[p] for p in parts[1:])


@dataclass
class SequenceResult:
    """Every finished keyframe of a sequence, in first-appearance order (plain data)."""

    keyframes: list[KeyframeResult]  # done keyframes (fewer than asked when cancelled)
    cfg: SequenceConfig  # what was run
    requested: int  # keyframes asked for (K)
    seconds: float  # wall time of the whole sequence
    cancelled: bool = False  # the cancel event stopped it: only the keyframes finished before it

    @property
    def thetas(self) -> np.ndarray:
        """``(K, 21)`` rad, the final poses."""
        return np.stack([k.theta for k in self.keyframes]) if self.keyframes else np.zeros((0, 21))

    @property
    def shadows(self) -> np.ndarray:
        """``(K, R, R)`` uint8, the rendered shadows."""
        return np.stack([k.shadow for k in self.keyframes])

    def totals(self, reading: str = "base") -> np.ndarray:
        """``(K,)`` the transition test's endpoint totals (:meth:`KeyframeResult.total`)."""
        return np.array([k.total(reading) for k in self.keyframes], dtype=np.float64)

    def transitions(self, cfg: TransitionConfig | None = None) -> TransitionReport:
        """Transition success between consecutive keyframes (DESIGN §4), totals read as ``cfg.total``."""
        cfg = cfg or TransitionConfig()
        return transition_success(self.thetas, self.totals(cfg.total), cfg)[1]
