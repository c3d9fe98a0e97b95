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
show is played and reviewed again); ``--force`` starts a fresh project. Exit codes: 0 played; 1 no show or the
playback stopped (the message says why); 2 bad input; 130 Ctrl-C (finished keyframes stay in the project).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

from studio.assets import asset
from studio.cli.project import add_run_flags, clip_of, print_run, run_config_from_args, run_with_bars

DEMO_STILL = asset("targets/asl_o.jpeg")  # the bundled still the demo starts with
PROJECT_NAME = "demo.shadow"  # the project folder inside --out


def _project(out: Path, force: bool):
    """The demo's project in ``out``: reused when there, made fresh (``force``: after removing the old one)."""
    from studio.project.project import Project, ProjectError
    from studio.project.project_format import DOC
    from studio.targets.video import DEFAULT_VIDEO

    path = out / PROJECT_NAME
    if path.exists() and force:
        if not (path / DOC).is_file() and any(path.iterdir()):
            raise ProjectError(f"{path} is not a project folder; --force removes only a project: move it away")
        shutil.rmtree(path)
    if (path / DOC).is_file():
        project = Project.open(path)
        print(f"reusing {path} (--force starts fresh)", file=sys.stderr)
        return project, False
    return Project.create(path, sources=[DEMO_STILL, DEFAULT_VIDEO], title="demo"), True


def _self_model(model_path: Path | None):
    """θ (K, 21) rad → the self-model's shadows (K, R, R), for the review's self-model view."""
    import numpy as np
    import torch

    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.selfmodel import load_selfmodel

    model, _ = load_selfmodel(Path(model_path or DEFAULT_MODEL), device="cpu")

    def predict(theta: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return model(torch.as_tensor(np.asarray(theta), dtype=torch.float32))[:, 0].numpy()

    return predict


def _play(project, show, quiet: bool):
    """Play ``show`` on the emulator as a job of the project's queue (a bar, Ctrl-C cancels) → the finished job."""
    from studio.cli.progress import ctrl_c_cancels
    from studio.jobs import TqdmBars
    from studio.project.jobs import queue_for
    from studio.project.play import play_job

    queue = queue_for(project)
    bars = TqdmBars(disable=quiet)
    unsubscribe = queue.subscribe(bars)
    try:
        with ctrl_c_cancels() as cancel:
            job = queue.submit(play_job(show, title="demo show"))
            while not job.finished:
                if cancel.is_set():
                    job.cancel()
                job.wait(0.1)
    finally:
        unsubscribe()
        bars.close()
    return job


def _demo(args: argparse.Namespace) -> int:
    from studio.project.jobs import queue_for
    from studio.project.project import ProjectError
    from studio.review.recording import ProjectRecording

    t0 = time.perf_counter()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder for demo.shadow, show.json and review.rrd")
    out.mkdir(parents=True, exist_ok=True)
    project, fresh = _project(out, args.force)
    cfg = run_config_from_args(args)
    clip = clip_of(args)
    summary = {"project": str(project.path), "show": None, "review": str(out / "review.rrd"),
               "keyframes": len(project.keyframes), "played": False}  # fmt: skip
    with ProjectRecording(path=out / "review.rrd") as review:
        queue_for(project).subscribe(review.job_progress())  # every job's loss and live shadow on opt_step
        try:
            report = run_with_bars(project, cfg, clip, args.quiet, args.model)
        except ProjectError as e:
            raise ProjectError(f"{e} (or start fresh: shadow-studio demo --out {out} --force)") from None
        print_run(report)
        summary |= {k: v for k, v in report.summary().items() if k not in ("project", "show", "seconds", "error")}
        summary["fresh_project"] = fresh
        review.log_project(project, _self_model(args.model))
        if report.cancelled or not report.ok:
            summary["seconds"] = round(time.perf_counter() - t0, 2)
            print(json.dumps(summary))
            return 130 if report.cancelled else 1
        show_path = project.export_show(out / "show.json")
        summary["show"] = str(show_path)
        print(f"wrote {show_path}: {project.show.duration:.2f} s, {len(project.show.times)} samples; playing it on "
              "the emulator", file=sys.stderr)  # fmt: skip
        job = _play(project, project.show, args.quiet)
        played = job.result
        if played is not None:
            review.log_playback(played)
    summary["played"] = bool(job.state.value == "done" and played is not None and played.ok)
    if played is not None:
        summary["playback"] = {"reason": played.reason.value, "ticks": len(played.t), "commands": played.commands,
                               "max_tracking_error_rad": round(float(played.max_tracking_error_rad), 5)}  # fmt: skip
    summary["no_clip"] = clip is None
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    print(f"wrote {out / 'review.rrd'} (open it with: rerun {out / 'review.rrd'})", file=sys.stderr)
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
    p.add_argument("--force", action="store_true", help="start a fresh project (default: reuse DIR/demo.shadow)")
    add_run_flags(p, allow_late=True)  # the horse is faster than the servos: stretch and say so (--no-allow-late)
    p.set_defaults(func=_demo)
