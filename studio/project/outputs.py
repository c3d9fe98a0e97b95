"""What a project run leaves beside it for a person and for the planner: the same files from every face.

``write_outputs(project, out)`` writes into the folder ``out``:

- ``keyframes.json``: the keyframes file ``shadow-studio plan`` reads (``keyframes``: the planner keyframes on the
  show clock, each with its frame, keyframe id, source frame, target and loss), plus the sources, every frame's
  source, time and keyframe (``frames``, ``assignment``: a frame's keyframe as its place in first-appearance order),
  every keyframe's pose and losses (``poses``), the transition report and the provenance. When a keyframe has no
  current result yet (a cancelled run), ``keyframes`` is empty and ``complete`` false: the finished poses are kept
  (run again to finish; nothing is recomputed);
- ``show.json``: the planned show, when there is a current one (``validate`` accepts it);
- ``contact.png``: target | shadow for every frame (the shadow of the pose its keyframe plays; blank without one);
- ``side_by_side.mp4``: source frame | target | the show's shadow at that moment, at the first video's rate (25 fps
  without one), when there is a show;
- ``review.rrd``: the project's review (:class:`~studio.review.recording.ProjectRecording`: frames, keyframes and
  their shadows on ``frame``, the show with the hand, light and backdrop on ``show_time``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from studio.atomic import write_json
from studio.errors import ProgressFn
from studio.motion.show import save_show
from studio.project.sources import framed_frames
from studio.project.status import ProjectHandle
from studio.sim.roll import file_deg, mount_text

FILES = ("keyframes.json", "show.json", "contact.png", "side_by_side.mp4", "review.rrd")  # what write_outputs writes
DEFAULT_FPS = 25.0  # the side-by-side video's rate when no source is a video


def _finite(d: dict) -> dict:
    """JSON-safe numbers: NaN (a term not computed) becomes null."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def keyframes_document(project: ProjectHandle, run: Any = None, provenance: dict | None = None) -> dict:
    """The ``keyframes.json`` document of ``project`` (module doc); ``run``: the run's report, for its transitions."""
    from studio.sim.hand import load_hand

    hand, s, status = load_hand(), project.state, project.status()
    complete = not status.pending
    planner: list[dict] = []
    if complete:
        timing = project.show_timing()
        kf = timing.keyframes
        planner = [
            {"t": float(kf.times[i]), "pose": hand.pose_to_dict(kf.poses[i]), "hold": bool(kf.hold[i]),
             "source_frame": kf.source_frame[i], "frame": int(timing.frame[i]), "keyframe": int(timing.cluster[i]),
             "target": kf.target[i], "loss": kf.extra["keyframe_losses"][i]}
            for i in range(len(kf.times))
        ]  # fmt: skip
    poses = []
    for pos, k in enumerate(project.keyframes):
        r = s.results.get(k.id)
        if r is None or k.id in status.stale:
            continue
        f = s.frames[k.representative]
        poses.append({
            "keyframe": pos, "id": k.id, "frame": k.representative, "source": f.source,
            "source_frame": f.source_frame, "t": f.time_s, "pose": dict(r.pose), "loss": _finite(dict(r.loss)),
            "evaluation": _finite(dict(r.evaluation)), "collision_free": r.collision_free,
            "seconds": round(r.seconds, 2),
        })  # fmt: skip
    sources = [
        {"path": src.path, "absolute": src.absolute, "kind": src.kind, "footage": src.footage, "fps": src.fps,
         "duration_s": src.duration_s, "frames": sum(f.source == i for f in s.frames),
         "frame_box": None if src.frame_box is None else list(src.frame_box)}
        for i, src in enumerate(s.sources)
    ]  # fmt: skip
    media = project.show.media if project.show is not None else None
    return {
        "keyframes": planner,
        "title": s.title,
        "roll_deg": file_deg(s.mount.roll),  # the hand's mount roll (DESIGN §1), what `plan` keeps
        "mount": mount_text(s.mount.roll),
        "loss_weights": s.weights.to_dict(),
        "media": None if media is None else dataclasses.asdict(media),
        "sources": sources,
        "hz": s.video.hz,
        "frames": [{"source": f.source, "source_frame": f.source_frame, "t": f.time_s} for f in s.frames],
        "assignment": project.assignment().tolist(),
        "poses": poses,
        "transitions": None if run is None else run.transitions,
        "complete": complete,
        "provenance": provenance or {},
    }


