"""``shadow-studio project <verb> NAME.shadow``: an artist's project folder from the command line.

- ``project new NAME.shadow --source FILE…``: load the sources (stills, videos or frame folders) sampled at
  ``--hz``, binarised at ``--threshold`` (videos) / ``--still-threshold`` (stills), and compute the frames, their
  expressive masks and keyframes (``--tau``); colour footage needs ``--box`` or ``--first-mask``.
- ``project info NAME.shadow``: sources (missing or changed?), frames, keyframes and their results (current,
  stale or missing), the show; human lines, then a JSON summary last.
- ``project run NAME.shadow``: optimise every keyframe whose result is missing or stale (one job each, sequential
  from the keyframe before it in its source, ``--preset`` and the budget flags; CLIP by the one rule of
  :mod:`studio.cli.clip_flags`), then plan the show when it is missing or stale
  (:meth:`studio.project.project.Project.run`, what ``imitate``, ``imitate-video`` and the notebook run); a bar per
  job and stage, a JSON summary last. Exit 0 done (or nothing
  to do); 1 a keyframe job failed or no show (a transition too fast without ``--allow-late``, listed; the
  keyframes are saved); 2 the project cannot run (a source missing or changed: nothing changed); 130 Ctrl-C (the
  keyframes finished before it are saved, nothing else changed).
  ``--keyframe K…`` optimises those keyframes again whatever their state; ``--wait S`` waits for another writer
  (default: refused at once, naming it: :mod:`studio.project.lock`).
- ``project relink NAME.shadow SOURCE PATH``: source number SOURCE moved to PATH (same content keeps every result).
- ``project export NAME.shadow --out show.json``: write the planned show (an error if none is planned yet or
  it is stale); ``--files DIR`` also writes what ``imitate-video`` writes (:mod:`studio.project.outputs`:
  ``keyframes.json``, ``show.json``, ``contact.png``, ``side_by_side.mp4``, ``review.rrd``).

Each verb is registered by a ``_register_*`` function.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from studio.cli.clip_flags import clip_from_args
from studio.cli.flags import ranged
from studio.cli.run_flags import add_budget_flags, add_engine_flags, add_show_flags, run_config_from_args
from studio.cli.runs import print_run, run_with_bars
from studio.cli.scale_flags import add_fanout_flags, fanout_from_args, models_from_args
from studio.cli.source_flags import add_source_flags, roll_arg, source_settings_from_args
from studio.errors import count, plural
from studio.learn.threads import torch_threads


def print_info(project) -> dict:
    """Print ``project``'s human summary lines, then its JSON summary last; returns the summary."""
    from studio.project.state import AWAITS
    from studio.project.summary import apart_text

    s = project.summary()
    state = project.state
    sources, frames, keyframes = count(len(s["sources"]), "source"), count(s["frames"], "frame"), s["keyframes"]
    print(f"project {s['project']} ({s['title']!r}): {sources}, {frames} at {s['hz']:g} Hz ({s['size']} px), "
          f"{count(len(keyframes), 'keyframe')} (tau {s['tau']:g})")  # fmt: skip
    for i, src in enumerate(s["sources"]):
        note = f"MISSING (was at {src['absolute']})" if src["missing"] else ""
        note = "CHANGED since it was read" if src["changed"] else note
        frames = count(src["frames"], "frame")
        print(f"source {i}: {src['path']} ({src['kind']}, {src['footage']}), {frames} {note}".rstrip())
    print(f"mount: {s['mount']['how']}")
    if s["mount"]["apart"]:
        print(f"  {apart_text(s['mount']['apart'])}")
    for kf in s["keyframes"]:
        f = state.frames[kf["representative"]]
        extra = "".join([f", at {kf['time_s']:g} s" if kf["time_s"] is not None else "", ", hold" * kf["hold"],
                         ", edited" * kf["edited"]])  # fmt: skip
        loss = f" (loss {kf['loss']:.4f})" if kf["loss"] is not None else ""
        collides = f"; COLLIDES with itself (project run {s['project']} --keyframe {kf['id']})" * kf["collides"]
        together = f"; {AWAITS[kf['awaits']]}" if kf["awaits"] else ""
        print(
            f"keyframe {kf['id']}: frame {kf['representative']} (source {f.source}, {f.time_s:.2f} s), "
            f"{count(len(kf['members']), 'frame')}{extra}; result {kf['result']}{loss}{collides}{together}"
        )
    if s["show"] is None:
        print("show: none planned yet")
    else:
        print(f"show: {s['show']['duration_s']:.2f} s, {s['show']['samples']} samples{' (STALE)' * s['show']['stale']}")
    print(json.dumps(s))
    return s


def _new(args: argparse.Namespace) -> int:
    from studio.jobs import TqdmBars
    from studio.project.project import Project
    from studio.targets.source import read_first_mask

    settings = source_settings_from_args(args)
    first = None if settings.first_mask is None else read_first_mask(settings.first_mask)
    with TqdmBars() as bars:  # reading and segmenting the sources
        project = Project.create(
            Path(args.name), sources=args.source, title=args.title, video=settings.video, still=settings.still,
            clustering=settings.clustering, box=settings.box, first_mask=first, progress=bars, roll=settings.roll,
        )  # fmt: skip
    print_info(project)
    return 0


def _info(args: argparse.Namespace) -> int:
    from studio.project.project import Project

    print_info(Project.open(Path(args.name)))
    return 0


