"""The optimiser on reachable targets: shadows of known collision-free poses, so the hand's reach is not in the loss.

Draws ``--count`` self-exploration poses (seeded; :mod:`studio.evaluate.reachable`), frames each one's fine render
like an image file, and imitates it with the studio's method, the studio's without the block sweep, and the
paper's configuration (``--preset paper`` at the CPU budget: sampled search, hill climbing 8 × 1000), all with the
shipped 128² self-model and no CLIP. "roll auto" draws the same poses' shadows as a mount rolled by a random angle
casts them (uniform over the circle, seeded) and runs the studio's method after ``--roll auto`` chose the roll: its
row adds the roll error (mean and worst, degrees; the share found within 2°) and its floor is the known pose at the
known roll. Prints a Markdown table (mean IoU loss, its floor — the known pose's own shadow — the excess over the
floor, the share of targets within 0.02 of it, the share in collision, seconds per target), then the objective the
studio optimises (Total) for its answers and for the known poses, with the share of targets where that objective
prefers a wrong pose (a lower Total than the known pose's, an IoU loss more than 0.02 above it), and, last, a JSON
line with the same, how many targets have holes (``targets_with_holes``: the only ones the holes' term weighs) and the
ratios of each method's excess to the paper configuration's (below 1: closer to the floor).

    python benchmarks/bench_reach.py [--count 12] [--seed 7] [--methods studio no-sweep paper roll-auto]
                                     [--hole-weight W]

``--hole-weight W`` imitates (and scores Total) with the holes' expressive term weighted ``W`` instead of 1.0: how
much of the excess over the floor that term causes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import time

import numpy as np

from studio.evaluate.reachable import ReachableConfig, reach_summary, reachable_targets
from studio.evaluate.table1 import score
from studio.imitate.config import (
    CPU_REFINE,
    CPU_SEARCH,
    PAPER_IMITATE,
    PAPER_REFINE,
    PAPER_SWEEP,
    STUDIO_SEARCH,
    ImitateConfig,
    LossConfig,
    SweepConfig,
)
from studio.imitate.still import Imitator
from studio.learn.threads import DEFAULT_THREADS, set_torch_threads
from studio.sim.roll import wrap_deg
from studio.sim.shadow import ShadowRenderer
from studio.targets.expressive import still_expressive

METHODS = {  # name → (search, refine, imitate, sweep): `--preset studio|paper` (paper at the CPU budget),
    # and the studio's before the sweep
    "studio": (STUDIO_SEARCH, CPU_REFINE, ImitateConfig(), SweepConfig()),
    "no-sweep": (CPU_SEARCH, CPU_REFINE, ImitateConfig(), PAPER_SWEEP),
    "paper": (CPU_SEARCH, PAPER_REFINE, PAPER_IMITATE, PAPER_SWEEP),
    "roll-auto": (STUDIO_SEARCH, CPU_REFINE, ImitateConfig(), SweepConfig()),  # the studio's, on rolled targets
}
ROLL_FOUND_DEG = 2.0  # a roll within this of the true one counts as found


def objective_summary(totals, floor_totals, losses, floors, tolerance: float = 0.02) -> dict:
    """The objective the studio optimises (Total, ``(N,)``) for its answers and for the known poses, and the share
    of targets where it prefers a wrong pose: the answer's Total below the known pose's although its IoU loss is
    more than ``tolerance`` above the known pose's (the objective, not the search, keeps it from the floor)."""
    wrong = (totals < floor_totals) & (losses > floors + tolerance)
    return {"total": float(totals.mean()), "floor_total": float(floor_totals.mean()),
            "wrong_pose_preferred_pct": float(100.0 * wrong.mean()),
            "wrong_pose_preferred": [int(i) for i in np.flatnonzero(wrong)],
            "per_target_floor": [round(float(f), 4) for f in floors],
            "per_target_total": [round(float(t), 4) for t in totals],
            "per_target_floor_total": [round(float(t), 4) for t in floor_totals]}  # fmt: skip


