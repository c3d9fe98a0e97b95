"""The optimiser on reachable targets: shadows of known collision-free poses, so the hand's reach is not in the loss.

Draws ``--count`` self-exploration poses (seeded; :mod:`studio.evaluate.reachable`), frames each one's fine render
like an image file, and imitates it with the studio's method, the studio's without the block sweep, and the
paper's configuration (``--preset paper`` at the CPU budget: sampled search, hill climbing 8 × 1000), all with the
shipped 128² self-model and no CLIP. Prints a Markdown table (mean IoU loss, its floor — the known pose's own shadow
— the excess over the floor, the share of targets within 0.02 of it, the share in collision, seconds per target)
and, last, a JSON line with the same and the ratios of each method's excess to the paper configuration's (below 1:
closer to the floor).

    python benchmarks/bench_reach.py [--count 12] [--seed 7] [--methods studio no-sweep paper]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time

import numpy as np
import torch

from studio.evaluate.reachable import ReachableConfig, reach_summary, reachable_targets
from studio.imitate.config import (
    CPU_REFINE,
    CPU_SEARCH,
    PAPER_IMITATE,
    PAPER_REFINE,
    PAPER_SWEEP,
    STUDIO_SEARCH,
    ImitateConfig,
    SweepConfig,
)
from studio.imitate.still import Imitator
from studio.targets.expressive import still_expressive

METHODS = {  # name → (search, refine, imitate, sweep): `--preset studio|paper` (paper at the CPU budget),
    # and the studio's before the sweep
    "studio": (STUDIO_SEARCH, CPU_REFINE, ImitateConfig(), SweepConfig()),
    "no-sweep": (CPU_SEARCH, CPU_REFINE, ImitateConfig(), PAPER_SWEEP),
    "paper": (CPU_SEARCH, PAPER_REFINE, PAPER_IMITATE, PAPER_SWEEP),
}


def run_method(name: str, theta: np.ndarray, targets: np.ndarray) -> dict:
    search, refine, config, sweep = METHODS[name]
    losses, floors, seconds, collides = [], [], [], []
    with Imitator(search=search, refine=refine, config=config, sweep=sweep) as im:
        for truth, target in zip(theta, targets):
            expressive = still_expressive(target)
            result = im.imitate(target, expressive)
            floor = im.refiner.score(im.loss_fn(target, expressive), truth[None])[1]["iou_loss"][0]
            losses.append(result.loss["iou_loss"])
            floors.append(float(floor))
            seconds.append(result.seconds)
            collides.append(not result.collision_free)
    row = reach_summary(np.array(losses), np.array(floors))
    row |= {"collide_pct": 100.0 * float(np.mean(collides)), "seconds": float(np.mean(seconds))}
    row["per_target"] = [round(x, 4) for x in losses]
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=12, help="reachable targets (default 12)")
    parser.add_argument("--seed", type=int, default=7, help="seed of the pose draws (default 7)")
    parser.add_argument("--methods", nargs="+", choices=tuple(METHODS), default=list(METHODS))
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(1)
    cfg = ReachableConfig(count=args.count, seed=args.seed)
    with Imitator(config=dataclasses.replace(ImitateConfig(), retrieve=False)) as im:
        theta, targets = reachable_targets(im.hand, im.refiner.world, im.resolution, cfg)
    rows = {}
    for name in args.methods:
        t0 = time.perf_counter()
        rows[name] = run_method(name, theta, targets)
        rows[name]["wall_seconds"] = round(time.perf_counter() - t0, 1)
    print(f"\n{args.count} reachable targets (seed {args.seed}), 128² shipped self-model, no CLIP, IoU loss:\n")
    print(
        "| Method | IoU loss | Floor (known pose) | Excess over floor | Within 0.02 (%) | In collision (%) "
        "| Seconds / target |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, r in rows.items():
        print(f"| {name} | {r['iou_loss']:.3f} | {r['floor']:.3f} | {r['excess']:.3f} | {r['reached_pct']:.0f} "
              f"| {r['collide_pct']:.0f} | {r['seconds']:.1f} |")  # fmt: skip
    summary = {"targets": args.count, "seed": args.seed, "methods": rows}
    if "paper" in rows and rows["paper"]["excess"] > 0:
        summary["excess_vs_paper"] = {n: round(r["excess"] / rows["paper"]["excess"], 3) for n, r in rows.items()}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
