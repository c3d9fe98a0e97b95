"""``shadow-studio demo --out DIR``: the bundled default end to end, without a browser.

A bundled still (:data:`DEMO_STILL`, the ASL "o") and the bundled video (``studio.targets.video.DEFAULT_VIDEO``, the
Muybridge horse) become the project ``DIR/demo.shadow`` (frames, expressive masks, keyframes), whose keyframes are
optimised (search through the self-model, refinement on the renderer, collision checked; sequential within the
video, the CPU preset unless the budget flags say otherwise, no CLIP unless ``--clip-weights``) and whose show is
planned (the still held, then the horse at its own clock; transitions too fast for the servos are stretched,
``--no-allow-late`` refuses them instead, and each is listed). Then it writes ``DIR/show.json``, plays the show on
the built-in emulator (21 virtual servos over real pyserial, ``hardware.dry_run``) and writes ``DIR/review.rrd``
(the project's review: every job's loss on ``opt_step``, frames and keyframes on ``frame``, the show with the hand,
light and backdrop on ``show_time``, and the played show's commanded vs measured servo angles). A JSON summary
comes last: ``{"project", "show", "review", "keyframes", "played", "seconds", ...}``.

Run again on the same DIR, it reuses the project: keyframes whose results are current are not recomputed (only the
show is played and reviewed again); ``--fresh`` starts a new project (as on ``imitate-video``; ``--force``, its old
name, still works). Exit codes: 0 played; 1 no show or the playback stopped (the message says why); 2 bad input;
130 Ctrl-C (finished keyframes stay in the project).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import shutil
import sys
import time
from pathlib import Path

from studio.cli.clip_flags import clip_from_args
from studio.cli.run_flags import add_budget_flags, add_engine_flags, add_show_flags, run_config_from_args
from studio.cli.runs import print_run, run_with_bars


def _project(out: Path, fresh_start: bool):
    """The demo's project in ``out`` (:func:`studio.project.demo.demo_project`): reused when there, made fresh
    (``fresh_start``: after removing the old one)."""
    from studio.project.demo import PROJECT_NAME, demo_project
    from studio.project.project import ProjectError
    from studio.project.project_format import DOC

    path = out / PROJECT_NAME
    if path.exists() and fresh_start:
        if not (path / DOC).is_file() and any(path.iterdir()):
            raise ProjectError(f"{path} is not a project folder; --fresh removes only a project: move it away")
        shutil.rmtree(path)
    project, fresh = demo_project(out)
    if not fresh:
        print(f"reusing {path} (--fresh starts a new one)", file=sys.stderr)
    return project, fresh


def _beyond_soft_limits(show) -> list[tuple[str, float]]:
    """The joints ``show`` asks beyond the shipped calibration's soft limits, where the emulator's player stops
    them (:func:`hardware.show_checks.beyond_soft_limits`)."""
    from hardware.calibration import load_calibration
    from hardware.show_checks import beyond_soft_limits
    from studio.sim.hand import load_hand

    return beyond_soft_limits(show.positions, show.joint_names, load_calibration(None, load_hand()))


def _play(show, queue, cancel, **_):
    """Play ``show`` on the emulator as a job of ``queue`` until it ends or ``cancel`` is set → the finished job."""
    from studio.project.play import play_job

    job = queue.submit(play_job(show, title="demo show"))
    while not job.finished:
        if cancel.is_set():
            job.cancel()
        job.wait(0.1)
    return job


def _demo(args: argparse.Namespace) -> int:
    from hardware.show_checks import soft_limit_text
    from studio.project.outputs import self_model_predictor
    from studio.project.project import ProjectError
    from studio.review.recording import ProjectRecording
    from studio.targets.path_checks import check_outputs

    t0 = time.perf_counter()
    out = Path(args.out)
    check_outputs([out / "show.json", out / "review.rrd"], inputs=[args.model, args.clip_weights])
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder for demo.shadow, show.json and review.rrd")
    out.mkdir(parents=True, exist_ok=True)
    project, fresh = _project(out, args.fresh)
    cfg = dataclasses.replace(run_config_from_args(args), device=args.device)
    clip = clip_from_args(args)
    summary = {"project": str(project.path), "show": None, "review": str(out / "review.rrd"),
               "keyframes": len(project.keyframes), "played": False}  # fmt: skip
    with ProjectRecording(path=out / "review.rrd") as review:
        try:  # every job's loss and live shadow on opt_step
            report = run_with_bars(
                lambda progress, **kw: project.run(cfg, clip=clip, model_path=args.model, **kw),
                args.quiet,
                review.job_progress(),
            )
        except ProjectError as e:
            raise ProjectError(f"{e} (or start fresh: shadow-studio demo --out {out} --fresh)") from None
        print_run(report)
        summary |= {k: v for k, v in report.summary().items() if k not in ("project", "show", "seconds", "error")}
        summary["fresh_project"] = fresh
        review.log_project(project, self_model_predictor(args.model))
        if report.cancelled or not report.ok:
            summary["seconds"] = round(time.perf_counter() - t0, 2)
            print(json.dumps(summary))
            return 130 if report.cancelled else 1
        show_path = project.export_show(out / "show.json")
        summary["show"] = str(show_path)
        print(f"wrote {show_path}: {project.show.duration:.2f} s, {len(project.show.times)} samples; playing it on "
              "the emulator", file=sys.stderr)  # fmt: skip
        beyond = _beyond_soft_limits(project.show)
        if note := soft_limit_text(beyond):
            print(f"note: {note}", file=sys.stderr)
        job = run_with_bars(functools.partial(_play, project.show), args.quiet)
        played = job.result
        if played is not None:
            review.log_playback(played)
    summary["played"] = bool(job.state.value == "done" and played is not None and played.ok)
    if played is not None:
        summary["playback"] = {"reason": played.reason.value, "ticks": len(played.t), "commands": played.commands,
                               "max_tracking_error_rad": round(float(played.max_tracking_error_rad), 5),
                               "beyond_soft_limits_deg": {n: round(math.degrees(r), 2) for n, r in beyond}}  # fmt: skip
    summary["no_clip"] = clip is None
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    print(json.dumps(summary))
    if job.state.value == "cancelled":
        print("shadow-studio demo: playback cancelled", file=sys.stderr)
        return 130
    if not summary["played"]:
        print(f"shadow-studio demo: the show did not play to its end: {job.error or played.message}", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the bundled still and video end to end: project, poses, show, emulator, review")
    p.add_argument("--out", required=True, help="folder for demo.shadow (the project), show.json and review.rrd")
    p.add_argument(
        "--fresh",
        "--force",
        action="store_true",
        dest="fresh",
        help="start a new project even when DIR holds one (default: reuse DIR/demo.shadow)",
    )
    add_budget_flags(p)
    add_show_flags(p, allow_late=True)  # the horse is faster than the servos: stretch and say so (--no-allow-late)
    add_engine_flags(p)
    p.set_defaults(func=_demo)
