"""How the Optimise panel draws a job's events (mixed into :class:`widgets.optimise.OptimisePanel`): a bar per
stage, the overall bar ("2 of 5 keyframes done"), the live best shadow beside its target, the loss so far, the run's
message in the notebook's words and the job list. Only widget trait sets, from the panel's writer thread. And the
budgets list the panel starts its jobs with (:func:`budget_list`)."""

from __future__ import annotations

import html
import math
from functools import partial

import ipywidgets as w
import numpy as np

from studio.errors import count
from studio.imitate.config import PRESET_WORDS, PRESETS, STUDIO, SequenceConfig
from studio.jobs import JobEvent, JobState
from studio.project.run import RunReport
from widgets.images import background, mask_picture
from widgets.words import ALLOW_LATE, bar_label, late_lines, stage


def budget_list(sequence: SequenceConfig, gpu: bool | None = None) -> w.Dropdown:
    """The budgets list: the presets every verb's ``--preset`` names (``sequence``'s selected when it is one), and
    first, when ``sequence`` is none of them, "this studio's own" (value None: ``sequence`` itself). Without a GPU
    (``gpu``; None: whether torch sees CUDA, asked in the background once torch has loaded, so that the studio opens
    without waiting for torch) a preset whose search is far larger than the studio's says so."""
    chosen = next((name for name, cfg in PRESETS.items() if cfg == sequence), None)
    options = _budget_options(chosen, gpu is not False)
    dropdown = w.Dropdown(options=options, value=chosen, description="budgets", style={"description_width": "60px"},
                          layout=w.Layout(width="860px"), tooltip="the search and refinement budgets of every "
                          "keyframe (the same presets as the command line's)")  # fmt: skip
    if gpu is None:
        background(partial(_say_when_no_gpu, dropdown, chosen), "budgets-gpu")
    return dropdown


def _budget_options(chosen: str | None, gpu: bool) -> list[tuple[str, str | None]]:
    ours = PRESETS[STUDIO].first.batch * PRESETS[STUDIO].first.iterations

    def label(name: str, words: str) -> str:
        times = PRESETS[name].first.batch * PRESETS[name].first.iterations / ours
        slow = "" if gpu or times < 2 else f" — no GPU here: its search is {times:,.0f}× the studio's"
        return f"{name}: {words}{slow}"

    options: list[tuple[str, str | None]] = [(label(name, words), name) for name, words in PRESET_WORDS.items()]
    if chosen is None:
        options.insert(0, ("this studio's own (set where the studio was opened)", None))
    return options


def _say_when_no_gpu(dropdown: w.Dropdown, chosen: str | None) -> None:
    import torch

    if not torch.cuda.is_available():
        value = dropdown.value  # the artist's choice meanwhile stays chosen
        dropdown.options = _budget_options(chosen, gpu=False)
        dropdown.value = value


