"""Gradient search over joint angles through the frozen self-model (DESIGN §4 "Gradient search").

A batch of joint vectors is optimised at once; joint limits hold by construction through the reparameterisation
``θ = lower + (upper − lower)·sigmoid(φ)``; the best sample of the batch (by the full loss on the final step) is
the answer. Paper defaults: batch 256 × 2000 iterations per frame; sequences 500 × 3000 for the first frame and
128 × 1200 for later frames initialised at the previous optimum + N(0, 0.05 rad). The CPU preset is smaller.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from studio.errors import ProgressFn, report, stopped
from studio.imitate.adam import Adam
from studio.imitate.config import SearchConfig
from studio.imitate.losses import ImageLoss
from studio.learn.selfmodel import SelfModel
from studio.sim.hand import Hand
from studio.sim.sampling import sample_poses


@dataclass
class SearchResult:
    """What a gradient search returns (plain data)."""

    theta: np.ndarray  # (21,) rad, the best joint vector of the batch
    loss: float  # its total loss under the self-model
    components: dict[str, float]  # its loss components (NaN = not computed)
    batch_theta: np.ndarray  # (B, 21) rad, every final joint vector
    batch_loss: np.ndarray  # (B,) their final totals
    curve: list[tuple[int, float, float]] = field(default_factory=list)  # (step, best, mean) loss
    iterations: int = 0  # steps actually run (fewer when cancelled)
    cancelled: bool = False


def _to_phi(theta: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    u = ((theta - lo) / (hi - lo)).clamp(1e-4, 1 - 1e-4)
    return torch.log(u) - torch.log1p(-u)


def initial_poses(
    hand: Hand, cfg: SearchConfig, init: np.ndarray | None = None, starts: np.ndarray | None = None
) -> np.ndarray:
    """``(B, 21)`` starting poses: around ``init`` (N(0, init_noise)) or drawn by the self-exploration sampler;
    ``starts (K, 21)`` (e.g. retrieved poses) then take the first ``min(K, B)`` rows."""
    rng = np.random.default_rng(cfg.seed)
    if init is not None:
        theta = np.asarray(init, dtype=float)[None] + rng.normal(0, cfg.init_noise, (cfg.batch, hand.dof))
        theta[0] = init
    else:
        theta = sample_poses(hand, cfg.batch, rng)[0]
        if cfg.include_rest:
            theta[0] = hand.rest_pose()
    if starts is not None and len(starts):
        k = min(len(starts), cfg.batch)
        theta[:k] = np.asarray(starts, dtype=float)[:k]
    return np.clip(theta, hand.lower, hand.upper)


def gradient_search(
    model: SelfModel,
    loss_fn: ImageLoss,
    cfg: SearchConfig | None = None,
    init: np.ndarray | None = None,
    theta_prev: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    best_pose: Callable[[np.ndarray], None] | None = None,
    starts: np.ndarray | None = None,
    box: tuple[np.ndarray, np.ndarray] | None = None,
) -> SearchResult:
    """Minimise ``loss_fn(model(θ))`` (+ the temporal term against ``theta_prev``) over a batch of θ.

    Reports stage "search" (step of ``cfg.iterations``, the batch's best loss) every ``log_every`` steps and at the
    last, just after ``best_pose(θ (21,) rad)`` with the pose of that best loss (for live previews); ``cancel`` stops
    within a step and the best pose so far is returned (``cancelled=True``).
    ``starts (K, 21)`` rad seed the first rows of the batch (:func:`initial_poses`). ``box`` ``(lower, upper)``
    ``(21,)`` rad narrows the joint limits (a keyframe's reach on the show's clock): the reparameterisation then
    keeps every pose inside it.
    """
    cfg = cfg or SearchConfig()
    hand = model.hand
    device = next(model.parameters()).device
    low, high = (hand.lower, hand.upper) if box is None else box
    high = np.maximum(high, low + 1e-6)  # a pinned joint keeps a sliver of room (the sigmoid needs hi > lo)
    lo = torch.tensor(low, dtype=torch.float32, device=device)
    hi = torch.tensor(high, dtype=torch.float32, device=device)
    theta0 = np.clip(initial_poses(hand, cfg, init, starts), low, high)
    theta0 = torch.tensor(theta0, dtype=torch.float32, device=device)
    phi = _to_phi(theta0, lo, hi).requires_grad_(True)
    prev = None if theta_prev is None else torch.tensor(theta_prev, dtype=torch.float32, device=device)
    opt = Adam(phi, lr=cfg.lr)  # torch.optim.Adam's step, without its torch._dynamo import (studio.imitate.adam)
    model.eval().requires_grad_(False)
    curve: list[tuple[int, float, float]] = []
    step, cancelled = 0, False
    for step in range(1, cfg.iterations + 1):
        if stopped(cancel):
            cancelled, step = True, step - 1
            break
        theta = lo + (hi - lo) * torch.sigmoid(phi)
        total, _ = loss_fn(model(theta), theta, prev)
        opt.zero_grad()
        total.sum().backward()
        opt.step()
        if step % cfg.log_every == 0 or step == cfg.iterations:
            best = float(total.detach().min())
            curve.append((step, best, float(total.detach().mean())))
            if best_pose:
                best_pose(theta[int(torch.argmin(total.detach()))].detach().double().cpu().numpy())
            report(progress, "search", step, cfg.iterations, best)
    with torch.no_grad():
        theta = lo + (hi - lo) * torch.sigmoid(phi)
        total, comps = loss_fn(model(theta), theta, prev)
    b = int(torch.argmin(total))
    return SearchResult(
        theta=theta[b].double().cpu().numpy(),
        loss=float(total[b]),
        components={k: float(v[b]) for k, v in comps.items()},
        batch_theta=theta.double().cpu().numpy(),
        batch_loss=total.cpu().numpy(),
        curve=curve,
        iterations=step,
        cancelled=cancelled,
    )
