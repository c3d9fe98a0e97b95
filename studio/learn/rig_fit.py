"""Fit the rig to captured shadows: light and backdrop distances, the mount's place and roll, the foam's thickness.

Given poses ``theta (N, 21)`` played on the real hand and the shadows a camera saw, ``captured (N, R, R)`` uint8
(1 = shadow, rectified into the rig's window), find the :class:`~studio.sim.shadow.Rig` whose rendered shadows match
them best under the **window** IoU loss (``1 - IoU`` of the whole window, position and scale included; not the
crop-aligned loss of imitation, which would forgive exactly what is being measured).

What the shadows can tell apart: a point ``p`` of the hand falls at ``A p_xy / (C - p_z)`` on the backdrop (light
on the axis), with ``A`` the light-to-backdrop and ``C`` the light-to-hand distance. So a hand moved along the light
axis by ``d`` casts exactly the shadows of a light moved by ``-d`` and a backdrop by ``+d``: the fit keeps the mount's
``z`` where the starting rig has it and measures the light and backdrop distances from there. ``A / C`` (the
shadow's scale) is sharp; ``C`` alone shows only through perspective (the parts nearer the light grow more), which
is why the calibration poses should bend the hand towards the light (:func:`calibration_poses`).

The search compares **coverage**, not masks: each captured pixel's darkness normalised to [0, 1] (what share of it
the shadow covers, as the camera's rectified image says) against the rendered shadow drawn at ``supersample`` times
the captures' resolution and averaged into coverage fractions, then blurred by the camera's blur (fitted too, σ in
window pixels: without it a blurred capture pulled the light's distance 2-3 % long), by their mean absolute
difference. Binary masks
would quantise away the sub-pixel shifts that tell the light's distance from the backdrop's (measured: along the
line of equal scale, the binary loss wanders by more than it changes, while the coverage loss has one clean minimum
at the true rig). Nelder–Mead (scipy) runs from the starting rig in scaled coordinates, then again from its answer
(a restart escapes a collapsed simplex), after a scan of the roll over the whole circle (a mount may be rolled far
from where the calibration had it). The figures reported are the window IoU losses of the binary masks.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from studio.errors import Cancelled, ProgressFn, StudioError, plural, report
from studio.sim.hand import Hand, load_hand
from studio.sim.shadow import Rig, ShadowRenderer

log = logging.getLogger(__name__)

# the fitted parameters: name → (how to read it from a rig, its scale in the search: a typical error of a rig set
# up by hand, so one unit is as far in every direction)
PARAMETERS = {
    "light_distance": (lambda r: r.light[2], 0.3),  # m
    "backdrop_distance": (lambda r: -r.backdrop_z, 0.2),  # m
    "hand_x": (lambda r: r.hand_offset[0], 0.02),  # m
    "hand_y": (lambda r: r.hand_offset[1], 0.02),  # m
    "roll": (lambda r: r.roll, math.radians(3.0)),  # rad
    "foam": (lambda r: r.foam, 0.002),  # m
    "blur": (lambda r: 0.8, 0.5),  # the camera's blur as the captures show it, σ in window pixels (from 0.8: a lens)
}
LIGHT_RANGE = (1.0, 8.0)  # light distances the line search along the weak direction considers, m
ROLL_SCAN_DEG = 3.0  # step of the first scan over the whole circle of rolls, degrees
SCALE_STEP = 0.02  # search scale of the shadow's magnification (light-to-backdrop over light-to-hand)


@dataclass(frozen=True)
class RigFitConfig:
    """How the rig is fitted."""

    fit: tuple[str, ...] = tuple(PARAMETERS)  # which parameters move (the rest stay at the starting rig's values)
    supersample: int = 2  # render at this multiple of the captures' resolution, averaged into coverage [1, 8]
    max_evals: int = 1500  # loss evaluations per simplex search (two searches) [50, 100000]
    tolerance: float = 1e-5  # stop when the simplex's losses differ by less than this

    def __post_init__(self) -> None:
        unknown = set(self.fit) - set(PARAMETERS)
        if unknown:
            raise ValueError(
                f"unknown rig {plural('parameter', len(unknown))} {sorted(unknown)}: choose from "
                f"{', '.join(PARAMETERS)}"
            )
        if not 1 <= self.supersample <= 8 or self.max_evals < 50:
            raise ValueError("supersample must be within 1..8 and max_evals at least 50")


@dataclass(frozen=True)
class RigFit:
    """The answer: the rig before and after, their window IoU losses (binary, at the captures' resolution)."""

    before: Rig  # the starting (nominal) rig
    after: Rig  # the fitted rig
    loss_before: float  # mean window IoU loss of the captures against the starting rig's shadows
    loss_after: float  # the same against the fitted rig's shadows
    per_pose_after: tuple[float, ...]  # each capture's window IoU loss against the fitted rig
    evaluations: int  # loss evaluations spent
    blur_px: float  # the camera's blur the fit found, σ in capture pixels (0 when not fitted)
    seconds: float  # wall time of the fit


class RigFitError(StudioError):
    """The captures cannot be fitted (empty, mismatched, nothing in them)."""


def window_iou_loss(captured: np.ndarray, rendered: np.ndarray) -> np.ndarray:
    """``1 - IoU`` over the last two axes of ``captured (..., R, R)`` {0, 1} and ``rendered (..., R, R)`` in [0, 1]
    (coverage fractions allowed: a soft IoU ``Σ min / Σ max``); two empty images have loss 0."""
    c = captured.astype(np.float32)
    r = rendered.astype(np.float32)
    inter = np.minimum(c, r).sum(axis=(-2, -1))
    union = np.maximum(c, r).sum(axis=(-2, -1))
    return np.where(union > 0, 1.0 - inter / np.maximum(union, 1e-9), 0.0)


def _rig_with(start: Rig, values: dict[str, float]) -> Rig:
    v = {name: get(start) for name, (get, _) in PARAMETERS.items()} | values
    light = (start.light[0], start.light[1], float(v["light_distance"]))
    offset = (float(v["hand_x"]), float(v["hand_y"]), start.hand_offset[2])
    foam = float(np.clip(v["foam"], -0.005, 0.05))
    return replace(start, light=light, backdrop_z=-float(v["backdrop_distance"]), hand_offset=offset,
                   roll=float(v["roll"]), foam=foam)  # fmt: skip


def coverage(renderer: ShadowRenderer, theta: np.ndarray, supersample: int) -> np.ndarray:
    """Shadows of ``theta (N, 21)`` as coverage fractions ``(N, R, R)`` float32, where the renderer draws at
    ``R * supersample`` and each block of pixels is averaged."""
    img = renderer.render(theta, check=False).astype(np.float32)
    return img if supersample == 1 else block_mean(img, supersample)


def block_mean(img: np.ndarray, k: int) -> np.ndarray:
    """``img (N, k R, k R)`` float32 averaged over each ``k × k`` block → ``(N, R, R)``: the block's rows added, then
    its columns, as ``k`` strided additions each (``reshape(N, R, k, R, k).mean(axis=(2, 4))`` gives the same numbers,
    exactly for sums of 0s and 1s, but ~17× slower here: numpy reduces the two inner axes element by element)."""
    n, big = img.shape[0], img.shape[1]
    r = big // k
    rows = img.reshape(n, r, k, big)
    acc = rows[:, :, 0].copy()
    for i in range(1, k):
        acc += rows[:, :, i]
    cols = acc.reshape(n, r, r, k)
    out = cols[..., 0].copy()
    for j in range(1, k):
        out += cols[..., j]
    return out / np.float32(k * k)


def calibration_poses(hand: Hand, n: int = 12, seed: int = 0, pool: int = 3000) -> np.ndarray:
    """``(n, 21)`` poses to calibrate with: collision-free (they are played on the real hand), each telling the
    light's distance well (the most pixels differ between two rigs of equal shadow scale, light near and far), and
    unlike one another (greedy farthest-point choice in joint space among the most telling quarter of a seeded
    pool), in the order that plays them quickest from the rest pose (:func:`travel_order`)."""
    from studio.sim.physics import CollisionWorld
    from studio.sim.sampling import sample_poses

    if n < 1:
        raise ValueError("calibrate with at least one pose")
    cand = sample_poses(hand, max(pool, 4 * n), np.random.default_rng(seed))[0]
    with CollisionWorld(hand) as world:
        cand = cand[~world.in_collision(cand)]
    # how much each pose tells the light's distance from the shadow's scale: the pixels that differ between two rigs
    # of equal scale (4/3), the light at 2.4 m and at 3.6 m (only the perspective of the parts nearer the light does)
    near = ShadowRenderer(hand, Rig(light=(0.0, 0.0, 2.4), backdrop_z=-0.8, resolution=128)).render(cand, check=False)
    far = ShadowRenderer(hand, Rig(light=(0.0, 0.0, 3.6), backdrop_z=-1.2, resolution=128)).render(cand, check=False)
    telling = (near != far).sum(axis=(1, 2))
    deep = cand[np.argsort(-telling)[: max(n, len(cand) // 4)]]
    chosen = [0]
    dist = np.linalg.norm(deep - deep[0], axis=1)
    while len(chosen) < min(n, len(deep)):
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(deep - deep[chosen[-1]], axis=1))
    return travel_order(deep[chosen], np.zeros(hand.dof))


def travel_order(poses: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``poses (N, 21)`` reordered to play quickly from ``start (21,)``: each next pose the one whose largest joint
    move is smallest (a move's time is its largest joint's distance over the joint speed)."""
    left, out, at = list(range(len(poses))), [], np.asarray(start, dtype=float)
    while left:
        k = min(left, key=lambda i: float(np.abs(poses[i] - at).max()))
        out.append(k)
        left.remove(k)
        at = poses[k]
    return poses[out]


def fit_rig(
    theta: np.ndarray,
    captured: np.ndarray,
    start: Rig,
    cfg: RigFitConfig | None = None,
    hand: Hand | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> RigFit:
    """Fit ``start``'s parameters named in ``cfg.fit`` to ``captured (N, R, R)`` shadows of ``theta (N, 21)``:
    coverage in [0, 1] (float; best) or binary masks (uint8 1 = shadow).

    ``start``'s window is the captures' window; its resolution is ignored (the captures' ``R`` is used). Progress
    is reported as stage ``"fit"`` (evaluations of the budget, the best coverage loss); ``cancel`` raises
    :class:`~studio.errors.Cancelled`.
    """
    from scipy.optimize import minimize, minimize_scalar

    cfg = cfg or RigFitConfig()
    hand = hand or load_hand()
    theta = np.ascontiguousarray(np.atleast_2d(theta), dtype=np.float64)
    captured = np.asarray(captured)
    if captured.ndim != 3 or captured.shape[1] != captured.shape[2] or len(captured) != len(theta) or not len(theta):
        raise RigFitError(f"need one square capture per pose: {len(theta)} poses, captures of shape {captured.shape}")
    if not captured.any(axis=(1, 2)).any():
        raise RigFitError("every capture is empty: the camera saw no shadow (is the light on, the backdrop found?)")
    res = captured.shape[1]
    soft = np.clip(captured.astype(np.float32), 0.0, 1.0)
    captured = (soft >= 0.5).astype(np.float32)
    start = start.with_resolution(res)
    # Searched in (light distance, shadow scale A / C) rather than (light, backdrop): the scale is sharp and the
    # light's distance at a given scale shows only through perspective, so the weak direction lies along one axis.
    both = {"light_distance", "backdrop_distance"} <= set(cfg.fit)
    names = ["shadow_scale" if both and n == "backdrop_distance" else n for n in cfg.fit]
    L0, B0 = start.light[2], -start.backdrop_z
    get = {n: PARAMETERS[n][0] for n in PARAMETERS} | {"shadow_scale": lambda r: (L0 + B0) / L0}
    x_start = np.array([get[n](start) for n in names])
    scale = np.array([SCALE_STEP if n == "shadow_scale" else PARAMETERS[n][1] for n in names])
    budget, evals, best, t0 = 2 * cfg.max_evals, 0, math.inf, time.perf_counter()

    def rig_at(x: np.ndarray) -> Rig:
        values = dict(zip(names, x_start + scale * x))
        if both:
            k = values.pop("shadow_scale")
            values["backdrop_distance"] = (k - 1.0) * values["light_distance"]
        return _rig_with(start, values)

    def blur_of(x: np.ndarray) -> float:
        if "blur" not in names:
            return 0.0
        i = names.index("blur")
        return abs(float(x_start[i] + scale[i] * x[i]))  # |σ|: the search passes through 0 instead of sticking there

    def loss(x: np.ndarray, target: np.ndarray) -> float:
        nonlocal evals, best
        if cancel is not None and cancel.is_set():
            raise Cancelled("the rig fit was cancelled")
        evals += 1
        if evals % 25 == 0:
            report(progress, "fit", min(evals, budget), budget, best)
        try:
            rig = rig_at(x).with_resolution(target.shape[1] * cfg.supersample)
        except ValueError:  # a rig that cannot be (the hand behind the light): as bad as can be
            return 2.0
        drawn = coverage(ShadowRenderer(hand, rig), theta, cfg.supersample)
        sigma = blur_of(x) * target.shape[1] / res  # σ in this stage's pixels
        if sigma > 0.05:  # the captures are the shadow seen through a lens: blur the drawing alike before comparing
            drawn = np.stack([cv2.GaussianBlur(d, (0, 0), sigma) for d in drawn])
        value = float(np.abs(drawn - target).mean())
        best = min(best, value)
        return value

    # Coarse to fine: the first search on the coverage averaged over 2×2 blocks (a quarter of the pixels to draw),
    # the second restarts the simplex around its answer at the captures' own resolution.
    half = block_mean(soft, 2) if res % 2 == 0 and res >= 64 else soft
    x = np.zeros(len(names))
    if "roll" in names:  # a mount rolled far from where the calibration had it: start from the best of a scan
        k = names.index("roll")
        scan = np.arange(-180.0, 180.0, ROLL_SCAN_DEG)
        trials = [np.where(np.arange(len(names)) == k, math.radians(d) / scale[k], 0.0) for d in scan]
        x = min(trials, key=lambda t: loss(t, half))
    for target in (half, soft):
        opts = {"maxfev": cfg.max_evals, "xatol": 1e-3, "fatol": cfg.tolerance * 1e-3}
        opts["initial_simplex"] = np.vstack([x, x + np.eye(len(names)) * 0.5])
        x = minimize(loss, x, args=(target,), method="Nelder-Mead", options=opts).x
    if both:  # the weak direction: the light's distance at the fitted scale, searched along its own line, then polished
        i = names.index("light_distance")
        lo, hi = (LIGHT_RANGE[0] - x_start[i]) / scale[i], (LIGHT_RANGE[1] - x_start[i]) / scale[i]
        along = minimize_scalar(lambda v: loss(np.where(np.arange(len(x)) == i, v, x), soft), bounds=(lo, hi),
                                method="bounded", options={"xatol": 0.01})  # fmt: skip
        x[i] = along.x
        opts = {"maxfev": cfg.max_evals // 2, "xatol": 1e-3, "fatol": cfg.tolerance * 1e-3}
        opts["initial_simplex"] = np.vstack([x, x + np.eye(len(names)) * 0.2])
        x = minimize(loss, x, args=(soft,), method="Nelder-Mead", options=opts).x
    after = rig_at(x)
    binary = ShadowRenderer(hand, after).render(theta, check=False)
    per_pose = window_iou_loss(captured, binary)
    before = float(window_iou_loss(captured, ShadowRenderer(hand, start).render(theta, check=False)).mean())
    report(progress, "fit", evals, evals, best)
    return RigFit(start, after, before, float(per_pose.mean()), tuple(float(v) for v in per_pose), evals,
                  blur_of(x), time.perf_counter() - t0)  # fmt: skip
