"""``--roll auto``: the one mount roll under which the hand casts a still, or every keyframe of a show, best.

The roll turns only the target (:mod:`studio.sim.roll`), so candidate rolls are ranked on the retrieval index alone,
within the first answer's budget (≈ 3 ms an angle and target, compiled, :meth:`RetrievalIndex.best`):

1. **coarse**: every ``coarse_deg`` around the circle, each target turned into the hand's frame and scored by the
   index's best pixel loss; a show's score is the mean over its keyframes (one mount for the whole show);
2. **index refinement**: the ``top`` best coarse angles, each by halving steps (± half the grid, then ± a quarter …)
   down to ``index_deg``;
3. **exact** (where it pays, since the index's 32-pixel crops are coarse): each refined angle's best index poses
   (the query's shortlist, scored on the renderer) → the angle whose poses cast the targets best; then, with those
   poses held, halving steps on the rendered loss down to ``fine_deg``. These scores are taken as the audience sees
   them: each pose rendered by the *rolled* mount and scored against the target as it is (a hole or a thin part
   that turning the target would blur never decides the roll);
4. **one quick sweep** (a still; ``swept`` candidates): the exact stage's ranking is close between angles whose
   poses differ a lot, so at each of the best candidates the index's best pose for the target is block-swept one
   pass with few draws (:func:`~studio.imitate.seeding.sweep`, scored as the rolled mount casts it), and the roll
   whose swept pose casts it best is chosen (signer 1's ``dif`` letters, ``bench_roll_choice.py``: IoU loss 0.1571
   → 0.1543 for 0.2 s a letter). A show keeps the exact stage's choice: its keyframes are posed within each other's
   reach at its clock, which a free sweep ignores (Table 2's studio row: Total 0.3255 → 0.3318 with the sweep);
5. **what the one mount costs** (a show): a target whose first answer on the roll chosen is clearly worse
   (``apart_ratio`` ×, and ``apart_margin`` more) than at the coarse roll best for it alone is named
   (:attr:`RollChoice.apart`): why it reads worse, where it would read better (the demo's ASL "o" beside the
   Muybridge horse: 0.235 at the horse's −83.4° against 0.106 at −15°). The roll is not changed. A roll the artist
   sets is measured the same way (:func:`check_roll`).

Every stage scores the outline (MAE + IoU, + CLIP when on), as the index does; the expressive term (a still's holes)
is left to the imitation (a hole leak let it decide the roll: ``bench_reach.py``, 8 of 12 rolls within 2°, not 11).
Pure compute over an index and a refiner (renderer + collision world); the caller imitates at the roll chosen.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from studio.errors import ProgressFn, report, stopped
from studio.imitate.config import SweepConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.rendered_loss import fast_loss
from studio.imitate.retrieval import RetrievalIndex
from studio.imitate.seeding import sweep
from studio.sim.roll import into_hand_frame, wrap_deg
from studio.sim.shadow import ShadowRenderer


@dataclass(frozen=True)
class RollSearchConfig:
    """How ``--roll auto`` searches the mount roll."""

    coarse_deg: float = 15.0  # first pass: a candidate roll every this many degrees around the circle (0, 90]
    top: int = 3  # best coarse angles refined on the index and compared exactly [1, ∞)
    index_deg: float = 1.875  # index refinement stops at this step, degrees (0, coarse_deg]
    fine_deg: float = 0.25  # exact refinement (rendered loss, poses held) stops at this step, degrees (0, ∞)
    exact_k: int = 4  # best index poses per target scored exactly at each refined angle [1, ∞); with 1 a lucky pose won
    swept: int = 3  # a still's best candidates ranked again by a quick sweep (module doc, 4.) [1, ∞); 1: no sweep
    sweep_draws: int = 256  # settings drawn per finger block in that sweep's one pass; the wrist a quarter [4, 16384]
    apart_ratio: float = 1.5  # a show's target is named as better cast on another mount when its first answer on the
    apart_margin: float = 0.05  # roll chosen is ≥ ratio × and ≥ margin above its best roll's (module doc, 5.)

    def __post_init__(self) -> None:
        if not 0 < self.coarse_deg <= 90 or not 0 < self.index_deg <= self.coarse_deg or self.fine_deg <= 0:
            raise ValueError("roll search needs 0 < index_deg ≤ coarse_deg ≤ 90 and fine_deg > 0 (degrees)")
        if self.top < 1 or self.exact_k < 1 or self.swept < 1 or not 4 <= self.sweep_draws <= 16384:
            raise ValueError("roll search needs top ≥ 1, exact_k ≥ 1, swept ≥ 1 and 4 ≤ sweep_draws ≤ 16384")
        if self.apart_ratio < 1 or self.apart_margin < 0:
            raise ValueError("roll search needs apart_ratio ≥ 1 and apart_margin ≥ 0")

    @property
    def quick_sweep(self) -> SweepConfig:
        """The sweep that ranks the candidates: one start, one pass, ``sweep_draws``."""
        return SweepConfig(starts=1, draws=self.sweep_draws, wrist_draws=self.sweep_draws // 4, passes=1)

    @property
    def grid(self) -> list[float]:
        """The coarse pass's rolls: every ``coarse_deg`` around the circle, degrees in (-180, 180]."""
        return [float(wrap_deg(d)) for d in np.arange(0.0, 360.0, self.coarse_deg)]


