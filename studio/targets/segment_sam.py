"""Optional Segment Anything adapter for :func:`studio.targets.segment.segment_video`.

Used only when its package is importable (``segment_anything``, Meta's SAM, or ``sam2``) AND a local checkpoint
exists: ``SegmentConfig.sam_checkpoint``, else one put in the cache's ``sam`` folder (``~/.cache/shadow-studio/sam/``,
which every face then uses). Nothing is downloaded: without either, the
classical method runs (``method="auto"``) or a :class:`TargetError` says which package or file to provide
(``method="sam"``).

With ``sam2`` the video predictor tracks the object itself (its memory of earlier frames carries it through
occlusions): the frames go to it as JPEGs in a temporary folder, frame 0 is prompted with the artist's box or mask,
and every frame's mask comes from its propagation (``sam_image_size`` sets its input side: smaller runs faster on a
CPU). With ``segment_anything`` (images only) tracking is by box prompts: frame 0 is prompted with the box (or the
first mask's box, the mask itself kept as frame 0's answer), every later frame with the previous answer's box grown
by ``sam_box_grow`` per side.
"""

from __future__ import annotations

import importlib.util
import logging
import re
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn, TargetError, report, stopped
from studio.home import cache_dir

log = logging.getLogger(__name__)

PACKAGES = ("segment_anything", "sam2")
SAM_CACHE = "sam"  # the cache's folder where a checkpoint is found when none is given
SAM1_TYPES = ("vit_h", "vit_l", "vit_b")  # segment_anything's sam_model_registry keys
SAM2_SIZES = {"tiny": "t", "small": "s", "base_plus": "b+", "large": "l"}  # checkpoint name → config suffix


def installed_package() -> str | None:
    """The first Segment Anything package that can be imported here, or None."""
    for name in PACKAGES:
        if importlib.util.find_spec(name) is not None:
            return name
    return None


def cached_checkpoint() -> Path | None:
    """A checkpoint put in the cache's ``sam`` folder (``~/.cache/shadow-studio/sam/``) for the installed package:
    ``*.pt`` for sam2, ``*.pth`` for segment_anything (the first by name); None when there is none."""
    package = installed_package()
    if package is None:
        return None
    found = sorted((cache_dir() / SAM_CACHE).glob("*.pt" if package == "sam2" else "*.pth"))
    return found[0] if found else None


def with_checkpoint(cfg):
    """``cfg`` with ``sam_checkpoint`` set to the cached one when it names none (every face then finds it)."""
    if cfg.sam_checkpoint or cfg.method == "classical":
        return cfg
    found = cached_checkpoint()
    return cfg if found is None else replace(cfg, sam_checkpoint=str(found))


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
            f"sam2.1_hiera_small.pt for sam2) and put it in {cache_dir() / SAM_CACHE} or pass its path as "
            "SegmentConfig(sam_checkpoint=...)"
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


def _sam2_config(cfg) -> str:
    """The sam2 config of ``cfg.sam_model`` or of the checkpoint's file name (``sam2.1_hiera_small.pt``)."""
    if cfg.sam_model:
        return cfg.sam_model
    match = re.search(r"(sam2(?:\.1)?)_hiera_(tiny|small|base_plus|large)", Path(cfg.sam_checkpoint).name)
    if match is None:
        raise TargetError(
            f"cannot tell the sam2 config of {Path(cfg.sam_checkpoint).name}: set sam_model (e.g. "
            "configs/sam2.1/sam2.1_hiera_s.yaml)"
        )
    version, size = match.groups()
    suffix = SAM2_SIZES[size]
    return f"configs/sam2.1/sam2.1_hiera_{suffix}.yaml" if version == "sam2.1" else f"sam2_hiera_{suffix}.yaml"


def _predictor(cfg):
    """A SAM 1 predictor with ``set_image(rgb)`` and ``predict(box=…)`` for the checkpoint."""
    from segment_anything import SamPredictor, sam_model_registry

    ckpt = Path(cfg.sam_checkpoint)
    kind = cfg.sam_model or next((k for k in SAM1_TYPES if k in ckpt.name), "")
    if kind not in sam_model_registry:
        raise TargetError(f"cannot tell the SAM model type of {ckpt.name}: set sam_model to one of {SAM1_TYPES}")
    model = sam_model_registry[kind](checkpoint=str(ckpt))
    return SamPredictor(model.to(_device(cfg.sam_device)))


def _sam2_video(frames, box, mask, cfg, progress, cancel) -> np.ndarray:
    """Masks ``(N, H, W)`` by the sam2 video predictor (module doc)."""
    import tempfile

    import torch
    from PIL import Image
    from sam2.build_sam import build_sam2_video_predictor

    n, h, w = frames.shape[:3]
    extra = [f"++model.image_size={cfg.sam_image_size}"] if cfg.sam_image_size else []
    try:
        predictor = build_sam2_video_predictor(_sam2_config(cfg), str(cfg.sam_checkpoint),
                                               device=_device(cfg.sam_device), hydra_overrides_extra=extra)  # fmt: skip
    except Exception as e:  # noqa: BLE001 - torch.load, hydra and the state dict fail in many ways; say it in one line
        raise TargetError(f"the sam2 checkpoint {cfg.sam_checkpoint} does not load ({type(e).__name__}: {e})") from None
    out = np.zeros((n, h, w), np.uint8)
    done = 0
    with tempfile.TemporaryDirectory(prefix="sam2-frames-") as folder, torch.inference_mode():
        for t in range(n):
            Image.fromarray(frames[t]).save(f"{folder}/{t:05d}.jpg", quality=95)
        state = predictor.init_state(folder, offload_video_to_cpu=True, offload_state_to_cpu=True)
        if mask is not None:
            predictor.add_new_mask(state, frame_idx=0, obj_id=1, mask=torch.as_tensor(mask > 0))
        else:
            x, y, bw, bh = box
            predictor.add_new_points_or_box(state, frame_idx=0, obj_id=1,
                                            box=np.array([x, y, x + bw - 1, y + bh - 1], np.float32))  # fmt: skip
        for t, _, logits in predictor.propagate_in_video(state):
            out[t] = (logits[0, 0] > 0).cpu().numpy()
            done += 1
            report(progress, "segment", done, n)
            if stopped(cancel) and done < n:
                log.info("segmentation cancelled after %d of %d frames", done, n)
                return out[:done]
    if mask is not None:
        out[0] = mask
    return out


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
    """Masks ``(N, H, W)`` uint8 {0, 1} by Segment Anything (see the module docstring); reports
    ``Progress("segment", step, total)`` after each frame, ``cancel`` returns the frames done."""
    if installed_package() == "sam2":
        return _sam2_video(frames, box, mask, cfg, progress, cancel)
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
