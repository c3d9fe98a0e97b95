"""Self-collision checks per second in the reused PyBullet world (random self-exploration poses).

    python benchmarks/bench_collision.py [--n 20000]

Last line JSON: checks_per_s (in_collision), scores_per_s (full S_col with the soft-proximity term),
reference_scores_per_s (the all-pairs getClosestPoints reference), and the share of poses in collision.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from studio.sim.hand import load_hand
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20000)
    args = ap.parse_args()
    hand = load_hand()
    poses = sample_poses(hand, args.n, np.random.default_rng(0))[0]
    with CollisionWorld(hand) as world:
        world.collision_score(poses[:10])
        t = time.perf_counter()
        hits = world.in_collision(poses)
        checks = args.n / (time.perf_counter() - t)
        m = min(args.n, 5000)
        t = time.perf_counter()
        world.collision_score(poses[:m])
        scores = m / (time.perf_counter() - t)
        r = min(args.n, 500)
        t = time.perf_counter()
        for q in poses[:r]:
            world.closest_pairs_reference(q)
        ref = r / (time.perf_counter() - t)
    print(json.dumps({
        "checks_per_s": round(checks, 1), "scores_per_s": round(scores, 1),
        "reference_scores_per_s": round(ref, 1), "score_speedup_vs_reference": round(scores / ref, 1),
        "colliding_share": round(float(hits.mean()), 3),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
