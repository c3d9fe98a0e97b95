"""Transition success of independent vs sequential +Exp+Temp optimisation on the shared DAVIS mask sequences.

Every sequence is loaded by ``load_video`` at its defaults (4 Hz, 128 px), its expressive masks by
``expressive_masks`` and its keyframes by ``cluster_keyframes`` at the default τ; both modes then optimise the
keyframes in first-appearance order with the CPU preset (``CPU_SEQUENCE``) and the shipped self-model, no CLIP,
one torch thread. The reference is the independent mode (each keyframe alone from a fresh sampler batch, with the
expressive term, no temporal term) measured in the same run. Printed: one line per sequence and mode, then a JSON
object last: per mode the transition success (count, transitions, % with the default ``L_base`` reading and with
the ``L_base + L_expr`` reading, see ``studio.imitate.transitions``), the mean endpoint totals, mean|Δθ|, the
keyframes in collision and seconds per sequence; and sequential minus independent in percentage points.

    python benchmarks/bench_sequence.py [--davis DIR] [--sequences bear,dog]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from studio.imitate.config import CPU_SEQUENCE, LossConfig
from studio.imitate.sequence import SequenceImitator
from studio.imitate.still import DEFAULT_MODEL
from studio.imitate.transitions import TransitionConfig
from studio.learn.selfmodel import load_selfmodel
from studio.learn.threads import DEFAULT_THREADS, set_torch_threads
from studio.targets.expressive import expressive_masks
from studio.targets.keyframes import cluster_keyframes, keyframe_targets
from studio.targets.video import VideoConfig, load_video

DAVIS = Path(__file__).resolve().parents[2] / "shared" / "targets" / "davis"
MODES = {
    "independent": replace(CPU_SEQUENCE, mode="independent", expressive=True, temporal=False),
    "sequential": replace(CPU_SEQUENCE, mode="sequential", expressive=True, temporal=True),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--davis", default=str(DAVIS), help="folder of DAVIS mask sequences (one folder each)")
    parser.add_argument("--sequences", default="", help="comma-separated names (default: every sub-folder)")
    args = parser.parse_args()
    set_torch_threads(DEFAULT_THREADS)  # the studio's own thread count (studio.learn.threads)
    root = Path(args.davis)
    names = [n for n in args.sequences.split(",") if n] or sorted(p.name for p in root.iterdir() if p.is_dir())
    targets = {}
    for name in names:
        video = load_video(root / name, VideoConfig())
        expressive = expressive_masks(video.masks)
        clusters = cluster_keyframes(expressive, shadows=video.masks)
        targets[name] = keyframe_targets(video.masks, expressive, clusters.representatives)
    model, _ = load_selfmodel(DEFAULT_MODEL, device="cpu")
    loss_cfg = LossConfig(use_clip=False, crop_size=model.cfg.resolution)
    base_cfg, image_cfg = TransitionConfig(total="base"), TransitionConfig(total="image")
    summary = {}
    for mode, cfg in MODES.items():
        ok = ok_image = n = collide = keyframes = 0
        seconds, base, image, steps = [], [], [], []
        with SequenceImitator(model, cfg, loss_cfg=loss_cfg) as seq:
            for name, (masks, expressive) in targets.items():
                result = seq.imitate(masks, expressive)
                rep, rep_image = result.transitions(base_cfg), result.transitions(image_cfg)
                ok, ok_image, n = ok + rep.count, ok_image + rep_image.count, n + rep.total
                collide += sum(not k.collision_free for k in result.keyframes)
                keyframes += len(result.keyframes)
                seconds.append(result.seconds)
                base += result.totals("base").tolist()
                image += result.totals("image").tolist()
                steps += rep.mean_step.tolist()
                print(
                    f"{mode:11s} {name:10s} {len(masks)} keyframes  success {rep.count}/{rep.total} "
                    f"(image reading {rep_image.count})  L_base {np.round(result.totals('base'), 3).tolist()}  "
                    f"mean|Δθ| {np.round(rep.mean_step, 2).tolist()}  max|Δθ| {np.round(rep.max_step, 2).tolist()}  "
                    f"{result.seconds:.1f} s",
                    flush=True,
                )
        summary[mode] = {
            "success": ok,
            "transitions": n,
            "success_pct": round(100 * ok / n, 1) if n else None,
            "success_pct_image_reading": round(100 * ok_image / n, 1) if n else None,
            "base_mean": round(float(np.mean(base)), 4),
            "image_total_mean": round(float(np.mean(image)), 4),
            "mean_step_rad": round(float(np.mean(steps)), 3) if steps else None,
            "keyframes": keyframes,
            "keyframes_in_collision": collide,
            "seconds_per_sequence": round(float(np.mean(seconds)), 1),
        }
    ind, seq_ = summary["independent"], summary["sequential"]
    if ind["success_pct"] is not None:
        summary["sequential_minus_independent_pct_points"] = round(seq_["success_pct"] - ind["success_pct"], 1)
    summary["sequential_vs_independent_seconds"] = round(seq_["seconds_per_sequence"] / ind["seconds_per_sequence"], 3)
    summary["sequences"] = names
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
