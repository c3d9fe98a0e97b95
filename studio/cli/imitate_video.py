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
import math
import sys
import time
from pathlib import Path

import numpy as np

from studio.cli.flags import add_config_flags, config_from_args, dest_of, given, ranged
from studio.cli.imitate import _finite, ctrl_c_cancels
from studio.imitate.keyframes import KeyframeConfig
from studio.imitate.refine import RefineConfig
from studio.imitate.search import SearchConfig
from studio.imitate.sequence import CPU_SEQUENCE, MODES, PAPER_SEQUENCE, SequenceConfig
from studio.imitate.video import VideoConfig
from studio.motion.limits import LimitsConfig
from studio.motion.plan import PlanConfig
from studio.motion.timing import TimingConfig

PRESETS = {"cpu": CPU_SEQUENCE, "paper": PAPER_SEQUENCE}  # --preset: the search/refine sizes
SEGMENT_MAX_HZ = 30.0  # raw footage is segmented at its source rate, at most this (or hz if higher)


class Bars:
    """One tqdm bar per stage on stderr, each closed when the next stage starts (none with ``quiet``)."""

    def __init__(self, quiet: bool):
        self.quiet, self.bar, self.stage = quiet, None, None

    def __call__(self, stage: str, step: int, total: int, best: float | None = None) -> None:
        if self.quiet:
            return
        from tqdm import tqdm

        if stage != self.stage:
            self.close()
            self.bar, self.stage = tqdm(total=total, desc=stage, unit="step", file=sys.stderr), stage
        self.bar.update(step - self.bar.n)
        if best is not None and math.isfinite(best):
            self.bar.set_postfix(best=f"{best:.4f}", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar, self.stage = None, None


def _given_fields(args: argparse.Namespace, cls: type, prefix: str = "") -> dict:
    """The fields of ``cls`` whose ``--PREFIX-FIELD`` flag was on the command line, with their values."""
    names = [f.name for f in dataclasses.fields(cls)]
    return {n: getattr(args, dest_of(prefix, n)) for n in names if given(args, dest_of(prefix, n))}


def sequence_config_from_args(args: argparse.Namespace) -> SequenceConfig:
    """``--preset``'s :class:`SequenceConfig` with every budget flag given on the command line applied over it."""
    base = PRESETS[args.preset]
    seed = {} if args.seed is None else {"seed": args.seed}
    return dataclasses.replace(
        base,
        **_given_fields(args, SequenceConfig),
        mode=args.mode,
        first=dataclasses.replace(base.first, **_given_fields(args, SearchConfig, "first-"), **seed),
        next=dataclasses.replace(base.next, **_given_fields(args, SearchConfig, "next-"), **seed),
        refine=dataclasses.replace(base.refine, **_given_fields(args, RefineConfig, "refine-"), **seed),
        refine_enabled=base.refine_enabled and not args.no_refine,
    )


def parse_box(text: str) -> tuple[int, int, int, int]:
    """``"x,y,w,h"`` (source pixels) → a box; an argparse error otherwise."""
    try:
        box = tuple(int(v) for v in text.split(","))
    except ValueError:
        box = ()
    if len(box) != 4 or box[2] < 1 or box[3] < 1 or box[0] < 0 or box[1] < 0:
        raise argparse.ArgumentTypeError(f"expected x,y,w,h in source pixels (w, h ≥ 1), got {text!r}")
    return box  # type: ignore[return-value]


def read_first_mask(path: Path) -> np.ndarray:
    """A first-frame mask PNG/JPEG → ``(H, W)`` uint8, 1 = object: pixels above grey 127, or any nonzero pixel when
    none is that bright (a palette mask such as DAVIS's dark-red object on black)."""
    from PIL import Image, UnidentifiedImageError

    from studio.imitate.targets import TargetError

    path = Path(path)
    if not path.is_file():
        raise TargetError(f"first mask not found: {path}")
    try:
        with Image.open(path) as im:
            grey = np.asarray(im.convert("L"))
    except (UnidentifiedImageError, OSError) as e:
        raise TargetError(f"the first mask is not a readable image ({e}): {path}") from None
    return (grey > 127 if grey.max() > 127 else grey > 0).astype(np.uint8)


def load_source(args: argparse.Namespace, cfg: VideoConfig, progress, cancel):
    """The sampled video: thresholded/mask footage as :func:`load_video` reads it, or colour footage segmented from
    ``--box``/``--first-mask`` and framed by :func:`video_from_masks`. None when ``cancel`` stopped it.

    Segmentation propagates the object from frame to frame, so it runs on every source frame up to
    ``SEGMENT_MAX_HZ`` (neighbouring frames), and the sampled frames take their masks from it: on DAVIS blackswan
    from the first mask's box, segmenting only the 4 Hz samples scored J 0.37, every frame (24 fps) then sampled
    J 0.88."""
    from studio.imitate.video import load_video, read_footage, video_from_masks

    if args.box is None and args.first_mask is None:
        video = load_video(args.src, cfg, progress, cancel)
        return None if video.cancelled else video
    from studio.imitate.segment import segment_video

    first = None if args.first_mask is None else read_first_mask(args.first_mask)
    sampled = read_footage(args.src, cfg.hz, cfg.fps, cfg.max_bad_share, progress, cancel)
    dense = sampled
    if sampled.fps > cfg.hz and not sampled.cancelled:
        rate = min(sampled.fps, max(SEGMENT_MAX_HZ, cfg.hz))
        dense = read_footage(args.src, rate, cfg.fps, cfg.max_bad_share, progress, cancel)
    if dense.cancelled or sampled.cancelled:
        return None
    masks = segment_video(dense.frames, box=args.box, first_mask=first, progress=progress, cancel=cancel)
    if len(masks) < len(dense.frames):
        return None
    # each sampled frame's mask: the segmented frame with its source index (else the nearest in time)
    same = {int(i): k for k, i in enumerate(dense.frame_index)}
    nearest = [int(np.argmin(np.abs(dense.times - t))) for t in sampled.times]
    pick = [same.get(int(i), j) for i, j in zip(sampled.frame_index, nearest)]
    return video_from_masks(sampled, masks[pick], cfg, progress=progress)


def plan_video(hand, timing, cfg: PlanConfig, world, bars: Bars, title: str, media):
    """Plan ``timing``'s keyframes (:class:`~studio.motion.video_timing.VideoTiming`) at the video's clock.

    Returns ``(show or None, late transitions, message)``: no show when a transition is too fast without
    ``allow_late`` (each is listed), or when planning fails (the message says why)."""
    from studio.motion.errors import PlanError, SegmentTooFastError
    from studio.motion.plan import plan_show

    home = bool(timing.keyframes.times[0] > 0)  # the planner prepends home unless the first keyframe is at t = 0
    try:
        planned = plan_show(
            hand, timing.keyframes, cfg, world=world,
            progress=lambda stage, frac: bars("plan", int(round(100 * frac)), 100), title=title,
        )  # fmt: skip
    except SegmentTooFastError as e:
        late = timing.late_transitions(e.segments, home)
        return None, late, (
            f"{len(late)} transition(s) too fast for the servos at the video's clock (listed above): no show.json; "
            "pass --allow-late to stretch them (the show then runs longer than the video), or run shadow-studio plan "
            "OUT/keyframes.json --out OUT/show.json --allow-late"
        )  # fmt: skip
    except PlanError as e:
        return None, [], f"no show: {e}"
    show = dataclasses.replace(planned.show, media=media)
    return show, timing.late_transitions(planned.trajectory.late, planned.home_added), ""


def keyframes_document(src: Path, hand, video, clusters, result, timing, covered: int, provenance: dict) -> dict:
    """The ``keyframes.json`` document (module doc): the planner keyframes ``plan`` reads (the first ``covered``
    frames), the assignment, every keyframe's pose and losses, the transition report and ``provenance``."""
    kf = timing.keyframes
    planner = [
        {"t": float(kf.times[i]), "pose": hand.pose_to_dict(kf.poses[i]), "hold": bool(kf.hold[i]),
         "source_frame": kf.source_frame[i], "frame": int(timing.frame[i]), "keyframe": int(timing.cluster[i]),
         "target": kf.target[i], "loss": kf.extra["keyframe_losses"][i]}
        for i in range(len(kf.times))
    ]  # fmt: skip
    poses = []
    for k in result.keyframes:
        rep = int(clusters.representatives[k.index])
        poses.append({
            "keyframe": k.index, "frame": rep, "source_frame": int(video.frame_index[rep]),
            "t": float(video.times[rep]), "pose": hand.pose_to_dict(k.theta), "loss": _finite(k.loss),
            "evaluation": _finite(k.evaluation), "collision_free": k.collision_free, "seconds": round(k.seconds, 2),
        })  # fmt: skip
    report = result.transitions().to_dict()
    report["rate"] = None if math.isnan(report["rate"]) else report["rate"]
    return {
        "keyframes": planner,
        "title": src.stem,
        "loss_weights": provenance["loss_config"],
        "media": {"path": str(src.resolve()), "kind": "video", "offset_s": 0.0},
        "video": {
            "source": str(src),
            "kind": video.kind,
            "fps": video.fps,
            "hz": video.hz,
            "duration_s": video.duration_s,
            "end_s": timing.end_s,
            "frames": len(video.times),
            "frames_covered": covered,
            "times": video.times[:covered].tolist(),
            "source_frames": video.frame_index[:covered].tolist(),
            "box": list(video.box),
            "skipped": [list(s) for s in video.skipped],
        },  # fmt: skip
        "assignment": clusters.assignment[:covered].tolist(),
        "representatives": clusters.representatives.tolist(),
        "poses": poses,
        "transitions": report,
        "cancelled": result.cancelled,
        "provenance": provenance,
    }


@dataclasses.dataclass
class Run:
    """One imitate-video run's state after the imitation (the verb's plain data)."""

    src: Path  # the source given
    out: Path  # the output folder
    hand: object  # studio.sim.hand.Hand
    video: object  # studio.imitate.video.Video
    expressive: np.ndarray  # (N, S, S) uint8
    clusters: object  # studio.imitate.keyframes.Clusters
    result: object  # studio.imitate.sequence.SequenceResult
    seq: object  # the open studio.imitate.sequence.SequenceImitator (renderer, collision world)
    covered: int = 0  # frames whose keyframes are finished (a prefix; all of them unless cancelled)
    end_s: float = 0.0  # the end of the covered video, s
    timing: object = None  # studio.motion.video_timing.VideoTiming of the covered frames

    @property
    def frame_shadows(self) -> np.ndarray:
        """``(covered, R, R)`` the shadow each covered frame plays (its keyframe's)."""
        return self.result.shadows[self.clusters.assignment[: self.covered]]


def imitate_frames(args, model, video, seq_cfg, key_cfg, clip, bars, cancel) -> tuple:
    """Expressive masks → keyframes → imitation: ``(expressive, clusters, result, seq)``, the imitator left open."""
    from studio.imitate.expressive import expressive_masks
    from studio.imitate.keyframes import cluster_keyframes
    from studio.imitate.losses import LossConfig
    from studio.imitate.sequence import SequenceImitator, keyframe_targets

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


def time_frames(run: Run) -> None:
    """The covered prefix of the video and its planner keyframes (:mod:`studio.motion.video_timing`)."""
    from studio.motion.video_timing import video_end, video_keyframes

    video, clusters, result = run.video, run.clusters, run.result
    done = len(result.keyframes)
    # keyframes are numbered in order of first appearance: the finished ones cover a prefix of the frames
    run.covered = int(np.argmax(clusters.assignment >= done)) if done < clusters.count else len(video.times)
    times = video.times[: run.covered]
    full = run.covered == len(video.times)
    run.end_s = video_end(times, video.hz, video.duration_s) if full else float(video.times[run.covered])
    run.timing = video_keyframes(
        times, clusters.assignment[: run.covered], result.thetas, run.end_s, video.frame_index[: run.covered],
        targets=[f"{run.src.name}#{int(video.frame_index[r])}" for r in clusters.representatives[:done]],
        losses=[k.loss["total"] for k in result.keyframes],
    )  # fmt: skip


def write_review(run: Run, show, bars: Bars) -> int:
    """``side_by_side.mp4`` and ``review.rrd`` (the show's shadows when there is a show); returns the mp4's frames."""
    from studio.review.rerun import log_video
    from studio.review.video_review import frame_at, video_times, write_side_by_side

    video, renderer, n = run.video, run.seq.renderer, run.covered
    mp4_t = video_times(run.end_s, video.fps)
    if show is not None:
        mp4_shadows = renderer.render(show.sample(mp4_t), check=False)
        show_shadows = renderer.render(show.positions, check=False)
    else:
        mp4_shadows, show_shadows = run.frame_shadows[frame_at(video.times[:n], mp4_t)], None
    frames = None if video.frames is None else video.frames[:n]
    write_side_by_side(run.out / "side_by_side.mp4", frames, video.masks[:n], run.expressive[:n], video.times[:n],
                       mp4_shadows, video.fps, progress=bars)  # fmt: skip
    bars.close()
    clip = run.seq.imitator.clip
    losses = np.array([k.loss["total"] for k in run.result.keyframes])[run.clusters.assignment[:n]]
    log_video(run.out / "review.rrd", run.hand, video.masks[:n], run.expressive[:n], run.frame_shadows,
              frames=frames, keyframe=run.clusters.assignment[:n], losses=losses, show=show,
              show_shadows=show_shadows, name=run.src.stem,
              notes="CLIP term off (--no-clip)" if clip is None else f"CLIP: {clip.name}")  # fmt: skip
    return len(mp4_t)


def _imitate_video(args: argparse.Namespace) -> int:
    bars = Bars(args.quiet)
    try:
        return _run(args, bars)
    finally:
        bars.close()  # before main prints an error line, so a bar never shares its line


def _run(args: argparse.Namespace, bars: Bars) -> int:
    import torch

    from studio.atomic import write_json
    from studio.imitate.clip_loss import clip_from_args
    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.selfmodel import load_selfmodel
    from studio.motion.show import MediaRef, save_show
    from studio.review.video_review import write_contact

    t_start = time.perf_counter()
    torch.set_num_threads(args.threads)  # one thread is far faster when the cores are shared, and close otherwise
    src, out = Path(args.src), Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder for keyframes.json, show.json and the review files")
    seq_cfg = sequence_config_from_args(args)
    key_cfg = config_from_args(args, KeyframeConfig)
    model_path = Path(args.model or DEFAULT_MODEL)
    model, info = load_selfmodel(model_path, device=args.device)
    video_cfg = config_from_args(args, VideoConfig, size=model.cfg.resolution)
    with ctrl_c_cancels() as cancel:  # the first Ctrl-C stops reading or imitating and keeps what was done
        video = load_source(args, video_cfg, lambda stage, i, n: bars(stage, i, n), cancel)
        bars.close()
        if video is None:
            print("shadow-studio imitate-video: cancelled while reading the video; nothing written", file=sys.stderr)
            return 130
        clip = clip_from_args(args, device=next(model.parameters()).device)
        expressive, clusters, result, seq = imitate_frames(args, model, video, seq_cfg, key_cfg, clip, bars, cancel)
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
        doc = keyframes_document(src, run.hand, video, clusters, result, run.timing, run.covered, provenance)
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
        show, late, message = plan_video(
            run.hand,
            run.timing,
            PlanConfig(timing=config_from_args(args, TimingConfig), limits=config_from_args(args, LimitsConfig)),
            seq.refiner.world,
            bars,
            src.stem,
            MediaRef(str(src.resolve()), "video"),
        )
        bars.close()
        summary["show"] = None if show is None else str(save_show(show, out / "show.json", run.hand))
        if show is not None:
            summary["show_seconds"] = round(show.duration, 4)
        summary["side_by_side_frames"] = write_review(run, show, bars)
    summary["late_transitions"] = late
    summary["collision_free"] = summary["keyframes_collision_free"] and show is not None
    for t in late:
        origin = "home" if t["from_frame"] is None else f"frame {t['from_frame']}"
        print(f"{'late' if show is not None else 'too fast'}: {origin} → frame {t['to_frame']} "
              f"({t['t_start']:.3f} → {t['t_end']:.3f} s) needs {t['needed_s']:.3f} s, the video gives "
              f"{t['given_s']:.3f} s{'; stretched, later keyframes shift' if show is not None else ''}")  # fmt: skip
    summary["seconds"] = round(time.perf_counter() - t_start, 2)
    print(json.dumps(summary))
    if show is None:
        print(f"shadow-studio imitate-video: {message.replace('OUT', str(out))}", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from studio.imitate.clip_loss import add_clip_arguments

    p = sub.add_parser("imitate-video", help="a video end to end: keyframes, poses and a show at the video's clock")
    p.add_argument("src", help="video file (mp4, avi, mov, webm, GIF) or folder of frames (PNG/JPEG)")
    p.add_argument("--out", required=True, help="folder for keyframes.json, show.json, contact.png, "
                   "side_by_side.mp4 and review.rrd")  # fmt: skip
    add_config_flags(p, VideoConfig, ("hz", "fps"))
    raw = p.add_mutually_exclusive_group()
    raw.add_argument("--box", type=parse_box, default=None, metavar="X,Y,W,H",
                     help="raw colour footage: the object's box in the first frame, source pixels; it is segmented "
                          "through the video (studio.imitate.segment)")  # fmt: skip
    raw.add_argument("--first-mask", type=Path, default=None, metavar="PNG",
                     help="raw colour footage: the object's mask in the first frame (white or nonzero = object, "
                          "the source's size), segmented through the video")  # fmt: skip
    add_config_flags(p, KeyframeConfig, ("tau",))
    p.add_argument("--mode", choices=MODES, default=SequenceConfig.mode,
                   help=f"independent: each keyframe from scratch; sequential: from the previous keyframe's pose "
                        f"(default: {SequenceConfig.mode})")  # fmt: skip
    add_config_flags(p, SequenceConfig, ("expressive", "temporal", "candidates"), base=CPU_SEQUENCE,
                     base_name="CPU_SEQUENCE")  # fmt: skip
    p.add_argument("--preset", choices=tuple(PRESETS), default="cpu",
                   help="search/refine sizes: cpu = CPU_SEQUENCE (minutes on 2 cores), paper = PAPER_SEQUENCE (the "
                        "paper's, for a GPU); the budget flags override it (default: cpu)")  # fmt: skip
    add_config_flags(p, SearchConfig, ("batch", "iterations"), prefix="first-", base=CPU_SEQUENCE.first,
                     base_name="CPU_SEQUENCE, first keyframe", aliases={"iterations": "iters"})  # fmt: skip
    add_config_flags(p, SearchConfig, ("batch", "iterations"), prefix="next-", base=CPU_SEQUENCE.next,
                     base_name="CPU_SEQUENCE, later keyframes", aliases={"iterations": "iters"})  # fmt: skip
    add_config_flags(p, RefineConfig, ("steps", "restarts"), prefix="refine-", base=CPU_SEQUENCE.refine,
                     base_name="CPU_SEQUENCE")  # fmt: skip
    p.add_argument("--no-refine", action="store_true", help="keep the searched poses (no rendered-shadow refinement)")
    p.add_argument("--seed", type=ranged(int, "[0, ∞)"), default=None, metavar="N",
                   help="seed of the searches and refinements (default: the preset's)")  # fmt: skip
    add_config_flags(p, TimingConfig, ("allow_late",))
    add_config_flags(p, LimitsConfig, ("velocity_scale", "acceleration", "jerk"),
                     ranges={"velocity_scale": "(0, 1]", "acceleration": "(0, ∞)", "jerk": "(0, ∞)"})  # fmt: skip
    p.add_argument("--model", default=None, help="self-model checkpoint (default: the shipped CPU model)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    p.add_argument("--threads", type=ranged(int, "[1, ∞)"), default=1, metavar="N",
                   help="torch CPU threads (default: 1, fastest on shared cores; ≥ 1)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_clip_arguments(p)
    p.set_defaults(func=_imitate_video)
