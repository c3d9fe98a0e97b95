"""Commanded vs measured servo angles of a played show, in Rerun (plain data in: no ``hardware`` import).

Per joint, ``servo/<joint>/commanded`` (rad sent after clipping, every tick) and ``servo/<joint>/measured`` (rad read
back), on ``play_time`` (s since playback started: tick 0 is the start of the ramp to the first frame). A finished
playback (:func:`log_playback`) also carries ``show_time`` (``play_time`` minus the ramp; negative during the ramp),
so its series line up with the planned show; a live one (:class:`PlaybackSampleLog`, the player's ``on_sample``
hook) does not know the ramp's length ahead, so it has ``play_time`` only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import rerun as rr

from studio.review.blueprint import PLAY_TIME, PLAYBACK_LOG, SHOW_TIME, servo_path, set_time, time_column
from studio.review.series import VersionedLog


def tick_seconds(t: np.ndarray, default: float = 1 / 40) -> float:
    """The tick period of a playback from its tick times ``t (T,)`` s (multiples of the period, skips allowed)."""
    d = np.diff(np.asarray(t, dtype=float))
    d = d[d > 1e-9]
    return float(d.min()) if len(d) else default


def log_playback(
    rec: rr.RecordingStream, result: Any, rate_hz: float | None = None, versions: VersionedLog | None = None
) -> float:
    """Log a finished playback: ``result`` is a ``hardware.playback_log.PlaybackResult`` (or anything with its
    ``t (T,)``, ``sent (T, J)``, ``measured_t``/``measured_joint``/``measured_rad (M,)``, ``ramp_ticks``,
    ``joint_names``, ``reason``, ``message``). ``rate_hz`` is the player's tick rate (default: read from ``t``).
    ``versions``: the recording's (:mod:`studio.review.series`), so that this playback's angles replace the last
    one's. Returns the ramp's length in s (``play_time - show_time``)."""
    names = list(result.joint_names)
    t = np.asarray(result.t, dtype=float)
    sent = np.asarray(result.sent, dtype=float).reshape(len(t), len(names))
    dt = 1.0 / rate_hz if rate_hz else tick_seconds(t)
    ramp = int(result.ramp_ticks) * dt
    versions = versions or VersionedLog(rec)
    for j, name in enumerate(names):
        index = [time_column(PLAY_TIME, t), time_column(SHOW_TIME, t - ramp)]
        versions.scalars(servo_path(name, "commanded"), index, sent[:, j], name=f"{name} commanded")
        mine = np.asarray(result.measured_joint) == j
        mt = np.asarray(result.measured_t, dtype=float)[mine]
        q = np.asarray(result.measured_rad, dtype=float)[mine]
        index = [time_column(PLAY_TIME, mt), time_column(SHOW_TIME, mt - ramp)]
        versions.scalars(servo_path(name, "measured"), index, q, name=f"{name} measured")  # none read: hidden
    reason = getattr(result.reason, "value", str(result.reason))
    set_time(rec, play_time=float(t[-1]) if len(t) else 0.0)
    level = "INFO" if reason == "completed" else "WARN"
    rec.log(PLAYBACK_LOG, rr.TextLog(f"playback {reason}: {result.message}", level=level))
    rec.reset_time()
    return ramp


class PlaybackSampleLog:
    """The player's ``on_sample(t, commanded (J,), measured (J,))`` hook streaming to a recording as a show plays.

    ``joint_names`` name the columns in the player's order (its calibration's ``joint_names``). ``measured`` is the
    player's latest read-back of each joint (joints are read in turn, so a value may be a few ticks old). Called on
    the player's thread; about 0.6 ms a tick for 21 joints. It streams to the plain ``servo/<joint>/…`` paths, the
    first version of :func:`log_playback`'s (:mod:`studio.review.series`): a second finished playback logged to the
    same recording hides what it streamed."""

    def __init__(self, rec: rr.RecordingStream, joint_names: Sequence[str]):
        self.rec = rec
        self.joint_names = list(joint_names)
        self._commanded = [servo_path(n, "commanded") for n in self.joint_names]
        self._measured = [servo_path(n, "measured") for n in self.joint_names]
        self.samples = 0  # ticks logged

    def __call__(self, t: float, commanded: np.ndarray, measured: np.ndarray) -> None:
        commanded, measured = np.asarray(commanded, dtype=float), np.asarray(measured, dtype=float)
        if commanded.shape != (len(self.joint_names),) or measured.shape != commanded.shape:
            raise ValueError(
                f"on_sample got commanded {commanded.shape} and measured {measured.shape} for "
                f"{len(self.joint_names)} joints: give PlaybackSampleLog the player's joint names"
            )
        set_time(self.rec, play_time=float(t))
        for path, q in zip(self._commanded, commanded):
            self.rec.log(path, rr.Scalars(float(q)))
        for path, q in zip(self._measured, measured):
            self.rec.log(path, rr.Scalars(float(q)))
        self.rec.reset_time()
        self.samples += 1
