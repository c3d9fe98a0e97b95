"""Photograph the backdrop: a shadow window ``(R, R)`` (1 = shadow) → a camera image ``(H, W, 3)`` uint8 BGR.

The virtual camera of the rig (issue 25). The backdrop (:class:`studio.sim.backdrop.BackdropLayout`) is a square
sheet in the plane ``z = backdrop_z`` (DESIGN §1), lit by the point light; the shadow covers only the window
(``window_m`` square centred on the light axis), the rest of the sheet is lit. The light model, on the sheet:
``paper · (falloff · (1 − (1 − ambient) · shadow) + spill · ramp) · ink``: the point light's ``cos³`` falloff, an
ambient share of it that also falls on the shadow, an uneven light spill (a linear ramp across the sheet, light
from elsewhere that lights the shadow too), and the ArUco markers' black ink. A pinhole camera
(:class:`CameraModel`) sees the sheet through the homography ``K [r1 r2 t]`` (``cv2.warpPerspective``); then
vignetting, blur and gaussian noise, all deterministic given ``seed``.

The paper photographs the shadow from behind a translucent backdrop, so the default camera sits behind it
(z < backdrop_z), a little off-axis; such a camera sees the backdrop mirrored in x (markers printed for the front
read mirrored), which the footage stage's homography handles (:mod:`studio.targets.backdrop`). The camera sees only
the sheet: the hand and the rest of the room are not drawn.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from studio.sim.backdrop import BackdropLayout

__all__ = ["CameraModel", "camera_from_backdrop", "photograph"]

BGR_TINT = np.array([0.92, 0.97, 1.0], dtype=np.float32)  # a warm light: blue a little lower than red
SUPERSAMPLE = 2  # samples per camera pixel side (a sensor integrates over its pixels' area)
TEXTURE_PX_M = 0.001  # finest texture pixel of the sheet, metres (finer than any default camera pixel)


def _vec3(value: object, name: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in value)  # type: ignore[union-attr]
    except (TypeError, ValueError) as e:
        raise ValueError(f"camera {name} must be three numbers [x, y, z], got {value!r}") from e
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise ValueError(f"camera {name} must be three finite numbers [x, y, z], got {value!r}")
    return v  # type: ignore[return-value]


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera looking at the backdrop, with its image effects (world frame of DESIGN §1, metres)."""

    position_m: tuple[float, float, float] = (0.15, 0.1, -2.6)  # camera centre: behind the backdrop, off-axis
    look_at_m: tuple[float, float, float] = (0.0, 0.0, -1.0)  # the point at the image centre
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)  # world direction that appears up in the image
    fov_deg: float = 50.0  # horizontal field of view, degrees (0, 170)
    width: int = 960  # image width, pixels
    height: int = 720  # image height, pixels
    blur_px: float = 1.0  # gaussian blur sigma (focus, lens), camera pixels; 0 = none
    noise: float = 0.01  # std of additive gaussian noise, 0..1 intensity units
    vignetting: float = 0.2  # darkening at the image corners, 0..1 (quadratic in the distance from the centre)
    ambient: float = 0.15  # share of the light that also falls on the shadow, 0..1 (0: black shadow)
    spill: float = 0.1  # strength of an uneven light spill across the backdrop (a linear ramp), 0..1
    spill_deg: float = 30.0  # direction (in backdrop x, y) in which the spill grows, degrees from +x
    markers: bool = True  # print the ArUco markers on the backdrop
    paper: float = 0.85  # brightness of the lit backdrop at the light axis, 0..1
    background: float = 0.06  # brightness of whatever the camera sees beyond the sheet, 0..1
    seed: int = 0  # seed of the noise

    def __post_init__(self) -> None:
        for name in ("position_m", "look_at_m", "up"):
            object.__setattr__(self, name, _vec3(getattr(self, name), name))
        if not 0 < self.fov_deg < 170:
            raise ValueError(f"camera fov_deg must be in (0, 170), got {self.fov_deg}")
        if self.width < 16 or self.height < 16:
            raise ValueError(f"camera image must be at least 16×16 pixels, got {self.width}×{self.height}")
        for name in ("noise", "vignetting", "ambient", "spill", "paper", "background"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"camera {name} must be in [0, 1], got {getattr(self, name)}")
        if self.blur_px < 0:
            raise ValueError(f"camera blur_px must be ≥ 0, got {self.blur_px}")
        forward = np.subtract(self.look_at_m, self.position_m)
        if np.linalg.norm(forward) < 1e-9 or np.linalg.norm(np.cross(forward, self.up)) < 1e-9 * np.linalg.norm(
            forward
        ):
            raise ValueError("camera look_at_m must differ from position_m and not lie along its up direction")

    @classmethod
    def from_dict(cls, d: dict | None) -> CameraModel:
        """A camera from a YAML mapping (keys as the fields; missing keys take the defaults); unknown keys raise
        ``ValueError`` naming the known ones."""
        d = dict(d or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown camera keys {unknown}; known: {', '.join(sorted(known))}")
        casts = {"width": int, "height": int, "seed": int, "markers": bool}
        kw = {}
        for k, v in d.items():
            if k in ("position_m", "look_at_m", "up"):
                kw[k] = _vec3(v, k)
            else:
                try:
                    kw[k] = casts.get(k, float)(v)
                except (TypeError, ValueError) as e:
                    raise ValueError(f"camera {k} must be a {casts.get(k, float).__name__}, got {v!r}") from e
        return cls(**kw)

    def to_dict(self) -> dict:
        """The fields as plain YAML-ready values (``from_dict`` reads it back)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    def intrinsics(self) -> np.ndarray:
        """``K (3, 3)``: square pixels, principal point at the image centre (OpenCV pixel centres at integers)."""
        f = (self.width / 2) / math.tan(math.radians(self.fov_deg) / 2)
        return np.array([[f, 0.0, (self.width - 1) / 2], [0.0, f, (self.height - 1) / 2], [0.0, 0.0, 1.0]])

    def rotation(self) -> np.ndarray:
        """``R_cam_world (3, 3)``: rows are the camera's x (image right), y (image down), z (forward) in world."""
        z = np.subtract(self.look_at_m, self.position_m)
        z = z / np.linalg.norm(z)
        x = np.cross(z, self.up)
        x = x / np.linalg.norm(x)
        return np.stack([x, np.cross(z, x), z])


def camera_from_backdrop(camera: CameraModel, backdrop_z: float = -1.0) -> np.ndarray:
    """``(3, 3)`` homography backdrop metres (x, y) → camera pixels (OpenCV: pixel centres at integers)."""
    R = camera.rotation()
    t = R @ (np.array([0.0, 0.0, backdrop_z]) - np.asarray(camera.position_m))
    H = camera.intrinsics() @ np.column_stack([R[:, 0], R[:, 1], t])
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


def _ink(layout: BackdropLayout, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Reflectance of the print at backdrop points ``x, y (N, N)`` metres: 0.06 on the markers' black cells, else 1
    (each texel samples the marker at its centre, so the markers' edges sit where the layout says)."""
    ink = np.ones(x.shape)
    h = layout.marker_m / 2
    for mid, (cx, cy) in zip(layout.ids, layout.centres_m()):
        bits = layout.marker_image(mid, cells_px=1) > 127  # one pixel per cell, as it reads from its readable side
        if layout.readable_from == "back":
            bits = bits[:, ::-1]  # as the audience sees a print that reads from behind
        cell = layout.marker_m / bits.shape[0]
        inside = (np.abs(x - cx) < h) & (np.abs(y - cy) < h)
        col = np.clip(((x[inside] - (cx - h)) / cell).astype(int), 0, bits.shape[1] - 1)
        row = np.clip((((cy + h) - y[inside]) / cell).astype(int), 0, bits.shape[0] - 1)
        ink[inside] = np.where(bits[row, col], 1.0, 0.06)
    return ink


@functools.lru_cache(maxsize=8)
def _sheet(
    layout: BackdropLayout, camera: CameraModel, pixel_m: float, n: int, light_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The sheet's light as textures ``(n, n)`` float32 of ``pixel_m`` texels centred on the light axis: ``lit``
    (no shadow anywhere) and ``shade`` (what a shadow takes away: the point light's share less the ambient).
    ``camera`` carries no seed here (the cache holds one entry per rig and camera)."""
    c = (np.arange(n) - (n - 1) / 2) * pixel_m
    x, y = np.meshgrid(c, -c, indexing="xy")  # row 0 at the top (+y), column 0 at the left (-x)
    falloff = (1.0 + (x * x + y * y) / light_m**2) ** -1.5  # cos³ of a point light light_m from the backdrop
    a = math.radians(camera.spill_deg)
    along = np.clip((x * math.cos(a) + y * math.sin(a)) / layout.size_m + 0.5, 0.0, 1.0)  # 0..1 across the sheet
    scale = camera.paper / (1.0 + camera.spill / 2)
    ink = _ink(layout, x, y) if camera.markers else 1.0
    direct = scale * falloff * ink
    lit = (direct + scale * camera.spill * along * ink).astype(np.float32)
    return lit, ((1.0 - camera.ambient) * direct).astype(np.float32)


@functools.lru_cache(maxsize=8)
def _vignette(camera: CameraModel) -> np.ndarray:
    """``(H, W)`` float32 multiplier: 1 at the image centre, ``1 − vignetting`` at the corners."""
    u = np.arange(camera.width) - (camera.width - 1) / 2
    v = np.arange(camera.height) - (camera.height - 1) / 2
    r2 = (u[None, :] ** 2 + v[:, None] ** 2) / ((camera.width / 2) ** 2 + (camera.height / 2) ** 2)
    return (1.0 - camera.vignetting * r2).astype(np.float32)


def photograph(
    shadow_window: np.ndarray,
    window_m: float,
    layout: BackdropLayout | None = None,
    camera: CameraModel | None = None,
    backdrop_z: float = -1.0,
    light_m: float = 4.0,
) -> np.ndarray:
    """Photograph the backdrop with ``shadow_window (R, R)`` (uint8 or bool, 1 = shadow; window pixel convention of
    :mod:`studio.sim.backdrop`) on it. ``window_m``: the window's side, metres; ``backdrop_z``: the backdrop plane;
    ``light_m``: the light's distance from the backdrop (its falloff).
    Returns the camera's ``(H, W, 3)`` uint8 BGR image. Deterministic given ``camera.seed``."""
    layout = layout or BackdropLayout()
    camera = camera or CameraModel()
    shadow = np.asarray(shadow_window)
    if shadow.ndim != 2 or shadow.shape[0] != shadow.shape[1] or shadow.shape[0] < 1:
        raise ValueError(f"shadow_window must be a square (R, R) image, got shape {shadow.shape}")
    if not 0 < window_m <= layout.size_m:
        raise ValueError(f"a {window_m} m window does not fit the {layout.size_m} m backdrop")
    H_cam = camera_from_backdrop(camera, backdrop_z)
    half = layout.size_m / 2
    sheet_corners = np.array([[x, y, backdrop_z] for x in (-half, half) for y in (-half, half)])
    if np.any((sheet_corners - camera.position_m) @ camera.rotation()[2] <= 1e-6):  # depth along the optical axis
        raise ValueError("the camera does not face the whole backdrop (part of it is behind the camera)")

    res = shadow.shape[0]
    factor = max(1, int(math.ceil((window_m / res) / TEXTURE_PX_M - 1e-9)))  # texture pixels per shadow pixel
    pixel_m = window_m / (res * factor)
    win = res * factor
    n = win + 2 * int(math.ceil((layout.size_m / pixel_m - win) / 2))  # the window's texels centred exactly
    lit, shade = _sheet(layout, dataclasses.replace(camera, seed=0), pixel_m, n, float(light_m))
    light = lit.copy()
    r0 = (n - win) // 2
    up = shadow.astype(bool)
    if factor > 1:
        up = np.repeat(np.repeat(up, factor, axis=0), factor, axis=1)
    inside = np.s_[r0 : r0 + win, r0 : r0 + win]
    np.subtract(light[inside], shade[inside], out=light[inside], where=up)

    # texture pixel (c, r) centre (OpenCV) → backdrop metres; the texture spans the sheet exactly
    sheet_m = n * pixel_m
    M_bd_tex = np.array([[pixel_m, 0, -sheet_m / 2 + pixel_m / 2], [0, -pixel_m, sheet_m / 2 - pixel_m / 2], [0, 0, 1]])
    # each camera pixel integrates light over its area (as a sensor does): 2×2 samples, averaged
    ss = SUPERSAMPLE
    fine_from_cam = np.array([[ss, 0.0, (ss - 1) / 2], [0.0, ss, (ss - 1) / 2], [0.0, 0.0, 1.0]])
    img = cv2.warpPerspective(
        light,
        fine_from_cam @ H_cam @ M_bd_tex,
        (camera.width * ss, camera.height * ss),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=float(camera.background),
    )
    if ss > 1:
        img = cv2.resize(img, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    if camera.vignetting:
        img *= _vignette(camera)
    if camera.blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), camera.blur_px)
    if camera.noise > 0:
        rng = np.random.default_rng(camera.seed)
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(camera.noise)
    bgr = cv2.transform(cv2.max(img, 0.0)[..., None], (BGR_TINT * 255.0).reshape(3, 1))
    return cv2.convertScaleAbs(bgr)  # rounds and saturates at 255
