"""Image losses between predicted and target shadows (DESIGN §4 "Losses"), in torch, per sample.

Images are probabilities in [0, 1], 1 = shadow, as ``(B, H, W)`` or ``(B, 1, H, W)``. Both sides are compared on
crops aligned by :mod:`studio.sim.crop` (the target is cropped once; each prediction by the box of its pixels above
0.5), so the losses ignore where the shadow sits and, up to the fixed pad, how large it is:

- ``L_base = 0.06·MAE + 0.4·(1 − IoU) + 0.02·(1 − cos(CLIP(pred), CLIP(target)))``
- ``L_expr = 1.0·(1 − IoU(M⊙target, M⊙pred)) + 0.05·(1 − cos(CLIP(M⊙pred), CLIP(M⊙target)))``, with ``M`` the
  expressive region in the target's frame (cropped with the target's box; its crop masks both sides)
- ``L_temp = 0.2·‖θ_i − θ*_{i−1}‖²``

IoU is the soft IoU ``Σ min(p, t) / Σ max(p, t)`` on probabilities (1 when both sides are empty). A component that
was not computed (CLIP with ``use_clip=False``, the expressive terms without ``M``, the temporal term without
poses) is reported as NaN and left out of the total, so tables and logs show that it was not used.
"""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import torch

from studio.errors import StudioError
from studio.imitate.clip_loss import ClipImageEncoder
from studio.imitate.config import COMPONENTS, LossConfig
from studio.sim.crop import as_image_batch, crop_boxes, square_boxes


