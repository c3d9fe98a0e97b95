"""The show preview's frames: ``source frame | target | shadow`` at every preview time, encoded as JPEG for a player
in the browser (pure numpy + OpenCV, plain data in; a project's preview is :mod:`studio.project.preview`).

A :class:`PreviewClock` says what plays when: the preview times on the show clock, the project frame in view and
the pose at each (a NaN row: no pose yet, a blank backdrop), the keyframe ticks and the late transitions.
:func:`render_frames` makes every frame with :func:`~studio.review.video_review.side_by_side_frame`, the frame
``side_by_side.mp4`` is made of (one way to draw a moment of the show), the shadow rendered with the rig as mounted
(the mount roll). :func:`show_clock_map` and :func:`home_move` are the clock's pure parts: the show's time against
the project's clock (a late transition the planner stretched moves every keyframe after it), and the move from home
the player makes before a show (a straight ramp at its speed).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from studio.errors import ProgressFn, report, stopped
from studio.motion.show import Show
from studio.review.video_review import side_by_side_frame

CHUNK = 32  # frames rendered between two progress reports / cancel checks


@dataclass(frozen=True)
class PreviewTick:
    """A keyframe's pose reached on the show clock."""

    t: float  # show time, s
    keyframe: int  # the keyframe id
    frame: int  # the project frame it stands at
    status: str  # its result: "missing", "stale" or "current"


@dataclass
class PreviewClock:
    """What the preview plays when; arrays over the M preview frames."""

    times: np.ndarray  # (M,) s show time of each preview frame (negative: the move from home before the show)
    frame: np.ndarray  # (M,) int, the project frame in view at each
    theta: np.ndarray  # (M, 21) rad, the pose at each (a NaN row: no pose, blank shadow)
    start: float  # s, the timeline's start (times[0]; < 0 with a move from home)
    end: float  # s, the timeline's end (the show's end)
    fps: float  # preview frames per second of show time
    planned: bool  # True: the poses are the planned show's; False: each frame's keyframe pose (no current show)
    ticks: list[PreviewTick] = field(default_factory=list)  # keyframes reached, in time order
    late: list[tuple[float, float]] = field(default_factory=list)  # show-time spans of late (stretched) transitions
    note: str = ""  # one line for the artist: what the shadow column shows


def show_clock_map(show: Show) -> tuple[np.ndarray, np.ndarray]:
    """``(show_t, clock_t)``: matching times of the show and of the clock it was planned on (its keyframe markers
    and the times they were asked for; home at 0 on both), for :func:`remap` either way; the identity when the show
    does not say."""
    marks = np.array([m.t for m in show.keyframes], float)
    asked = np.asarray(show.provenance.get("requested_times", []), float)
    if len(marks) != len(asked) or len(marks) < 1 or (np.diff(marks) <= 0).any() or (np.diff(asked) <= 0).any():
        return np.array([0.0, 1.0]), np.array([0.0, 1.0])
    if asked[0] > 0 and marks[0] > 0:
        marks, asked = np.r_[0.0, marks], np.r_[0.0, asked]
    return marks, asked


def remap(x: np.ndarray | float, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x`` from clock ``a`` to clock ``b`` (matching times ``a``, ``b`` ascending): piecewise linear, slope 1
    beyond the ends."""
    x = np.asarray(x, float)
    if len(a) < 2:
        return x - a[0] + b[0]
    y = np.interp(x, a, b)
    return np.where(x < a[0], b[0] + x - a[0], np.where(x > a[-1], b[-1] + x - a[-1], y))


def home_move(rest: np.ndarray, first: np.ndarray, fps: float, speed: float) -> tuple[np.ndarray, np.ndarray]:
    """The move from ``rest (21,)`` to ``first (21,)`` rad as a player makes it (a straight ramp, the joint that
    moves most at ``speed`` rad/s) sampled at ``fps`` before show time 0 → ``(times (L,) s < 0, theta (L, 21))``."""
    rest, first = np.asarray(rest, float), np.asarray(first, float)
    lead = float(np.max(np.abs(first - rest))) / speed if speed > 0 else 0.0
    n = int(math.ceil(lead * fps - 1e-9))
    if n <= 0:
        return np.zeros(0), np.zeros((0, len(rest)))
    t = -lead + np.arange(n) / fps
    return t, rest + (first - rest) * ((t + lead) / lead)[:, None]


def preview_shadows(theta: np.ndarray, resolution: int, roll: float) -> np.ndarray:
    """Shadows ``(M, R, R)`` uint8 {0, 1} of poses ``theta (M, 21) rad`` on the rig as mounted (``roll`` rad); a NaN
    row (no pose) gives a blank backdrop."""
    from studio.sim.hand import load_hand
    from studio.sim.shadow import Rig, ShadowRenderer

    theta = np.asarray(theta, float).reshape(len(theta), -1)
    out = np.zeros((len(theta), resolution, resolution), np.uint8)
    posed = ~np.isnan(theta).any(axis=1)
    if posed.any():
        renderer = ShadowRenderer(load_hand(), Rig(resolution=resolution, roll=roll))
        out[posed] = renderer.render(theta[posed], check=False)
    return out


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """An RGB ``(H, W, 3)`` uint8 image as JPEG bytes."""
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR),
                            [cv2.IMWRITE_JPEG_QUALITY, int(quality)])  # fmt: skip
    if not ok:
        raise OSError("OpenCV could not encode a preview frame as JPEG")
    return data.tobytes()


def decode_image(data: bytes) -> np.ndarray:
    """JPEG or PNG bytes → RGB ``(H, W, 3)`` uint8 (for tests and tools)."""
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError("not a JPEG or PNG image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def frame_text(t: float, frame: int) -> str:
    """The label on a preview frame's source column: the show time and project frame (``home`` before 0)."""
    return f"home {t:.2f}s" if t < 0 else f"{t:.2f}s #{frame}"


def render_frames(
    clock: PreviewClock,
    sources: Sequence[np.ndarray | None],
    targets: np.ndarray,
    expressive: np.ndarray,
    roll: float,
    tile: int = 160,
    quality: int = 85,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> list[bytes] | None:
    """Every frame of ``clock`` as JPEG bytes: the project frame in view (``sources``: its framed RGB image
    ``(S, S, 3)`` or None, then its target is shown; ``targets``/``expressive`` ``(N, S, S)``) beside the shadow of
    the pose then (rig ``S``² as mounted with ``roll`` rad), columns ``tile`` px. Progress "preview" m of M; None
    when ``cancel`` is set (half a preview is no preview)."""
    size = targets.shape[-1]
    frames: list[bytes] = []
    total = len(clock.times)
    for a in range(0, total, CHUNK):
        if stopped(cancel):
            return None
        b = min(a + CHUNK, total)
        shadows = preview_shadows(clock.theta[a:b], size, roll)
        for m in range(a, b):
            i = int(clock.frame[m])
            rgb = side_by_side_frame(sources[i], targets[i], expressive[i], shadows[m - a],
                                     frame_text(float(clock.times[m]), i), tile)  # fmt: skip
            frames.append(encode_jpeg(rgb, quality))
        report(progress, "preview", b, total)
    return frames
