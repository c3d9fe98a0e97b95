"""What the Export panel runs as jobs (mixed into :class:`widgets.export.ExportPanel`): play the planned show on the
built-in emulator or on the hand at a serial port (the Jog panel's bus when it is connected to that port, so its
e-stop stops the show; else a :class:`hardware.session.ServoSession` of its own, closed fail-safe when the job ends),
stop, and draw every job's events: progress at most ``redraw_hz`` times a second from the queue's thread, and a
finished plan or play in the artist's words (a show too fast for the servos names its late transitions)."""

from __future__ import annotations

import logging
import time

from hardware.player import PlayerConfig
from hardware.session import ServoSession
from hardware.show_checks import check_mount, check_show_hand
from studio.errors import count
from studio.jobs import Job, JobEvent, JobState
from studio.project.play import play_job
from studio.project.run_report import TooFast
from widgets.calibration_file import calibration_path, studio_calibration
from widgets.words import ALLOW_LATE, late_lines, seconds

log = logging.getLogger(__name__)


class ExportJobs:
    """Jobs of ``ExportPanel`` (it provides ``state``, ``hand``, ``cfg``, ``jobs``, ``_sessions``, ``_timings``,
    ``_last_draw``, ``messages``, the widgets, ``current_show`` and ``show_info``). A show plays on the studio's
    calibration (:mod:`widgets.calibration_file`), refused in one line when it records another mount roll."""

    def play(self) -> Job | None:
        """Play the planned show on the emulator or on the hand at the port, as a job."""
        return self.messages.run(self._play)

    def _play(self) -> Job:
        show = self.current_show()
        cal = studio_calibration(self.state, self.hand, strict=True)  # the artist's hand and rig, as Jog and Live
        check_show_hand(show.hand_hash, self.hand)  # refused here, in one line, before any servo is opened
        check_mount(show.roll, cal, calibration_path(self.state))
        bus, session = None, None
        if self.target.value == "port":
            port = self.port.value.strip()
            if not port:
                raise ValueError(
                    "type the serial port of the servo adapter (e.g. /dev/ttyUSB0), or play on the emulator"
                )
            jog = self.state.extras.get("jog")
            if jog is not None and jog.bus is not None and jog.bus.config.port == port:
                bus = jog.bus  # the Jog panel's: its e-stop stops the show
            else:
                release = not (self.cfg.player or PlayerConfig()).hold_torque_on_stop  # as the player leaves it
                session = ServoSession(port, calibration=cal, release_on_close=release).open()
                bus = session.bus
        job = play_job(show, calibration=cal, config=self.cfg.player, bus=bus, title=f"play {show.title}")
        try:
            self._submit(job, session)
        except BaseException:
            if session is not None:
                session.close()
            raise
        return job

    def stop(self) -> bool:
        """Cancel this panel's running or queued jobs (a show stops within a tick); whether any was."""
        stopped = [j.cancel() for j in self.jobs if not j.finished]
        if any(stopped):
            self.messages.say("stopping…")
        return any(stopped)

    def _submit(self, job: Job, session: ServoSession | None = None) -> Job:
        self.stop_button.disabled = False
        self.progress.description, self.progress.value = job.kind, 0.0
        self.status.value = f"{job.title}: queued"
        if session is not None:
            self._sessions[job] = session
        self.jobs.append(job)
        try:
            self.state.queue.submit(job)
        except BaseException:
            self.jobs.remove(job)
            self._sessions.pop(job, None)
            raise
        return job

    # ---------------------------------------------------------------- job events (the queue's thread)
    def _on_event(self, e: JobEvent) -> None:
        try:
            self._draw(e)
        except Exception:  # a redraw must never disturb the queue; logged quietly, no traceback in the notebook
            log.debug("the Export panel failed to draw a job event", exc_info=True)

    def _draw(self, e: JobEvent) -> None:
        job = next((j for j in list(self.jobs) if j.id == e.job_id and j.id), None)
        if job is None:
            return
        now = time.monotonic()
        if not e.final and now - self._last_draw < 1.0 / self.cfg.redraw_hz:
            return  # throttled: the next event (or the final one) draws
        self._last_draw = now
        if not e.final:
            self.progress.description = e.stage or job.kind
            self.progress.value = e.fraction if e.total > 0 else 0.0
            self.status.value = f"{job.title}: {e.stage} {e.step}/{e.total}" if e.total else f"{job.title}: {e.stage}"
            return
        self._finished(job, e)

    def _finished(self, job: Job, e: JobEvent) -> None:
        session = self._sessions.pop(job, None)
        if session is not None:
            session.close()  # servos stopped, torque as the player's config says; never raises
        self.stop_button.disabled = all(j.finished for j in self.jobs)
        self.progress.description = e.state.value
        if e.state == JobState.DONE:
            self.progress.value = 1.0
        self.status.value = f"{job.title}: {e.state.value} after {seconds(e.elapsed, 1)}"
        timing = self._timings.pop(job, None)
        if e.state == JobState.FAILED:
            too_fast = e.error is not None and e.error.type == "SegmentTooFastError"
            hint = f" (tick '{ALLOW_LATE}' to stretch them)" if too_fast else ""
            self.messages.say(f"{job.title} failed: {e.error.message if e.error else 'unknown error'}{hint}", True)
        elif e.state == JobState.CANCELLED:
            self.messages.say(f"{job.title} stopped")
        elif job.kind == "plan" and isinstance(job.result, TooFast):
            self.progress.description = "no show"
            late = [] if timing is None else timing.late_transitions(job.result.segments, job.result.home_added)
            listed = f": {'; '.join(late_lines(late))}" if late else ""
            n = len(late) or len(job.result.segments)
            self.messages.say(
                f"no show: {count(n, 'transition')} too fast for the servos{listed}. Tick '{ALLOW_LATE}' to stretch "
                "them (the show then runs longer), or give those keyframes more time", error=True,
            )  # fmt: skip
        elif job.kind == "plan":
            late = job.result.show.provenance.get("late_segments") or []
            stretched = f", {count(len(late), 'late transition')} stretched" if late else ""
            self.messages.say(f"planned a {seconds(job.result.show.duration)} show{stretched}; write it or play it")
            self.show_info()
            self.state.changed("project")  # other panels see the new show
        elif job.kind == "play":
            r = job.result
            self.messages.say(f"played: {r.message} (torque {r.torque}, {count(r.commands, 'move packet')})")
