"""``shadow-studio imitate TARGET --out DIR``: one still target end to end.

Writes ``pose.json`` (joint names → radians, plus losses and provenance; its ``keyframes`` list is what
``shadow-studio plan`` reads), ``shadow.png`` (the final pose's rendered
shadow), ``compare.png`` (target | self-model | rendered | overlay), ``review.rrd`` (Rerun) and prints a JSON
summary last.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from studio.atomic import write_bytes, write_json


def _finite(d: dict) -> dict:
    """JSON-safe loss dict: NaN (a term not computed) becomes null."""
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in d.items()}


def write_compare_png(path: Path, result) -> None:
    """target | self-model | rendered | overlay, each in display convention, side by side."""
    import cv2

    from studio.review.rerun import display, overlay

    tiles = [display(result.target), display(result.predicted), display(result.shadow)]
    tiles = [np.repeat(t[..., None], 3, axis=2) for t in tiles] + [overlay(result.target, result.shadow)]
    gap = np.full((tiles[0].shape[0], 4, 3), 128, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    ok, png = cv2.imencode(".png", cv2.cvtColor(row, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f"could not encode {path} as PNG")
    write_bytes(path, png.tobytes())


def _imitate(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from studio.cli.hand import write_shadow_png
    from studio.imitate.clip_loss import clip_from_args
    from studio.imitate.losses import LossConfig
    from studio.imitate.refine import RefineConfig
    from studio.imitate.search import CPU_SEARCH
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.learn.selfmodel import load_selfmodel
    from studio.review.rerun import log_imitation

    torch.set_num_threads(args.threads)  # one thread is far faster when the cores are shared, and close otherwise
    target_path = Path(args.target)
    model, info = load_selfmodel(Path(args.model or DEFAULT_MODEL), device=args.device)
    clip = clip_from_args(args, device=next(model.parameters()).device)
    search = replace(CPU_SEARCH, batch=args.search_batch or CPU_SEARCH.batch,
                     iterations=args.search_iters or CPU_SEARCH.iterations, seed=args.seed)  # fmt: skip
    refine = RefineConfig(steps=args.refine_steps, seed=args.seed)
    loss_cfg = LossConfig(use_clip=clip is not None, crop_size=model.cfg.resolution)
    imitator = Imitator(model, loss_cfg=loss_cfg, clip=clip, search=search, refine=refine, candidates=args.candidates)
    target = imitator.load(target_path)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    bars: dict[str, tqdm] = {}

    def progress(stage: str, step: int, total: int, best: float) -> None:
        if args.quiet:
            return
        bar = bars.get(stage) or bars.setdefault(stage, tqdm(total=total, desc=stage, unit="step"))
        bar.update(step - bar.n)
        bar.set_postfix(best=f"{best:.4f}", refresh=False)

    result = imitator.imitate(target, refine=not args.no_refine, progress=progress)
    for bar in bars.values():
        bar.close()
    hand = imitator.hand
    provenance = {
        "target": str(target_path), "model": str(args.model or DEFAULT_MODEL), "model_metrics": info.metrics,
        "clip": None if clip is None else clip.name, "no_clip": clip is None, "loss_config": loss_cfg.to_dict(),
        "search": asdict(search), "refine": asdict(refine), "candidates": args.candidates, "hand_hash": hand.hash,
    }  # fmt: skip
    keyframe = {"t": args.at, "pose": hand.pose_to_dict(result.theta), "hold": True, "target": str(target_path),
                "loss": result.loss["total"]}  # fmt: skip
    write_json(out / "pose.json", {
        "keyframes": [keyframe],  # the shape `shadow-studio plan` reads
        "pose": hand.pose_to_dict(result.theta), "loss": _finite(result.loss), "collision_free": result.collision_free,
        "unrefined": {"pose": hand.pose_to_dict(result.search.theta), "loss": _finite(result.unrefined_loss),
                      "collides": result.unrefined_collides, "self_model_loss": result.search.loss},
        "provenance": provenance,
    })  # fmt: skip
    write_shadow_png(out / "shadow.png", result.shadow)
    write_compare_png(out / "compare.png", result)
    notes = "CLIP term off (--no-clip)" if clip is None else f"CLIP: {clip.name}"
    log_imitation(out / "review.rrd", result, hand, name=target_path.stem, notes=notes)
    summary = {
        "total": result.loss["total"], "iou_loss": result.loss["iou_loss"], "collision_free": result.collision_free,
        "seconds": round(result.seconds, 2), "no_clip": clip is None, "out": str(out),
    }  # fmt: skip
    if result.refine is not None and not result.refine.collision_free:
        summary["warning"] = result.refine.message
    print(json.dumps(_finite(summary)))
    return 0 if result.collision_free else 1


def register(sub: argparse._SubParsersAction) -> None:
    from studio.imitate.clip_loss import add_clip_arguments

    p = sub.add_parser("imitate", help="find a collision-free hand pose whose shadow matches a still target")
    p.add_argument("target", help="target image (PNG, JPEG, GIF, BMP): a silhouette, either polarity")
    p.add_argument("--out", required=True, help="folder for pose.json, shadow.png, compare.png, review.rrd")
    p.add_argument("--model", default=None, help="self-model checkpoint (default: the shipped CPU model)")
    p.add_argument("--search-batch", type=int, default=None, help="joint vectors searched together")
    p.add_argument("--search-iters", type=int, default=None, help="gradient steps")
    p.add_argument("--refine-steps", type=int, default=1000, help="hill-climbing steps per chain (default 1000)")
    p.add_argument("--no-refine", action="store_true", help="skip the collision-aware refinement")
    p.add_argument("--candidates", type=int, default=4, help="distinct best search results refined (default 4)")
    p.add_argument("--at", type=float, default=2.0, help="time of this pose in a show, s (pose.json keyframe)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_clip_arguments(p)
    p.set_defaults(func=_imitate)