def mae(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean absolute error per sample of ``(B, H, W)`` images → ``(B,)``."""
    return (pred - target).abs().flatten(1).mean(dim=1)


def soft_iou(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Soft IoU per sample of probability images ``(B, H, W)`` → ``(B,)`` in [0, 1] (1 when both are empty).

    ``Σ min(p, t) / Σ max(p, t)``: the IoU of binary masks, and exactly 1 for identical soft images (the product
    form ``Σ p·t / Σ (p + t − p·t)`` is below 1 for an image against itself once resampling has softened edges).
    """
    inter = torch.minimum(pred, target).flatten(1).sum(dim=1)
    union = torch.maximum(pred, target).flatten(1).sum(dim=1)
    return (inter + eps) / (union + eps)


def clip_distance(clip: ClipImageEncoder, pred: torch.Tensor, target_emb: torch.Tensor) -> torch.Tensor:
    """``1 − cos(CLIP(pred), target_emb)`` per sample: pred ``(B, S, S)``, target_emb ``(B or 1, D)`` → ``(B,)``."""
    emb = clip(pred)  # on pred's device, whatever the encoder's
    return 1.0 - (emb * target_emb.to(emb.device)).sum(dim=-1)


def temporal_loss(theta: torch.Tensor, theta_prev: torch.Tensor, weight: float = 0.2) -> torch.Tensor:
    """``weight · ‖θ − θ_prev‖²`` per sample: theta ``(B, J)`` rad, theta_prev ``(J,)`` or ``(B, J)`` → ``(B,)``."""
    return weight * ((theta - theta_prev) ** 2).sum(dim=-1)


class ImageLoss:
    """The paper's image loss against fixed target(s): cropped (and CLIP-embedded) once, then called per batch.

    ``target``: ``(H, W)`` or ``(N, [1,] H, W)`` shadow masks (1 = shadow; arrays or tensors); ``expressive``: the
    region ``M`` of the same shape(s) in the target frame, or None. A call takes predictions ``(B, [1,] H', W')``
    with ``N == 1`` (one target for the whole batch) or ``N == B`` (one target per sample); ``H', W'`` may differ
    from the target's since both are resampled to ``crop_size``.
    """

    def __init__(
        self,
        target: torch.Tensor | np.ndarray,
        cfg: LossConfig | None = None,
        clip: ClipImageEncoder | None = None,
        expressive: torch.Tensor | np.ndarray | None = None,
    ) -> None:
        self.cfg = cfg or LossConfig()
        if self.cfg.use_clip and clip is None:
            raise StudioError(
                "the CLIP loss term needs a CLIP model: pass clip=load_clip(weights=PATH) or LossConfig(use_clip=False)"
            )
        self.clip = clip if self.cfg.use_clip else None
        t = as_image_batch(target).float()
        if not bool((t > 0.5).flatten(1).any(dim=1).all()):
            raise StudioError("a target has no shadow pixels (nothing to imitate)")
        self.target_boxes = square_boxes(t, 0.5, self.cfg.pad)  # (N, 4) pixel edges in the target frame
        self.target_crop = crop_boxes(t, self.target_boxes, self.cfg.crop_size)  # (N, S, S)
        self.mask_crop: torch.Tensor | None = None  # (N, S, S) expressive region M in the target crop frame
        if expressive is not None:
            m = as_image_batch(expressive).float()
            if m.shape != t.shape:
                raise ValueError(f"expressive mask shape {tuple(m.shape)} differs from the target's {tuple(t.shape)}")
            self.mask_crop = crop_boxes(m, self.target_boxes, self.cfg.crop_size)
        self._embed_targets()

    @torch.no_grad()
    def _embed_targets(self) -> None:
        self.target_emb = self.exp_target_emb = None  # (N, D) CLIP embeddings of target and M⊙target
        if self.clip is None:
            return
        device = next(self.clip.parameters()).device
        self.target_emb = self.clip(self.target_crop.to(device))
        if self.mask_crop is not None:
            self.exp_target_emb = self.clip((self.mask_crop * self.target_crop).to(device))

    def pixel_only(self) -> ImageLoss:
        """This loss with the CLIP terms off (the same target crops and expressive region): the pixel terms
        alone, e.g. to rank thousands of candidate shadows before the full loss re-scores the best. Itself when
        CLIP is already off."""
        if self.clip is None:
            return self
        twin = copy.copy(self)
        twin.cfg, twin.clip = replace(self.cfg, use_clip=False), None
        twin.target_emb = twin.exp_target_emb = None
        return twin

    @property
    def n_targets(self) -> int:
        return self.target_crop.shape[0]

    def to(self, device: str | torch.device) -> ImageLoss:
        """Move the cached target crops and embeddings (and the CLIP model) to ``device``."""
        for name in ("target_boxes", "target_crop", "mask_crop", "target_emb", "exp_target_emb"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, value.to(device))
        if self.clip is not None:
            self.clip.to(device)
        return self

    def crop_predictions(self, pred: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Predictions ``(B, [1,] H, W)`` → aligned crops ``(B, S, S)`` (differentiable in the pixels)."""
        p = as_image_batch(pred)
        if p.shape[0] != self.n_targets and self.n_targets != 1:
            raise ValueError(f"{p.shape[0]} predictions for {self.n_targets} targets (need 1 target or one each)")
        return crop_boxes(p, square_boxes(p, self.cfg.box_threshold, self.cfg.pad), self.cfg.crop_size)

    def __call__(
        self,
        pred: torch.Tensor | np.ndarray,
        theta: torch.Tensor | None = None,
        theta_prev: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Per-sample totals ``(B,)`` and components ``{name: (B,)}`` (:data:`COMPONENTS`; NaN = not computed).

        ``theta`` ``(B, J)`` rad and ``theta_prev`` ``(J,)``/``(B, J)``, when both are given, add the temporal term.
        """
        cfg = self.cfg
        p = self.crop_predictions(pred)
        t = self.target_crop.to(p.device)
        nan = torch.full((p.shape[0],), math.nan, dtype=p.dtype, device=p.device)
        c = {"mae": mae(p, t), "iou_loss": 1.0 - soft_iou(p, t, cfg.eps)}
        c["clip"] = clip_distance(self.clip, p, self.target_emb) if self.clip is not None else nan
        base = cfg.w_mae * c["mae"] + cfg.w_iou * c["iou_loss"]
        c["base"] = base + cfg.w_clip * c["clip"] if self.clip is not None else base
        total = c["base"]
        if self.mask_crop is not None:
            m = self.mask_crop.to(p.device)
            c["exp_iou"] = 1.0 - soft_iou(m * p, m * t, cfg.eps)
            c["exp_clip"] = clip_distance(self.clip, m * p, self.exp_target_emb) if self.clip is not None else nan
            expr = cfg.w_exp_iou * c["exp_iou"]
            c["expr"] = expr + cfg.w_exp_clip * c["exp_clip"] if self.clip is not None else expr
            total = total + c["expr"]
        else:
            c["exp_iou"] = c["exp_clip"] = c["expr"] = nan
        if theta is not None and theta_prev is not None:
            c["temporal"] = temporal_loss(theta, theta_prev.to(theta), cfg.w_temporal)
            total = total + c["temporal"]
        else:
            c["temporal"] = nan
        c["total"] = total
        return total, {k: c[k] for k in COMPONENTS}
