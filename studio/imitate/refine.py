"""Collision-aware refinement: hill climbing on the *rendered* shadow (DESIGN §4 "Refinement").

Chains start from the best pose (chain 0 exactly there, the others at N(0, 0.25 rad) around it, clipped to the
limits) and take ``steps`` proposals each: ``θ' = clip(θ + N(0, σ))`` with σ from 0.08 rad shrinking ×0.995 per
step to a floor of 0.01 rad. A proposal is accepted only if it is collision-free and lowers the image loss of the
shadow the exact renderer casts. The paper's 8 restarts run here as 8 parallel chains, so each step renders,
scores and collision-checks one batch. The answer is the best collision-free pose any chain visited.

``method="cmaes"`` (the studio's default, :data:`CPU_REFINE`) replaces the isotropic proposals with CMA-ES
(:mod:`studio.imitate.cmaes`): each generation renders, scores and collision-checks ``popsize`` candidates drawn from
a covariance it learns (joints that must move together, joints that do not matter), colliding candidates rank last.
:data:`PAPER_REFINE` keeps the paper's hill climbing. Without CLIP the shadows are scored by the compiled
:mod:`studio.imitate.rendered_loss`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from studio.errors import ClosedError, ProgressFn, report, stopped
from studio.imitate.cmaes import CMAES
from studio.imitate.config import RefineConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.rendered_loss import RenderedLoss, fast_loss
from studio.sim.physics import CollisionWorld
from studio.sim.shadow import ShadowRenderer


@dataclass
class RefineResult:
    """What refinement returns (plain data)."""

    theta: np.ndarray  # (21,) rad: best collision-free pose found (the start pose if none was)
    loss: float  # its rendered-shadow loss (inf if no collision-free pose was found)
    components: dict[str, float]  # its loss components
    collision_free: bool  # False: no collision-free pose was found; ``theta`` is then the (colliding) start
    start_loss: float  # rendered-shadow loss of the start pose
    start_collides: bool  # the start pose penetrates itself
    curve: list[tuple[int, float]] = field(default_factory=list)  # (step, best collision-free loss)
    evaluations: int = 0  # shadows rendered and scored
    cancelled: bool = False

    @property
    def message(self) -> str:
        if self.collision_free:
            return f"collision-free pose found, loss {self.start_loss:.4f} → {self.loss:.4f}"
        return "no collision-free pose was found near the start pose; try more restarts or a larger restart noise"


class Refiner:
    """Holds the renderer and the collision world so repeated refinements reuse them.

    A world passed in stays the caller's; one made here is disconnected by ``close()`` (or the end of a ``with``
    block), after which the refiner raises :class:`~studio.errors.ClosedError`.
    """

    def __init__(self, renderer: ShadowRenderer, world: CollisionWorld | None = None):
        self.renderer = renderer
        self.hand = renderer.hand
        self._owns_world = world is None
        self.world = world or CollisionWorld(self.hand)
        self.closed = False
        self._fast: tuple[ImageLoss | None, RenderedLoss | None] = (None, None)  # (loss, its compiled twin)
        self.box: tuple[np.ndarray, np.ndarray] | None = None  # (lower, upper) (21,) rad narrower than the joints'

    @property
    def lower(self) -> np.ndarray:
        """``(21,)`` rad: the lowest angles a pose may take here (the joint limits, or :meth:`bounded`'s box)."""
        return self.hand.lower if self.box is None else self.box[0]

    @property
    def upper(self) -> np.ndarray:
        """``(21,)`` rad: the highest angles a pose may take here."""
        return self.hand.upper if self.box is None else self.box[1]

    @contextmanager
    def bounded(self, box: tuple[np.ndarray, np.ndarray] | None) -> Iterator[Refiner]:
        """Within the block, every proposal, sweep draw and seed stays in ``box`` ``(lower (21,), upper (21,))``
        rad (e.g. a keyframe's reach from the posed keyframes on the show's clock,
        :func:`studio.motion.reach.clock_boxes`); None: the joint limits."""
        before = self.box
        if box is not None:
            lo = np.maximum(np.asarray(box[0], float), self.hand.lower)
            hi = np.minimum(np.asarray(box[1], float), self.hand.upper)
            box = (lo, np.maximum(hi, lo))
        self.box = box
        try:
            yield self
        finally:
            self.box = before

    def with_roll(self, roll: float) -> Refiner:
        """A refiner that renders and scores poses as a mount rolled by ``roll`` rad casts them (the shadows of the
        audience's frame), on this one's collision world (a roll changes no collision) and with its box; itself
        when ``roll`` is 0. Closing it leaves the world to this one."""
        if not roll:
            return self
        rolled = Refiner(ShadowRenderer(self.hand, self.renderer.rig.with_roll(roll)), self.world)
        rolled.box = self.box
        return rolled

    def close(self) -> None:
        """Disconnect the collision world if this refiner made it (idempotent)."""
        if self._owns_world:
            self.world.close()
        self.closed = True

    def __enter__(self) -> Refiner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_open(self) -> None:
        if self.closed:
            raise ClosedError("this Refiner was closed; make a new one (or refine inside its `with` block)")

    @torch.no_grad()
    def score(
        self, loss_fn: ImageLoss, theta: np.ndarray, theta_prev: np.ndarray | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Rendered-shadow losses of poses ``(B, 21)`` → totals ``(B,)`` and components.

        With ``theta_prev (21,)`` rad the totals add the temporal term ``w_temporal·‖θ − θ_prev‖²`` (reported as
        the ``temporal`` component, NaN without it). Without CLIP the compiled ``rendered_loss`` scores them; with
        CLIP the renders go to the CLIP encoder's device (a CUDA encoder scores CUDA crops)."""
        self._check_open()
        if self._fast[0] is not loss_fn:
            self._fast = (loss_fn, fast_loss(loss_fn))
        fast = self._fast[1]
        if fast is not None:  # the compiled twin of loss_fn (no CLIP, one target): same numbers, several times faster
            return fast(self.renderer.render(theta, check=False), theta, theta_prev)
        device = next(loss_fn.clip.parameters()).device if loss_fn.clip is not None else torch.device("cpu")
        shadows = torch.from_numpy(self.renderer.render(theta, check=False)).float().to(device)
        if theta_prev is None:
            total, comps = loss_fn(shadows)
        else:
            th = torch.as_tensor(np.asarray(theta, dtype=np.float64), device=device)
            total, comps = loss_fn(shadows, th, torch.as_tensor(np.asarray(theta_prev, dtype=np.float64)))
        return total.double().cpu().numpy(), {k: v.double().cpu().numpy() for k, v in comps.items()}

    def refine(
        self,
        loss_fn: ImageLoss,
        theta_start: np.ndarray,
        cfg: RefineConfig | None = None,
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
        theta_prev: np.ndarray | None = None,
        best_pose: Callable[[np.ndarray], None] | None = None,
    ) -> RefineResult:
        """Hill-climb (or CMA-ES) from ``theta_start (21,)`` rad (module doc). Reports stage "refine" (step of the
        schedule's steps, the best collision-free loss: inf before one is found) every ``log_every`` steps, just after
        ``best_pose(θ (21,) rad)`` with the best collision-free pose so far (none yet: not called). ``cancel`` stops
        within a step: the result is then flagged ``cancelled`` and holds the best pose so far.

        ``theta_prev (21,)`` rad (a sequence's previous keyframe optimum) adds the temporal term to every score,
        so a proposal that drifts away from the previous pose must pay for it with a better shadow; None scores
        the shadow alone.
        """
        self._check_open()
        cfg = cfg or RefineConfig()
        start = np.clip(self.hand.check_theta(theta_start)[0], self.lower, self.upper)
        rng = np.random.default_rng(cfg.seed)
        start_loss = float(self.score(loss_fn, start[None], theta_prev)[0][0])
        start_collides = bool(self.world.in_collision(start, check=False)[0])
        climb = self._hill if cfg.method == "hill" else self._cmaes
        best_theta, best_loss, curve, evaluations, cancelled = climb(
            loss_fn, start, cfg, rng, progress, cancel, theta_prev, best_pose
        )
        found = bool(np.isfinite(best_loss))
        theta = best_theta if found else start
        _, comps = self.score(loss_fn, theta[None], theta_prev)
        return RefineResult(
            theta=theta,
            loss=best_loss if found else float("inf"),
            components={k: float(v[0]) for k, v in comps.items()},
            collision_free=found,
            start_loss=start_loss,
            start_collides=start_collides,
            curve=curve,
            evaluations=evaluations,
            cancelled=cancelled,
        )

    def _hill(self, loss_fn, start, cfg, rng, progress, cancel, theta_prev, best_pose):
        """The paper's hill climbing: ``restarts`` parallel chains, isotropic proposals (module docstring)."""
        lo, hi = self.lower, self.upper
        cur = np.clip(start + rng.normal(0, cfg.restart_noise, (cfg.restarts, self.hand.dof)), lo, hi)
        cur[0] = start
        cur_loss, _ = self.score(loss_fn, cur, theta_prev)
        # A colliding chain has loss +inf: it accepts any collision-free proposal, and meanwhile any proposal that
        # lowers its collision score S_col (so a chain that starts deep in collision can climb out of it).
        cur_col = self.world.collision_score(cur, check=False)
        cur_loss[self.world.in_collision(cur, check=False)] = np.inf
        best_i = int(np.argmin(cur_loss))
        best_theta, best_loss = cur[best_i].copy(), float(cur_loss[best_i])
        curve, evaluations, sigma, cancelled = [], cfg.restarts + 1, cfg.sigma0, False
        for step in range(1, cfg.steps + 1):
            if stopped(cancel):
                cancelled = True
                break
            prop = np.clip(cur + rng.normal(0, sigma, cur.shape), lo, hi)
            loss, _ = self.score(loss_fn, prop, theta_prev)
            evaluations += len(prop)
            better = loss < cur_loss
            accepted = np.zeros(len(prop), dtype=bool)
            if better.any():
                free = ~self.world.in_collision(prop[better], check=False)
                accept = np.flatnonzero(better)[free]
                cur[accept], cur_loss[accept] = prop[accept], loss[accept]
                accepted[accept] = True
                i = int(np.argmin(cur_loss))
                if cur_loss[i] < best_loss:
                    best_theta, best_loss = cur[i].copy(), float(cur_loss[i])
            stuck = np.flatnonzero(~np.isfinite(cur_loss) & ~accepted)  # chains still in collision
            if len(stuck):
                col = self.world.collision_score(prop[stuck], check=False)
                lower = col < cur_col[stuck]
                cur[stuck[lower]], cur_col[stuck[lower]] = prop[stuck[lower]], col[lower]
            sigma = max(cfg.sigma_min, sigma * cfg.decay)
            if step % cfg.log_every == 0 or step == cfg.steps:
                curve.append((step, best_loss))
                if best_pose and np.isfinite(best_loss):
                    best_pose(best_theta.copy())
                report(progress, "refine", step, cfg.steps, best_loss)
        return best_theta, best_loss, curve, evaluations, cancelled

    def _cmaes(self, loss_fn, start, cfg, rng, progress, cancel, theta_prev, best_pose):
        """CMA-ES runs one after another (run 0 from the start pose, the others from N(0, restart_noise) around
        it), each ``steps`` generations of ``popsize`` candidates. A colliding candidate ranks after every
        collision-free one, by ``1 + loss + S_col`` (so a run that starts in collision climbs out of it)."""
        lo, hi = self.lower, self.upper
        free0 = not bool(self.world.in_collision(start, check=False)[0])
        best_theta = start.copy()
        best_loss = float(self.score(loss_fn, start[None], theta_prev)[0][0]) if free0 else float("inf")
        curve: list[tuple[int, float]] = []
        evaluations, cancelled, total = 1, False, cfg.restarts * cfg.steps
        for run in range(cfg.restarts):
            mean = start if run == 0 else np.clip(start + rng.normal(0, cfg.restart_noise, start.shape), lo, hi)
            es = CMAES(mean, cfg.sigma0, lo, hi, cfg.popsize, rng)
            for gen in range(1, cfg.steps + 1):
                if stopped(cancel):
                    cancelled = True
                    break
                x = es.ask()
                loss, _ = self.score(loss_fn, x, theta_prev)
                evaluations += len(x)
                hit = self.world.in_collision(x, check=False)
                fit = loss.copy()
                if hit.any():
                    fit[hit] = 1.0 + loss[hit] + self.world.collision_score(x[hit], check=False)
                free = np.flatnonzero(~hit)
                if len(free):
                    i = free[int(np.argmin(loss[free]))]
                    if loss[i] < best_loss:
                        best_theta, best_loss = x[i].copy(), float(loss[i])
                es.tell(x, fit)
                step = run * cfg.steps + gen
                if step % cfg.log_every == 0 or step == total:
                    curve.append((step, best_loss))
                    if best_pose and np.isfinite(best_loss):
                        best_pose(best_theta.copy())
                    report(progress, "refine", step, total, best_loss)
            if cancelled:
                break
        return best_theta, best_loss, curve, evaluations, cancelled
