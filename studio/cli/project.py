"""``shadow-studio project <verb> NAME.shadow``: an artist's project folder from the command line.

- ``project new NAME.shadow --source FILE…``: load the sources (stills, videos or frame folders) sampled at
  ``--hz``, binarised at ``--threshold`` (videos) / ``--still-threshold`` (stills), and compute the frames, their
  expressive masks and keyframes (``--tau``); colour footage needs ``--box`` or ``--first-mask``.
- ``project info NAME.shadow``: sources (missing or changed?), frames, keyframes and their results (current,
  stale or missing), the show; human lines, then a JSON summary last.
- ``project run NAME.shadow``: optimise every keyframe whose result is missing or stale (one job each, sequential
  from the keyframe before it in its source, the CPU preset's budget unless flags say otherwise; no CLIP unless
  ``--clip-weights`` names local weights), then plan the show when it is missing or stale
  (:func:`studio.project.jobs.run_project`); a bar per job and stage, a JSON summary last. Exit 0 done (or nothing
  to do); 1 a keyframe job failed or no show (a transition too fast without ``--allow-late``, listed; the
  keyframes are saved); 2 the project cannot run (a source missing or changed: nothing changed); 130 Ctrl-C (the
  keyframes finished before it are saved, nothing else changed).
- ``project export NAME.shadow --out show.json``: write the planned show (an error if none is planned yet or
  it is stale).

Each verb is registered by a ``_register_*`` function.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args
from studio.cli.footage import parse_box
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig


def print_info(project) -> dict:
    """Print ``project``'s human summary lines, then its JSON summary last; returns the summary."""
    s = project.summary()
    state = project.state
    print(
        f"project {s['project']} ({s['title']!r}): {len(s['sources'])} source(s), {s['frames']} frames at "
        f"{s['hz']:g} Hz ({s['size']} px), {len(s['keyframes'])} keyframes (tau {s['tau']:g})"
    )
    for i, src in enumerate(s["sources"]):
        note = f"MISSING (was at {src['absolute']})" if src["missing"] else ""
        note = "CHANGED since it was read" if src["changed"] else note
        print(f"source {i}: {src['path']} ({src['kind']}, {src['footage']}), {src['frames']} frame(s) {note}".rstrip())
    for kf in s["keyframes"]:
        f = state.frames[kf["representative"]]
        extra = "".join([f", at {kf['time_s']:g} s" if kf["time_s"] is not None else "", ", hold" * kf["hold"],
                         ", edited" * kf["edited"]])  # fmt: skip
        loss = f" (loss {kf['loss']:.4f})" if kf["loss"] is not None else ""
        print(
            f"keyframe {kf['id']}: frame {kf['representative']} (source {f.source}, {f.time_s:.2f} s), "
            f"{len(kf['members'])} frame(s){extra}; result {kf['result']}{loss}"
        )
    if s["show"] is None:
        print("show: none planned yet")
    else:
        print(f"show: {s['show']['duration_s']:.2f} s, {s['show']['samples']} samples{' (STALE)' * s['show']['stale']}")
    print(json.dumps(s))
    return s


def _new(args: argparse.Namespace) -> int:
    from studio.project.project import Project

    video = config_from_args(args, VideoConfig)
    if args.otsu:
        video = config_from_args(args, VideoConfig, threshold=None)
    project = Project.create(
        Path(args.name),
        sources=args.source,
        title=args.title,
        video=video,
        still=config_from_args(args, TargetConfig, prefix="still-"),
        clustering=KeyframeConfig(tau=args.tau),  # by hand: config_from_args would give it VideoConfig's --size
        box=args.box,
        first_mask=args.first_mask,
    )
    print_info(project)
    return 0


def _info(args: argparse.Namespace) -> int:
    from studio.project.project import Project

    print_info(Project.open(Path(args.name)))
    return 0


def _export(args: argparse.Namespace) -> int:
    from studio.project.project import Project

    project = Project.open(Path(args.name))
    out = project.export_show(Path(args.out))
    show = project.show
    print(f"wrote {out}: {show.duration:.2f} s, {len(show.times)} samples, {len(show.keyframes)} keyframes")
    print(json.dumps({"project": str(project.path), "show": str(out), "duration_s": show.duration}))
    return 0


def run_with_bars(project, cfg, clip=None, quiet: bool = False, model_path: Path | None = None):
    """:func:`studio.project.jobs.run_project` with a tqdm bar per job and stage on stderr (none when ``quiet``) and
    the first Ctrl-C cancelling it (a second stops at once); returns its ``RunReport``."""
    from tqdm import tqdm

    from studio.cli.progress import ctrl_c_cancels
    from studio.jobs import TqdmBars
    from studio.project.jobs import queue_for
    from studio.project.run import run_project

    queue = queue_for(project)
    bars = TqdmBars(disable=quiet)
    unsubscribe = queue.subscribe(bars)

    def on_job(job, what: str) -> None:
        if not quiet:
            tqdm.write(f"job #{job.id}: {what}", file=sys.stderr)

    try:
        with ctrl_c_cancels() as cancel:
            return run_project(project, cfg, clip, queue, cancel, model_path, on_job)
    finally:
        unsubscribe()
        bars.close()


def print_run(report) -> None:
    """The human lines of a run: what it did, the late transitions, why it stopped."""
    from studio.cli.video_outputs import print_late

    print_late(report.late, stretched=report.show is not None)
    print(report.message, file=sys.stderr if report.error or report.cancelled or report.show is None else sys.stdout)


