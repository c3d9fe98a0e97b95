"""Self-model ablation: FK input vs θ input, trained with the same budget and compared on the 26 ASL letters.

Trains two 128² CPU self-models that differ only in their input (``--input fk``: the FK joint frames, the paper's
model; ``--input theta``: sin/cos of the raw angles, the paper's ablation) with the same steps, batch, seed and
on-the-fly pairs, into ``OUT/fk.pt`` and ``OUT/theta.pt``. A checkpoint that exists with the same settings and a
finished run (a test MAE) is reused; an interrupted one is resumed; one with other settings is replaced.

Both models then run the paper's gradient search (CPU preset 32 × 150, same seed, the batch's best pose by the
model's own loss; no retrieval seeding, no refinement: only the model differs) on the first image of each letter,
and the rendered shadow of each searched pose is scored by the target's image loss (CLIP off; Total = Base + the
expressive term on a letter's holes). Prints a Markdown
table, then, last, a JSON line: each model's test MAE (from its checkpoint), mean Total, Base and IoU loss over the
targets, the ratios θ/FK and "FK better by X %" = 100 · (1 − FK / θ); ``OUT/per_target.json`` holds every target's
losses.

    python benchmarks/bench_ablation.py [--steps 1200] [--batch-size 64] [--seed 0] [--out runs/ablation]
                                        [--targets DIR] [--per-folder 1] [--limit N]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch

from studio.imitate.config import CPU_SEARCH, LossConfig, SearchConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.search import gradient_search
from studio.learn.checkpoint import CheckpointError, read_checkpoint
from studio.learn.config import TrainConfig
from studio.learn.selfmodel import load_selfmodel
from studio.learn.threads import set_torch_threads
from studio.learn.train import train
from studio.sim.physics import CollisionWorld
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.expressive import still_expressive
from studio.targets.image_sets import gather_targets
from studio.targets.images import load_target

ROOT = Path(__file__).resolve().parent.parent
ASL = ROOT.parent / "shared" / "targets" / "asl"
INPUTS = ("fk", "theta")  # the paper's model, then its ablation
# training fields that must match for a checkpoint to count as the same run (threads and device do not change it)
SAME_RUN = ("model", "input", "resolution", "data", "steps", "batch_size", "lr", "weight_decay", "warmup",
            "eval_every", "eval_size", "seed")  # fmt: skip
LOSSES = ("total", "base", "mae", "iou_loss")  # rendered-shadow loss components averaged over the targets

log = logging.getLogger("bench_ablation")


def train_config(args: argparse.Namespace, inp: str) -> TrainConfig:
    """The training run of one input: the same budget for both."""
    return TrainConfig(out=str(Path(args.out) / f"{inp}.pt"), model="cpu", input=inp, steps=args.steps,
                       batch_size=args.batch_size, seed=args.seed, eval_size=args.eval_size,
                       device="cpu", threads=args.threads)  # fmt: skip


def ensure_model(cfg: TrainConfig) -> tuple[dict, str]:
    """Train ``cfg`` unless its checkpoint already holds that finished run; returns (metrics, "reused" |
    "resumed" | "trained")."""
    out = Path(cfg.out)
    wanted = asdict(cfg)
    action = "trained"
    if out.exists():
        try:
            ck = read_checkpoint(out, "selfmodel")
            same = all(ck.train.get(k) == wanted[k] for k in SAME_RUN)
        except CheckpointError as e:
            log.warning("%s", e)
            same, ck = False, None
        if same and "test_mae" in ck.metrics and ck.metrics.get("steps") == cfg.steps:
            log.info("%s: reusing the finished %d-step run", out, cfg.steps)
            return dict(ck.metrics), "reused"
        action = "resumed" if same else "trained"
    log.info("%s: %s (%s input, %d steps × %d pairs)", out, "resuming" if action == "resumed" else "training",
             cfg.input, cfg.steps, cfg.batch_size)  # fmt: skip
    metrics = train(cfg, resume=action == "resumed", overwrite=action == "trained")
    return metrics, action


def search_targets(model_path: Path, targets: list[tuple[str, np.ndarray]], search: SearchConfig) -> list[dict]:
    """The paper's gradient search through one model (no retrieval, no refinement; the pose is the batch's best
    by the model's own loss) on each ``(name, (R, R) mask)``. One record per target: the rendered shadow's loss
    components, the model's own Total of its image, whether the pose collides, seconds.

    Calls the search, renderer, loss and collision world directly rather than ``Imitator.imitate``, so the
    studio's seeding and selection choices (which lean less on the model) stay out of the ablation."""
    model, _ = load_selfmodel(model_path, device="cpu")
    renderer = ShadowRenderer(model.hand, Rig(resolution=model.cfg.resolution))
    loss_cfg = LossConfig(use_clip=False, crop_size=model.cfg.resolution)
    records = []
    with CollisionWorld(model.hand) as world:
        for name, mask in targets:
            t0 = time.perf_counter()
            loss_fn = ImageLoss(mask, loss_cfg, None, still_expressive(mask))
            found = gradient_search(model, loss_fn, search)
            seconds = time.perf_counter() - t0
            with torch.no_grad():
                _, comps = loss_fn(torch.from_numpy(renderer.render_one(found.theta).astype(np.float32)[None]))
            rec = {"target": name, **{k: float(comps[k][0]) for k in LOSSES}}
            rec |= {"predicted_total": float(found.loss), "collides": bool(world.in_collision(found.theta)[0]),
                    "seconds": seconds}  # fmt: skip
            records.append(rec)
            log.info("%s %s: total %.3f (model says %.3f)", model_path.stem, name, rec["total"], rec["predicted_total"])
    return records


