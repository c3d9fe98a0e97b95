"""An artist's work as a project folder ``NAME.shadow/`` with a small typed API (DESIGN §4 "The studio's state").

    project = Project.create("horse.shadow", sources=["horse.gif"])   # frames, expressive masks, keyframes
    project.move_frame(5, k=0)                                         # every edit is saved atomically …
    project.undo()                                                     # … and can be undone / redone
    report = project.run()                                             # every missing or stale keyframe, the show
    project.status()                                                   # missing/stale keyframes, sources, show
    keyframes = project.show_timing().keyframes                        # the planner's, on the show clock

Every edit makes a new :class:`~studio.project.project_format.ProjectState` (plain data, arrays read-only), saves
it (:func:`~studio.project.project_format.save_state`: a save killed midway leaves the previous project readable)
and records the change, so :meth:`Project.undo` and :meth:`Project.redo` walk the list of changes (results and
shows that jobs apply are edits too; :mod:`.history`). An edit that raises, or changes nothing, records nothing.
The history lives as long as the ``Project`` object. One process writes a project at a time (:mod:`.lock`: a second
is refused, saying who holds it; a save never goes over another process's newer save); one ``Project`` object's
methods may be called from several threads (a lock serialises them). A project reads and writes only its own files
(:mod:`.containment`), and a damaged ``project.json`` is one clear error (:mod:`.project_read`).

Opening never fails for a moved or deleted source: it is listed in :attr:`Project.missing_sources` with its old
path (and a warning); edits that must re-read it ask for :meth:`Project.relink_source`. A source whose content
changed since it was read is listed in :attr:`Project.changed_sources`, and the results from it are stale until
:meth:`Project.reload_sources`. Results (and the show) computed from inputs that differ from the current ones, and
results a run found it must optimise again, are stale (:meth:`Project.is_stale`, :meth:`Project.stale_keyframes`),
never reported as current.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn
from studio.imitate.config import LossConfig
from studio.motion.show import Show, save_show
from studio.motion.video_timing import VideoTiming
from studio.project import edits
from studio.project.containment import check_new_folder
from studio.project.editing import KEEP, Editing, mask_arg
from studio.project.history import Change, History, now_text
from studio.project.inputs import keyframe_inputs, show_inputs
from studio.project.keyframe_editing import KeyframeEditing
from studio.project.lock import WriterLock, stamp
from studio.project.project_format import DOC, SUFFIX, save_state
from studio.project.project_read import load_state
from studio.project.run import Running
from studio.project.show_timing import ShowLayout, project_timing
from studio.project.sources import check_sources, load_sources, make_source
from studio.project.state import (
    Frame,
    Keyframe,
    Mount,
    PoseResult,
    ProjectError,
    ProjectState,
    ShowNeeded,
    Source,
    frozen,
)
from studio.project.status import MissingSource, ProjectStatus
from studio.project.summary import summarise
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig

__all__ = ["KEEP", "Change", "MissingSource", "Project", "ProjectError", "ShowLayout"]

log = logging.getLogger(__name__)


class Project(Editing, KeyframeEditing, Running, History):
    """An open project folder (module doc). Make one with :meth:`create` or :meth:`open`."""

    _now = staticmethod(now_text)

    def __init__(self, path: Path, state: ProjectState):
        self.path = Path(path)
        self._state = state
        self._undo: list[Change] = []
        self._redo: list[Change] = []
        self._lock = threading.RLock()
        self._writer = WriterLock(self.path)  # one writing process at a time (studio.project.lock)
        self._stamp = stamp(self.path)  # project.json as this object last read or wrote it
        self.missing_sources: list[MissingSource] = []
        self.changed_sources: list[int] = []
        self._orders: list[tuple[tuple, list]] = []  # (clustering_reads, merge orders), newest first (merge_orders)
        self._check_sources()

    # ---------------------------------------------------------------- opening
    @classmethod
    def create(
        cls,
        path: str | Path,
        sources: Sequence[str | Path],
        title: str | None = None,
        video: VideoConfig | None = None,
        still: TargetConfig | None = None,
        clustering: KeyframeConfig | None = None,
        weights: LossConfig | None = None,
        box: tuple[int, int, int, int] | None = None,
        first_mask: np.ndarray | str | Path | None = None,
        progress: ProgressFn | None = None,
        roll: str | float = "auto",
    ) -> Project:
        """A new project at ``path`` (a folder named ``*.shadow``, not yet a project) from ``sources`` (stills,
        videos, frame folders): frames, expressive masks and keyframes at the given settings (defaults: the
        configs'). ``box``/``first_mask`` segment colour footage (every video source's first frame); ``roll``: the
        mount roll, ``"auto"`` (chosen when the keyframes are first optimised) or degrees."""
        path = Path(path)
        if path.suffix != SUFFIX:
            raise ProjectError(f"a project folder's name ends in {SUFFIX}: {path} (try {path.name}{SUFFIX})")
        if (path / DOC).exists():
            raise ProjectError(f"a project already exists at {path}: open it, or choose another name")
        check_new_folder(path)
        if not sources:
            raise ProjectError("a project needs at least one source (a still, a video or a folder of frames)")
        srcs = [make_source(s) for s in sources]
        mask = None if first_mask is None else mask_arg(first_mask, None, "the first mask")
        path_text = str(first_mask) if isinstance(first_mask, (str, Path)) else None
        seg = {"box": box, "first_mask": mask, "first_mask_path": path_text}
        srcs = [s if s.kind == "still" else replace(s, **seg) for s in srcs]
        video, still = video or VideoConfig(), still or TargetConfig()
        clustering, weights = clustering or KeyframeConfig(), weights or LossConfig()
        loaded, frames, targets, auto = load_sources(srcs, [Path(s.absolute) for s in srcs], video, still, progress)
        state = ProjectState(
            title=title or path.stem, created=now_text(), sources=loaded, video=video, still=still,
            clustering=clustering, weights=weights, frames=frames, targets=frozen(targets), auto=frozen(auto),
            additions={}, erasures={}, keyframes=(), next_id=0, results={}, mount=Mount.from_setting(roll),
        )  # fmt: skip
        keyframes, next_id = edits.cluster(frames, edits.combined_masks(state), clustering, shadows=state.targets)
        state = replace(state, keyframes=keyframes, next_id=next_id)
        check_new_folder(path)  # still nothing there after the sources were read
        path.mkdir(parents=True, exist_ok=True)
        with WriterLock(path).hold("project new"):
            if (path / DOC).exists():
                raise ProjectError(f"a project was made at {path} meanwhile: open it, or choose another name")
            save_state(path, state, state.created)
        log.info("project %s: %d sources, %d frames, %d keyframes", path, len(loaded), len(frames), len(keyframes))
        return cls(path, state)

    @classmethod
    def open(cls, path: str | Path) -> Project:
        """Open the project at ``path``; a ProjectError for a damaged folder or a newer format version."""
        path = Path(path)
        for attempt in range(50):  # another process saving meanwhile: read again, so the stamp matches the state
            before = stamp(path)
            try:
                state, _ = load_state(path)
            except ProjectError:
                if stamp(path) == before:  # damaged as it stands, not a save in flight
                    raise
                time.sleep(0.01 * attempt)
                continue
            project = cls(path, state)
            if project._stamp == before:
                return project
        raise ProjectError(f"{path} keeps changing while it is read (another process is saving it); try again")

    def _check_sources(self) -> None:
        self.missing_sources, self.changed_sources = check_sources(self._state.sources, self.path)

    # ---------------------------------------------------------------- reading
    @property
    def state(self) -> ProjectState:
        """The current state (plain data; read-only arrays)."""
        return self._state

    @property
    def sources(self) -> tuple[Source, ...]:
        return self._state.sources

    @property
    def frames(self) -> tuple[Frame, ...]:
        return self._state.frames

    @property
    def keyframes(self) -> tuple[Keyframe, ...]:
        """In order of first appearance."""
        return self._state.keyframes

    @property
    def weights(self) -> LossConfig:
        return self._state.weights

    @property
    def mount(self) -> Mount:
        """The hand's mount roll for the show (``mount.roll`` rad; ``auto``: the studio chooses it)."""
        return self._state.mount

    @property
    def results(self) -> dict[int, PoseResult]:
        """Keyframe id → its result (current or stale: :meth:`is_stale`)."""
        return dict(self._state.results)

    @property
    def show(self) -> Show | None:
        """The planned show, if any (current or stale: :meth:`is_show_stale`)."""
        return self._state.show

    def combined_masks(self) -> np.ndarray:
        """The expressive masks the artist sees ``(N, S, S)`` uint8: automatic ∪ additions minus erasures."""
        return edits.combined_masks(self._state)

    def combined_mask(self, frame: int) -> np.ndarray:
        """Frame ``frame``'s expressive mask as the artist sees it, ``(S, S)`` uint8 (:meth:`combined_masks`' row)."""
        return edits.combined_mask(self._state, frame)

    def assignment(self) -> np.ndarray:
        """``(N,)`` int: each frame's keyframe as its position in :attr:`keyframes` (first-appearance order)."""
        return edits.assignment(self._state.keyframes, len(self._state.frames))

    def keyframe_masks(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Keyframe ``k``'s optimisation targets: its representative's mask and expressive mask, ``(S, S)`` each."""
        rep = self._state.keyframe(k).representative
        return self._state.targets[rep], self.combined_mask(rep)

    def keyframe_inputs(self, k: int) -> str:
        """The fingerprint of keyframe ``k``'s inputs now (capture it before computing a result)."""
        return keyframe_inputs(self._state, k)

    def show_inputs(self) -> str:
        """The fingerprint of what a show would be planned from now."""
        return show_inputs(self._state)

    def _changed(self, k: int) -> bool:
        kf = self._state.keyframe(k)
        return self._state.frames[kf.representative].source in self.changed_sources

    def is_stale(self, k: int) -> bool:
        """Whether keyframe ``k`` has a result computed from inputs that have changed since, or that a run found it
        must optimise again (``PoseResult.awaits``; False: none or current)."""
        r = self._state.results.get(k)
        return r is not None and (self._changed(k) or r.awaits == "again" or r.inputs != self.keyframe_inputs(k))

    def stale_keyframes(self) -> list[int]:
        """Ids of the keyframes whose result is stale, in first-appearance order."""
        return [kf.id for kf in self._state.keyframes if self.is_stale(kf.id)]

    def missing_keyframes(self) -> list[int]:
        """Ids of the keyframes with no result yet."""
        return [kf.id for kf in self._state.keyframes if kf.id not in self._state.results]

    def pending_keyframes(self) -> list[int]:
        """Ids of the keyframes whose result is missing or stale (what a run computes), first-appearance order."""
        return [kf.id for kf in self._state.keyframes if kf.id not in self._state.results or self.is_stale(kf.id)]

    def is_show_stale(self) -> bool:
        """Whether the planned show was planned from inputs that have changed since (False when there is none)."""
        s = self._state
        return s.show is not None and (bool(self.changed_sources) or s.show_inputs != self.show_inputs())

    def show_timing(self, layout: ShowLayout | None = None) -> VideoTiming:
        """The planner's keyframes of this project on the show clock (``.keyframes``; :mod:`.show_timing`): each
        video at its own clock, a still held, sources one after another; a ProjectError when a keyframe has no
        current result yet."""
        from studio.sim.hand import load_hand

        return project_timing(self._state, self.status(), load_hand().joint_names, layout)

    def frame_show_times(self) -> np.ndarray | None:
        """Show time ``(N,)`` s at which each frame starts to play in the current show (None: no current show)."""
        from studio.project.preview_clock import frame_show_times

        return frame_show_times(self._state, self.status())

    def export_show(self, out: str | Path) -> Path:
        """Write the planned show to ``out`` (a show file); a ProjectError when none is planned or it is stale."""
        if self._state.show is None:
            raise ShowNeeded(f"{self.path} has no planned show yet: optimise its keyframes and plan the show first")
        if self.is_show_stale():
            raise ShowNeeded(
                f"{self.path}'s planned show is stale (its sources, settings, keyframes or results changed since it "
                "was planned): plan it again"
            )
        return save_show(self._state.show, out)

    def summary(self) -> dict:
        """Plain data for ``project info`` and the widgets (:func:`studio.project.summary.summarise`)."""
        return summarise(self._state, self.status())

    def status(self) -> ProjectStatus:
        """Where the project stands now (:class:`~studio.project.status.ProjectStatus`, plain data)."""
        with self._lock:
            return ProjectStatus(
                path=str(self.path), missing_sources=tuple(self.missing_sources),
                changed_sources=tuple(self.changed_sources), missing=tuple(self.missing_keyframes()),
                stale=tuple(self.stale_keyframes()), pending=tuple(self.pending_keyframes()),
                show_stale=self.is_show_stale(), can_undo=self.can_undo, can_redo=self.can_redo,
            )  # fmt: skip