def run_config_from_args(args: argparse.Namespace):
    """The ``RunConfig`` of ``project run``'s flags (and ``demo``'s)."""
    from studio.cli.sequence_flags import sequence_config_from_args
    from studio.motion.limits import LimitsConfig
    from studio.motion.plan import PlanConfig
    from studio.project.run import RunConfig
    from studio.project.show_timing import ShowLayout

    return RunConfig(
        sequence=sequence_config_from_args(args), plan=PlanConfig(limits=config_from_args(args, LimitsConfig)),
        allow_late=args.allow_late, layout=config_from_args(args, ShowLayout),
    )  # fmt: skip


def add_run_flags(p: argparse.ArgumentParser, allow_late: bool = False) -> None:
    """The flags ``project run`` and ``demo`` share: sequence budgets, show layout and limits, CLIP, model;
    ``allow_late``: the default of ``--allow-late/--no-allow-late``."""
    from studio.cli.progress import add_quiet_flag
    from studio.cli.sequence_flags import add_sequence_flags
    from studio.motion.limits import LimitsConfig
    from studio.motion.timing import TimingConfig
    from studio.project.show_timing import ShowLayout

    add_sequence_flags(p, ("mode", "expressive", "temporal", "candidates", "refine_enabled", "retrieve"))
    add_config_flags(p, TimingConfig, ("allow_late",), base=TimingConfig(allow_late=allow_late))
    add_config_flags(p, ShowLayout)
    add_config_flags(p, LimitsConfig, ("velocity_scale",), ranges={"velocity_scale": "(0, 1]"})
    p.add_argument("--clip-weights", type=Path, default=None, metavar="PATH",
                   help="a local CLIP checkpoint: adds the CLIP loss terms (never downloaded; default: none, no "
                        "CLIP)")  # fmt: skip
    p.add_argument("--clip-model", default="ViT-B-32", help="open_clip model name of --clip-weights")
    p.add_argument("--model", type=Path, default=None, help="self-model checkpoint (default: the shipped CPU model)")
    add_quiet_flag(p)


def clip_of(args: argparse.Namespace):
    """The CLIP encoder of ``--clip-weights`` (None without it: the CLIP terms are off)."""
    if args.clip_weights is None:
        return None
    from studio.imitate.clip_loss import load_clip

    return load_clip(args.clip_model, weights=args.clip_weights)


def _run(args: argparse.Namespace) -> int:
    from studio.project.project import Project

    project = Project.open(Path(args.name))
    if args.reload_sources and project.changed_sources:
        print(f"re-reading changed source(s) {project.changed_sources}", file=sys.stderr)
        project.reload_sources()
    cfg = run_config_from_args(args)
    report = run_with_bars(project, cfg, clip_of(args), args.quiet, args.model)
    print_run(report)
    summary = report.summary() | {"clip": args.clip_weights is not None and str(args.clip_weights)}
    print(json.dumps(summary))
    if report.cancelled:
        return 130
    return 0 if report.ok else 1


def _register_run(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("run", help="optimise every missing or stale keyframe, then plan the show (JSON last)")
    p.add_argument("name", help="the project folder, NAME.shadow")
    add_run_flags(p)
    p.add_argument("--reload-sources", action="store_true",
                   help="re-read sources that changed on disk first (their keyframes are then recomputed)")  # fmt: skip
    p.set_defaults(func=_run)


def _register_new(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("new", help="make a project from sources: frames, expressive masks and keyframes")
    p.add_argument("name", help="the project folder to make, NAME.shadow")
    p.add_argument("--source", nargs="+", required=True, metavar="FILE",
                   help="stills, video files (mp4, GIF, …) or folders of frames (masks or footage)")  # fmt: skip
    p.add_argument("--title", default=None, help="the project's title (default: NAME)")
    add_config_flags(p, VideoConfig, ("hz", "fps", "threshold", "size"))
    p.add_argument("--otsu", action="store_true", help="videos: Otsu's threshold instead of --threshold")
    add_config_flags(p, TargetConfig, ("threshold",), prefix="still-")
    add_config_flags(p, KeyframeConfig, ("tau",))
    seg = p.add_mutually_exclusive_group()
    seg.add_argument("--box", type=parse_box, default=None, metavar="X,Y,W,H",
                     help="colour footage: the object's box in the first frame, source pixels")  # fmt: skip
    seg.add_argument("--first-mask", default=None, metavar="PNG",
                     help="colour footage: the object's mask in the first frame (white = object)")  # fmt: skip
    p.set_defaults(func=_new)


def _register_info(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("info", help="what a project holds (JSON summary last)")
    p.add_argument("name", help="the project folder, NAME.shadow")
    p.set_defaults(func=_info)


def _register_export(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("export", help="write a project's planned show to a show file")
    p.add_argument("name", help="the project folder, NAME.shadow")
    p.add_argument("--out", required=True, help="the show file to write (show.json)")
    p.set_defaults(func=_export)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("project", help="an artist's project folder NAME.shadow: new, info, run, export")
    verbs = p.add_subparsers(title="project verbs", dest="project_verb", metavar="<project verb>")
    for add in (_register_new, _register_info, _register_run, _register_export):
        add(verbs)
    p.set_defaults(func=lambda args: p.print_help() or 0)
