"""``shadow-studio imitate TARGET --out DIR``: one still target end to end.

Writes ``pose.json`` (joint names → radians, plus losses and provenance; its ``keyframes`` list is what
``shadow-studio plan`` reads), ``shadow.png`` (the final pose's rendered
shadow), ``compare.png`` (target | self-model | rendered | overlay), ``review.rrd`` (Rerun) and prints a JSON
summary last. The target's holes (its openings) are the expressive region, as in ``evaluate``. Ctrl-C stops the
search or refinement early and still writes the best pose found so far (exit code 130); a second Ctrl-C stops at
once.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from studio.atomic import write_bytes, write_json
from studio.cli.device_flags import add_device_flags, torch_threads
from studio.cli.flags import add_config_flags, config_from_args, given, ranged
from studio.cli.progress import StageBars, add_quiet_flag, ctrl_c_cancels
from studio.cli.still_flags import add_still_flags, still_configs
from studio.imitate.config import SearchConfig
from studio.targets.images import TargetConfig


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


def add_target_flags(parser: argparse.ArgumentParser) -> None:
    """``--threshold N`` or ``--otsu``: how target images are thresholded (:class:`TargetConfig`)."""
    group = parser.add_mutually_exclusive_group()
    add_config_flags(group, TargetConfig, ("threshold",))
    group.add_argument("--otsu", action="store_true", help="threshold the target by Otsu's method")


def target_config_from_args(args: argparse.Namespace) -> TargetConfig:
    """``--threshold N`` (a fixed level, always used) or ``--otsu``; neither: the defaults (Otsu by itself on a
    backdrop that is not dark)."""
    if args.otsu:
        return TargetConfig(threshold=None)
    return config_from_args(args, TargetConfig, auto_otsu=not given(args, "threshold"))


def _imitate(args: argparse.Namespace) -> int:
    with torch_threads(args.threads):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from studio.cli.clip_flags import clip_from_args
    from studio.cli.hand import write_shadow_png
    from studio.imitate.config import LossConfig
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.learn.selfmodel import load_selfmodel
    from studio.review.rerun import log_imitation
    from studio.targets.expressive import still_expressive
    from studio.targets.images import load_target

    target_path = Path(args.target)
    target_cfg = target_config_from_args(args)
    model, info = load_selfmodel(Path(args.model or DEFAULT_MODEL), device=args.device)
    search, refine, config, sweep = still_configs(args, args.seed)
    target = load_target(target_path, size=model.cfg.resolution, cfg=target_cfg)  # before CLIP and the slow set-up
    clip = clip_from_args(args, device=next(model.parameters()).device)
    loss_cfg = LossConfig(use_clip=clip is not None, crop_size=model.cfg.resolution)
    imitator = Imitator(model, loss_cfg=loss_cfg, clip=clip, search=search, refine=refine, config=config, sweep=sweep)
    expressive = still_expressive(target)  # a still target's openings (as `evaluate` does)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with imitator, StageBars(args.quiet) as bars, ctrl_c_cancels() as cancel:
        result = imitator.imitate(target, expressive, refine=not args.no_refine, progress=bars, cancel=cancel)
    hand = imitator.hand
    provenance = {
        "target": str(target_path), "target_config": asdict(target_cfg),
        "expressive_pixels": 0 if expressive is None else int(expressive.sum()),
        "model": str(args.model or DEFAULT_MODEL), "model_metrics": info.metrics,
        "clip": None if clip is None else clip.name, "no_clip": clip is None, "loss_config": loss_cfg.to_dict(),
        "method": args.method, "search": asdict(search), "refine": asdict(refine), "imitate": asdict(config),
        "sweep": asdict(sweep), "hand_hash": hand.hash,
    }  # fmt: skip
    keyframe = {"t": args.at, "pose": hand.pose_to_dict(result.theta), "hold": True, "target": str(target_path),
                "loss": result.loss["total"]}  # fmt: skip
    write_json(out / "pose.json", {
        "keyframes": [keyframe],  # the shape `shadow-studio plan` reads
        "pose": hand.pose_to_dict(result.theta), "loss": _finite(result.loss), "collision_free": result.collision_free,
        "cancelled": result.cancelled,
        "unrefined": {"pose": hand.pose_to_dict(result.unrefined_theta), "loss": _finite(result.unrefined_loss),
                      "collides": result.unrefined_collides, "self_model_loss": result.search.loss},
        "provenance": provenance,
    })  # fmt: skip
    write_shadow_png(out / "shadow.png", result.shadow)
    write_compare_png(out / "compare.png", result)
    notes = "CLIP term off (--no-clip)" if clip is None else f"CLIP: {clip.name}"
    log_imitation(out / "review.rrd", result, hand, name=target_path.stem, notes=notes)
    summary = {
        "total": result.loss["total"], "iou_loss": result.loss["iou_loss"], "collision_free": result.collision_free,
        "exp_iou": result.loss["exp_iou"], "seconds": round(result.seconds, 2), "no_clip": clip is None,
        "cancelled": result.cancelled, "out": str(out),
    }  # fmt: skip
    if result.refine is not None and not result.refine.collision_free:
        summary["warning"] = result.refine.message
    print(json.dumps(_finite(summary)))
    if result.cancelled:
        print(f"shadow-studio imitate: cancelled: wrote the best pose found so far to {out}", file=sys.stderr)
        return 130
    return 0 if result.collision_free else 1


def register(sub: argparse._SubParsersAction) -> None:
    from studio.cli.clip_flags import add_clip_arguments

    p = sub.add_parser("imitate", help="find a collision-free hand pose whose shadow matches a still target")
    p.add_argument("target", help="target image (PNG, JPEG, GIF, BMP): a silhouette, either polarity")
    p.add_argument("--out", required=True, help="folder for pose.json, shadow.png, compare.png, review.rrd")
    p.add_argument("--model", default=None, help="self-model checkpoint (default: the shipped CPU model)")
    add_target_flags(p)
    add_still_flags(p)
    p.add_argument("--no-refine", action="store_true", help="skip the collision-aware refinement")
    p.add_argument("--at", type=ranged(float, "[0, ∞)"), default=2.0, metavar="S",
                   help="time of this pose in a show, s (the pose.json keyframe; default: 2.0; ≥ 0)")  # fmt: skip
    p.add_argument("--seed", type=ranged(int, "[0, ∞)"), default=SearchConfig.seed, metavar="N",
                   help=f"seed of the search and the refinement (default: {SearchConfig.seed}; ≥ 0)")  # fmt: skip
    add_device_flags(p)
    add_quiet_flag(p)
    add_clip_arguments(p)
    p.set_defaults(func=_imitate)