def _export(args: argparse.Namespace) -> int:
    from studio.motion.show_info import keyframe_text
    from studio.project.outputs import FILES
    from studio.project.project import Project
    from studio.targets.path_checks import check_outputs

    check_outputs([args.out], folders=[args.name])  # nothing is written inside the project being exported
    check_outputs([Path(args.files) / f for f in FILES] if args.files is not None else [], folders=[args.name])
    project = Project.open(Path(args.name))
    out = project.export_show(Path(args.out))
    show = project.show
    marks = keyframe_text(show, len(project.keyframes))
    print(f"wrote {out}: {show.duration:.2f} s, {len(show.times)} samples; {marks}")
    summary = {"project": str(project.path), "show": str(out), "duration_s": show.duration}
    if args.files is not None:
        from studio.project.outputs import self_model_predictor, write_outputs

        files = write_outputs(project, args.files, self_model=self_model_predictor())
        print(f"wrote {', '.join(str(f) for f in files.values())}")
        summary["files"] = {k: str(v) for k, v in files.items()}
    print(json.dumps(summary))
    return 0


def _run(args: argparse.Namespace) -> int:
    from studio.project.project import Project

    project = Project.open(Path(args.name))
    if args.reload_sources and project.changed_sources:
        print(
            f"re-reading changed {plural('source', len(project.changed_sources))} {project.changed_sources}",
            file=sys.stderr,
        )
        project.reload_sources()
    if args.roll is not None:
        project.set_roll(args.roll)  # another roll: the keyframes are optimised again for it
    cfg = replace(run_config_from_args(args), device=args.device, fanout=fanout_from_args(args))
    clip = clip_from_args(args)
    models = models_from_args(args) if cfg.spread else None
    forced = None if args.keyframe is None else sorted(set(args.keyframe))
    with torch_threads(args.threads):
        report = run_with_bars(
            lambda progress, **kw: project.run(
                cfg,
                clip=clip,
                model_path=args.model,
                keyframes=forced,
                wait=args.wait,
                progress=progress,
                models=models,
                **kw,
            ),
            args.quiet,
            threads=args.threads,
        )
    print_run(report)
    summary = report.summary() | {"clip": None if clip is None else clip.name}
    print(json.dumps(summary))
    if report.cancelled:
        return 130
    return 0 if report.ok else 1


def _register_run(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("run", help="optimise every missing or stale keyframe, then plan the show (JSON last)")
    p.add_argument("name", help="the project folder, NAME.shadow")
    add_budget_flags(p)
    add_show_flags(p)
    add_engine_flags(p)
    add_fanout_flags(p)
    p.add_argument("--reload-sources", action="store_true",
                   help="re-read sources that changed on disk first (their keyframes are then recomputed)")  # fmt: skip
    p.add_argument("--roll", type=roll_arg, default=None, metavar="auto|DEG",
                   help="set the hand's mount roll first (auto: chosen again for the whole show; degrees: the "
                        "artist's); default: keep the project's")  # fmt: skip
    p.add_argument("--keyframe", type=ranged(int, "[0, 1000000]"), nargs="+", default=None, metavar="K",
                   help="optimise exactly these keyframe ids again, current or not (then plan the show when every "
                        "keyframe is current)")  # fmt: skip
    p.add_argument("--wait", type=ranged(float, "[0, 86400]"), default=0.0, metavar="S",
                   help="when another process is writing the project, wait up to S seconds for it (default: refuse "
                        "at once, saying who holds it)")  # fmt: skip
    p.set_defaults(func=_run)


def _relink(args: argparse.Namespace) -> int:
    from studio.jobs import TqdmBars
    from studio.project.project import Project

    project = Project.open(Path(args.name))
    with TqdmBars() as bars, project.writing("project relink"):
        project.relink_source(args.source, args.path, progress=bars)
    src = project.sources[args.source]
    print(f"source {args.source} is now {src.path} ({src.absolute})")
    print_info(project)
    return 0


def _register_relink(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("relink", help="a moved source: tell the project where it is now (same content keeps "
                                        "every result; other content is read again)")  # fmt: skip
    p.add_argument("name", help="the project folder, NAME.shadow")
    p.add_argument("source", type=ranged(int, "[0, 100000]"), help="the source's number (project info lists them)")
    p.add_argument("path", help="where that source is now (a still, a video file or a folder of frames)")
    p.set_defaults(func=_relink)


def _register_new(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("new", help="make a project from sources: frames, expressive masks and keyframes")
    p.add_argument("name", help="the project folder to make, NAME.shadow")
    p.add_argument("--source", nargs="+", action="extend", required=True, metavar="FILE",
                   help="stills, video files (mp4, GIF, …) or folders of frames (masks or footage); "
                        "given again, more sources follow")  # fmt: skip
    p.add_argument("--title", default=None, help="the project's title (default: NAME)")
    add_source_flags(p, size=True)
    p.set_defaults(func=_new)


def _register_info(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("info", help="what a project holds (JSON summary last)")
    p.add_argument("name", help="the project folder, NAME.shadow")
    p.set_defaults(func=_info)


def _register_export(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("export", help="write a project's planned show to a show file")
    p.add_argument("name", help="the project folder, NAME.shadow")
    p.add_argument("--out", required=True, help="the show file to write (show.json)")
    p.add_argument(
        "--files",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write keyframes.json, show.json, contact.png, side_by_side.mp4 and review.rrd there",
    )
    p.set_defaults(func=_export)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("project", help="an artist's project folder NAME.shadow: new, info, run, relink, export")
    verbs = p.add_subparsers(title="project verbs", dest="project_verb", metavar="<project verb>")
    for add in (_register_new, _register_info, _register_run, _register_relink, _register_export):
        add(verbs)
    p.set_defaults(func=lambda args: p.print_help() or 0)
