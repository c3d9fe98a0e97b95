"""``shadow-studio imitate TARGET --out DIR`` and ``shadow-studio imitate-video SRC --out DIR``: one source end to
end, a thin face over :func:`studio.project.pipeline.imitate_video` (what ``project run`` and the notebook run).

The source becomes the project ``DIR/<name>.shadow`` (``shadow-studio lab DIR/<name>.shadow`` opens it in the
studio); every keyframe is optimised (``--preset`` and the budget flags), the show is planned at the video's clock
(a still is held ``--still-hold-s``), and ``keyframes.json`` (what ``shadow-studio plan`` reads), ``show.json``,
``contact.png``, ``side_by_side.mp4`` and ``review.rrd`` are written into DIR; a JSON summary comes last. Run again
on the same DIR, the project is reopened and only what is missing or stale is computed (``--fresh`` starts over).

Exit codes: 0 a show; 1 no show (a transition too fast for the servos: each is printed, ``--allow-late`` stretches
them; a keyframe in collision or a failed job) or a keyframe pose that collides; 2 bad input (one line); 130 Ctrl-C
(the first stops the work and writes the files of the keyframes finished so far; the same command resumes).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from studio.cli.run_flags import add_budget_flags, add_engine_flags, add_show_flags, run_config_from_args
from studio.cli.runs import print_run, run_with_bars
from studio.cli.source_flags import add_source_flags, source_settings_from_args
from studio.learn.threads import torch_threads


def _imitate(args: argparse.Namespace) -> int:
    from studio.targets.source import source_kind

    src = Path(args.src)
    if not src.exists():
        raise FileNotFoundError(f"source not found: {src}")
    if args.verb == "imitate" and source_kind(src) in ("video", "folder"):
        raise ValueError(f"{src} is a video: imitate it with shadow-studio imitate-video {src} --out ...")
    from studio.project.outputs import FILES
    from studio.targets.path_checks import check_outputs

    inputs = [src, args.model, getattr(args, "first_mask", None), args.clip_weights]
    check_outputs([Path(args.out) / f for f in FILES], inputs=inputs, folders=[src] if src.is_dir() else [])
    with torch_threads(args.threads):
        return _run(args, src)


def _run(args: argparse.Namespace, src: Path) -> int:
    import torch

    from studio.cli.clip_flags import clip_from_args
    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.selfmodel import load_selfmodel
    from studio.project.pipeline import imitate_video

    t0 = time.perf_counter()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder for the project and its files")
    settings = source_settings_from_args(args)  # a bad source or flag is reported before the model loads
    model, _ = load_selfmodel(Path(args.model or DEFAULT_MODEL), device="cpu")
    settings = replace(settings, video=replace(settings.video, size=model.cfg.resolution))  # the model's own frame
    if args.verb == "imitate":  # a bad still is said before anything else (reading it again later costs little)
        from studio.targets.images import load_target

        load_target(src, size=settings.video.size, cfg=settings.still)
    cfg = replace(run_config_from_args(args), device=args.device)
    clip = clip_from_args(args, device=args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    provenance = {"verb": f"shadow-studio {args.verb}", "preset": args.preset, "no_clip": clip is None}
    result = run_with_bars(
        lambda **kw: imitate_video(src, out, settings, cfg, clip=clip, model_path=args.model, fresh=args.fresh,
                                   provenance=provenance, **kw),
        args.quiet,
        threads=args.threads,
    )  # fmt: skip
    report, project = result.report, result.project
    print_run(report)
    summary = report.summary() | {
        "project": str(project.path), "frames": len(project.frames), "keyframes": len(project.keyframes),
        "show": None if result.show is None else str(result.files["show.json"]),
        "video_seconds": round(project.show_timing().end_s, 4) if not project.status().pending else None,
        "files": {k: str(v) for k, v in result.files.items()}, "fresh_project": result.fresh,
        "no_clip": clip is None, "out": str(out), "seconds": round(time.perf_counter() - t0, 2),
    }  # fmt: skip
    summary["collision_free"] = bool(
        result.show is not None and all(r.collision_free for r in project.results.values())
    )
    print(json.dumps(summary))
    if report.cancelled:
        print(f"shadow-studio {args.verb}: cancelled: the finished keyframes are kept in {project.path}; the same "
              "command resumes", file=sys.stderr)  # fmt: skip
        return 130
    return 0 if report.ok and summary["collision_free"] else 1


def _register(sub: argparse._SubParsersAction, verb: str, video: bool) -> None:
    what = "a video (file, GIF or frame folder)" if video else "a still target image"
    p = sub.add_parser(verb, help=f"{what} end to end: a project, its keyframes' poses, the show and review files")
    p.add_argument("src", help="video file (mp4, avi, mov, webm, GIF) or folder of frames (PNG/JPEG)" if video else
                   "target image (PNG, JPEG, GIF, BMP): a silhouette, either polarity")  # fmt: skip
    p.add_argument("--out", required=True, help="folder for the project (<name>.shadow), keyframes.json, show.json, "
                   "contact.png, side_by_side.mp4 and review.rrd")  # fmt: skip
    p.add_argument("--fresh", action="store_true", help="start a new project even when OUT holds one of this source")
    add_source_flags(p, video=video, still=not video)
    add_budget_flags(p, video=video)
    add_show_flags(p, layout=not video)
    add_engine_flags(p)
    p.set_defaults(func=_imitate)


def register(sub: argparse._SubParsersAction) -> None:
    _register(sub, "imitate", video=False)
    _register(sub, "imitate-video", video=True)
