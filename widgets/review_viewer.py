"""The Rerun viewer of the Review panel: the project's live recording, as wide as the notebook, following the studio.

    box = ViewerBox(recording, queue)      # box.widget: the viewer under a height control and a "follow" switch
    box.at_frame(3)                        # the viewer shows frame 3 (when following)

The viewer (:func:`studio.review.notebook_viewer.notebook_viewer`) reads the recording's gRPC stream, so it shows what
is logged as it is logged, not a file. While **follow** is on, its time follows what the studio does: the selected
frame (``frame``), a running optimisation's newest step (``opt_step``, where its best loss and shadow are drawn), the
show player's time (``show_time``; ``frame`` when there is no planned show yet), and a finished play, whose commanded
vs measured servo angles are logged when it ends and then played on ``show_time`` from the start of its ramp, with
the servo plot in front and the show's frames beside it (the loss plot comes back in front when the viewer next
goes to a frame or a job's step, where servo angles have no time). Switch it off to browse the recording by hand.
Job events arrive on the queue's thread: a lock keeps one writer at a time, and moves come at most every
``min_interval_s`` while a job or the player runs.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import ipywidgets as w

from studio.review.blueprint import FRAME, LOSS_TAB, OPT_STEP, SERVO_TAB, SHOW_TIME
from studio.review.notebook_viewer import MAX_HEIGHT, MIN_HEIGHT, clamp_height
from studio.review.recording import ProjectRecording

log = logging.getLogger(__name__)


class ViewerBox:
    """The viewer on ``recording``'s stream (made with ``notebook=True``) with its controls (module doc);
    ``queue``: the project's job queue (None: no jobs to follow)."""

    def __init__(self, recording: ProjectRecording, queue: Any = None, height: int = 560, min_interval_s: float = 0.5):
        self.recording = recording
        self.queue = queue
        self.min_interval_s = min_interval_s
        self.viewer = recording.notebook_widget(height=height)
        self.height = w.IntSlider(value=clamp_height(height), min=MIN_HEIGHT, max=min(MAX_HEIGHT, 1600), step=40,
                                  description="height", continuous_update=False, readout_format="d",
                                  layout={"width": "320px"})  # fmt: skip
        self.height.observe(lambda c: setattr(self.viewer, "_height", clamp_height(c["new"])), names="value")
        self.follow = w.Checkbox(value=True, description="follow the studio", indent=False,
                                 tooltip="the viewer's time follows the selected frame, a running job, the show "
                                         "player and a finished play")  # fmt: skip
        self.widget = w.VBox([w.HBox([self.follow, self.height]), self.viewer], layout={"width": "100%"})
        self.where: tuple[str, float] | None = None  # (timeline, time) the viewer was last moved to
        self._lock = threading.RLock()
        self._last = 0.0  # monotonic time of the last move
        self._drawn: dict[int, int] = {}  # running job id → the opt_step where it last drew its progress

    # ---------------------------------------------------------------- moving the viewer's time
    def _move(self, timeline: str, value: float, play: bool = False, throttle: bool = False) -> bool:
        """Move the viewer to ``value`` on ``timeline`` (steps on ``frame``/``opt_step``, seconds on the others);
        False when not following, or a throttled move came too soon after the last."""
        with self._lock:
            if not self.follow.value:
                return False
            now = time.monotonic()
            if throttle and now - self._last < self.min_interval_s:
                return False
            self._last = now
            if timeline in (FRAME, OPT_STEP):
                self.recording.front_plot(LOSS_TAB, timeline)  # after a play: the servo angles have no frame
                self.viewer.set_time_ctrl(timeline, sequence=int(value), play=play)
            else:
                self.viewer.set_time_ctrl(timeline, duration_nanos=round(float(value) * 1e9), play=play)
            self.where = (timeline, float(value))
            return True

    def at_frame(self, frame: int) -> bool:
        """Show frame ``frame`` (the studio's selection)."""
        return self._move(FRAME, frame)

    def at_show_time(self, t: float, playing: bool = False) -> bool:
        """Show the planned show at ``t`` s (the show player's time; throttled while it plays)."""
        return self._move(SHOW_TIME, t, throttle=playing)

    def on_step(self, event: Any, step: int) -> None:
        """A job drew its progress at ``step`` on ``opt_step``, or ended (the recording's job subscriber calls this):
        the viewer goes there, throttled while it runs, and to where it last drew when a job that drew ends."""
        with self._lock:
            if not event.final:
                self._drawn[event.job_id] = step
                self._move(OPT_STEP, step, throttle=True)
            elif event.job_id in self._drawn:  # where it last drew (its final event is logged after that)
                self._move(OPT_STEP, self._drawn.pop(event.job_id))

    def job_event(self, event: Any) -> None:
        """A queue event: a play that ended with a result has its commanded vs measured angles logged
        (:func:`log_finished_play`), and the viewer plays them on ``show_time`` from the start of the ramp, the
        servo plot in front, the show's frames and rig beside it."""
        ramp = log_finished_play(self.recording, self.queue, event)
        if ramp is not None:
            with self._lock:
                if self.follow.value:
                    self.recording.front_plot(SERVO_TAB, SHOW_TIME)
                    self._move(SHOW_TIME, -ramp, play=True)


def log_finished_play(recording: ProjectRecording, queue: Any, event: Any) -> float | None:
    """Log the commanded vs measured angles of the play job that ``event`` ends (done, or cancelled with a
    ``PlaybackResult``) to ``recording``; the ramp's length in s when it logged them (``show_time`` is ``play_time``
    minus it), else None. A queue subscriber: never raises."""
    state = getattr(event.state, "value", str(event.state))
    if event.kind != "play" or state not in ("done", "cancelled") or queue is None or recording.closed:
        return None
    try:
        result = queue.get(event.job_id).result
        if result is None or not hasattr(result, "sent"):
            return None
        ramp = recording.log_playback(result)
        recording.flush()
        return ramp
    except Exception:  # a subscriber never stops a job; the log says what went wrong
        log.exception("review: the playback of job %s could not be logged", event.job_id)
        return None
