"""The joint ↔ servo map: which servo drives each joint, which way, where its zero is, and its soft limits.

File format (YAML, ``assets/calibration.yaml`` for the shipped hand)::

    format: shadow-studio-calibration
    version: 1
    hand_hash: 1a2b3c...        # optional: the URDF this was made for (a mismatch is only a warning)
    rig: {roll_deg: 30.0}       # optional: how the hand is mounted on this rig (DESIGN §1); absent: not recorded
                                # calibrate-rig adds the measured rig: light_distance_m, backdrop_distance_m,
                                # hand_offset_m, foam_mm (studio.sim.rig_file)
    joints:
      wrist: {id: 1, direction: 1, zero: 500, lower: -1.52, upper: 1.52}
      ...

``units = zero + direction · θ · UNITS_PER_RAD`` (θ in rad, 1000 units = 240°); ``lower``/``upper`` are soft
limits in rad, inside the URDF limits and inside the servo's 0..1000 travel. A calibration that records the rig's
mount roll plays only shows made for that roll (:func:`hardware.show_checks.check_mount`); one that does not (the
shipped file, files made before the roll existed) plays any, and the player says how the show wants the hand
mounted.
"""

from __future__ import annotations

import logging
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from studio.assets import asset

from hardware import constants as C
from hardware.errors import CalibrationError, CalibrationMissing
from studio.atomic import write_text
from studio.sim.hand import Hand
from studio.sim.rig_file import RigFileError, rig_from_mapping
from studio.sim.roll import file_deg
from studio.sim.shadow import Rig

log = logging.getLogger(__name__)

FORMAT_NAME = "shadow-studio-calibration"
DEFAULT_CALIBRATION = asset("calibration.yaml")
TOL = 1e-6  # rad slack when comparing against the URDF limits


@dataclass(frozen=True)
class JointCalibration:
    """One joint's servo."""

    name: str  # joint name, as in the URDF
    servo_id: int  # bus ID 0..253
    direction: int  # +1: servo units grow with the joint angle; -1: they shrink
    zero: float  # servo units at θ = 0
    lower: float  # soft lower limit, rad
    upper: float  # soft upper limit, rad


@dataclass(frozen=True)
class Calibration:
    """The map for every joint, in the hand's joint order."""

    joints: tuple[JointCalibration, ...]  # one per joint, hand order
    hand_hash: str | None = None  # URDF hash it was made for
    roll: float | None = None  # the rig's mount roll, rad, as recorded (None: the file does not say)
    measured: dict | None = None  # the rest of the rig as calibrate-rig measured it (rig-file keys); None: nominal

    def rig(self, base: Rig | None = None) -> Rig:
        """The rig this calibration records: ``base`` (default nominal) with the measured geometry and the roll."""
        rig = rig_from_mapping(self.measured or {}, base)
        return rig if self.roll is None else rig.with_roll(self.roll)

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def ids(self) -> list[int]:
        return [j.servo_id for j in self.joints]

    @property
    def lower(self) -> np.ndarray:
        """(J,) soft lower limits, rad."""
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        """(J,) soft upper limits, rad."""
        return np.array([j.upper for j in self.joints])

    def hand_box(self, hand: Hand) -> tuple[np.ndarray, np.ndarray]:
        """``(lower (21,), upper (21,))`` rad in ``hand``'s joint order: where the player stops each joint, these
        soft limits within the URDF's (a joint this calibration does not map: the URDF's)."""
        lower, upper = hand.lower.copy(), hand.upper.copy()
        for j in self.joints:
            if j.name in hand.joint_names:
                k = hand.joint_names.index(j.name)
                lower[k], upper[k] = max(lower[k], j.lower), min(upper[k], j.upper)
        return lower, upper

    def to_units(self, theta: np.ndarray) -> np.ndarray:
        """θ (..., J) rad → servo units (..., J), float (rounding happens on the bus)."""
        d = np.array([j.direction for j in self.joints], dtype=float)
        z = np.array([j.zero for j in self.joints], dtype=float)
        return z + d * np.asarray(theta, dtype=float) * C.UNITS_PER_RAD

    def to_rad(self, units: np.ndarray) -> np.ndarray:
        """Servo units (..., J) → θ (..., J) rad."""
        d = np.array([j.direction for j in self.joints], dtype=float)
        z = np.array([j.zero for j in self.joints], dtype=float)
        return (np.asarray(units, dtype=float) - z) * d / C.UNITS_PER_RAD

    def joint(self, name: str) -> JointCalibration:
        for j in self.joints:
            if j.name == name:
                return j
        raise CalibrationError(f"joint {name!r} is not in the calibration; known: {', '.join(self.joint_names)}")


