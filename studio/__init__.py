"""Shadow Studio's public API: what a notebook or a script uses, re-exported from the stages (DESIGN §3).

    import studio
    target = studio.load_target(studio.DEFAULT_TARGET, size=128)   # (128, 128) uint8, 1 = shadow
    result = studio.imitate_still(target)                          # roll auto → search → refine: a free pose
    keyframes = studio.Keyframes.at([2.0], [result.theta], roll=result.roll)  # hold it at t = 2 s, on that mount
    show = studio.plan_show(studio.load_hand(), keyframes).show      # jerk-limited, collision-checked
    studio.save_show(show, "show.json")
    horse = studio.imitate_video(studio.DEFAULT_VIDEO, "out/horse")     # a video → a project, its poses, the show
    horse.show, horse.report.late                                      # (None without a show: report.message says)

Names are imported on first use (``studio.X`` loads only the stage that defines ``X``), so ``import studio`` and
the command line stay quick; ``dir(studio)`` lists them all.
"""

from __future__ import annotations

import importlib as _importlib
import os as _os
from typing import Any as _Any

# Idle OpenMP threads sleep instead of spinning. numba's parallel kernels (renderer, compiled loss) and torch keep
# separate OpenMP pools; with the default (spin) policy the renderer's idle threads steal the cores from the
# self-model's gradient steps that follow (measured here: a 16-pose search step 83 ms → 1,234 ms after one parallel
# render on 2 cores). Set before torch or numba start their pools; a value the user set is kept.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# name → the module that defines it, grouped by stage
_API: dict[str, str] = {
    # the hand and its world
    "Hand": "studio.sim.hand",
    "load_hand": "studio.sim.hand",
    "Rig": "studio.sim.shadow",
    "ShadowRenderer": "studio.sim.shadow",
    "into_hand_frame": "studio.sim.roll",
    "mount_text": "studio.sim.roll",
    "CollisionWorld": "studio.sim.physics",
    # footage: stills, videos, segmentation, expressive masks, keyframes
    "DEFAULT_TARGET": "studio.targets.images",
    "SAMPLE_DIR": "studio.targets.images",
    "TargetConfig": "studio.targets.images",
    "load_target": "studio.targets.images",
    "find_holes": "studio.targets.holes",
    "DEFAULT_VIDEO": "studio.targets.video",
    "VideoConfig": "studio.targets.video",
    "Video": "studio.targets.video",
    "open_source": "studio.targets.source",
    "SegmentConfig": "studio.targets.segment_config",
    "segment_video": "studio.targets.segment",
    "expressive_masks": "studio.targets.expressive",
    "KeyframeConfig": "studio.targets.keyframes",
    "cluster_keyframes": "studio.targets.keyframes",
    # learning
    "SelfModel": "studio.learn.selfmodel",
    "load_selfmodel": "studio.learn.selfmodel",
    # imitation
    "LossConfig": "studio.imitate.config",
    "ImageLoss": "studio.imitate.losses",
    "SearchConfig": "studio.imitate.config",
    "RefineConfig": "studio.imitate.config",
    "SequenceConfig": "studio.imitate.config",
    "PRESETS": "studio.imitate.config",
    "Imitator": "studio.imitate.still",
    "ImitationResult": "studio.imitate.still_result",
    "imitate_still": "studio.imitate.one_still",
    "imitate_sequence": "studio.imitate.sequence",
    "find_clip": "studio.imitate.clip_loss",
    "choose_roll": "studio.imitate.roll_search",
    "RollSearchConfig": "studio.imitate.roll_search",
    # motion and the show file
    "Keyframes": "studio.motion.plan",
    "load_keyframes": "studio.motion.plan",
    "PlanConfig": "studio.motion.plan",
    "plan_show": "studio.motion.plan",
    "reach": "studio.motion.reach",
    "reach_box": "studio.motion.reach",
    "Show": "studio.motion.show",
    "save_show": "studio.motion.show",
    "load_show": "studio.motion.show",
    "export_csv": "studio.motion.show",
    # projects and the pipeline every face runs
    "Project": "studio.project.project",
    "RunConfig": "studio.project.run",
    "RunReport": "studio.project.run_report",
    "SourceSettings": "studio.project.pipeline",
    "VideoResult": "studio.project.pipeline",
    "imitate_video": "studio.project.pipeline",
    # progress
    "Progress": "studio.errors",
    # the typed errors a user can meet
    "StudioError": "studio.errors",
    "TargetError": "studio.errors",
    "SegmentationNeeded": "studio.targets.video",
    "ClipWeightsError": "studio.imitate.clip_loss",
    "CheckpointError": "studio.learn.checkpoint",
    "PlanError": "studio.motion.errors",
    "KeyframeCollisionError": "studio.motion.errors",
    "PathError": "studio.motion.errors",
    "SegmentTooFastError": "studio.motion.errors",
    "ShowError": "studio.motion.show",
    "ProjectError": "studio.project.state",
    "NotAProject": "studio.project.state",
    "ResultsNeeded": "studio.project.state",
    "ShowNeeded": "studio.project.state",
    "SourceMissing": "studio.project.status",
    "SourceChanged": "studio.project.status",
    "OtherProject": "studio.project.pipeline",
    "ShardError": "studio.errors",
    "ClosedError": "studio.errors",
    "Cancelled": "studio.errors",
    "PlanCancelled": "studio.motion.errors",
    "ReviewError": "studio.review.recording",
}

__all__ = sorted(_API)


def __getattr__(name: str) -> _Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'studio' has no attribute {name!r}")
    value = getattr(_importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    """The public API (and the stage modules already loaded), without this module's own helpers."""
    return sorted({n for n in globals() if not n.startswith("_") and n != "annotations"} | set(_API))
