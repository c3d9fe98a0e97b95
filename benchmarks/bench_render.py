"""Shadow renderer speed and agreement against PyBullet's camera at the light, same poses, same run.

    python benchmarks/bench_render.py [--n 20000] [--n-ref 60] [--resolution 256] [--resolutions 128,256]

Ours renders ``--n`` poses in one ``ShadowRenderer.render`` call (batched, all cores, a fresh output array
each call; best of 3); PyBullet's TinyRenderer renders the first ``--n-ref`` of them one by one with joint
resets, both on the plain URDF (coarse primitive capsules) and on the mesh twin (the exact reference).

The last line printed is JSON. Headline fields, at ``--resolution``: shadows_per_s (ours), pybullet_shadows_per_s
(the faster of the plain-URDF and the mesh-twin reference), pybullet_mesh_twin_shadows_per_s,
pybullet_plain_urdf_shadows_per_s, speedup (ours / the faster PyBullet), speedup_vs_plain_urdf, and the IoU of
ours against the mesh-twin reference (mean, min). ``by_resolution`` has, for each of ``--resolutions`` (and
``--resolution``): ours, PyBullet plain URDF, their ratio, and our CPU microseconds per shadow (process time
over all threads: the work, independent of how busy the machine's cores are with other jobs).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from studio.sim.hand import Hand, load_hand
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer, iou
from studio.sim.shadow_reference import PyBulletShadowCamera


def pybullet_rate(cam: PyBulletShadowCamera, poses: np.ndarray) -> tuple[float, np.ndarray]:
    t = time.perf_counter()
    imgs = np.stack([cam.render(q) for q in poses])
    return len(poses) / (time.perf_counter() - t), imgs


def our_rate(ours: ShadowRenderer, poses: np.ndarray, keep: int, repeats: int = 3) -> tuple[float, float, np.ndarray]:
    """Best shadows/s over ``repeats`` calls, the CPU µs per shadow of that call, and its first ``keep`` images."""
    ours.render(poses[:8])  # compile / load the kernel cache outside the timing
    best, cpu_us, imgs = 0.0, 0.0, None
    for _ in range(repeats):
        imgs = None  # free the previous batch first, as a caller looping over batches would
        t, c = time.perf_counter(), time.process_time()
        imgs = ours.render(poses)
        rate = len(poses) / (time.perf_counter() - t)
        if rate > best:
            best, cpu_us = rate, (time.process_time() - c) / len(poses) * 1e6
    return best, cpu_us, imgs[:keep].copy()


def plain_urdf_rate(hand: Hand, rig: Rig, poses: np.ndarray) -> float:
    """PyBullet's camera on the plain URDF (coarse primitive capsules): faster but less exact."""
    with PyBulletShadowCamera(hand, rig) as plain:
        import pybullet as p

        p.removeBody(plain.body, physicsClientId=plain.client)
        plain.body = p.loadURDF(str(hand.urdf_path), useFixedBase=True, physicsClientId=plain.client)
        return pybullet_rate(plain, poses)[0]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20000, help="poses for our renderer")
    ap.add_argument("--n-ref", type=int, default=60, help="poses for PyBullet (slow)")
    ap.add_argument("--resolution", type=int, default=256, help="resolution of the headline fields")
    ap.add_argument("--resolutions", default="128,256", help="comma-separated resolutions for by_resolution")
    args = ap.parse_args()

    hand = load_hand()
    poses = sample_poses(hand, args.n, np.random.default_rng(0))[0]
    ref_poses = poses[: args.n_ref]
    resolutions = sorted({args.resolution, *(int(r) for r in args.resolutions.split(",") if r)})
    by_res, result = {}, {}
    for res in resolutions:
        rig = Rig(resolution=res)
        best, cpu_us, imgs = our_rate(ShadowRenderer(hand, rig), poses, args.n_ref)
        plain_rate = plain_urdf_rate(hand, rig, ref_poses)
        by_res[str(res)] = {
            "shadows_per_s": round(best, 1),
            "pybullet_plain_urdf_shadows_per_s": round(plain_rate, 2),
            "speedup_vs_plain_urdf": round(best / plain_rate, 1),
            "cpu_us_per_shadow": round(cpu_us, 2),
        }
        if res != args.resolution:
            continue
        with PyBulletShadowCamera(hand, rig) as cam:
            twin_rate, ref = pybullet_rate(cam, ref_poses)
        scores = iou(imgs, ref)
        pb = max(twin_rate, plain_rate)
        result = {
            "resolution": res,
            "shadows_per_s": round(best, 1),
            "pybullet_shadows_per_s": round(pb, 2),
            "pybullet_mesh_twin_shadows_per_s": round(twin_rate, 2),
            "pybullet_plain_urdf_shadows_per_s": round(plain_rate, 2),
            "speedup": round(best / pb, 1),
            "speedup_vs_plain_urdf": round(best / plain_rate, 1),
            "iou_vs_pybullet_mean": round(float(scores.mean()), 4),
            "iou_vs_pybullet_min": round(float(scores.min()), 4),
        }
    result["by_resolution"] = by_res
    print(json.dumps(result))


if __name__ == "__main__":
    main()