def calibration_problems(cal: Calibration, hand: Hand) -> list[str]:
    """Every way ``cal`` disagrees with ``hand`` or the servos, one sentence each (empty when valid)."""
    problems = []
    names = [j.name for j in cal.joints]
    missing = [n for n in hand.joint_names if n not in names]
    unknown = [n for n in names if n not in hand.joint_names]
    twice = sorted({n for n in names if names.count(n) > 1})
    if missing:
        problems.append(f"joints not mapped to a servo: {', '.join(missing)}")
    if unknown:
        problems.append(f"joints not in the hand: {', '.join(unknown)}")
    if twice:
        problems.append(f"joints mapped more than once: {', '.join(twice)}")
    ids = [j.servo_id for j in cal.joints]
    for i in sorted({i for i in ids if ids.count(i) > 1}):
        problems.append(f"servo ID {i} is used by {', '.join(j.name for j in cal.joints if j.servo_id == i)}")
    urdf = {j.name: j for j in hand.joints}
    for j in cal.joints:
        if not 0 <= j.servo_id <= C.MAX_ID:
            problems.append(f"{j.name}: servo ID {j.servo_id} is outside 0..{C.MAX_ID}")
        if j.direction not in (1, -1):
            problems.append(f"{j.name}: direction must be 1 or -1, got {j.direction}")
        if not 0 <= j.zero <= C.POS_UNITS:
            problems.append(f"{j.name}: zero {j.zero} is outside the servo's 0..{C.POS_UNITS} units")
        if not j.lower < j.upper:
            problems.append(f"{j.name}: soft lower limit {j.lower:.4f} rad is not below the upper {j.upper:.4f} rad")
        if j.name in urdf:
            u = urdf[j.name]
            if j.lower < u.lower - TOL or j.upper > u.upper + TOL:
                problems.append(
                    f"{j.name}: soft limits [{j.lower:.4f}, {j.upper:.4f}] rad go outside the URDF limits "
                    f"[{u.lower:.4f}, {u.upper:.4f}] rad"
                )
        ends = sorted(j.zero + j.direction * np.array([j.lower, j.upper]) * C.UNITS_PER_RAD)
        if ends[0] < -0.5 or ends[1] > C.POS_UNITS + 0.5:
            problems.append(
                f"{j.name}: soft limits reach servo units {ends[0]:.0f}..{ends[1]:.0f}, beyond the servo's "
                f"0..{C.POS_UNITS}: move the zero or narrow the limits"
            )
    return problems


def validate(cal: Calibration, hand: Hand, path: str | Path | None = None) -> Calibration:
    """Return ``cal`` in the hand's joint order, or raise ``CalibrationError`` listing every problem."""
    problems = calibration_problems(cal, hand)
    if problems:
        where = f"{path}: " if path else ""
        raise CalibrationError(f"{where}calibration is invalid: " + "; ".join(problems))
    if cal.hand_hash and cal.hand_hash != hand.hash:
        log.warning("calibration was made for hand %s, this hand is %s", cal.hand_hash, hand.hash)
    order = {n: k for k, n in enumerate(hand.joint_names)}
    return Calibration(tuple(sorted(cal.joints, key=lambda j: order[j.name])), cal.hand_hash, cal.roll, cal.measured)


def default_calibration(hand: Hand, margin: float = 0.05) -> Calibration:
    """IDs 1..21 in joint order, direction +1, zero 500 (= 120°), soft limits ``margin`` rad inside the URDF
    (but never excluding the rest pose, so the hand can always go home)."""
    rest = hand.rest_pose()
    joints = tuple(
        JointCalibration(
            j.name,
            k + 1,
            1,
            float(C.CENTER_UNITS),
            float(min(j.lower + margin, rest[k])),
            float(max(j.upper - margin, rest[k])),
        )
        for k, j in enumerate(hand.joints)
    )
    return Calibration(joints, hand.hash)


