"""Shadow Studio's public API: what a notebook or a script uses, re-exported from the stages (DESIGN §3).

    import studio
    target = studio.load_target(studio.DEFAULT_TARGET, size=128)   # (128, 128) uint8, 1 = shadow
    result = studio.imitate_still(target)                          # search → refine: a collision-free pose
    keyframes = studio.Keyframes.at([2.0], [result.theta])          # hold that pose at t = 2 s
    show = studio.plan_show(studio.load_hand(), keyframes).show      # jerk-limited, collision-checked
    studio.save_show(show, "show.json")

Names are imported on first use (``studio.X`` loads only the stage that defines ``X``), so ``import studio`` and
the command line stay quick; ``dir(studio)`` lists them all.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

# Idle OpenMP threads sleep instead of spinning. numba's parallel kernels (renderer, compiled loss) and torch keep
# separate OpenMP pools; with the default (spin) policy the renderer's idle threads steal the cores from the
# self-model's gradient steps that follow (measured here: a 16-pose search step 83 ms → 1,234 ms after one parallel
# render on 2 cores). Set before torch or numba start their pools; a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# name → the module that defines it, grouped by stage
_API: dict[str, str] = {
    # the hand and its world
    "Hand": "studio.sim.hand",
    "load_hand": "studio.sim.hand",
    "Rig": "studio.sim.shadow",
    "ShadowRenderer": "studio.sim.shadow",
    "CollisionWorld": "studio.sim.physics",
    # learning
    "SelfModel": "studio.learn.selfmodel",
    "load_selfmodel": "studio.learn.selfmodel",
    # targets and imitation
    "DEFAULT_TARGET": "studio.targets.images",
    "SAMPLE_DIR": "studio.targets.images",
    "TargetError": "studio.errors",
    "load_target": "studio.targets.images",
    "find_holes": "studio.targets.images",
    "LossConfig": "studio.imitate.config",
    "ImageLoss": "studio.imitate.losses",
    "SearchConfig": "studio.imitate.config",
    "CPU_SEARCH": "studio.imitate.config",
    "RefineConfig": "studio.imitate.config",
    "Imitator": "studio.imitate.still",
    "ImitationResult": "studio.imitate.still",
    "imitate_still": "studio.imitate.still",
    # videos
    "DEFAULT_VIDEO": "studio.targets.video",
    "VideoConfig": "studio.targets.video",
    "Video": "studio.targets.video",
    "load_video": "studio.targets.video",
    "SegmentConfig": "studio.targets.segment_config",
    "segment_video": "studio.targets.segment",
    "expressive_masks": "studio.targets.expressive",
    "KeyframeConfig": "studio.targets.keyframes",
    "cluster_keyframes": "studio.targets.keyframes",
    "SequenceConfig": "studio.imitate.config",
    "CPU_SEQUENCE": "studio.imitate.config",
    "PAPER_SEQUENCE": "studio.imitate.config",
    "imitate_sequence": "studio.imitate.sequence",
    # motion and the show file
    "Keyframes": "studio.motion.plan",
    "load_keyframes": "studio.motion.plan",
    "PlanConfig": "studio.motion.plan",
    "plan_show": "studio.motion.plan",
    "video_keyframes": "studio.motion.video_timing",
    "video_end": "studio.motion.video_timing",
    "Show": "studio.motion.show",
    "save_show": "studio.motion.show",
    "load_show": "studio.motion.show",
    "export_csv": "studio.motion.show",
    # projects
    "Project": "studio.project.project",
    "ProjectError": "studio.project.state",
    # errors
    "StudioError": "studio.errors",
}

__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'studio' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
