"""A project's review in Rerun: its entity paths, timelines and viewer layout, stated once (DESIGN §5.6).

Timelines: ``frame`` (sampled frame k of the project's sources), ``opt_step`` (a job's search and refinement
steps), ``show_time`` (s into the planned show) and ``play_time`` (s since a playback started, its ramp included).

Entities (images in display convention: dark shadow on a light backdrop)::

    images/source      RGB source frame (when given)              frame, show_time
    images/target      the frame's shadow mask                    frame, show_time
    images/expressive  the mask with its expressive region tinted frame, show_time
    images/self_model  the self-model's shadow of the frame's keyframe pose   frame, show_time
    images/rendered    its rendered shadow (a job's live best shadow on opt_step)   frame, opt_step, show_time

On ``show_time`` the images are those of the frame a current show plays then (:mod:`studio.review.show_frames`).
    frames/keyframe    which keyframe each frame plays (its position in first-appearance order; dots)   frame, show_time
    loss/frame/*       the loss of each frame's keyframe result   frame, show_time
    loss/<job>/<stage> a job's best loss so far                   opt_step
    log/*              keyframes, jobs, the show, playbacks (text)
    world/hand/...     the hand's shell and skeleton, loaded from the URDF (static)
    world/pose/<joint> each joint's transform (parent link frame → child link frame)   frame, show_time
    world/light        the point light and its rays to the window's corners (static)
    world/backdrop     the backdrop window (z = backdrop_z) textured with the shadow then   frame, show_time
    servo/<joint>/commanded, servo/<joint>/measured   rad   play_time, show_time

``frames/keyframe``, ``loss/frame/*``, ``log/keyframes``, ``log/show`` and a finished playback's ``servo/*`` are
logged whole, each version replacing the last (:mod:`studio.review.series`: version n > 0 at ``PATH/vN``; a version
equal to the one on show is not logged).
"""

from __future__ import annotations

import re

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

FRAME, OPT_STEP, SHOW_TIME, PLAY_TIME = "frame", "opt_step", "show_time", "play_time"

SOURCE = "images/source"
TARGET = "images/target"
EXPRESSIVE = "images/expressive"
SELF_MODEL = "images/self_model"
RENDERED = "images/rendered"
KEYFRAME_OF_FRAME = "frames/keyframe"
LOSS = "loss"
FRAME_LOSS = "loss/frame"
LOG = "log"
KEYFRAMES_LOG, JOBS_LOG, SHOW_LOG, PLAYBACK_LOG = "log/keyframes", "log/jobs", "log/show", "log/playback"
WORLD = "world"
HAND = "world/hand"
POSE = "world/pose"
LIGHT = "world/light"
BACKDROP = "world/backdrop"
SERVO = "servo"
LOSS_TAB, SERVO_TAB = "loss", "servos: commanded vs measured"  # the plot tabs a layout can open on


def part(name: str) -> str:
    """``name`` as one entity path part: lower case, runs of anything but letters, digits and ``_`` become ``_``."""
    return re.sub(r"[^a-z0-9_]+", "_", str(name).lower()).strip("_") or "_"


def pose_path(joint: str) -> str:
    """Entity of joint ``joint``'s transform."""
    return f"{POSE}/{part(joint)}"


def servo_path(joint: str, which: str) -> str:
    """Entity of joint ``joint``'s ``"commanded"`` or ``"measured"`` angle series."""
    return f"{SERVO}/{part(joint)}/{which}"


def time_column(timeline: str, values: np.ndarray) -> rr.TimeColumn:
    """Times of many rows: steps on the sequence timelines (``frame``, ``opt_step``), seconds on the others."""
    if timeline in (FRAME, OPT_STEP):
        return rr.TimeColumn(timeline, sequence=np.asarray(values, dtype=np.int64))
    return rr.TimeColumn(timeline, duration=np.asarray(values, dtype=np.float64))


def set_time(rec: rr.RecordingStream, **times: float) -> None:
    """Make the given timelines (and only them) the current time of this thread's rows: steps on ``frame`` and
    ``opt_step``, seconds on the others (``set_time(rec, show_time=1.5)``)."""
    rec.reset_time()
    for timeline, value in times.items():
        if timeline in (FRAME, OPT_STEP):
            rec.set_time(timeline, sequence=int(value))
        else:
            rec.set_time(timeline, duration=float(value))


def servo_plot(name: str = SERVO_TAB) -> rrb.TimeSeriesView:
    """The servo angles' plot: every joint's commanded and measured angle (42 series), without a legend (it would
    cover a third of the plot, and still not fit: hovering a line names it)."""
    return rrb.TimeSeriesView(origin=SERVO, name=name, plot_legend=rrb.PlotLegend(visible=False))


def project_blueprint(timeline: str = FRAME, sources: bool = False, plot: str = LOSS_TAB) -> rrb.Blueprint:
    """The viewer layout of a project's review: the images side by side (source, when ``sources``, then target,
    expressive mask, self-model shadow, rendered shadow), under them tabs of plots (loss, servo angles, keyframe per
    frame) and the text log, and the rig in 3D on the right (hand, light, backdrop carrying the shadow).
    ``timeline`` is the one the viewer opens on; ``plot`` the tab in front (``LOSS_TAB`` or ``SERVO_TAB``)."""
    views = [
        rrb.Spatial2DView(origin=TARGET, name="target"),
        rrb.Spatial2DView(origin=EXPRESSIVE, name="expressive mask"),
        rrb.Spatial2DView(origin=SELF_MODEL, name="self-model shadow"),
        rrb.Spatial2DView(origin=RENDERED, name="rendered shadow"),
    ]
    if sources:
        views.insert(0, rrb.Spatial2DView(origin=SOURCE, name="source"))
    plots = rrb.Tabs(
        rrb.TimeSeriesView(origin=LOSS, name=LOSS_TAB),
        servo_plot(),
        rrb.TimeSeriesView(origin=KEYFRAME_OF_FRAME, name="keyframe per frame"),
        rrb.TextLogView(origin=LOG, name="log"),
        active_tab=plot,
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Horizontal(*views), plots, row_shares=[1, 1]),
            rrb.Spatial3DView(origin=WORLD, name="rig: hand, light, backdrop"),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=timeline),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )
