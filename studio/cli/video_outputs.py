"""What ``imitate-video`` makes of a finished (or cancelled) imitation: the covered frames' timing, the
``keyframes.json`` document, the show at the video's clock, ``side_by_side.mp4`` and ``review.rrd``, and the lines
that report transitions too fast for the servos (the module doc of :mod:`studio.cli.imitate_video` lists the files).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from studio.cli.imitate import _finite
from studio.cli.progress import StageBars
from studio.motion.plan import PlanConfig


@dataclasses.dataclass
class Run:
    """One imitate-video run's state after the imitation (the verb's plain data)."""

    src: Path  # the source given
    out: Path  # the output folder
    hand: object  # studio.sim.hand.Hand
    video: object  # studio.targets.video.Video
    expressive: np.ndarray  # (N, S, S) uint8
    clusters: object  # studio.targets.keyframes.Clusters
    result: object  # studio.imitate.sequence.SequenceResult
    seq: object  # the open studio.imitate.sequence.SequenceImitator (renderer, collision world)
    covered: int = 0  # frames whose keyframes are finished (a prefix; all of them unless cancelled)
    end_s: float = 0.0  # the end of the covered video, s
    timing: object = None  # studio.motion.video_timing.VideoTiming of the covered frames

    @property
    def frame_shadows(self) -> np.ndarray:
        """``(covered, R, R)`` the shadow each covered frame plays (its keyframe's)."""
        return self.result.shadows[self.clusters.assignment[: self.covered]]


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


def keyframes_document(run: Run, provenance: dict) -> dict:
    """The ``keyframes.json`` document: the planner keyframes ``plan`` reads (the covered frames), the assignment,
    every keyframe's pose and losses, the transition report and ``provenance``."""
    src, hand, video, clusters, result, covered = run.src, run.hand, run.video, run.clusters, run.result, run.covered
    kf = run.timing.keyframes
    planner = [
        {"t": float(kf.times[i]), "pose": hand.pose_to_dict(kf.poses[i]), "hold": bool(kf.hold[i]),
         "source_frame": kf.source_frame[i], "frame": int(run.timing.frame[i]), "keyframe": int(run.timing.cluster[i]),
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
            "end_s": run.end_s,
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


def plan_video(run: Run, cfg: PlanConfig, bars: StageBars):
    """Plan ``run.timing``'s keyframes at the video's clock, the source as the show's media.

    Returns ``(show or None, late transitions, message)``: no show when a transition is too fast without
    ``allow_late`` (each is listed), or when planning fails (the message says why)."""
    from studio.motion.errors import PlanError, SegmentTooFastError
    from studio.motion.plan import plan_show
    from studio.motion.show import MediaRef

    timing = run.timing
    home = bool(timing.keyframes.times[0] > 0)  # the planner prepends home unless the first keyframe is at t = 0
    try:
        planned = plan_show(
            run.hand, timing.keyframes, cfg, world=run.seq.refiner.world,
            progress=lambda stage, frac: bars("plan", int(round(100 * frac)), 100), title=run.src.stem,
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
    finally:
        bars.close()
    show = dataclasses.replace(planned.show, media=MediaRef(str(run.src.resolve()), "video"))
    return show, timing.late_transitions(planned.trajectory.late, planned.home_added), ""


def write_review(run: Run, show, bars: StageBars) -> int:
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


def print_late(late: list[dict], stretched: bool) -> None:
    """One line per transition too fast for the servos at the video's clock: frames, needed vs given seconds
    (``stretched``: ``--allow-late`` made them slower, so later keyframes shift)."""
    for t in late:
        origin = "home" if t["from_frame"] is None else f"frame {t['from_frame']}"
        print(f"{'late' if stretched else 'too fast'}: {origin} → frame {t['to_frame']} "
              f"({t['t_start']:.3f} → {t['t_end']:.3f} s) needs {t['needed_s']:.3f} s, the video gives "
              f"{t['given_s']:.3f} s{'; stretched, later keyframes shift' if stretched else ''}")  # fmt: skip
