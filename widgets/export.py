"""The Export panel: plan the project's show, write and validate the show file, describe it, export CSV, play it.

A face of the engine (DESIGN §5.7): **plan** runs :func:`studio.project.run.plan_project_job` (the plan step of
``project run`` and of the Optimise tab) on the project's queue through the keyframes of :meth:`Project.show_timing`
("allow late transitions" stretches transitions too fast for the servos instead of refusing, and lists them),
applied by ``project.set_show``; **write** is :meth:`Project.export_show` to the path in the box (default next to
the project) read back by :func:`studio.motion.show.load_show`, which validates it; **show info** is what
``shadow-studio show-info`` prints in the artist's terms, with the late transitions, the ramp-in before the show and
the joints the soft limits stop (:mod:`widgets.show_text`), on the studio's calibration
(:mod:`widgets.calibration_file`, which play uses too: a show for another mount roll is refused in one line);
**CSV** is :func:`studio.motion.show.export_csv`; **play** runs :func:`studio.project.jobs.play_job` on the
built-in emulator or on the hand at a serial port (the Jog panel's bus when it is connected to that port, so its
e-stop stops the show; else a :class:`hardware.session.ServoSession` of its own, closed fail-safe when the job
ends), with progress and stop (a cancel: the player stops within a tick, torque as configured).

Job events arrive on the queue's thread: the panel only sets widget values there, at most ``redraw_hz`` times a
second (DESIGN §6); every error is a message in the panel, never a traceback. Playing and the jobs' events:
:mod:`widgets.export_jobs`.
"""

from __future__ import annotations

import html
import logging
from dataclasses import dataclass, replace
from pathlib import Path

import ipywidgets as w

from hardware.player import PlayerConfig
from hardware.session import ServoSession
from studio.errors import StudioError, count
from studio.jobs import Job
from studio.motion.errors import SegmentTiming
from studio.motion.plan import PlanConfig
from studio.motion.show import Show, export_csv, load_show
from studio.motion.video_timing import VideoTiming
from studio.project.run import plan_project_job
from studio.project.show_timing import ShowLayout
from studio.project.state import ProjectError
from studio.sim.hand import Hand, load_hand
from widgets.calibration_file import studio_calibration
from widgets.export_jobs import ExportJobs
from widgets.images import Messages, title
from widgets.real_vs_sim import real_vs_sim_view
from widgets.show_text import ProjectView, artist_lines, limits_line, ramp_line
from widgets.state import StudioState
from widgets.words import ALLOW_LATE, seconds

log = logging.getLogger(__name__)


@dataclass
class ExportConfig:
    """How the Export panel plans and plays."""

    allow_late: bool = True  # the "allow late transitions" box's start value: stretch too-fast moves, not no show
    redraw_hz: float = 10.0  # progress redraws per second at most, from the queue's thread (0, 30]
    layout: ShowLayout | None = None  # how the project's sources share the show clock (None: the defaults)
    plan: PlanConfig | None = None  # the planner (None: the defaults; its allow_late comes from the box)
    player: PlayerConfig | None = None  # how a show plays (None: the player's defaults: 40 Hz, torque held on stop)
    close_wait_s: float = 2.0  # closing the panel mid-show: how long to wait for the player to stop before closing


def default_show_path(state: StudioState) -> Path:
    """``NAME.show.json`` beside the project folder ``NAME.shadow``."""
    p = state.project.path
    return p.parent / f"{p.stem}.show.json"


