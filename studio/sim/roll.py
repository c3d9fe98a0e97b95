"""The mount roll (DESIGN §1): turning images between the backdrop's frame and the unrolled hand's frame.

A mount rolled by ``roll`` rad about the light axis turns every shadow by ``roll`` about the image centre
(counter-clockwise as the audience sees the backdrop, image row 0 at the top), and changes nothing else: the
self-model, renderer, collision world and retrieval index all work in the unrolled hand's frame, and only the target
turns into it (by ``-roll``) for what works on images of the unrolled hand (the self-model's search, the index's
ranking); what the audience will see is rendered by the rolled rig itself (``Rig.with_roll``) and scored against
the target as it is (:class:`studio.imitate.framing.Framed`). Two operations, both pure compute on ``(…, S, S)`` images:

- :func:`turn` turns images about the image centre (what the rolled mount shows: ``turn(render(θ), roll)`` equals
  the rolled renderer's shadow up to edge aliasing; the rig window holds every rolled shadow).
- :func:`into_hand_frame` turns a target (and its expressive mask, by the very same map) by ``-roll`` about the
  target's own centre, shrunk only if it would leave the frame. The losses compare aligned crops (box, square, resize),
  so where the target sits and how large it is do not matter: only its shape turns.

Degrees are for people (flags, summaries, show files' ``roll_deg``); radians inside.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

FIT_MARGIN = 2  # pixels kept clear around a turned target (the crops' pad lies inside the frame)


def wrap_deg(deg: float) -> float:
    """An angle in degrees wrapped to ``(-180, 180]``."""
    d = math.fmod(float(deg), 360.0)
    d = d - 360.0 if d > 180.0 else d + 360.0 if d <= -180.0 else d
    return 0.0 if d == 0 else d


def parse_roll(setting: str | float | None) -> float | None:
    """A roll as people give it → rad: ``"auto"`` (or None) → None (the studio chooses it); a number, or its text,
    in degrees → that roll, wrapped to ``(-180°, 180°]``. A ValueError saying what a roll is, otherwise."""
    if setting is None or (isinstance(setting, str) and setting.strip().lower() == "auto"):
        return None
    try:
        deg = float(setting)
    except (TypeError, ValueError):
        raise ValueError(f"a roll is 'auto' or an angle in degrees, not {setting!r}") from None
    if not math.isfinite(deg):
        raise ValueError(f"a roll is 'auto' or a finite angle in degrees, not {setting!r}")
    return math.radians(wrap_deg(deg))


def file_deg(roll: float) -> float:
    """A roll in rad → degrees as files record it: wrapped to ``(-180, 180]``, rounded to 1e-6° (so 30° stays 30)."""
    return wrap_deg(round(math.degrees(roll), 6))


def roll_deg(roll: float) -> float:
    """A roll in rad → degrees for people, wrapped to ``(-180, 180]`` and rounded to 0.1°."""
    return round(wrap_deg(math.degrees(roll)), 1)


def mount_text(roll: float) -> str:
    """How to mount the hand for a show at ``roll`` rad, in one phrase for people."""
    deg = roll_deg(roll)
    if deg == 0:
        return "mount the hand upright (roll 0°, the paper's rig)"
    way = "counter-clockwise" if deg > 0 else "clockwise"
    return f"mount the hand rolled {abs(deg):.1f}° {way} as seen from the audience (roll {deg:+.1f}°)"


def _warp(images: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Images ``(…, S, S)`` through the affine map ``M (2, 3)``, bilinear, outside = 0; binary inputs come back
    binary (thresholded at half coverage), others as float32."""
    a = np.asarray(images)
    binary = a.dtype == np.uint8 or a.dtype == bool
    flat = a.reshape(-1, *a.shape[-2:]).astype(np.float32)
    h, w = a.shape[-2:]
    out = np.stack([
        cv2.warpAffine(im, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        for im in flat
    ]).reshape(a.shape)  # fmt: skip
    return (out >= 0.5).astype(np.uint8) if binary else out


def turn(images: np.ndarray, roll: float) -> np.ndarray:
    """Images ``(…, S, S)`` turned by ``roll`` rad about the image centre, counter-clockwise on screen for a positive
    roll (uint8/bool in → uint8 {0, 1} out, thresholded at half coverage; float in → float32)."""
    a = np.asarray(images)
    if not roll:
        return (a != 0).astype(np.uint8) if a.dtype == bool else a
    h, w = a.shape[-2:]
    M = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), math.degrees(roll), 1.0)
    return _warp(a, M)


def hand_frame_map(target: np.ndarray, roll: float) -> np.ndarray | None:
    """The affine map ``(2, 3)`` that turns ``target (S, S)`` by ``-roll`` about its shadow's box centre, to the
    frame centre, shrunk only as far as the turned shadow needs to fit inside the frame (``FIT_MARGIN``); None when
    the roll is 0 or the target is empty (nothing to turn)."""
    t = np.asarray(target)
    rows, cols = np.nonzero(t)
    if not roll or len(rows) == 0:
        return None
    h, w = t.shape
    cy, cx = (rows.min() + rows.max()) / 2.0, (cols.min() + cols.max()) / 2.0
    c, s = math.cos(-roll), math.sin(-roll)
    # the turned pixel corners' extent (screen coordinates: a counter-clockwise turn by -roll)
    ys, xs = rows - cy, cols - cx
    corners = [(dx, dy) for dx in (-0.5, 0.5) for dy in (-0.5, 0.5)]
    ext_x = max(np.abs(c * (xs + dx) + s * (ys + dy)).max() for dx, dy in corners)
    ext_y = max(np.abs(-s * (xs + dx) + c * (ys + dy)).max() for dx, dy in corners)
    room = min(w, h) / 2.0 - FIT_MARGIN
    scale = min(1.0, room / max(ext_x, ext_y, 1e-9))
    M = cv2.getRotationMatrix2D((cx, cy), math.degrees(-roll), scale)
    M[:, 2] += [(w - 1) / 2.0 - cx, (h - 1) / 2.0 - cy]
    return M


def into_hand_frame(
    target: np.ndarray, expressive: np.ndarray | None, roll: float
) -> tuple[np.ndarray, np.ndarray | None]:
    """A target ``(S, S)`` and its expressive mask (or None) as the unrolled hand must cast them for a mount rolled
    by ``roll`` rad: both turned by ``-roll`` through the same :func:`hand_frame_map` (unchanged at roll 0)."""
    M = hand_frame_map(target, roll)
    if M is None:
        return np.asarray(target), expressive
    return _warp(target, M), (None if expressive is None else _warp(expressive, M))
