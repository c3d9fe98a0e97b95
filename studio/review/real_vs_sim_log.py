"""A show played with a camera, in Rerun: every keyframe's target, captured and simulated shadow on ``show_time``.

Plain data in (no ``hardware`` or ``project`` import): each capture is anything with ``index``, ``show_t`` (s),
``target`` / ``captured`` / ``simulated`` (``(S, S)`` / ``(R, R)`` uint8, 1 = shadow, or None), ``losses`` (a
mapping of :data:`LOSS_NAMES` → value, NaN where not computed) and ``error`` (why there is no picture), such as
``studio.project.show_capture_data.KeyframeCapture``. Entities, added to :mod:`studio.review.blueprint`'s tree
(images in display convention: dark shadow on a light backdrop), each at the keyframe's show time::

    images/target        the keyframe's target (when it has one)                 show_time
    images/captured      the camera's shadow, rectified into the backdrop window  show_time
    images/simulated     the commanded pose's shadow on the calibrated rig        show_time
    images/real_vs_sim   captured over simulated (studio.review.real_vs_sim's colours)   show_time
    loss/capture/<name>  captured_vs_target, simulated_vs_target, captured_vs_simulated  show_time
    log/playback         one line per keyframe: its losses, or why it has no picture     show_time

:func:`write_capture_recording` writes them to an ``.rrd`` with the playback's servo angles
(:func:`studio.review.playback.log_playback`) under :func:`capture_blueprint`, which opens on ``show_time``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from studio.review.blueprint import LOG, LOSS, PLAYBACK_LOG, SHOW_TIME, TARGET, servo_plot, set_time
from studio.review.playback import log_playback
from studio.review.real_vs_sim import overlay
from studio.review.recording import APPLICATION
from studio.review.sheets import display

CAPTURED = "images/captured"
SIMULATED = "images/simulated"
REAL_VS_SIM = "images/real_vs_sim"
CAPTURE_LOSS = f"{LOSS}/capture"
LOSS_NAMES = ("captured_vs_target", "simulated_vs_target", "captured_vs_simulated")


def capture_line(c: Any) -> str:
    """One keyframe in words: its show time and losses, or why it has no picture."""
    parts = [f"{n.replace('_vs_', ' vs ').replace('_', ' ')} {v:.3f}" for n in LOSS_NAMES
             if math.isfinite(v := float(c.losses.get(n, math.nan)))]  # fmt: skip
    said = ", ".join(parts) if parts else "no loss computed"
    return f"keyframe {c.index} at {c.show_t:.2f} s: {said}" + (f" ({c.error})" if c.error else "")


def log_captures(rec: rr.RecordingStream, captures: Sequence[Any]) -> int:
    """Log every capture at its keyframe's show time (module doc); returns how many had a picture."""
    pictures = 0
    for c in captures:
        set_time(rec, show_time=float(c.show_t))
        rec.log(TARGET, rr.Clear(recursive=False) if c.target is None else rr.Image(display(c.target)))
        rec.log(SIMULATED, rr.Image(display(c.simulated)))
        if c.captured is None:
            rec.log(CAPTURED, rr.Clear(recursive=False))
            rec.log(REAL_VS_SIM, rr.Clear(recursive=False))
        else:
            pictures += 1
            rec.log(CAPTURED, rr.Image(display(c.captured)))
            rec.log(REAL_VS_SIM, rr.Image(overlay(c.captured, c.simulated)))
        for name in LOSS_NAMES:
            value = float(c.losses.get(name, math.nan))
            if math.isfinite(value):  # a loss not computed is not drawn as a value
                rec.log(f"{CAPTURE_LOSS}/{name}", rr.Scalars(value))
        rec.log(PLAYBACK_LOG, rr.TextLog(capture_line(c), level="WARN" if c.error else "INFO"))
    rec.reset_time()
    return pictures


def capture_blueprint() -> rrb.Blueprint:
    """The viewer layout of a show played with a camera: target | captured | simulated | overlay, under them the
    losses, the servo angles and the log; it opens on ``show_time``."""
    images = [
        rrb.Spatial2DView(origin=TARGET, name="target"),
        rrb.Spatial2DView(origin=CAPTURED, name="captured (camera)"),
        rrb.Spatial2DView(origin=SIMULATED, name="simulated"),
        rrb.Spatial2DView(origin=REAL_VS_SIM, name="captured over simulated"),
    ]
    plots = rrb.Tabs(
        rrb.TimeSeriesView(origin=CAPTURE_LOSS, name="losses per keyframe"),
        servo_plot(),
        rrb.TextLogView(origin=LOG, name="log"),
    )
    return rrb.Blueprint(
        rrb.Vertical(rrb.Horizontal(*images), plots, row_shares=[1, 1]),
        rrb.TimePanel(timeline=SHOW_TIME),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


def write_capture_recording(
    path: str | Path, captures: Sequence[Any], playback: Any = None, rate_hz: float | None = None
) -> Path:
    """An ``.rrd`` at ``path`` (``rerun FILE`` opens it) with the captures and, when given, the playback's commanded
    vs measured servo angles (a ``hardware.playback_log.PlaybackResult``; ``rate_hz``: its tick rate)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION)
    rec.set_sinks(rr.FileSink(str(path)), default_blueprint=capture_blueprint())
    try:
        if playback is not None and len(np.asarray(playback.t)):
            log_playback(rec, playback, rate_hz)
        log_captures(rec, captures)
        rec.flush()
    finally:
        rec.disconnect()
    return path