def run_method(
    name: str, theta: np.ndarray, targets: np.ndarray, rolls: np.ndarray | None = None, loss: LossConfig | None = None
) -> dict:
    """One method over the targets; with ``rolls (N,)`` rad the targets are rolled and the roll is chosen first
    (roll auto), the pose then imitated and scored as the rolled mount casts it."""
    search, refine, config, sweep = METHODS[name]
    losses, floors, seconds, collides, errors = [], [], [], [], []
    totals, floor_totals = [], []  # the objective (Total) of the answer and of the known pose
    with Imitator(search=search, refine=refine, config=config, sweep=sweep, loss_cfg=loss) as im:
        for i, (truth, target) in enumerate(zip(theta, targets)):
            expressive = still_expressive(target)
            loss_fn = im.loss_fn(target, expressive)
            t0 = time.perf_counter()
            if rolls is None:
                result = im.imitate(target, expressive)
                known_total, known = im.refiner.score(loss_fn, truth[None])
                floor, floor_total = known["iou_loss"][0], float(known_total[0])
                loss = result.loss["iou_loss"]
            else:
                choice = im.choose_roll(target[None])
                errors.append(abs(wrap_deg(choice.deg - math.degrees(rolls[i]))))
                result = im.imitate(target, expressive, roll=choice.roll)
                truth_rolled = ShadowRenderer(im.hand, im.renderer.rig.with_roll(float(rolls[i])))
                loss = float(score(loss_fn, result.shadow)["iou_loss"])
                known = score(loss_fn, truth_rolled.render_one(truth))
                floor, floor_total = known["iou_loss"], float(known["total"])
            losses.append(loss)
            floors.append(float(floor))
            seconds.append(time.perf_counter() - t0)
            collides.append(not result.collision_free)
            totals.append(float(result.loss["total"]))
            floor_totals.append(floor_total)
    row = reach_summary(np.array(losses), np.array(floors))
    row |= objective_summary(np.array(totals), np.array(floor_totals), np.array(losses), np.array(floors))
    row |= {"collide_pct": 100.0 * float(np.mean(collides)), "seconds": float(np.mean(seconds))}
    row["per_target"] = [round(x, 4) for x in losses]
    if errors:
        row |= {"roll_error_mean_deg": round(float(np.mean(errors)), 2), "roll_error_max_deg": round(max(errors), 2),
                "roll_found_pct": 100.0 * float(np.mean(np.array(errors) <= ROLL_FOUND_DEG))}  # fmt: skip
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=12, help="reachable targets (default 12)")
    parser.add_argument("--seed", type=int, default=7, help="seed of the pose draws (default 7)")
    parser.add_argument("--methods", nargs="+", choices=tuple(METHODS), default=list(METHODS))
    parser.add_argument("--hole-weight", type=float, default=None, metavar="W",
                        help="weight of the holes' expressive term in the imitation (LossConfig.w_exp_iou; default: "
                        "the studio's 1.0); the known pose and the answer are scored with it too")  # fmt: skip
    args = parser.parse_args()
    if args.hole_weight is not None and not args.hole_weight >= 0:
        parser.error(f"--hole-weight must be ≥ 0 (a weight on a loss term), not {args.hole_weight}")
    logging.basicConfig(level=logging.WARNING)
    set_torch_threads(DEFAULT_THREADS)  # the studio's own thread count (studio.learn.threads)
    cfg = ReachableConfig(count=args.count, seed=args.seed)
    rolls = np.radians(np.random.default_rng(args.seed).uniform(-180.0, 180.0, args.count))
    with Imitator(config=dataclasses.replace(ImitateConfig(), retrieve=False)) as im:
        theta, targets = reachable_targets(im.hand, im.refiner.world, im.resolution, cfg)
        if "roll-auto" in args.methods:
            rolled_targets = reachable_targets(im.hand, im.refiner.world, im.resolution, cfg, rolls=rolls)[1]
    loss = None
    if args.hole_weight is not None:
        loss = LossConfig(use_clip=False, crop_size=im.resolution, w_exp_iou=args.hole_weight)
    rows = {}
    for name in args.methods:
        t0 = time.perf_counter()
        if name == "roll-auto":
            rows[name] = run_method(name, theta, rolled_targets, rolls, loss)
        else:
            rows[name] = run_method(name, theta, targets, loss=loss)
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
    print("\nThe objective the studio optimises (Total): its answer against the known pose's")
    for name, r in rows.items():
        wrong = r["wrong_pose_preferred_pct"]
        print(f"- {name}: {r['total']:.3f} against {r['floor_total']:.3f}; a wrong pose preferred (lower Total, IoU "
              f"loss > 0.02 above the known pose's) on {wrong:.0f} % of the targets")  # fmt: skip
    if "roll-auto" in rows:
        r = rows["roll-auto"]
        print(
            f"\nroll auto on {args.count} rolled target{'s' * (args.count != 1)}: roll error mean "
            f"{r['roll_error_mean_deg']:.2f}°, worst {r['roll_error_max_deg']:.2f}°, {r['roll_found_pct']:.0f} %"
            f" within {ROLL_FOUND_DEG:g}°"
        )
    holes = sum(still_expressive(t) is not None for t in targets)  # targets whose frame has holes (the term's)
    summary = {"targets": args.count, "targets_with_holes": int(holes), "seed": args.seed,
               "hole_weight": args.hole_weight, "methods": rows}  # fmt: skip
    if "paper" in rows and rows["paper"]["excess"] > 0:
        summary["excess_vs_paper"] = {n: round(r["excess"] / rows["paper"]["excess"], 3) for n, r in rows.items()}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
