"""``shadow-studio imitate-video SRC --out DIR``: a video end to end, from its frames to a planned show.

Stages (a progress bar each; ``--quiet`` hides them): load the video or frame folder sampled at ``--hz``
(``--box``/``--first-mask`` segment raw colour footage first) → expressive masks → keyframes (``--tau``) → imitate
the keyframes in first-appearance order (``--mode``, ``--no-expressive``, ``--no-temporal``, the search/refine
budget of ``--preset``) → plan the show at the video's own clock (:mod:`studio.motion.video_timing`). Writes into
DIR:

- ``keyframes.json``: the keyframes file ``shadow-studio plan`` reads (the planner keyframes at source times, with
  source frames and per-keyframe losses), plus the frame → keyframe assignment, every keyframe's pose and losses,
  the transition report and the provenance;
- ``show.json``: the planned show (``validate`` accepts it), its media the source video at offset 0;
- ``contact.png``: target | shadow for every sampled frame (the shadow of its keyframe's pose);
- ``side_by_side.mp4``: source frame | target mask | the show's shadow at that moment, at the source's rate;
- ``review.rrd``: targets, expressive masks and keyframe shadows on the ``frame`` timeline, the show (hand in 3D
  and its shadow) on ``show_time``;

and prints a JSON summary last. Exit codes: 0 done; 2 bad input (one line); 130 Ctrl-C: the first Ctrl-C stops
the reading, segmentation or imitation and writes what was done (``keyframes.json`` and ``contact.png`` for the
frames whose keyframes are finished), a second stops at once; 1 no show at the video's clock: a transition the
servos cannot make in the time the video gives (each is printed: frames, needed vs given seconds), a keyframe in
collision or no collision-free path. Every other file is still written, and ``shadow-studio plan
DIR/keyframes.json --out DIR/show.json --allow-late`` plans it stretched in seconds; ``--allow-late`` stretches
those transitions here (later keyframes shift, so the show runs longer than the video; the summary lists them).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from studio.cli.device_flags import add_device_flags, torch_threads
from studio.cli.flags import add_config_flags, config_from_args
from studio.cli.footage import load_source, parse_box
from studio.cli.progress import StageBars, add_quiet_flag, ctrl_c_cancels
from studio.cli.sequence_flags import add_sequence_flags, sequence_config_from_args
from studio.cli.video_outputs import Run, keyframes_document, plan_video, print_late, time_frames, write_review
from studio.motion.limits import LimitsConfig
from studio.motion.plan import PlanConfig
from studio.motion.timing import TimingConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig


def imitate_frames(model, video, seq_cfg, key_cfg, clip, bars: StageBars, cancel) -> tuple:
    """Expressive masks → keyframes → imitation: ``(expressive, clusters, result, seq)``, the imitator left open."""
    from studio.imitate.config import LossConfig
    from studio.imitate.sequence import SequenceImitator
    from studio.targets.expressive import expressive_masks
    from studio.targets.keyframes import cluster_keyframes, keyframe_targets

    expressive = expressive_masks(video.masks)
    clusters = cluster_keyframes(expressive, key_cfg)
    masks_k, expressive_k = keyframe_targets(video.masks, expressive, clusters.representatives)
    loss_cfg = LossConfig(use_clip=clip is not None, crop_size=model.cfg.resolution)
    seq = SequenceImitator(model, seq_cfg, loss_cfg=loss_cfg, clip=clip)
    try:
        result = seq.imitate(masks_k, expressive_k, bars, cancel)
    except BaseException:
        seq.close()
        raise
    bars.close()
    return expressive, clusters, result, seq


def _imitate_video(args: argparse.Namespace) -> int:
    # the bars close before main prints an error line, so a bar never shares its line
    with torch_threads(args.threads), StageBars(args.quiet) as bars:
        return _run(args, bars)


def _run(args: argparse.Namespace, bars: StageBars) -> int:
    from studio.atomic import write_json
    from studio.cli.clip_flags import clip_from_args
    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.selfmodel import load_selfmodel
    from studio.motion.show import save_show
    from studio.review.video_review import write_contact

    t_start = time.perf_counter()
    src, out = Path(args.src), Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder for keyframes.json, show.json and the review files")
    seq_cfg = sequence_config_from_args(args)
    key_cfg = config_from_args(args, KeyframeConfig)
    model_path = Path(args.model or DEFAULT_MODEL)
    model, info = load_selfmodel(model_path, device=args.device)
    video_cfg = config_from_args(args, VideoConfig, size=model.cfg.resolution)
    with ctrl_c_cancels() as cancel:  # the first Ctrl-C stops reading or imitating and keeps what was done
        video = load_source(args.src, video_cfg, args.box, args.first_mask, bars, cancel)
        bars.close()
        if video is None:
            print("shadow-studio imitate-video: cancelled while reading the video; nothing written", file=sys.stderr)
            return 130
        clip = clip_from_args(args, device=next(model.parameters()).device)
        expressive, clusters, result, seq = imitate_frames(model, video, seq_cfg, key_cfg, clip, bars, cancel)
    with seq:
        if not result.keyframes:
            print("shadow-studio imitate-video: cancelled before the first keyframe; nothing written", file=sys.stderr)
            return 130
        run = Run(src, out, model.hand, video, expressive, clusters, result, seq)
        time_frames(run)
        provenance = {
            "verb": "shadow-studio imitate-video", "preset": args.preset,
            "sequence": json.loads(json.dumps(dataclasses.asdict(seq_cfg))),
            "keyframes": dataclasses.asdict(key_cfg), "video_config": dataclasses.asdict(video_cfg),
            "loss_config": seq.loss_cfg.to_dict(), "model": str(model_path), "model_metrics": info.metrics,
            "clip": None if clip is None else clip.name, "no_clip": clip is None, "hand_hash": run.hand.hash,
            "imitation_seconds": round(result.seconds, 2),
        }  # fmt: skip
        out.mkdir(parents=True, exist_ok=True)
        doc = keyframes_document(run, provenance)
        write_json(out / "keyframes.json", doc)
        n = run.covered
        write_contact(out / "contact.png", video.masks[:n], expressive[:n], run.frame_shadows, video.times[:n],
                      clusters.assignment[:n])  # fmt: skip
        report = doc["transitions"]
        summary = {
            "frames": len(video.times), "keyframes": clusters.count, "reduction": round(clusters.reduction, 3),
            "transition_success": report["rate"], "transitions_ok": report["success"],
            "transitions": report["transitions"],
            "total_mean": float(np.mean([k.loss["total"] for k in result.keyframes])),
            "base_mean": float(np.mean([k.evaluation["base"] for k in result.keyframes])),
            "keyframes_collision_free": all(k.collision_free for k in result.keyframes),
            "video_seconds": round(run.end_s, 4), "no_clip": clip is None, "out": str(out),
        }  # fmt: skip
        if result.cancelled:
            summary.update(cancelled=True, frames_covered=n, show=None, seconds=round(time.perf_counter() - t_start, 2))
            print(json.dumps(summary))
            print(f"shadow-studio imitate-video: cancelled: wrote {len(result.keyframes)} of {clusters.count} "
                  f"keyframes (frames 0–{n - 1}) to {out}", file=sys.stderr)  # fmt: skip
            return 130
        plan_cfg = PlanConfig(timing=config_from_args(args, TimingConfig), limits=config_from_args(args, LimitsConfig))
        show, late, message = plan_video(run, plan_cfg, bars)
        summary["show"] = None if show is None else str(save_show(show, out / "show.json", run.hand))
        if show is not None:
            summary["show_seconds"] = round(show.duration, 4)
        summary["side_by_side_frames"] = write_review(run, show, bars)
    summary["late_transitions"] = late
    summary["collision_free"] = summary["keyframes_collision_free"] and show is not None
    print_late(late, stretched=show is not None)
    summary["seconds"] = round(time.perf_counter() - t_start, 2)
    print(json.dumps(summary))
    if show is None:
        print(f"shadow-studio imitate-video: {message.replace('OUT', str(out))}", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from studio.cli.clip_flags import add_clip_arguments

    p = sub.add_parser("imitate-video", help="a video end to end: keyframes, poses and a show at the video's clock")
    p.add_argument("src", help="video file (mp4, avi, mov, webm, GIF) or folder of frames (PNG/JPEG)")
    p.add_argument("--out", required=True, help="folder for keyframes.json, show.json, contact.png, "
                   "side_by_side.mp4 and review.rrd")  # fmt: skip
    add_config_flags(p, VideoConfig, ("hz", "fps"))
    raw = p.add_mutually_exclusive_group()
    raw.add_argument("--box", type=parse_box, default=None, metavar="X,Y,W,H",
                     help="raw colour footage: the object's box in the first frame, source pixels; it is segmented "
                          "through the video (studio.targets.segment)")  # fmt: skip
    raw.add_argument("--first-mask", type=Path, default=None, metavar="PNG",
                     help="raw colour footage: the object's mask in the first frame (white or nonzero = object, "
                          "the source's size), segmented through the video")  # fmt: skip
    add_config_flags(p, KeyframeConfig, ("tau",))
    add_sequence_flags(p, ("mode", "expressive", "temporal", "candidates", "refine_enabled", "retrieve"))
    add_config_flags(p, TimingConfig, ("allow_late",))
    add_config_flags(p, LimitsConfig, ("velocity_scale", "acceleration", "jerk"),
                     ranges={"velocity_scale": "(0, 1]", "acceleration": "(0, ∞)", "jerk": "(0, ∞)"})  # fmt: skip
    p.add_argument("--model", default=None, help="self-model checkpoint (default: the shipped CPU model)")
    add_device_flags(p)
    add_quiet_flag(p)
    add_clip_arguments(p)
    p.set_defaults(func=_imitate_video)