@dataclass(frozen=True)
class Apart:
    """One target of a show that another mount would cast clearly better (plain data)."""

    target: int  # its index in the targets
    loss: float  # its first answer's rendered outline loss on the roll chosen
    own_roll: float  # rad, the roll best for it alone
    own_loss: float  # its first answer's loss there


@dataclass
class RollChoice:
    """The roll chosen (plain data)."""

    roll: float  # rad, counter-clockwise as the audience sees the backdrop
    loss: float  # mean rendered outline (base) loss of the held (first-answer) poses over the targets at that roll
    upright_loss: float  # the same measure at roll 0 (the paper's rig), for the summary
    seconds: float  # wall time of the search
    coarse: dict[float, float] = field(default_factory=dict)  # degrees → mean index pixel loss (the first pass)
    candidates: list[tuple[float, float]] = field(default_factory=list)  # (degrees, loss): the roll chosen, then
    # the other refined angles by their exact loss, each angle once (benchmarks/bench_roll_choice.py imitates each)
    swept: list[float] = field(default_factory=list)  # the mean loss after the quick sweep (module doc, 4.) of the
    # first ``RollSearchConfig.swept`` candidates, in their order (empty: not swept); the roll chosen has the lowest
    apart: list[Apart] = field(default_factory=list)  # a show's targets that the roll chosen casts clearly worse
    # than a roll of their own would (module doc, 5.; empty for a still), in the targets' order

    @property
    def deg(self) -> float:
        return round(wrap_deg(math.degrees(self.roll)), 2)


LossFactory = Callable[[np.ndarray, "np.ndarray | None"], ImageLoss]  # (target, expressive) → its loss


class _Scorer:
    """Rendered shadows ``(P, R, R)`` → their totals ``(P,)`` under one target's loss (compiled when it can be)."""

    def __init__(self, loss_fn: ImageLoss):
        self.loss_fn, self.fast = loss_fn, fast_loss(loss_fn)

    def __call__(self, shadows: np.ndarray) -> np.ndarray:
        if self.fast is not None:
            return self.fast(shadows)[0]
        with torch.no_grad():
            return self.loss_fn(torch.from_numpy(np.asarray(shadows, np.float32)))[0].double().cpu().numpy()


def _rolled(refiner: Refiner, deg: float) -> ShadowRenderer:
    """The refiner's renderer with the mount rolled by ``deg`` degrees."""
    return ShadowRenderer(refiner.hand, refiner.renderer.rig.with_roll(math.radians(deg)))


def _swept(
    index: RetrievalIndex, refiner: Refiner, targets: np.ndarray, losses: list[ImageLoss], deg: float,
    one_pass: SweepConfig, cancel,
) -> list[float]:  # fmt: skip
    """Each target's loss after ``one_pass`` at the mount rolled by ``deg``: the index's best distinct poses for the
    turned target, scored and swept as that mount casts them against the target as it is (``losses``); fewer when
    ``cancel`` stops it."""
    rolled = refiner.with_roll(math.radians(deg))
    out = []
    for turned, fn in zip(_turned(targets, deg), losses, strict=True):
        if stopped(cancel):
            break
        first = index.query(turned, lambda th, fn=fn: rolled.score(fn, th)[0], one_pass.starts)
        out.append(float(sweep(rolled, one_pass, fn, first, cancel=cancel).loss[0]))
    return out


