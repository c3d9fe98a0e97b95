"""The Optimise panel: start an optimisation (this keyframe, every missing or stale keyframe, or the whole video) on
the budgets chosen (a preset, as ``--preset``), cancel it, the overall progress ("keyframe 3 (3 of 5)") and a bar per
stage, the live best shadow beside the target, the loss so far, the job list. "All stale" plans the show too,
stretching transitions too fast for the servos when "allow late transitions" is ticked (as in Export).

On a machine without the retrieval index yet (the searches' first answers, once per machine, then cached), the panel
builds it in the background as a job on the project's queue, with its own progress line (:mod:`widgets.index_warmup`).

    panel = OptimisePanel(state, OptimiseConfig(sequence=...))   # panel.widget goes in the notebook
    panel.start("keyframe")          # or "stale" (what `project run` does) / "video"; panel.cancel()
    panel.refresh()                  # draw every pending job event now (tests; the panel's writer does it itself)

The work is :meth:`studio.project.project.Project.run` (what ``project run``, ``imitate`` and ``imitate-video`` run),
told which keyframes: the one in view, the keyframes of its source (``source_keyframes``), or every missing or stale
one and then the show. Its jobs run on ``state.queue``'s worker thread, so the kernel stays free. Events reach the
panel through a queue subscriber that only stores them; one writer thread per panel draws them at most
``redraw_hz`` times a second with widget trait sets alone (DESIGN §6: never ``print`` or ``with out:`` from a
thread). A job that completes applies its result through the Project API (one undoable edit per keyframe); a
cancelled or failed one leaves the project as it was.
"""

from __future__ import annotations

import html
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import ipywidgets as w
import numpy as np

from studio.imitate.config import CPU_SEQUENCE, PRESETS, SequenceConfig
from studio.jobs import Job, JobEvent
from studio.project.run import RUN_JOB_KINDS, RunConfig, RunReport
from studio.project.run_spread import source_keyframes
from widgets.images import Messages, frame_picture, mask_picture, title
from widgets.index_warmup import IndexWarmup
from widgets.mount import MountControl, mount_line
from widgets.optimise_view import OptimiseDrawing, budget_list
from widgets.state import StudioState
from widgets.weights import clip_encoder
from widgets.words import ALLOW_LATE

log = logging.getLogger(__name__)

KINDS = ("keyframe", "stale", "video")  # what start() optimises: the keyframe in view, missing/stale ones, a video
STALE_TIP = "every missing or stale keyframe, what a stopped run still owes, then the show"


@dataclass(frozen=True)
class OptimiseConfig:
    """What the panel's jobs run and how it draws."""

    sequence: SequenceConfig = CPU_SEQUENCE  # budgets of every job until another preset is chosen (studio's)
    allow_late: bool = False  # the "allow late transitions" box's start value: "All stale" then stretches moves
    warm_index: bool = True  # build the retrieval index in the background when it is not cached yet (module doc)
    index: Any = None  # the RetrievalConfig of that index (None: the searches' own; tests give a small one)
    redraw_hz: float = 10.0  # the most redraws a second while a job reports (DESIGN §6: 10–30 Hz)
    image_px: int = 192  # side of the target and shadow images, px


