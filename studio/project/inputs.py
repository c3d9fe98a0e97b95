"""Fingerprints of what a result was computed from, so results computed from stale inputs are told apart.

A keyframe's inputs are its source's content hash (and segmentation), the settings that turned the source into
masks (a still's TargetConfig and frame size; a video's VideoConfig), its member frames and representative (by
frame key), the representative's target mask and expressive mask (automatic + paint), the loss weights and the
mount roll (the pose is chosen for it). Its
time and hold are not: they shape the show, not the pose. A show's inputs are every keyframe's inputs, the result
(pose) each one holds, its time and hold, and the frames' times.

A result (or show) is current when the fingerprint it was computed from equals the fingerprint now.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from studio.project.edits import combined_masks
from studio.project.state import ProjectState, mask_hash, text_hash


def keyframe_inputs(state: ProjectState, k: int, combined: np.ndarray | None = None) -> str:
    """The fingerprint (sha256 hex) of keyframe ``k``'s inputs (module doc); ``combined`` = the artist's expressive
    masks ``(N, S, S)`` when already computed (:func:`studio.project.edits.combined_masks`)."""
    kf = state.keyframe(k)
    rep = state.frames[kf.representative]
    src = state.sources[rep.source]
    if src.kind == "still":
        still = dataclasses.asdict(state.still)
        if not state.still.pocket_reach:  # no crease pockets: as before the loader filled them
            del still["pocket_reach"], still["pocket_neck"]
        loading = {"still": still, "size": state.video.size}
    else:
        loading = {"video": dataclasses.asdict(state.video)}
    expressive = (combined if combined is not None else combined_masks(state))[kf.representative]
    roll = {"roll": state.mount.roll} if state.mount.roll else {}  # upright: as before the mount roll existed
    return text_hash(roll | {
        "source": {"sha256": src.sha256, "box": src.box,
                   "first_mask": None if src.first_mask is None else mask_hash(src.first_mask)},
        "loading": loading,
        "members": [state.frames[m].key for m in kf.members],
        "representative": rep.key,
        "target": mask_hash(state.targets[kf.representative]),
        "expressive": mask_hash(expressive),
        "weights": dataclasses.asdict(state.weights),
    })  # fmt: skip


def show_inputs(state: ProjectState, combined: np.ndarray | None = None) -> str:
    """The fingerprint (sha256 hex) of what a show of this state is planned from (module doc)."""
    combined = combined if combined is not None else combined_masks(state)
    keyframes = []
    for kf in state.keyframes:
        r = state.results.get(kf.id)
        keyframes.append({
            "id": kf.id, "inputs": keyframe_inputs(state, kf.id, combined),
            "result": None if r is None else {"inputs": r.inputs, "pose": sorted(r.pose.items())},
            "time_s": kf.time_s, "hold": kf.hold,
        })  # fmt: skip
    frames = [[f.key, f.time_s] for f in state.frames]
    clocks = [[s.fps, s.duration_s] for s in state.sources]
    return text_hash({"keyframes": keyframes, "frames": frames, "clocks": clocks, "hz": state.video.hz})