class OptimiseDrawing:
    """Drawing of ``OptimisePanel`` (it provides ``state``, ``cfg``, ``jobs``, the widgets and the followed job's
    fields: ``_following``, ``bars``, ``_bar_labels``, ``best``, ``last``, ``step``, ``_target_k``)."""

    def keyframes_of(self, job_id: int) -> list[int]:
        """The keyframe ids a job of this panel optimises (empty for another's)."""
        return next((list(job.meta.get("keyframes", [])) for job in list(self.jobs) if job.id == job_id), [])

    def job_line(self, job_id: int) -> str:
        """What a job of this panel does, in the artist's words: ``keyframe 3 (3 of 5)``, ``keyframes 0–4 together``,
        ``the show``."""
        job = next((j for j in list(self.jobs) if j.id == job_id), None)
        if job is None:
            return f"job #{job_id}"
        if job.kind == "plan":
            return "the show"
        if job.kind == "choose-roll":
            return "the mount roll"
        if job.kind == "imitate-together":
            ids = job.meta.get("keyframes", [])
            return f"keyframes {ids[0]}–{ids[-1]} together" if ids else "the keyframes together"
        ids = ", ".join(str(k) for k in job.meta.get("keyframes", []))
        of = job.meta.get("of")
        return f"keyframe {ids}" + (f" ({of[0]} of {of[1]})" if of else "")

    def _draw_event(self, e: JobEvent) -> bool:
        """One event drawn; True when it is a job's completion (its result was applied)."""
        if e.job_id != self._following and not e.final and e.stage not in ("", "start"):
            self._following, self.bars, self.best, self._bar_labels = e.job_id, {}, math.nan, {}
            self.bar_box.children = ()
        self.last, self.step = e, e.step
        if e.total > 0:
            bar = self.bars.get(e.stage)
            if bar is None:
                bar = self.bars[e.stage] = w.FloatProgress(min=0.0, max=1.0, style={"description_width": "240px"},
                                                           layout=w.Layout(width="560px"))  # fmt: skip
                self._bar_labels[e.stage] = bar_label(e.stage)
                self.bar_box.children = (*self.bar_box.children, bar)
            bar.value = min(1.0, e.step / e.total)
            bar.description = f"{self._bar_labels[e.stage]} {e.step:,}/{e.total:,}"
        self._draw_overall(e)
        if not math.isnan(e.best):  # the rendered loss of the pose on show (studio.imitate.live_best), which only
            self.best = e.best  # falls within a target; a later keyframe has another target, so it is not a minimum
            self.loss.value = f"best loss so far: <b>{self.best:.4f}</b> ({html.escape(e.stage)})"
        if e.shadow is not None:
            self.shown_shadow = np.asarray(e.shadow)
            self.shadow_image.value = mask_picture(self.shown_shadow, self.cfg.image_px)
            self._show_target(e)
        what = html.escape(self.job_line(e.job_id))
        if not e.final:
            self.status.value = f"{what}: {html.escape(stage(e.stage, e.total, e.item))} ({e.elapsed:.1f} s)"
            return False
        if e.error is not None:
            self.messages.say(str(e.error), error=True)
        done = e.state == JobState.DONE
        if done:
            if e.job_id == self._following:  # every stage of a finished job is complete, whatever it last reported
                for name, bar in self.bars.items():
                    bar.value, bar.description = 1.0, f"{self._bar_labels[name]}: done"
            self._show_result(e.job_id)
        return done

    def _draw_overall(self, e: JobEvent) -> None:
        """The run's overall bar: keyframes finished of those it optimises (``job.meta["of"]``)."""
        job = next((j for j in list(self.jobs) if j.id == e.job_id), None)
        of = None if job is None else job.meta.get("of")
        if of is None:
            if job is not None and job.kind == "plan" and e.final and e.state == JobState.DONE:
                self.overall.value, self.overall.description = 1.0, "show planned"
            return
        n, total = of
        finished = n if e.final and e.state == JobState.DONE else n - 1
        self.overall.layout.display = None
        self.overall.value = finished / total
        self.overall.description = f"{finished} of {count(total, 'keyframe')} done"

    def _report_text(self, report: RunReport) -> str:
        """A run's message in the notebook's words (what to tick, not a flag), with its late transitions."""
        text = report.message
        if report.too_fast:
            text += f". Tick '{ALLOW_LATE}' above (or in Export) to stretch them"
        if report.late:
            lines = late_lines(report.late)
            more = f"; and {len(lines) - 5} more" if len(lines) > 5 else ""
            text += f". Late: {'; '.join(lines[:5])}{more}"
        return text

    def _show_target(self, e: JobEvent) -> None:
        """The target of the keyframe whose shadow the event carries: a job's one keyframe, or of several (posed
        again last to first, :mod:`studio.imitate.together`) the one whose id the event's ``item`` names."""
        ids = self.keyframes_of(e.job_id)
        k = ids[0] if ids else None
        if e.item.isdigit() and int(e.item) in ids:  # the report names its keyframe (studio.imitate.together)
            k = int(e.item)
        if k is not None and k != self._target_k:
            self._target_k = k
            self.target_image.value = mask_picture(self.state.project.keyframe_masks(k)[0], self.cfg.image_px)

    def _show_result(self, job_id: int) -> None:
        """The applied result's shadow of the job's (last) keyframe, beside its target."""
        ids = [k for k in self.keyframes_of(job_id) if k in self.state.project.results]
        if not ids:
            return
        k = ids[-1]
        self._target_k = k
        self.target_image.value = mask_picture(self.state.project.keyframe_masks(k)[0], self.cfg.image_px)
        self.shown_shadow = np.asarray(self.state.project.results[k].shadow)
        self.shadow_image.value = mask_picture(self.shown_shadow, self.cfg.image_px)

    def _set_running(self, running: bool) -> None:
        self.cancel_button.disabled = not running
        for b in (*self.buttons.values(), self.mount.set_button, self.budget):
            b.disabled = running

    def _table(self) -> str:
        rows = self.state.queue.table()
        if not rows:
            return "<i>no jobs yet</i>"
        head = "<tr><th>#</th><th>job</th><th>state</th><th>stage</th><th>best</th><th>s</th></tr>"
        body = "".join(
            f"<tr><td>{r['id']}</td><td>{html.escape(job_name(r['kind'], r['title']))}</td>"
            f"<td>{r['state']}</td><td>{html.escape(stage(r['stage'], r['total']))} {r['step']:,}/{r['total']:,}</td>"
            f"<td>{_loss(r['best'])}</td><td>{r['elapsed']:.1f}</td></tr>"
            for r in rows[-12:]
        )  # fmt: skip
        return f"<table style='font-size:0.9em'>{head}{body}</table>"


def job_name(kind: str, title: str) -> str:
    """A job as the jobs list names it: its title where the title says what it does (``play horse``, ``show
    preview``), else its kind then its title (``imitate-keyframes keyframe 0``), never the kind twice."""
    verb = kind.split("-")[0]
    if not title:
        return kind
    return title if verb in title.lower().replace("-", " ").split() else f"{kind} {title}"


def _loss(value: float) -> str:
    return "" if math.isnan(value) else f"{value:.4f}"