class OptimisePanel(OptimiseDrawing):
    """The Optimise panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState, cfg: OptimiseConfig | None = None):
        self.state = state
        self.cfg = cfg or OptimiseConfig()
        self.messages = Messages()
        self.jobs: list[Job] = []  # the jobs this panel started (run_project's included)
        self.report: RunReport | None = None  # the last "stale" run's report
        self.last: JobEvent | None = None  # the newest event drawn
        self.step = 0  # the newest drawn event's step within its stage
        self.best = math.nan  # the newest stage's best loss so far, of the job followed (stages are not compared)
        self.shown_shadow: np.ndarray | None = None  # the shadow beside the target now (a preview or a result)
        self.bars: dict[str, w.FloatProgress] = {}  # stage → its bar, for the job followed
        self._following: int | None = None
        self._run: threading.Thread | None = None
        self._run_cancel = threading.Event()
        self._pending: deque[JobEvent] = deque()
        self._wake = threading.Condition()
        self._draw = threading.RLock()
        self._closed = False
        self._report_shown = False
        self._target_k: int | None = None  # the keyframe whose target is shown
        self._run_floor: int | None = None  # while a "stale" run goes: jobs numbered above this are its
        self.warmup = IndexWarmup(state, self.cfg.index, on_known=self._notify)  # the index's background build
        self._bar_labels: dict[str, str] = {}  # stage → what its bar says before the count

        px = self.cfg.image_px
        self.buttons = {
            "keyframe": w.Button(description="This keyframe", icon="play", tooltip="optimise the keyframe in view"),
            "stale": w.Button(description="All stale", icon="forward", tooltip=STALE_TIP),
            "video": w.Button(description="Whole video", icon="film", tooltip="the keyframes of this source"),
        }
        for kind, b in self.buttons.items():
            b.on_click(lambda _, kind=kind: self.start(kind))
        self.cancel_button = w.Button(description="Cancel", icon="stop", button_style="danger", disabled=True)
        self.cancel_button.on_click(lambda _: self.cancel())
        self.budget = budget_list(self.cfg.sequence)
        self.allow_late = w.Checkbox(value=self.cfg.allow_late, description=ALLOW_LATE, indent=False,
                                     tooltip="stretch moves too fast for the servos: the show runs longer")  # fmt: skip
        self.status = w.HTML("idle")
        self.overall = w.FloatProgress(min=0.0, max=1.0, description="overall", style={"description_width": "240px"},
                                       layout=w.Layout(width="560px", display="none"))  # fmt: skip
        self.loss = w.HTML("")
        self.bar_box = w.VBox([])
        self.target_image = frame_picture(px, mask_picture(None, px))
        self.shadow_image = frame_picture(px, mask_picture(None, px))
        self.job_list = w.HTML("")
        pictures = w.HBox([w.VBox([w.HTML("target"), self.target_image]),
                           w.VBox([w.HTML("best shadow"), self.shadow_image])])  # fmt: skip
        self.mount = MountControl(state, self.messages.say)
        self.widget = w.VBox([
            title("Optimise"), self.mount.widget, self.budget, w.HBox([*self.buttons.values(), self.cancel_button]),
            self.allow_late, self.warmup.line, self.status, self.overall, self.bar_box,
            self.loss, pictures, w.HTML("<b>jobs</b>"), self.job_list, self.messages.widget,
        ])  # fmt: skip
        self._unsubscribe = state.queue.subscribe(self._on_event)
        self._stop_listening = state.on_change(self._on_change)
        self._writer = threading.Thread(target=self._write, name="optimise-panel", daemon=True)
        self._writer.start()
        self.show_selection()
        if self.cfg.warm_index:
            self.warmup.start()

    # ---------------------------------------------------------------- what is in view
    def keyframe_in_view(self) -> int:
        """The selected keyframe id, else the keyframe of the selected frame."""
        p, sel = self.state.project, self.state.selection
        if sel.keyframe is not None:
            return sel.keyframe
        if not p.keyframes:
            raise ValueError("this project has no keyframes to optimise")
        return p.keyframes[int(p.assignment()[sel.frame])].id

    def show_selection(self) -> None:
        """The keyframe in view's target, and its result's shadow when it has one."""
        with self._draw:
            p, px = self.state.project, self.cfg.image_px
            try:
                k = self.keyframe_in_view()
            except (ValueError, KeyError, IndexError):
                self.target_image.value = self.shadow_image.value = mask_picture(None, px)
                return
            self.target_image.value = mask_picture(p.keyframe_masks(k)[0], px)
            result = p.results.get(k)
            self.shown_shadow = None if result is None else np.asarray(result.shadow)
            self.shadow_image.value = mask_picture(self.shown_shadow, px)

    def _on_change(self, what: str) -> None:
        if what == "project":
            self.mount.refresh()
        if what in ("selection", "project") and not self.busy:
            self.show_selection()

    # ---------------------------------------------------------------- start and cancel
    @property
    def busy(self) -> bool:
        """Whether a job this panel started (or its run) is still going."""
        return any(not j.finished for j in self.jobs) or (self._run is not None and self._run.is_alive())

    def start(self, kind: str) -> None:
        """Optimise ``kind`` (:data:`KINDS`) on the project's queue: the project's run (``Project.run``) goes on in
        its own thread, submitting its jobs one after another; each joins :attr:`jobs` as it is submitted. Errors
        are shown in the panel."""
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, not {kind!r}")
        if self.busy:
            self.messages.say("an optimisation is running: cancel it first, or wait for it", error=True)
            return
        self.messages.run(self._start, kind)
        self._set_running(self.busy)
        self.refresh()

    def _start(self, kind: str) -> None:
        p = self.state.project
        use_clip = p.weights.use_clip  # the encoder is found (and loaded) by the run's thread: the kernel stays free
        keyframes = None
        if kind != "stale":
            k = self.keyframe_in_view()
            keyframes = [k] if kind == "keyframe" else source_keyframes(p, k)
        self._run_cancel = threading.Event()
        self.report, self._report_shown = None, False
        self.overall.value, self.overall.layout.display = 0.0, "none"
        self._run_floor = len(self.state.queue.jobs())
        self._run = threading.Thread(target=self._run_jobs, args=(use_clip, keyframes), name="optimise-run",
                                     daemon=True)  # fmt: skip
        self._run.start()
        what = {"keyframe": "the keyframe in view", "video": "the keyframes of this source",
                "stale": "every missing or stale keyframe, then the show"}[kind]  # fmt: skip
        later = " (after the retrieval index, first use only)" if self.warmup.building else ""
        self.status.value = f"optimising {what}{later}"

    def _run_jobs(self, use_clip: bool, keyframes: list[int] | None) -> None:
        """The project's run in its own thread (it waits for each job); the panel draws its jobs' events as any."""
        chosen = self.budget.value  # a preset's name (--preset), or None: the panel's own budgets
        cfg = RunConfig(sequence=PRESETS.get(chosen, self.cfg.sequence), allow_late=bool(self.allow_late.value))
        try:
            clip = clip_encoder(self.state) if use_clip else None
            self.report = self.state.project.run(cfg, clip=clip, queue=self.state.queue, cancel=self._run_cancel,
                                                 on_job=lambda job, what: self.jobs.append(job), keyframes=keyframes,
                                                 plan=keyframes is None)  # fmt: skip
        except Exception as e:  # shown by the writer (a ProjectError says what happened)
            self.report = RunReport(str(self.state.project.path), message=f"{type(e).__name__}: {e}")
        self._notify()

    def cancel(self) -> bool:
        """Cancel what this panel started (the final events come within a second); False when nothing ran."""
        running = self.busy
        self._run_cancel.set()
        for job in self.jobs:
            job.cancel()
        self.refresh()
        return running

    # ---------------------------------------------------------------- events → widgets
    def _on_event(self, event: JobEvent) -> None:
        """The queue's subscriber (its thread): store the event and wake the writer, nothing more."""
        with self._wake:
            self._pending.append(event)
            self._wake.notify()

    def _notify(self) -> None:
        with self._wake:
            self._wake.notify()

    def _write(self) -> None:
        """The panel's one writer thread: draws pending events at most ``redraw_hz`` times a second."""
        period = 1.0 / self.cfg.redraw_hz
        last = 0.0
        while True:
            with self._wake:
                while not self._pending and not self._closed and not self._run_done():
                    self._wake.wait(0.5)
                if self._closed:
                    return
            time.sleep(max(0.0, last + period - time.monotonic()))
            last = time.monotonic()
            try:
                self.refresh()
            except Exception as e:  # a redraw must never kill the writer, nor print a traceback into the notebook
                log.debug("the Optimise panel failed to redraw", exc_info=True)
                self.messages.say(f"the panel could not redraw ({type(e).__name__}: {e})", error=True)

    def _run_done(self) -> bool:
        return self.report is not None and not self._report_shown

    def _mine(self, job_id: int) -> bool:
        running = self._run is not None and (self._run.is_alive() or not self._report_shown)
        if self.warmup.owns(job_id):
            return False  # drawn on its own line
        return any(j.id == job_id for j in list(self.jobs)) or (
            running and self._run_floor is not None and job_id > self._run_floor
            and self.state.queue.get(job_id).kind in RUN_JOB_KINDS  # not another panel's (a source added meanwhile)
        )  # fmt: skip

    def refresh(self) -> None:
        """Draw every pending event now (thread-safe; the writer calls it, tests may too)."""
        with self._draw:
            with self._wake:
                events = list(self._pending)
                self._pending.clear()
            applied = False
            for e in events:
                if self.warmup.owns(e.job_id):
                    self.warmup.draw(e)
                elif self._mine(e.job_id):
                    applied |= self._draw_event(e)
            if self.report is not None and not self._report_shown:
                self._report_shown = True
                self.messages.say(self._report_text(self.report), error=self.report.error is not None)
            self.job_list.value = self._table()
            self._set_running(self.busy)
            if applied or self._report_shown:
                self.mount.line.value = mount_line(self.state.project)  # a run may have chosen the roll
            if not self.busy and self.last is not None and self.last.final:
                self.status.value = f"{html.escape(self.job_line(self.last.job_id))}: {self.last.state.value}"
        if applied:
            self.state.changed("project")  # other panels show the new results

    def close(self) -> None:
        """Cancel what is running, stop listening and stop the writer."""
        self.cancel()
        self._unsubscribe()
        self._stop_listening()
        with self._wake:
            self._closed = True
            self._wake.notify()
        self._writer.join(2.0)


def optimise_panel(state: StudioState, cfg: OptimiseConfig | None = None) -> OptimisePanel:
    """The Optimise panel over ``state`` (its ``.widget`` is what the notebook shows)."""
    return OptimisePanel(state, cfg)