def _joint_from_yaml(name: str, d: object, where: str) -> JointCalibration:
    if not isinstance(d, dict):
        raise CalibrationError(f"{where}joint {name!r}: expected a mapping with id, direction, zero, lower, upper")
    missing = [k for k in ("id", "direction", "zero", "lower", "upper") if k not in d]
    extra = sorted(set(d) - {"id", "direction", "zero", "lower", "upper"})
    if missing or extra:
        raise CalibrationError(f"{where}joint {name!r}: missing keys {missing}, unknown keys {extra}")
    try:
        return JointCalibration(
            name, int(d["id"]), int(d["direction"]), float(d["zero"]), float(d["lower"]), float(d["upper"])
        )
    except (TypeError, ValueError) as e:
        raise CalibrationError(f"{where}joint {name!r}: values must be numbers ({e})") from e


def load_calibration(path: str | Path | None, hand: Hand) -> Calibration:
    """Read and validate a calibration file (default: the shipped ``assets/calibration.yaml``)."""
    p = Path(path) if path is not None else DEFAULT_CALIBRATION
    if not p.is_file():
        raise CalibrationMissing(f"calibration file not found: {p}")
    where = f"{p}: "
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise CalibrationError(f"{where}not valid YAML ({e})") from e
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        raise CalibrationError(f"{where}not a calibration file (expected 'format: {FORMAT_NAME}')")
    if doc.get("version") != 1:
        raise CalibrationError(f"{where}unsupported calibration version {doc.get('version')!r} (this code reads 1)")
    joints = doc.get("joints")
    if not isinstance(joints, dict) or not joints:
        raise CalibrationError(f"{where}'joints' must map each joint name to its servo")
    rig = doc.get("rig")
    roll, measured = None, None
    if rig is not None:
        deg = rig.get("roll_deg") if isinstance(rig, dict) else None
        if isinstance(deg, bool) or not isinstance(deg, (int, float)) or not math.isfinite(deg):
            raise CalibrationError(f"{where}'rig' must be a mapping with roll_deg: the mount roll in degrees")
        roll = math.radians(float(deg))
        measured = {k: v for k, v in rig.items() if k != "roll_deg"} or None
        try:
            rig_from_mapping(measured or {}, where=f"{where}rig: ")
        except RigFileError as e:
            raise CalibrationError(str(e)) from None
    joint_list = tuple(_joint_from_yaml(n, d, where) for n, d in joints.items())
    cal = Calibration(joint_list, doc.get("hand_hash"), roll, measured)
    return validate(cal, hand, p)


def save_calibration(cal: Calibration, path: str | Path) -> None:
    """Write ``cal`` as YAML atomically (``studio.atomic``)."""
    doc = {
        "format": FORMAT_NAME,
        "version": 1,
        "hand_hash": cal.hand_hash,
        **({} if cal.roll is None else {"rig": {"roll_deg": file_deg(cal.roll), **(cal.measured or {})}}),
        "joints": {
            j.name: {
                "id": j.servo_id,
                "direction": j.direction,
                "zero": round(float(j.zero), 3),
                "lower": round(float(j.lower), 6),
                "upper": round(float(j.upper), 6),
            }
            for j in cal.joints
        },
    }
    head = "# Joint ↔ servo map (shadow-studio calibrate). units = zero + direction·θ·238.73; limits in rad.\n"
    write_text(path, head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))


def check_writable(path: str | Path) -> Path:
    """Raise ``CalibrationError`` unless a calibration can be written to ``path``: not a folder, in a folder that
    exists and takes new files (probed with a real temporary file). Call it before a long session, not after."""
    p = Path(path)
    folder = p.parent
    if p.is_dir():
        raise CalibrationError(f"{p} is a folder: give a file to write, e.g. {p / 'calibration.yaml'}")
    if not folder.is_dir():
        raise CalibrationError(f"cannot write {p}: the folder {folder} does not exist (create it or pick another)")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        raise CalibrationError(f"cannot write {p}: the folder {folder} does not take new files ({e})") from e
    return p
