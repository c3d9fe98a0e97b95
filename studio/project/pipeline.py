"""One source end to end as a one-source project: what ``imitate`` and ``imitate-video`` run, and
``studio.imitate_video`` in a script.

    result = imitate_video("horse.gif", "out/horse")     # out/horse/horse.shadow, keyframes.json, show.json, ...
    result.show, result.report.late, result.project       # the planned show (None without one), the run, the project

The source becomes the project ``OUT/<name>.shadow`` (:meth:`Project.create` with :class:`SourceSettings`), the
project is run (:func:`~studio.project.run.run_project`: every keyframe, then the show, the very engine calls the
notebook's Optimise tab and ``project run`` make), and the files of :mod:`studio.project.outputs` are written
beside it. So the same source through ``imitate-video``, ``project run`` and the notebook gives the same keyframes,
poses and show. A still is a video of one frame: its one keyframe is searched from scratch and held.

Run again on the same ``OUT``, it reopens the project when it was made from the same source with the same settings:
current keyframes are kept (a cancelled run resumes where it stopped), only what is missing or stale is computed.
A project there made otherwise is a :class:`~studio.project.state.ProjectError` unless ``fresh=True`` starts over.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from studio.errors import ProgressFn
from studio.imitate.config import LossConfig
from studio.jobs.job import Job
from studio.jobs.queue import JobQueue
from studio.motion.show import Show
from studio.project.outputs import self_model_predictor, write_outputs
from studio.project.project import Project
from studio.project.project_format import DOC, SUFFIX
from studio.project.run import RunConfig, RunReport
from studio.project.sources import hash_source
from studio.project.state import Mount, ProjectError, same
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.source import read_first_mask
from studio.targets.video import VideoConfig

log = logging.getLogger(__name__)


class OtherProject(ProjectError):
    """The output folder holds a project of this name made from another source or with other settings."""


@dataclass(frozen=True)
class SourceSettings:
    """How a source becomes a project's frames, targets and keyframes (what ``project new`` sets)."""

    video: VideoConfig = field(default_factory=VideoConfig)  # sampling, binarising and framing of footage
    still: TargetConfig = field(default_factory=TargetConfig)  # binarising and framing of a still
    clustering: KeyframeConfig = field(default_factory=KeyframeConfig)  # keyframes by shape (tau)
    weights: LossConfig = field(default_factory=LossConfig)  # the loss weights of every keyframe
    box: tuple[int, int, int, int] | None = None  # raw colour footage: the object's first-frame box (x, y, w, h)
    first_mask: str | Path | None = None  # … or its first-frame mask image
    roll: str | float = "auto"  # the hand's mount roll: "auto" (one chosen for the whole show) or degrees


@dataclass
class VideoResult:
    """What :func:`imitate_video` made (plain data around the open project)."""

    project: Project  # the one-source project (open; its folder is OUT/<name>.shadow)
    report: RunReport  # what the run did: keyframes optimised and skipped, the show, late transitions
    files: dict[str, Path]  # the files written beside the project (studio.project.outputs)
    fresh: bool  # the project was made by this call (False: an existing one was reopened)

    @property
    def show(self) -> Show | None:
        """The planned show when it is current, else None (no show: ``report.message`` says why)."""
        p = self.project
        return p.show if p.show is not None and not p.is_show_stale() else None

    @property
    def thetas(self) -> np.ndarray:
        """``(K, 21)`` rad: the keyframes' poses in first-appearance order (finished ones only)."""
        from studio.sim.hand import load_hand

        names = load_hand().joint_names
        results = self.project.results
        done = [results[kf.id].theta(names) for kf in self.project.keyframes if kf.id in results]
        return np.stack(done) if done else np.zeros((0, len(names)))


def _settings_differ(project: Project, src: Path, settings: SourceSettings) -> list[str]:
    """What of ``settings`` (and the source) the existing ``project`` was not made with, in words."""
    s = project.state
    found = []
    if len(s.sources) != 1 or Path(s.sources[0].absolute) != src.resolve():
        found.append(f"its source is {[x.path for x in s.sources]}, not {src}")
    elif s.sources[0].sha256 != hash_source(src):
        found.append(f"{src} changed since the project read it")
    for name in ("video", "still", "clustering", "weights"):
        if not same(getattr(s, name), getattr(settings, name)):
            found.append(f"other {name} settings")
    if s.sources and s.sources[0].kind != "still":
        mask = None if settings.first_mask is None else read_first_mask(settings.first_mask)
        if s.sources[0].box != settings.box or not same(s.sources[0].first_mask, mask):
            found.append("another first-frame box or mask")
    return found


