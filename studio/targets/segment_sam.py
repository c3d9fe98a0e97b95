"""Optional Segment Anything adapter for :func:`studio.targets.segment.segment_video`.

Used only when its package is importable (``segment_anything``, Meta's SAM, or ``sam2``) AND
``SegmentConfig.sam_checkpoint`` names a local file that exists. Nothing is downloaded: without either, the
classical method runs (``method="auto"``) or a :class:`TargetError` says which package or file to provide
(``method="sam"``).

Tracking is by box prompts: frame 0 is prompted with the artist's box (or the first mask's box, the mask itself
kept as frame 0's answer), every later frame with the previous answer's box grown by ``sam_box_grow`` per side.
"""

from __future__ import annotations

import importlib.util
import logging
import re
import threading
from pathlib import Path

import numpy as np

from studio.errors import TargetError
from studio.progress import ProgressFn, report, stopped

log = logging.getLogger(__name__)

PACKAGES = ("segment_anything", "sam2")
SAM1_TYPES = ("vit_h", "vit_l", "vit_b")  # segment_anything's sam_model_registry keys
SAM2_SIZES = {"tiny": "t", "small": "s", "base_plus": "b+", "large": "l"}  # checkpoint name → config suffix


def installed_package() -> str | None:
    """The first Segment Anything package that can be imported here, or None."""
    for name in PACKAGES:
        if importlib.util.find_spec(name) is not None:
            return name
    return None


def unavailable(cfg) -> str | None:
    """None when Segment Anything can run with ``cfg`` (a SegmentConfig); else why not and what to provide."""
    package = installed_package()
    ckpt = cfg.sam_checkpoint
    missing = []
    if package is None:
        missing.append(
            "neither Python package 'segment_anything' (pip install segment-anything) nor 'sam2' (pip install sam2) "
            "is installed"
        )
    if not ckpt:
        missing.append(
            "no checkpoint was given: download one yourself (e.g. sam_vit_b_01ec64.pth for segment_anything, "
            "sam2.1_hiera_small.pt for sam2) and pass its path as SegmentConfig(sam_checkpoint=...)"
        )
    elif not Path(ckpt).is_file():
        missing.append(f"the checkpoint file {ckpt} does not exist: give the path of a local .pth/.pt file")
    if not missing:
        return None
    return "Segment Anything cannot run (nothing is downloaded): " + "; ".join(missing)


def _device(name: str) -> str:
    import torch

    if name != "auto":
        return name
    return "cuda" if torch.cuda.is_available() else "cpu"


def _predictor(cfg):
    """A predictor with ``set_image(rgb)`` and ``predict(box=…)`` for the installed package and the checkpoint."""
    package, ckpt = installed_package(), Path(cfg.sam_checkpoint)
    device = _device(cfg.sam_device)
    if package == "segment_anything":
        from segment_anything import SamPredictor, sam_model_registry

        kind = cfg.sam_model or next((k for k in SAM1_TYPES if k in ckpt.name), "")
        if kind not in sam_model_registry:
            raise TargetError(f"cannot tell the SAM model type of {ckpt.name}: set sam_model to one of {SAM1_TYPES}")
        model = sam_model_registry[kind](checkpoint=str(ckpt))
        return SamPredictor(model.to(device))
    from sam2.build_sam import build_sam2
    from sam2.sam2_image_predictor import SAM2ImagePredictor

    config = cfg.sam_model
    if not config:
        match = re.search(r"(sam2(?:\.1)?)_hiera_(tiny|small|base_plus|large)", ckpt.name)
        if match is None:
            raise TargetError(f"cannot tell the sam2 config of {ckpt.name}: set sam_model (e.g. sam2.1_hiera_s.yaml)")
        version, size = match.groups()
        suffix = SAM2_SIZES[size]
        config = f"configs/sam2.1/sam2.1_hiera_{suffix}.yaml" if version == "sam2.1" else f"sam2_hiera_{suffix}.yaml"
    return SAM2ImagePredictor(build_sam2(config, str(ckpt), device=device))


def _grown(mask: np.ndarray, grow: float) -> np.ndarray | None:
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return None
    h, w = mask.shape
    gy, gx = grow * (ys.max() - ys.min() + 1), grow * (xs.max() - xs.min() + 1)
    return np.array(
        [max(0, xs.min() - gx), max(0, ys.min() - gy), min(w - 1, xs.max() + gx), min(h - 1, ys.max() + gy)]
    )


def segment_video_sam(
    frames: np.ndarray,
    box: tuple[int, int, int, int] | None,
    mask: np.ndarray | None,
    cfg,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> np.ndarray:
    """Masks ``(N, H, W)`` uint8 {0, 1} by Segment Anything box prompts (see the module docstring); reports
    ``Progress("segment", step, total)`` after each frame, ``cancel`` returns the frames done."""
    predictor = _predictor(cfg)
    n, h, w = frames.shape[:3]
    out = np.zeros((n, h, w), np.uint8)
    if box is not None:
        x, y, bw, bh = box
        prompt = np.array([x, y, x + bw - 1, y + bh - 1], dtype=np.float64)
    else:
        prompt = _grown(mask, 0.0)
    for t in range(n):
        if stopped(cancel):
            log.info("segmentation cancelled after %d of %d frames", t, n)
            return out[:t]
        if t == 0 and mask is not None:
            out[0] = mask
        else:
            predictor.set_image(frames[t])
            masks, _, _ = predictor.predict(box=prompt, multimask_output=False)
            out[t] = np.asarray(masks[0]) > 0
        nxt = _grown(out[t], cfg.sam_box_grow)
        if nxt is not None:
            prompt = nxt
        report(progress, "segment", t + 1, n)
    return out
