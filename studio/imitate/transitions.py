"""Transition success between consecutive keyframes of a sequence (DESIGN §4 "Transition success").

Keyframes are taken in order of first appearance (the order :func:`~studio.targets.keyframes.cluster_keyframes`
numbers them and :mod:`studio.imitate.sequence` optimises them); K keyframes make K − 1 transitions. Transition
``k → k+1`` succeeds when both endpoints imitate their targets well enough (``total ≤ max_total``) and the hand can
get from one pose to the other without a jump: ``mean|Δθ| ≤ max_mean_step`` and ``max|Δθ| ≤ max_step`` (rad, over
the 21 joints). Every bound is inclusive. Paper: 34.5 % of the transitions succeed with independent optimisation,
86.2 % with sequential + expressive + temporal.

Which total is compared (our reading; the paper's L_total sums the base, expressive and temporal terms, and does
not say which it thresholds): by default the *base* loss ``L_base`` of the rendered shadow (``total="base"``), the
one term every row of Table 2 optimises, so all six rows are judged by the same measure, and one that does not
depend on how large a sequence's expressive region happens to be:

- the temporal term is left out: the Δθ bounds judge the motion directly, and at their scale ``L_temp`` (``0.2·‖Δθ‖²``
  is about 3 at ``mean|Δθ| = 0.85`` over 21 joints) would make them vacuous, failing every transition that moves;
- the expressive term is left out of the default: its weight (1.0 on ``1 − IoU`` inside M) is 2.5 times the base's
  IoU weight, and where the whole animal moves M is its whole silhouette, so ``L_base + L_expr`` measures the
  region's size as much as the imitation. Measured on the six shared DAVIS sequences (15 keyframes, 9
  transitions) with the shipped 128² model, no CLIP, ``CPU_SEQUENCE``: ``L_base`` 0.11–0.33 per keyframe,
  ``L_base + L_expr`` 0.49 (independent) and 0.56 (sequential) on average, so at 0.35 the literal reading passes
  no transition in either mode (the base reading: independent 0 of 9, sequential +Exp+Temp 9 of 9).
  ``total="image"`` (``L_base + L_expr``) and ``total="full"`` (+ ``L_temp``) select the other readings;
  ``benchmarks/bench_sequence.py`` reports the base and image readings.

:class:`~studio.imitate.sequence_result.SequenceResult` computes these totals for every row from its ``evaluation``
components (the expressive term whenever the sequence has expressive masks, the temporal term against the previous
keyframe).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TOTALS = ("base", "image", "full")  # the readings of "L_total" the test can compare (module doc)


@dataclass(frozen=True)
class TransitionConfig:
    """Thresholds of the transition-success test (paper values, DESIGN §4)."""

    max_total: float = 0.35  # each endpoint's total (``total``) at most this [0, 1000]
    max_mean_step: float = 0.85  # mean over joints of |θ_{k+1} − θ_k| at most this, rad [0, 10]
    max_step: float = 2.00  # largest single-joint |θ_{k+1} − θ_k| at most this, rad [0, 10]
    total: str = "base"  # endpoint total compared: "base" L_base, "image" L_base + L_expr, "full" + L_temp (doc)

    def __post_init__(self) -> None:
        if min(self.max_total, self.max_mean_step, self.max_step) < 0:
            raise ValueError("transition thresholds must be ≥ 0")
        if self.total not in TOTALS:
            raise ValueError(f"total must be one of {TOTALS}, not {self.total!r}")


@dataclass
class TransitionReport:
    """Per-transition details of :func:`transition_success` (arrays over the K − 1 transitions)."""

    ok: np.ndarray  # (K-1,) bool: the transition succeeds
    mean_step: np.ndarray  # (K-1,) rad, mean over joints of |Δθ|
    max_step: np.ndarray  # (K-1,) rad, largest single-joint |Δθ|
    totals_ok: np.ndarray  # (K,) bool: the keyframe's total is at most max_total (NaN fails)
    mean_ok: np.ndarray  # (K-1,) bool: mean|Δθ| within its bound
    max_ok: np.ndarray  # (K-1,) bool: max|Δθ| within its bound

    @property
    def count(self) -> int:
        """Successful transitions."""
        return int(self.ok.sum())

    @property
    def total(self) -> int:
        """Transitions judged (K − 1)."""
        return len(self.ok)

    @property
    def rate(self) -> float:
        """Share of successful transitions (NaN with fewer than two keyframes)."""
        return self.count / self.total if self.total else float("nan")

    def to_dict(self) -> dict:
        return {
            "success": self.count,
            "transitions": self.total,
            "rate": self.rate,
            "ok": self.ok.tolist(),
            "mean_step": self.mean_step.tolist(),
            "max_step": self.max_step.tolist(),
        }


def transition_success(
    thetas: np.ndarray, totals: np.ndarray, cfg: TransitionConfig | None = None
) -> tuple[np.ndarray, TransitionReport]:
    """Keyframe poses ``thetas (K, 21)`` rad in first-appearance order and their totals ``(K,)`` (the caller's
    reading, ``cfg.total`` for :class:`~studio.imitate.sequence_result.SequenceResult`) → ``ok (K-1,)`` bool and the
    :class:`TransitionReport`. A NaN total fails its endpoint."""
    cfg = cfg or TransitionConfig()
    thetas = np.asarray(thetas, dtype=np.float64)
    totals = np.asarray(totals, dtype=np.float64)
    if thetas.ndim != 2 or totals.shape != (len(thetas),):
        raise ValueError(f"thetas must be (K, J) and totals (K,), not {thetas.shape} and {totals.shape}")
    step = np.abs(np.diff(thetas, axis=0))  # (K-1, J)
    mean_step = step.mean(axis=1) if len(step) else np.zeros(0)
    max_step = step.max(axis=1) if len(step) else np.zeros(0)
    totals_ok = np.nan_to_num(totals, nan=np.inf) <= cfg.max_total
    mean_ok = mean_step <= cfg.max_mean_step
    max_ok = max_step <= cfg.max_step
    ok = totals_ok[:-1] & totals_ok[1:] & mean_ok & max_ok
    return ok, TransitionReport(ok, mean_step, max_step, totals_ok, mean_ok, max_ok)
