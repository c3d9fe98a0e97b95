"""The rig as people write it down: distances in metres, the roll in degrees, the foam in millimetres.

One mapping, read and written in three places: a **true rig** file (YAML, the virtual camera's world: the rig as it
really is, which the calibration must find), the **rig section** of a calibration file (the rig as calibrated), and
the JSON line ``calibrate-rig`` prints::

    light_distance_m: 2.7          # the point light's distance from the mount's nominal place (world z of the light)
    backdrop_distance_m: 1.0       # the backdrop's distance behind it (the backdrop is the plane z = -this)
    hand_offset_m: [0.01, 0.0, 0]  # where the mount really sits, from its nominal place, m
    mount_roll_deg: 3.0            # the mount's roll about the light axis (DESIGN §1)
    foam_mm: 1.5                   # the foam shell thicker than the URDF's by this much
    camera: {...}                  # a true rig only: the virtual camera (studio.sim.photo.CameraModel)

Missing keys take the base rig's values (the nominal rig of DESIGN §1 unless given). Radians and metres inside
(:class:`~studio.sim.shadow.Rig`); degrees and millimetres here, where people read them.
"""

from __future__ import annotations

import math
from pathlib import Path

import yaml

from studio.errors import StudioError, plural
from studio.sim.roll import file_deg
from studio.sim.shadow import Rig

KEYS = ("light_distance_m", "backdrop_distance_m", "hand_offset_m", "mount_roll_deg", "foam_mm")
ALIASES = {"roll_deg": "mount_roll_deg"}  # a calibration file's rig section names the roll roll_deg
EXTRA = ("camera",)  # keys a true rig file may carry beside the rig's own


class RigFileError(StudioError):
    """A rig file or rig section that cannot be read: the message names the file and the key."""


def _number(d: dict, key: str, where: str) -> float:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise RigFileError(f"{where}{key} must be a number, got {v!r}")
    return float(v)


def rig_from_mapping(d: dict, base: Rig | None = None, where: str = "") -> Rig:
    """The rig a mapping of :data:`KEYS` describes, on top of ``base`` (default: the nominal rig)."""
    base = base or Rig()
    if not isinstance(d, dict):
        raise RigFileError(f"{where}a rig must be a mapping of {', '.join(KEYS)}")
    d = {ALIASES.get(k, k): v for k, v in d.items()}
    unknown = set(d) - set(KEYS) - set(EXTRA)
    if unknown:
        raise RigFileError(
            f"{where}unknown {plural('key', len(unknown))} {', '.join(sorted(unknown))}: a rig has {', '.join(KEYS)}"
        )
    light = base.light
    if "light_distance_m" in d:
        light = (base.light[0], base.light[1], _number(d, "light_distance_m", where))
    backdrop_z = -_number(d, "backdrop_distance_m", where) if "backdrop_distance_m" in d else base.backdrop_z
    offset = base.hand_offset
    if "hand_offset_m" in d:
        v = d["hand_offset_m"]
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            raise RigFileError(f"{where}hand_offset_m must be [x, y, z] in metres, got {v!r}")
        offset = tuple(_number({"hand_offset_m": x}, "hand_offset_m", where) for x in v)
    roll = math.radians(_number(d, "mount_roll_deg", where)) if "mount_roll_deg" in d else base.roll
    foam = _number(d, "foam_mm", where) / 1000 if "foam_mm" in d else base.foam
    try:
        return Rig(light, backdrop_z, base.window, base.resolution, roll, offset, foam)
    except ValueError as e:
        raise RigFileError(f"{where}{e}") from None


def rig_to_mapping(rig: Rig) -> dict:
    """``rig`` as :data:`KEYS` (rounded to 0.1 mm, 1e-6°, 1 µm of foam: what a person can set or measure)."""
    return {
        "light_distance_m": round(rig.light[2], 4),
        "backdrop_distance_m": round(-rig.backdrop_z, 4),
        "hand_offset_m": [round(v, 4) for v in rig.hand_offset],
        "mount_roll_deg": file_deg(rig.roll),
        "foam_mm": round(rig.foam * 1000, 3),
    }


def read_rig_file(path: str | Path, base: Rig | None = None) -> tuple[Rig, dict | None]:
    """A true rig file → ``(rig, camera mapping or None)``; one clear :class:`RigFileError` for any problem."""
    p = Path(path)
    where = f"{p}: "
    if not p.is_file():
        raise RigFileError(f"rig file not found: {p}")
    try:
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise RigFileError(f"{where}not valid YAML ({e})") from None
    rig = rig_from_mapping(doc if doc is not None else {}, base, where)
    camera = doc.get("camera") if isinstance(doc, dict) else None
    if camera is not None and not isinstance(camera, dict):
        raise RigFileError(f"{where}camera must be a mapping (position_m, look_at_m, fov_deg, width, height, ...)")
    return rig, camera


def measured_rig(path: str | Path, base: Rig | None = None) -> Rig:
    """The rig geometry a calibration file (``calibrate-rig``'s ``calibration.yaml``: its ``rig`` section) or a rig
    file measured, on ``base``, **unrolled**: the mount's roll is a show's choice and the self-model, the retrieval
    index and training shadows live in the unrolled hand's frame (DESIGN §1); light, backdrop, offset and foam are the
    rig's own and go into every shadow they render."""
    p = Path(path)
    if not p.is_file():
        raise RigFileError(f"rig or calibration file not found: {p}")
    try:
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise RigFileError(f"{p}: not valid YAML ({e})") from None
    if isinstance(doc, dict) and "joints" in doc:  # a calibration file: its rig section, if it has one
        doc = doc.get("rig") or {}
    if not isinstance(doc, dict):
        raise RigFileError(f"{p}: a rig must be a mapping of {', '.join(KEYS)}")
    doc = {k: v for k, v in doc.items() if ALIASES.get(k, k) not in ("mount_roll_deg", *EXTRA)}
    return rig_from_mapping(doc, (base or Rig()).with_roll(0.0), f"{p}: ")
