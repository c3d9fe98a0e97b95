"""The show file: a versioned JSON format for a timed joint trajectory (schema: ``studio/motion/show.schema.json``).

Layout (version 1)::

    {"format": "shadow-studio-show", "version": 1, "title": ..., "created": "2026-01-01T00:00:00+00:00",
     "hand": {"hash": ..., "joint_names": [21 names]}, "calibration": null | "ref", "rate_hz": 40,
     "samples": [[t, q_0, ..., q_20], ...],            # s, rad; t strictly increasing from 0
     "keyframes": [{"t", "source_frame", "target", "hold"}, ...],
     "limits": {"lower", "upper", "velocity", "acceleration", "jerk"},   # (21,) each
     "media": null | {"path", "kind": "audio"|"video", "offset_s"},      # media time = show time + offset_s
     "mount": {"roll_deg": 0.0},                       # the hand's mount roll (DESIGN §1); absent: 0 (older files)
     "provenance": {"loss_weights": {...}, "keyframe_losses": [...], ...}}

Writes are atomic (``studio.atomic``); floats are written with Python's shortest round-trip repr, so a
save/load round trip is lossless. Loading reports every problem found, one clear message each.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from studio.atomic import JsonFileError, read_json, write_text
from studio.errors import StudioError
from studio.motion.bounds import MAX_SHOW_BYTES
from studio.motion.limits import JointLimits
from studio.motion.show_checks import FORMAT_NAME, show_problems
from studio.sim.hand import Hand, load_hand
from studio.sim.roll import file_deg

log = logging.getLogger(__name__)

FORMAT_VERSION = 1  # the version this code writes and reads
DEFAULT_RATE_HZ = 40.0  # the controller's playback rate (DESIGN §4 "Hardware")


class ShowError(StudioError):
    """A show file (or a show being built) is malformed; ``problems`` lists each problem as one sentence."""

    def __init__(self, problems: list[str] | str, path: str | Path | None = None):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        self.path = None if path is None else str(path)
        where = f"{self.path}: " if self.path else ""
        if len(self.problems) == 1:
            msg = f"{where}{self.problems[0]}"
        else:
            msg = f"{where}{len(self.problems)} problems: " + "; ".join(self.problems)
        super().__init__(msg)


@dataclass(frozen=True)
class KeyframeMarker:
    """A keyframe the show passes exactly."""

    t: float  # s from the show start
    source_frame: int | None = None  # index of the video/target frame it came from, if any
    target: str | None = None  # reference of the target shadow (path or id), if any
    hold: bool = False  # True when the hand passes it at rest


@dataclass(frozen=True)
class MediaRef:
    """A soundtrack or video that plays along with the show."""

    path: str  # file path or URI of the media
    kind: str = "audio"  # "audio" or "video"
    offset_s: float = 0.0  # media time = show time + offset_s


@dataclass
class Show:
    """A planned show: ``positions (N, 21) rad`` at ``times (N,) s`` (0 first, strictly increasing)."""

    title: str  # human title
    joint_names: list[str]  # column order of ``positions`` (the hand's joint order)
    hand_hash: str  # content hash of the hand URDF it was planned for
    times: np.ndarray  # (N,) s, times[0] == 0, strictly increasing
    positions: np.ndarray  # (N, 21) rad
    limits: JointLimits  # per-joint limits used when planning
    rate_hz: float = DEFAULT_RATE_HZ  # nominal playback rate
    keyframes: list[KeyframeMarker] = field(default_factory=list)  # markers of exact poses
    calibration: str | None = None  # reference of the servo calibration, if any
    media: MediaRef | None = None  # optional soundtrack/video with offset
    provenance: dict[str, Any] = field(default_factory=dict)  # loss weights, per-keyframe losses, planner report
    roll: float = 0.0  # the mount roll the poses were chosen for, rad (DESIGN §1; 0: the paper's upright rig)
    created: str = ""  # ISO 8601 UTC; filled in by ``from_samples`` / ``save_show`` when empty
    format_version: int = FORMAT_VERSION  # version of the file format

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample."""
        return float(self.times[-1] - self.times[0])

    @classmethod
    def from_samples(
        cls, hand: Hand, times: np.ndarray, positions: np.ndarray, title: str = "untitled", **fields: Any
    ) -> Show:
        """Build a validated show for ``hand`` from ``times (N,) s`` and ``positions (N, 21) rad``.

        Other fields (``keyframes``, ``limits``, ``calibration``, ``media``, ``provenance``, ``rate_hz``,
        ``created``) may be given by name; ``limits`` defaults to ``JointLimits.from_hand(hand)``.
        Raises ``ShowError`` listing every problem.
        """
        t, q = np.asarray(times, dtype=np.float64), np.asarray(positions, dtype=np.float64)
        if t.ndim != 1 or q.shape != (len(t), hand.dof):
            raise ShowError(f"times must be (N,) and positions (N, {hand.dof}); got {t.shape} and {q.shape}")
        fields.setdefault("limits", JointLimits.from_hand(hand))
        fields.setdefault("created", _now())
        show = cls(
            title=title,
            joint_names=list(hand.joint_names),
            hand_hash=hand.hash,
            times=t.copy(),
            positions=q.copy(),
            **fields,
        )
        problems = show_problems(show.to_dict(), hand)
        if problems:
            raise ShowError(problems)
        return show

    def sample(self, t: np.ndarray | float) -> np.ndarray:
        """Linear interpolation of the samples at times ``t`` (clamped to the show): (K, 21) or (21,) rad."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.stack([np.interp(tt, self.times, self.positions[:, j]) for j in range(self.positions.shape[1])], 1)
        return out[0] if np.ndim(t) == 0 else out

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (plain Python types)."""
        t = np.asarray(self.times, dtype=float)
        q = np.asarray(self.positions, dtype=float)
        rows = np.concatenate([t[:, None], q], axis=1) if q.ndim == 2 and len(q) == len(t) else []
        return {
            "format": FORMAT_NAME,
            "version": int(self.format_version),
            "title": self.title,
            "created": self.created,
            "hand": {"hash": self.hand_hash, "joint_names": list(self.joint_names)},
            "calibration": self.calibration,
            "rate_hz": float(self.rate_hz),
            "samples": np.asarray(rows, dtype=float).tolist(),
            "keyframes": [
                {"t": float(k.t), "source_frame": k.source_frame, "target": k.target, "hold": bool(k.hold)}
                for k in self.keyframes
            ],
            "limits": self.limits.as_dict(),
            "media": None
            if self.media is None
            else {"path": self.media.path, "kind": self.media.kind, "offset_s": float(self.media.offset_s)},
            "provenance": self.provenance,
            "mount": {"roll_deg": file_deg(self.roll)},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Show:
        """Inverse of ``to_dict`` (no validation: use ``load_show`` / ``show_problems`` for that)."""
        rows = np.asarray(d["samples"], dtype=float)
        media = d.get("media")
        return cls(
            title=d["title"],
            joint_names=list(d["hand"]["joint_names"]),
            hand_hash=d["hand"]["hash"],
            times=rows[:, 0].copy(),
            positions=rows[:, 1:].copy(),
            limits=JointLimits.from_dict(d["limits"]),
            rate_hz=float(d["rate_hz"]),
            keyframes=[KeyframeMarker(**k) for k in d.get("keyframes", [])],
            calibration=d.get("calibration"),
            media=None if media is None else MediaRef(**media),
            provenance=d.get("provenance", {}),
            roll=math.radians(float((d.get("mount") or {}).get("roll_deg", 0.0))),
            created=d["created"],
            format_version=int(d["version"]),
        )

    def equals(self, other: Show) -> bool:
        """Exact equality of every field (arrays bit for bit)."""
        a, b = self.to_dict(), other.to_dict()
        return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


@lru_cache(maxsize=1)
def show_schema() -> dict[str, Any]:
    """The JSON Schema of the show file (shipped as package data)."""
    return json.loads(resources.files("studio.motion").joinpath("show.schema.json").read_text())


def _dumps(doc: dict[str, Any]) -> str:
    """Indented JSON with one line per sample row (readable and diff-friendly, still valid JSON)."""
    rows = doc["samples"]
    text = json.dumps({**doc, "samples": "\x00SAMPLES\x00"}, indent=2, allow_nan=False)
    body = ",\n".join("    " + json.dumps(r, allow_nan=False) for r in rows)
    return text.replace('"\\u0000SAMPLES\\u0000"', "[\n" + body + "\n  ]") + "\n"


def save_show(show: Show, path: str | Path, hand: Hand | None = None) -> Path:
    """Validate ``show`` and write it atomically to ``path``; returns the path. Raises ``ShowError``."""
    if not show.created:
        show = replace(show, created=_now())
    doc = show.to_dict()
    problems = show_problems(doc, hand, schema=show_schema())
    if problems:
        raise ShowError(problems, path)
    write_text(path, _dumps(doc))
    return Path(path)


def load_show(path: str | Path, hand: Hand | None = None) -> Show:
    """Read and validate a show file against ``hand`` (default: the shipped hand). Raises ``ShowError``.

    Checks: JSON syntax, format/version, schema, joint names against the hand, finite values, strictly increasing
    time from 0, angles within the hand's and the file's limits, sample-to-sample speed within the velocity limits.
    """
    path = Path(path)
    if path.is_dir():
        raise ShowError("a folder, not a show file", path)
    if not path.is_file():
        raise FileNotFoundError(f"show file not found: {path}")
    try:
        doc = read_json(path, MAX_SHOW_BYTES, "show file")
    except JsonFileError as e:
        raise ShowError(f"{e.reason}; plan the show again" if e.corrupt else e.reason, path) from None
    hand = hand or load_hand()
    problems = show_problems(doc, hand, schema=show_schema())
    if problems:
        raise ShowError(problems, path)
    show = Show.from_dict(doc)
    if show.hand_hash != hand.hash:
        log.warning("%s was planned for hand %s; this hand is %s (joint names match)", path, show.hand_hash, hand.hash)
    return show


def export_csv(show: Show, path: str | Path, degrees: bool = False) -> Path:
    """Write the samples as CSV: header ``t,<joint names>`` (``t`` in s, angles in rad or degrees); atomic."""
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    unit = "deg" if degrees else "rad"
    w.writerow(["t_s"] + [f"{n}_{unit}" for n in show.joint_names])
    q = np.degrees(show.positions) if degrees else show.positions
    for t, row in zip(show.times, q):
        w.writerow([repr(float(t))] + [repr(float(v)) for v in row])
    write_text(path, buf.getvalue())
    return Path(path)