def source_project(
    src: str | Path,
    out: str | Path,
    settings: SourceSettings | None = None,
    fresh: bool = False,
    progress: ProgressFn | None = None,
) -> tuple[Project, bool]:
    """The one-source project ``out/<name>.shadow`` of ``src`` → ``(project, made now)``: reopened when it was made
    from the same source with the same settings, else made (``fresh``: an existing project there is removed
    first); a ProjectError when one made otherwise is in the way."""
    src, settings = Path(src), settings or SourceSettings()
    if not src.exists():
        raise ProjectError(f"source not found: {src}")
    path = Path(out) / f"{src.stem or 'source'}{SUFFIX}"
    if path.exists() and fresh:
        if not (path / DOC).is_file() and any(path.iterdir()):
            raise ProjectError(f"{path} is not a project folder; starting afresh removes only a project: move it")
        shutil.rmtree(path)
    if (path / DOC).is_file():
        project = Project.open(path)
        differ = _settings_differ(project, src, settings)
        if differ:
            raise OtherProject(f"{path} was made otherwise ({'; '.join(differ)}): start afresh to replace it")
        if not same(project.mount, _asked_mount(project.mount, settings.roll)):
            project.set_roll(settings.roll)  # another roll asked for: its keyframes are optimised again
        log.info("reopened %s: current keyframes are kept", path)
        return project, False
    mask = None if settings.first_mask is None else read_first_mask(settings.first_mask)
    project = Project.create(
        path, [src], title=src.stem, video=settings.video, still=settings.still, clustering=settings.clustering,
        weights=settings.weights, box=settings.box, first_mask=mask, progress=progress, roll=settings.roll,
    )  # fmt: skip
    return project, True


def _asked_mount(mount: Mount, roll: str | float) -> Mount:
    """The mount ``roll`` asks for, as the project would hold it: "auto" keeps a roll auto already chose."""
    asked = Mount.from_setting(roll)
    return mount if asked.auto and mount.auto else asked


def imitate_video(
    src: str | Path,
    out: str | Path | None = None,
    settings: SourceSettings | None = None,
    cfg: RunConfig | None = None,
    *,
    clip: Any = None,
    model_path: Path | None = None,
    fresh: bool = False,
    queue: JobQueue | None = None,
    cancel: threading.Event | None = None,
    on_job: Callable[[Job, str], None] | None = None,
    progress: ProgressFn | None = None,
    provenance: dict | None = None,
) -> VideoResult:
    """A video (a file, a GIF, a folder of frames; a still is a video of one frame) end to end: a one-source project
    in ``out`` (None: a new temporary folder), every keyframe optimised, the show planned at the video's clock, and
    the files written (module doc) → :class:`VideoResult`. ``cfg``: budgets, planner and late transitions
    (:class:`~studio.project.run.RunConfig`); ``clip``: a CLIP encoder for the CLIP terms (None: off); ``queue``:
    where the jobs run (default the project's; subscribe bars to it); ``cancel``: stops within a second, keeping
    the finished keyframes (files are still written); ``progress``: reading, segmentation and the review files."""
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="shadow-studio-"))
    if out.exists() and not out.is_dir():
        raise ProjectError(f"{out} is a file: give a folder for the project and its files")
    project, made = source_project(src, out, settings, fresh, progress)
    cfg = cfg or RunConfig()
    report = project.run(cfg, clip=clip, queue=queue, cancel=cancel, model_path=model_path, on_job=on_job)
    from studio.imitate.still import DEFAULT_MODEL

    base = {"sequence": _plain(cfg.sequence), "allow_late": cfg.allow_late, "model": str(model_path or DEFAULT_MODEL),
            "clip": getattr(clip, "name", None)}  # fmt: skip
    files = write_outputs(project, out, report, base | (provenance or {}), self_model_predictor(model_path), progress)
    return VideoResult(project, report, files, made)


def _plain(cfg: Any) -> Any:
    """A config as JSON-ready nested dicts."""
    import dataclasses
    import json

    return json.loads(json.dumps(dataclasses.asdict(cfg)))