def summarise(metrics: dict, records: list[dict]) -> dict:
    """One model's row: test MAE, mean losses over the targets, collisions (%), seconds per target."""
    row = {"test_mae": float(metrics["test_mae"]), "targets": len(records)}
    row |= {k: float(np.mean([r[k] for r in records])) for k in (*LOSSES, "predicted_total", "seconds")}
    row["collide_pct"] = 100.0 * float(np.mean([r["collides"] for r in records]))
    return row


def markdown(rows: dict[str, dict], wins: int) -> str:
    """The comparison as a Markdown table (one row per input) and a line of per-target wins."""
    cols = [("Test MAE", "test_mae", 4), ("Total", "total", 3), ("Base", "base", 3), ("MAE", "mae", 3),
            ("IoU loss", "iou_loss", 3), ("Model's own Total", "predicted_total", 3),
            ("In collision (%)", "collide_pct", 1), ("Seconds / target", "seconds", 1)]  # fmt: skip
    names = {"fk": "FK joint frames (paper)", "theta": "θ (sin/cos), ablation"}
    lines = ["| Self-model input | " + " | ".join(c[0] for c in cols) + " |", "|---|" + "---:|" * len(cols)]
    for inp, row in rows.items():
        lines.append(f"| {names[inp]} | " + " | ".join(f"{row[k]:.{d}f}" for _, k, d in cols) + " |")
    n = rows["fk"]["targets"]
    lines.append(f"\nFK input has the lower rendered Total on {wins} of {n} targets.")
    return "\n".join(lines)


def better_pct(fk: float, theta: float) -> float:
    """How much lower FK's value is than θ's, in % of θ's (the paper's "FK better by 31 %")."""
    return round(100.0 * (1.0 - fk / theta), 1)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=1200, help="optimiser steps of each model (default 1200)")
    p.add_argument("--batch-size", type=int, default=64, help="pairs per step (default 64)")
    p.add_argument("--seed", type=int, default=0, help="training seed and search seed (default 0)")
    p.add_argument("--eval-size", type=int, default=TrainConfig.eval_size, help="validation and test set size")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--out", default=str(ROOT / "runs" / "ablation"), help="folder of fk.pt and theta.pt")
    p.add_argument("--targets", default=str(ASL), help="target folder (default ../shared/targets/asl)")
    p.add_argument("--per-folder", type=int, default=1, help="images per sub-folder (default 1: one per letter)")
    p.add_argument("--limit", type=int, default=None, help="only the first N targets (quick checks)")
    p.add_argument("--search-batch", type=int, default=CPU_SEARCH.batch, help="joint vectors searched together")
    p.add_argument("--search-iterations", type=int, default=CPU_SEARCH.iterations, help="gradient steps of the search")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S", stream=sys.stderr)
    if args.threads:
        set_torch_threads(args.threads)
    t0 = time.perf_counter()
    files = gather_targets([args.targets], args.per_folder)[: args.limit]
    search = replace(CPU_SEARCH, batch=args.search_batch, iterations=args.search_iterations, seed=args.seed)
    rows, actions, per_target = {}, {}, {}
    for inp in INPUTS:
        cfg = train_config(args, inp)
        metrics, actions[inp] = ensure_model(cfg)
        size = cfg.model_config().resolution
        targets = [(f"{f.parent.name}/{f.name}", load_target(f, size)) for f in files]
        per_target[inp] = search_targets(Path(cfg.out), targets, search)
        rows[inp] = summarise(metrics, per_target[inp]) | {"train_seconds": metrics.get("seconds")}
    wins = sum(a["total"] < b["total"] for a, b in zip(per_target["fk"], per_target["theta"], strict=True))
    Path(args.out, "per_target.json").write_text(json.dumps({"rows": rows, "targets": per_target}, indent=1))
    print(markdown(rows, wins))
    fk, th = rows["fk"], rows["theta"]
    summary = {
        "targets": fk["targets"], "steps": args.steps, "batch_size": args.batch_size, "seed": args.seed,
        "search": {"batch": search.batch, "iterations": search.iterations, "seed": search.seed},
        "models": actions,
        **{f"{inp}_{k}": round(rows[inp][k], 5 if k == "test_mae" else 4) for inp in INPUTS
           for k in ("test_mae", "total", "base", "iou_loss")},
        "theta_vs_fk_total": round(th["total"] / fk["total"], 3),
        "theta_vs_fk_base": round(th["base"] / fk["base"], 3),
        "theta_vs_fk_iou_loss": round(th["iou_loss"] / fk["iou_loss"], 3),
        "theta_vs_fk_test_mae": round(th["test_mae"] / fk["test_mae"], 3),
        "fk_better_pct_total": better_pct(fk["total"], th["total"]),
        "fk_better_pct_base": better_pct(fk["base"], th["base"]),
        "fk_better_pct_iou_loss": better_pct(fk["iou_loss"], th["iou_loss"]),
        "fk_better_pct_test_mae": better_pct(fk["test_mae"], th["test_mae"]),
        "fk_wins": wins,
        "seconds": round(time.perf_counter() - t0, 1),
    }  # fmt: skip
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
