"""Benchmark: plan a 10-keyframe show (collision-free keyframes sampled reproducibly) and report the planner's cost.

Prints progress lines, then a JSON object as the last line:
``{"seconds", "collision_checks", "max_jerk_ratio", ...}`` (target: seconds < 5 on this machine).
"""

from __future__ import annotations

import json
import time

import numpy as np

from studio.motion.limits import JointLimits
from studio.motion.plan import Keyframes, plan_show
from studio.sim.hand import load_hand
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses


def main(n_keyframes: int = 10, seed: int = 7) -> dict:
    hand = load_hand()
    world = CollisionWorld(hand)
    rng = np.random.default_rng(seed)
    theta, _ = sample_poses(hand, 20 * n_keyframes, rng)
    poses = theta[~world.in_collision(theta)][:n_keyframes]
    limits = JointLimits.from_hand(hand)
    prev = np.concatenate([hand.rest_pose()[None], poses[:-1]])
    gaps = 0.8 + 3.0 * (np.abs(poses - prev) / limits.velocity).max(axis=1)  # generous, as an artist would allow
    kf = Keyframes(np.cumsum(gaps), poses, np.zeros(n_keyframes, bool), [None] * n_keyframes, [None] * n_keyframes)
    plan_show(hand, Keyframes(np.array([1.0]), poses[:1], np.zeros(1, bool), [None], [None]), world=world)  # warm-up
    t0 = time.perf_counter()
    result = plan_show(hand, kf, world=world)
    seconds = time.perf_counter() - t0
    world.close()
    out = {
        "seconds": round(seconds, 3),
        "collision_checks": int(result.collision_checks),
        "max_jerk_ratio": round(float(result.max_jerk_ratio), 6),
        "keyframes": n_keyframes,
        "show_seconds": round(result.show.duration, 3),
        "samples": len(result.show.times),
        "repaired_points": int(result.path.repaired.sum()),
        "ruckig_pieces": len(result.trajectory.pieces),
        "target_seconds": 5.0,
    }
    print(f"planned {n_keyframes} keyframes, {out['show_seconds']} s of show in {out['seconds']} s")
    return out


if __name__ == "__main__":
    print(json.dumps(main()))