def _turned(targets: np.ndarray, deg: float) -> np.ndarray:
    return np.stack([into_hand_frame(t, None, math.radians(deg))[0] for t in targets])


def _first_answer(
    index: RetrievalIndex, refiner: Refiner, make_loss: LossFactory, target: np.ndarray, audience: _Scorer,
    rolled: ShadowRenderer, deg: float, k: int,
) -> tuple[np.ndarray, float]:  # fmt: skip
    """The exact stage's score of ``target (S, S)`` on the mount ``rolled`` by ``deg``: the index's ``k`` best poses
    for the target turned into the hand's frame → those poses and the best outline loss of them as that mount casts
    them, against the target as it is (``audience``)."""
    turned = _turned(target[None], deg)[0]
    fn = make_loss(turned, None)
    got = index.query(turned, lambda th: refiner.score(fn, th)[0], k)
    return got.theta, float(audience(rolled.render(got.theta, check=False)).min())


def _index_each(index: RetrievalIndex, targets: np.ndarray, degs: list[float], memo: dict[float, np.ndarray]) -> list:
    """Each target's best index pixel loss, ``(K,)`` for each of ``degs`` (one compiled call for the new angles)."""
    keys = [round(wrap_deg(d), 6) for d in degs]
    new = list(dict.fromkeys(k for k in keys if k not in memo))
    if new:
        turned = np.concatenate([_turned(targets, k) for k in new])
        memo.update(zip(new, index.best(turned)[0].reshape(len(new), len(targets)), strict=True))
    return [memo[k] for k in keys]


def _index_scores(index: RetrievalIndex, targets: np.ndarray, degs: list[float], memo: dict[float, np.ndarray]) -> list:
    """Mean best index pixel loss of the targets turned by each of ``degs``."""
    return [float(np.mean(each)) for each in _index_each(index, targets, degs, memo)]


def _halve(score: Callable[[list[float]], list[float]], deg: float, step: float, stop: float) -> float:
    """Local search on one angle: try ± step (scored together), keep the best, halve the step until below ``stop``."""
    best, value = deg, score([deg])[0]
    while step >= stop - 1e-9:
        cands = [best - step, best + step]
        for cand, v in zip(cands, score(cands), strict=True):
            if v < value:
                best, value = cand, v
        step /= 2
    return best