def self_model_predictor(model_path: Path | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """θ ``(K, 21)`` rad → the self-model's shadows ``(K, R, R)`` in [0, 1] (the shipped model unless ``model_path``),
    for the review's self-model view."""
    import torch

    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.selfmodel import load_selfmodel

    model, _ = load_selfmodel(Path(model_path or DEFAULT_MODEL), device="cpu")

    def predict(theta: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return model(torch.as_tensor(np.asarray(theta), dtype=torch.float32))[:, 0].numpy()

    return predict


def _frame_shadows(project: ProjectHandle) -> np.ndarray:
    """``(N, S, S)`` uint8: each frame's keyframe shadow (zeros where the keyframe has no current result)."""
    s, status = project.state, project.status()
    size = s.targets.shape[-1]
    out = np.zeros(s.targets.shape, np.uint8)
    which = project.assignment()
    for pos, kf in enumerate(project.keyframes):
        r = s.results.get(kf.id)
        if r is not None and kf.id not in status.stale:
            shadow = np.asarray(r.shadow)
            if shadow.shape != (size, size):
                import cv2

                shadow = cv2.resize(shadow.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA) >= 0.5
            out[which == pos] = shadow
    return out


def write_outputs(
    project: ProjectHandle,
    out: str | Path,
    run: Any = None,
    provenance: dict | None = None,
    self_model: Callable[[np.ndarray], np.ndarray] | None = None,
    progress: ProgressFn | None = None,
) -> dict[str, Path]:
    """Write the files of the module doc into ``out`` → ``{name: path}`` of those written. ``run``: the run's
    report (its transitions go into ``keyframes.json``); ``self_model``: θ → predicted shadows for the review."""
    from studio.review.recording import ProjectRecording
    from studio.review.video_review import write_contact

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = project.state
    written = {"keyframes.json": write_json(out / "keyframes.json", keyframes_document(project, run, provenance))}
    shadows = _frame_shadows(project)
    times = np.array([f.time_s for f in s.frames])
    written["contact.png"] = write_contact(
        out / "contact.png", s.targets, project.combined_masks(), shadows, times, project.assignment()
    )
    sources = framed_frames(s.sources, s.frames, project.path, s.video)
    show = project.show if project.show is not None and not project.status().show_stale else None
    if show is not None:
        written["show.json"] = save_show(show, out / "show.json")
        written["side_by_side.mp4"] = _side_by_side(project, show, sources, out / "side_by_side.mp4", progress)
    else:
        for name in ("show.json", "side_by_side.mp4"):  # never leave a file of an earlier run beside these
            (out / name).unlink(missing_ok=True)
    with ProjectRecording(path=out / "review.rrd", sources=any(x is not None for x in sources)) as review:
        review.log_project(project, self_model, sources)
    written["review.rrd"] = out / "review.rrd"
    return written


def _side_by_side(project: ProjectHandle, show, sources: list, path: Path, progress: ProgressFn | None) -> Path:
    """``side_by_side.mp4``: the frames of the studio's show preview (:func:`~.preview_clock.preview_clock`: the
    frame played at each show time, late transitions stretched as planned, beside the show's shadow then, as
    mounted) at the source's rate."""
    from studio.project.preview_clock import preview_clock, preview_inputs
    from studio.review.preview import preview_shadows
    from studio.review.video_review import write_side_by_side

    s = project.state
    fps = next((src.fps for src in s.sources if src.kind != "still" and src.fps > 0), DEFAULT_FPS)
    clock = preview_clock(preview_inputs(project), fps)
    shadows = preview_shadows(clock.theta, s.targets.shape[-1], show.roll)
    rgb = None if all(f is None for f in sources) else sources
    return write_side_by_side(
        path, rgb, s.targets, project.combined_masks(), clock.frame, clock.times, shadows, fps, progress=progress
    )
