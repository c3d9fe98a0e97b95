"""A project's state as plain data: sources, frames, keyframes, masks, results and the show (DESIGN §4).

A :class:`ProjectState` is never changed in place: an edit makes a new one (``dataclasses.replace``) and the arrays
it holds are read-only (:func:`frozen`), so states can share arrays and the undo history can keep old states
cheaply. :mod:`studio.project.project_format` writes and reads them as a project folder.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from studio.errors import StudioError
from studio.imitate.config import LossConfig
from studio.motion.show import Show
from studio.sim.roll import parse_roll
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig


class ProjectError(StudioError):
    """A project folder is missing, damaged, of a newer format, or an edit cannot be made (the message says why)."""


class NotAProject(ProjectError):
    """A folder opened as a project has no project document (a face says how it makes one); ``file``: the path
    given when it is a file (an image or a video meant as the project's source)."""

    def __init__(self, message: str, file: str | None = None):
        super().__init__(message)
        self.file = file

    @classmethod
    def at(cls, path: Path) -> NotAProject:
        """The error for a ``path`` that is not there, or is a file rather than a project folder."""
        if path.is_file():
            return cls(f"not a project: {path} is a file (a project is a folder, NAME.shadow)", str(path))
        return cls(f"project not found: {path}")


class ResultsNeeded(ProjectError):
    """A show needs every keyframe's current result: some are missing or stale (optimise them first)."""


class ShowNeeded(ProjectError):
    """The project has no current show to export: optimise what is missing or stale and plan it."""


@dataclass(frozen=True)
class Source:
    """One source of a project (a still, a video file or a frame folder) and what loading it found."""

    path: str  # the path as the artist gave it
    absolute: str  # its absolute path when it was (last) read
    sha256: str  # content hash when it was read (a folder: its sorted file names and contents)
    kind: str  # "still" | "video" (a video file or an animated GIF) | "folder" (a folder of frames)
    footage: str = ""  # what the frames were: "still", "mask", "shadow" or "segmented"
    fps: float = 0.0  # source frame rate (0 for a still)
    duration_s: float = 0.0  # the source's clock, s (0 for a still)
    n_source: int = 1  # frames in the source
    frame_box: tuple[int, int, int, int] | None = None  # the shared square frame in source pixels (x, y, w, h)
    box: tuple[int, int, int, int] | None = None  # segmentation of colour footage: first-frame box (x, y, w, h)
    first_mask: np.ndarray | None = field(default=None, compare=False)  # … or first-frame mask (H, W) uint8 {0, 1}
    first_mask_path: str | None = None  # where that mask was read from, for the artist


@dataclass(frozen=True)
class Frame:
    """One sampled frame: where it comes from in its source."""

    source: int  # index into the project's sources
    source_frame: int  # frame index in the source
    time_s: float  # source time of that frame, s

    @property
    def key(self) -> str:
        """``"S:F"``: names the frame across re-samplings (painted strokes are kept by it)."""
        return f"{self.source}:{self.source_frame}"


@dataclass(frozen=True)
class Keyframe:
    """A cluster of frames that play one pose; ``id`` stays the same while the keyframe exists."""

    id: int  # stable number (results are kept by it)
    representative: int  # frame index whose target the pose imitates
    members: tuple[int, ...]  # ascending frame indices that play this keyframe's pose
    time_s: float | None = None  # the artist's show time for it (None: the video's clock)
    hold: bool = False  # the hand comes to rest at this pose
    edited: bool = False  # changed by hand since clustering

    def __post_init__(self) -> None:
        if self.representative not in self.members:
            raise ValueError(f"keyframe {self.id}: representative {self.representative} is not one of its members")


AWAITS = {  # what a run may still owe a result it saved, when it stops (cancelled, failed) before doing it
    "together": "to be refined together with its neighbours at the next run",  # studio.project.run_together
    "again": "to be optimised again at the next run: its move to or from another source is too fast",  # (stale)
}


@dataclass(frozen=True, eq=False)
class PoseResult:
    """An optimisation result of one keyframe and the inputs it was computed from."""

    pose: dict[str, float]  # joint name → rad
    loss: dict[str, float]  # loss components (studio.imitate.config.COMPONENTS; NaN = not computed)
    shadow: np.ndarray  # (R, R) uint8 {0, 1}, the rendered shadow of the pose
    inputs: str  # fingerprint of the inputs (studio.project.inputs.keyframe_inputs) it was computed from
    evaluation: dict[str, float] = field(default_factory=dict)  # components under the common measure, if any
    collision_free: bool = True  # the pose does not penetrate itself
    seconds: float = 0.0  # wall time it took
    awaits: str = ""  # what a run that stopped first still owes it (AWAITS: "together" or "again"); "": nothing

    def theta(self, joint_names: list[str]) -> np.ndarray:
        """The pose as ``(J,)`` rad in ``joint_names``' order."""
        return np.array([self.pose[n] for n in joint_names], dtype=np.float64)


@dataclass(frozen=True)
class MountApart:
    """A keyframe that the roll auto chose casts clearly worse than a roll of its own would: what one mount for the
    whole show costs it (:attr:`studio.imitate.roll_search.RollChoice.apart`)."""

    keyframe: int  # the keyframe's id
    frame: int  # its representative frame when the roll was chosen (a keyframe since made again is not named)
    loss: float  # its first answer's outline loss on the roll chosen
    own_roll: float  # rad, the roll best for it alone (to the roll search's coarse step)
    own_loss: float  # its first answer's outline loss there


@dataclass(frozen=True)
class Mount:
    """How the hand is mounted for the project's show (DESIGN §1): one roll about the light axis for all of it."""

    auto: bool = False  # the studio chooses the roll (``--roll auto``) before the keyframes are next optimised
    roll: float = 0.0  # rad, the roll the keyframes are optimised for (the artist's, or the one auto chose)
    chosen: bool = True  # auto: the roll has been chosen (False: it is chosen at the start of the next run)
    upright_loss: float | None = None  # auto: the retrieval's mean outline loss at roll 0, beside the chosen roll's
    loss: float | None = None  # auto: … at the chosen roll (both for the summary: what the roll bought)
    apart: tuple[MountApart, ...] = ()  # the keyframes another roll would cast clearly better (what this one costs)

    def measurable(self, keyframes: int) -> bool:
        """Whether the roll is one the artist set (not the paper's 0°) that nothing has measured yet, for a show of
        ``keyframes`` (at least two: a still has nothing to weigh it against)."""
        return not self.auto and bool(self.roll) and not self.apart and keyframes > 1

    @staticmethod
    def from_setting(roll: str | float | None) -> Mount:
        """``"auto"`` (or None) → to be chosen; a number → that roll in degrees, as the artist set it."""
        try:
            rad = parse_roll(roll)
        except ValueError as e:
            raise ProjectError(str(e)) from None
        return Mount(auto=True, chosen=False) if rad is None else Mount(auto=False, roll=rad)


@dataclass(frozen=True, eq=False)
class ProjectState:
    """Everything a project holds, as plain data; never changed in place (an edit makes a new state)."""

    title: str  # the artist's name for it
    created: str  # ISO 8601 UTC
    sources: tuple[Source, ...]  # what the frames come from
    video: VideoConfig  # sampling, threshold and framing of videos (``size`` frames stills too)
    still: TargetConfig  # threshold and framing of stills
    clustering: KeyframeConfig  # keyframe clustering (tau)
    weights: LossConfig  # loss weights
    frames: tuple[Frame, ...]  # N sampled frames, sources in order
    targets: np.ndarray  # (N, S, S) uint8 {0, 1}, the frames' shadow masks
    auto: np.ndarray  # (N, S, S) uint8 {0, 1}, automatic expressive masks
    additions: Mapping[str, np.ndarray]  # frame key → (S, S) uint8 {0, 1}, painted additions
    erasures: Mapping[str, np.ndarray]  # frame key → (S, S) uint8 {0, 1}, painted erasures
    keyframes: tuple[Keyframe, ...]  # in order of first appearance
    next_id: int  # the id the next new keyframe gets
    results: Mapping[int, PoseResult]  # keyframe id → its result
    show: Show | None = None  # the planned show
    show_inputs: str | None = None  # fingerprint (studio.project.inputs.show_inputs) the show was planned from
    mount: Mount = Mount()  # the hand's mount roll (projects from before it: upright, as they were optimised)

    def keyframe(self, k: int) -> Keyframe:
        """The keyframe with id ``k``; a ProjectError naming the ids there are otherwise."""
        for kf in self.keyframes:
            if kf.id == k:
                return kf
        raise ProjectError(f"no keyframe {k}; the keyframes are {[kf.id for kf in self.keyframes]}")


def same(a: Any, b: Any) -> bool:
    """Whether two pieces of project state hold the same values: arrays by shape and content, dataclasses field by
    field (``compare=False`` fields too), mappings and sequences item by item, floats with NaN equal to NaN.

    ``same(state_a, state_b)`` tells whether an edit changed anything, without the file format."""
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f" and b.dtype.kind == "f"))
    if type(a) is not type(b):
        return False
    if is_dataclass(a):
        return all(same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, Mapping):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def frozen(a: np.ndarray) -> np.ndarray:
    """A read-only uint8 {0, 1} copy of mask ``a`` (states share arrays, so none may change in place)."""
    out = (np.asarray(a) != 0).astype(np.uint8)
    out.flags.writeable = False
    return out


def mask_hash(mask: np.ndarray) -> str:
    """sha256 (hex) of a mask's shape and {0, 1} pixels."""
    m = np.ascontiguousarray(np.asarray(mask) != 0, dtype=np.uint8)
    h = hashlib.sha256(repr(m.shape).encode())
    h.update(m.tobytes())
    return h.hexdigest()


def text_hash(obj: Any) -> str:
    """sha256 (hex) of ``obj`` as canonical JSON."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, allow_nan=True).encode()).hexdigest()