def choose_roll(
    index: RetrievalIndex,
    refiner: Refiner,
    targets: np.ndarray,
    make_loss: LossFactory,
    cfg: RollSearchConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> RollChoice:
    """The roll (rad) under which the hand casts ``targets (K, S, S)`` (a still: K = 1; a show: its keyframes) best
    on average; ``make_loss(target, None)`` builds the (outline) loss a target is scored with (module doc: coarse,
    index refinement, exact, quick sweep). Stage "roll" (a step per candidate swept). ``cancel`` stops the sweeps:
    the exact stage's choice is returned (the caller sees the cancel)."""
    cfg = cfg or RollSearchConfig()
    t0 = time.perf_counter()
    targets = np.asarray(targets)
    if targets.ndim != 3 or not len(targets):
        raise ValueError(f"targets must be (K, S, S) with K ≥ 1, not shape {targets.shape}")
    memo: dict[float, np.ndarray] = {}
    grid = cfg.grid
    coarse = dict(zip(grid, _index_scores(index, targets, grid, memo), strict=True))
    starts = sorted(coarse, key=coarse.get)[: cfg.top]
    refined = [_halve(lambda ds: _index_scores(index, targets, ds, memo), d, cfg.coarse_deg / 2, cfg.index_deg)
               for d in starts]  # fmt: skip

    seen = [_Scorer(make_loss(t, None)) for t in targets]  # the targets as they are

    def exact_at(deg: float) -> tuple[float, list[np.ndarray]]:
        rolled = _rolled(refiner, deg)
        got = [_first_answer(index, refiner, make_loss, t, a, rolled, deg, cfg.exact_k) for t, a in zip(targets, seen)]
        return float(np.mean([loss for _, loss in got])), [theta for theta, _ in got]

    tried = sorted(((d, *exact_at(d)) for d in dict.fromkeys(round(wrap_deg(d), 6) for d in refined)),
                   key=lambda r: r[1])  # fmt: skip
    best_deg, _, poses = tried[0]

    def held(deg: float) -> float:  # the held poses' loss as the mount rolled by deg casts them
        rolled = _rolled(refiner, deg)
        each = [audience(rolled.render(p, check=False)).min() for audience, p in zip(seen, poses, strict=True)]
        return float(np.mean(each))

    best_deg = wrap_deg(_halve(lambda ds: [held(d) for d in ds], best_deg, cfg.index_deg / 2, cfg.fine_deg))
    upright = exact_at(0.0)[0]
    loss = held(best_deg)
    others = tried[1:]
    if upright <= loss:  # the upright rig is as good: keep the paper's rig
        best_deg, loss, others = 0.0, upright, tried
    candidates = [(float(best_deg), loss)]
    for d, v, _ in others:  # each angle once: the upright rig kept may be a refined angle too
        if all(abs(wrap_deg(d - c)) >= cfg.fine_deg for c, _ in candidates):
            candidates.append((float(wrap_deg(d)), v))
    # a still only (module doc, 4.): a show's keyframes are posed within each other's reach, not freely
    n, one_pass = (min(cfg.swept, len(candidates)) if len(targets) == 1 else 0), cfg.quick_sweep
    swept: list[float] = []
    seen_losses = [s.loss_fn for s in seen]
    for i, (deg, _) in enumerate(candidates[:n] if n > 1 else []):  # one candidate: nothing to choose between
        each = _swept(index, refiner, targets, seen_losses, deg, one_pass, cancel)
        if len(each) < len(targets):  # cancelled: the exact stage's choice stands
            swept = []
            break
        swept.append(float(np.mean(each)))
        report(progress, "roll", i + 1, n, min(swept))
    if swept:  # the roll whose swept poses cast the targets best, first
        pick = int(np.argmin(swept))
        order = [pick] + [i for i in range(len(candidates)) if i != pick]
        candidates = [candidates[i] for i in order]
        swept = [swept[i] for i in order if i < len(swept)]
    best_deg, loss = candidates[0]
    apart = [] if len(targets) < 2 or stopped(cancel) else _apart(index, refiner, targets, make_loss, seen, memo, grid,
                                                                  best_deg, cfg)  # fmt: skip
    return RollChoice(math.radians(best_deg), loss, upright, time.perf_counter() - t0, coarse, candidates, swept, apart)


def check_roll(index: RetrievalIndex, refiner: Refiner, targets: np.ndarray, make_loss: LossFactory, deg: float,
               cfg: RollSearchConfig | None = None) -> list[Apart]:  # fmt: skip
    """What a roll the artist set (``deg`` degrees) costs a show of ``targets (K, S, S)``: the targets it casts clearly
    worse than the coarse roll best for each alone, measured as for a roll chosen (module doc, 5.; none for K < 2)."""
    cfg, targets = cfg or RollSearchConfig(), np.asarray(targets)
    seen = [_Scorer(make_loss(t, None)) for t in targets] if len(targets) > 1 else []
    return _apart(index, refiner, targets, make_loss, seen, {}, cfg.grid, float(wrap_deg(deg)), cfg) if seen else []


def _apart(
    index: RetrievalIndex, refiner: Refiner, targets: np.ndarray, make_loss: LossFactory, seen: list[_Scorer],
    memo: dict[float, np.ndarray], grid: list[float], chosen_deg: float, cfg: RollSearchConfig,
) -> list[Apart]:  # fmt: skip
    """The targets of a show that the roll chosen casts clearly worse than the coarse roll best for each alone
    (module doc, 5.), each scored as the exact stage scores: its index shortlist at that mount, rendered rolled and
    scored against the target as it is."""

    each = np.stack(_index_each(index, targets, grid, memo))  # (G, K): each target's index loss at each coarse roll
    out = []
    for k in range(len(targets)):
        own = float(grid[int(np.argmin(each[:, k]))])
        if abs(wrap_deg(own - chosen_deg)) < cfg.coarse_deg / 2:  # its own roll is the one chosen
            continue
        here, there = (_first_answer(index, refiner, make_loss, targets[k], seen[k], _rolled(refiner, d), d,
                                     cfg.exact_k)[1] for d in (chosen_deg, own))  # fmt: skip
        if here >= cfg.apart_ratio * there and here - there >= cfg.apart_margin:
            out.append(Apart(k, here, math.radians(wrap_deg(own)), there))
    return out
