"""``shadow-studio project <verb> NAME.shadow``: an artist's project folder from the command line.

- ``project new NAME.shadow --source FILE…``: load the sources (stills, videos or frame folders) sampled at
  ``--hz``, binarised at ``--threshold`` (videos) / ``--still-threshold`` (stills), and compute the frames, their
  expressive masks and keyframes (``--tau``); colour footage needs ``--box`` or ``--first-mask``.
- ``project info NAME.shadow``: sources (missing or changed?), frames, keyframes and their results (current,
  stale or missing), the show; human lines, then a JSON summary last.
- ``project export NAME.shadow --out show.json``: write the planned show (an error if none is planned yet or
  it is stale).

Each verb is registered by a ``_register_*`` function, so more (``run``) join the group the same way.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args
from studio.cli.imitate_video import parse_box
from studio.imitate.keyframes import KeyframeConfig
from studio.imitate.targets import TargetConfig
from studio.imitate.video import VideoConfig


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
    p = sub.add_parser("project", help="an artist's project folder NAME.shadow: new, info, export")
    verbs = p.add_subparsers(title="project verbs", dest="project_verb", metavar="<project verb>")
    for add in (_register_new, _register_info, _register_export):
        add(verbs)
    p.set_defaults(func=lambda args: p.print_help() or 0)