class ExportPanel(ExportJobs):
    """The Export panel of one studio (``.widget``)."""

    def __init__(self, state: StudioState, cfg: ExportConfig | None = None, hand: Hand | None = None):
        self.state = state
        self.cfg = cfg or ExportConfig()
        self.hand = hand or load_hand()
        self.jobs: list[Job] = []  # the jobs this panel started, in order
        self._sessions: dict[Job, ServoSession] = {}  # servos this panel opened for a play job (closed when it ends)
        self._last_draw = 0.0
        self._timings: dict[Job, VideoTiming] = {}  # plan job → the timing it planned (names its late transitions)
        self.messages = Messages()
        self.allow_late = w.Checkbox(value=self.cfg.allow_late, description=ALLOW_LATE, indent=False,
                                     tooltip="stretch moves too fast for the servos: the show runs longer")  # fmt: skip
        self.plan_button = w.Button(description="plan show", button_style="primary")
        path = default_show_path(state)
        self.path = w.Text(value=str(path), description="show file", layout=w.Layout(width="520px"))
        self.write_button = w.Button(description="write + validate")
        self.validate_button = w.Button(description="validate file")
        self.info = w.HTML()
        self.csv_path = w.Text(value=str(path.with_suffix(".csv")), description="CSV file",
                               layout=w.Layout(width="520px"))  # fmt: skip
        self.degrees = w.Checkbox(value=False, description="degrees", indent=False)
        self.csv_button = w.Button(description="export CSV")
        self.target = w.ToggleButtons(options=[("emulator", "emulator"), ("hand (port)", "port")], value="emulator")
        self.port = w.Text(placeholder="/dev/ttyUSB0", description="port", layout=w.Layout(width="260px"))
        self.play_button = w.Button(description="play", icon="play", button_style="success")
        self.stop_button = w.Button(description="stop", icon="stop", button_style="danger", disabled=True)
        self.progress = w.FloatProgress(value=0.0, min=0.0, max=1.0, description="idle")
        self.status = w.Label("")
        self.plan_button.on_click(lambda _: self.plan())
        self.write_button.on_click(lambda _: self.write())
        self.validate_button.on_click(lambda _: self.validate())
        self.csv_button.on_click(lambda _: self.export_csv())
        self.play_button.on_click(lambda _: self.play())
        self.stop_button.on_click(lambda _: self.stop())
        self.target.observe(lambda _: self.show_info(), names="value")  # the ramp-in depends on where it plays
        self.real_vs_sim = real_vs_sim_view(state, self)  # play with a camera: real vs simulated shadows
        self.widget = w.VBox([
            title("Export"),
            w.HBox([self.plan_button, self.allow_late]),
            w.HBox([self.path, self.write_button, self.validate_button]),
            self.info,
            w.HBox([self.csv_path, self.degrees, self.csv_button]),
            w.HBox([self.target, self.port, self.play_button, self.stop_button]),
            w.HBox([self.progress, self.status]),
            self.messages.widget,
            self.real_vs_sim.widget,
        ])  # fmt: skip
        self._unsubscribe = state.queue.subscribe(self._on_event)
        self._stop_listening = state.on_change(self._on_change)
        self.show_info()

    # ---------------------------------------------------------------- the show
    def current_show(self) -> Show:
        """The project's planned show; a ProjectError saying what to do when there is none or it is stale."""
        p = self.state.project
        if p.show is None:
            raise ProjectError("no show planned yet: press 'plan show' (every keyframe needs a current result)")
        if p.is_show_stale():
            raise ProjectError("the planned show is stale (keyframes, results or settings changed): plan it again")
        return p.show

    def show_info(self, show: Show | None = None, note: str = "") -> None:
        """Describe ``show`` (default: the project's show) in the artist's terms (:mod:`widgets.show_text`)."""
        p = self.state.project
        show = show or p.show
        if show is None:
            self.info.value = "<i>no show planned yet</i>"
            return
        mine = p.show is not None and (show is p.show or (show.created, show.title) == (p.show.created, p.show.title))
        stale = "(stale: plan it again)\n" if mine and p.is_show_stale() else ""
        view = ProjectView()
        if mine:
            names = tuple(Path(s.path).name for s in p.sources)
            view = ProjectView(len(p.keyframes), names, None if stale else self._project_late(show))
        lines = artist_lines(show, view, self._hand_lines(show))
        text = note + ("\n" if note else "") + stale + "\n".join(lines)
        self.info.value = f"<pre style='margin:2px 0'>{html.escape(text)}</pre>"

    def _project_late(self, show: Show) -> list[dict] | None:
        """The project's show's late transitions by frame and keyframe (None when its timing cannot say)."""
        try:
            timing = self.state.project.show_timing(self.cfg.layout)
            late = [SegmentTiming(**d) for d in show.provenance.get("late_segments", [])]
            return timing.late_transitions(late, bool(show.provenance.get("home_added", False)))
        except (ProjectError, TypeError, IndexError) as e:  # another layout or a hand-edited show: by time
            log.debug("late transitions by time only: %s", e)
            return None

    def _hand_lines(self, show: Show) -> list[str]:
        """The ramp-in and limits lines for where the show would play, on the studio's calibration
        (:mod:`widgets.calibration_file`); one line saying why when it cannot be read."""
        try:
            cal = studio_calibration(self.state, self.hand, strict=True)
            ramp = ramp_line(show, cal, self.target.value == "emulator", self.cfg.player)
            return [ramp, limits_line(show, cal)]
        except (StudioError, ValueError) as e:
            log.debug("no ramp-in or limits line: %s", e)
            return [f"calibration:  {e}"]

    def plan(self) -> Job | None:
        """Plan the show as a job on the project's queue (applied by ``set_show`` when it completes)."""

        def go() -> Job:
            timing = self.state.project.show_timing(self.cfg.layout)
            base = self.cfg.plan or PlanConfig()
            cfg = replace(base, timing=replace(base.timing, allow_late=bool(self.allow_late.value)))
            job = plan_project_job(self.state.project, timing.keyframes, cfg)
            self._timings[job] = timing
            try:
                return self._submit(job)
            except BaseException:
                self._timings.pop(job, None)
                raise

        return self.messages.run(go)

    def write(self) -> Path | None:
        """Write the planned show to the path in the box, then read it back (validated)."""

        def go() -> Path:
            out = self.state.project.export_show(Path(self.path.value).expanduser())
            show = load_show(out, self.hand)
            self.show_info(show, f"{out}: valid show, version {show.format_version}")
            self.messages.say(f"wrote {out} and validated it")
            return out

        return self.messages.run(go)

    def validate(self) -> Show | None:
        """Validate the show file at the path in the box; its info when valid, every problem when not."""

        def go() -> Show:
            path = Path(self.path.value).expanduser()
            show = load_show(path, self.hand)
            self.show_info(show, f"{path}: valid show, version {show.format_version}")
            self.messages.say(f"{path}: valid, {count(len(show.times), 'sample')}, {seconds(show.duration, 3)}")
            return show

        return self.messages.run(go)

    def export_csv(self) -> Path | None:
        """The planned show's samples as CSV at the path in the box (t, one column per joint)."""

        def go() -> Path:
            out = export_csv(self.current_show(), Path(self.csv_path.value).expanduser(), degrees=self.degrees.value)
            self.messages.say(f"wrote {out}")
            return out

        return self.messages.run(go)

    def _on_change(self, what: str) -> None:
        if what == "hardware":  # the Rig panel saved the studio's calibration: the ramp-in and limits lines
            self.show_info()
        if what == "project":
            self.show_info()

    def close(self) -> None:
        """Stop listening. A plan job keeps running on the project's queue (:meth:`stop` cancels it); a show playing
        on servos this panel opened is stopped (within a tick) and its servos closed fail-safe, since no one would be
        left to close them."""
        self._unsubscribe()
        self._stop_listening()
        self.real_vs_sim.close()
        for job, session in list(self._sessions.items()):
            job.cancel()
            if not job.wait(self.cfg.close_wait_s).finished:
                log.warning("%s went on past %.1f s: its servos closed anyway", job.title, self.cfg.close_wait_s)
            self._sessions.pop(job, None)
            session.close()  # stopped, torque as the player's config says; never raises


def export_panel(state: StudioState, cfg: ExportConfig | None = None) -> ExportPanel:
    """The Export panel (its widget is ``.widget``)."""
    return ExportPanel(state, cfg)
