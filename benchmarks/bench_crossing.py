"""Benchmark: moves whose straight line collides, each given a multiple of its rest-to-rest time (the clock's).

    python benchmarks/bench_crossing.py [--shows 30] [--factor 1.11] [--seed 0]

The keyframe boxes of ``studio.motion.reach`` give every move of a show its straight rest-to-rest time divided by
the clock's margin (0.9: ``--factor 1.11``). Here each show is home → A → B, A and B collision-free
self-exploration poses (``studio.sim.sampling``) whose straight move collides, every move given ``factor`` × its
rest-to-rest time + 0.05 s. Each show is planned with late segments allowed (so each is counted), with the planner's
via search (``studio.motion.via_search``) and without it (``ViaSearch(tries=0)``, the reference path: the repaired
path's corners alone), in the same run. Prints a line per way, then JSON last: late segments, shows with one, shows
that failed (``PathError``), seconds, and the ratios.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np

from studio.motion.errors import PlanError
from studio.motion.limits import JointLimits
from studio.motion.plan import Keyframes, PlanConfig, plan_show
from studio.motion.reach import rest_to_rest_time
from studio.motion.via_search import ViaSearch
from studio.sim.hand import load_hand
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses


def crossing_shows(hand, world, limits, n: int, factor: float, seed: int) -> list[Keyframes]:
    """``n`` shows home → A → B whose straight move A → B collides (module doc)."""
    rng = np.random.default_rng(seed)
    shows: list[Keyframes] = []
    while len(shows) < n:
        theta, _ = sample_poses(hand, 64, rng)
        free = theta[~world.in_collision(theta)]
        for a, b in zip(free[0::2], free[1::2]):
            line = a + np.linspace(0.0, 1.0, 60)[:, None] * (b - a)
            if len(shows) == n or not world.in_collision(line).any():
                continue
            t1 = 1.0 + factor * float(rest_to_rest_time(a - hand.rest_pose(), limits).max()) + 0.05
            t2 = t1 + factor * float(rest_to_rest_time(b - a, limits).max()) + 0.05
            shows.append(Keyframes(np.array([t1, t2]), np.stack([a, b]), np.zeros(2, bool), [None] * 2, [None] * 2))
    return shows


def run(hand, world, shows: list[Keyframes], tries: int) -> dict:
    """Plan every show with late segments allowed; what came late, what failed, and the seconds."""
    base = PlanConfig()
    cfg = replace(base, timing=replace(base.timing, allow_late=True, via=ViaSearch(tries=tries)))
    late = late_shows = failed = 0
    t0 = time.perf_counter()
    for kf in shows:
        try:
            got = plan_show(hand, kf, cfg, world=world)
        except PlanError:
            failed += 1
            continue
        late += len(got.trajectory.late)
        late_shows += bool(got.trajectory.late)
    return {"late_segments": late, "late_shows": late_shows, "failed": failed,
            "seconds": round(time.perf_counter() - t0, 2)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shows", type=int, default=30, help="crossing shows planned each way")
    ap.add_argument("--factor", type=float, default=1.11, help="each move's time: factor × rest-to-rest + 0.05 s")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sampled poses")
    args = ap.parse_args()
    hand = load_hand()
    limits = JointLimits.from_hand(hand)
    with CollisionWorld(hand) as world:
        shows = crossing_shows(hand, world, limits, args.shows, args.factor, args.seed)
        ref = run(hand, world, shows, tries=0)
        via = run(hand, world, shows, tries=ViaSearch().tries)
    for name, r in (("corners only (reference)", ref), ("via search", via)):
        print(f"{name}: late segments {r['late_segments']} in {r['late_shows']} of {args.shows} shows, "
              f"{r['failed']} failed, {r['seconds']} s")  # fmt: skip
    print(json.dumps({
        "shows": args.shows, "factor": args.factor, "seed": args.seed, "reference": ref, "via_search": via,
        "late_ratio": round(via["late_segments"] / max(ref["late_segments"], 1), 3),
        "seconds_ratio": round(via["seconds"] / max(ref["seconds"], 1e-9), 3),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
