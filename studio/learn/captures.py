"""Capture sets: photographs of the real hand's shadow at measured poses, for learning from real shadows.

A capture set is a folder holding two files, written atomically (``studio.atomic``)::

    captures.npz   theta (N, 21) float32 measured joint angles, rad; masks (N, R, R) uint8, 1 = shadow in the
                   rig's window (rectified and binarised: the pixel convention and window of studio.sim.shadow.Rig);
                   t (N,) float64 capture times, s
    captures.json  {"format": "shadow-studio-captures", "version": 1, "resolution": R, "window_m": ...,
                    "rig": Rig.to_dict() used to rectify, "hand_hash": ..., "source": "...", "count": N,
                    "sha256": hash of the three arrays}

The arrays are written first and the record second, so the record never describes arrays that are not on disk.
:class:`CaptureRecorder` serves a capture loop: it adds pairs as they come and saves every ``save_every`` of them,
so an interrupted session keeps all but the last few. :func:`split` draws the held-out pairs deterministically.
"""

from __future__ import annotations

import hashlib
import logging
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from studio.atomic import JsonFileError, read_json, write_json, write_with
from studio.errors import StudioError, count

if TYPE_CHECKING:
    from studio.sim.hand import Hand
    from studio.sim.shadow import Rig

log = logging.getLogger(__name__)
FORMAT_NAME = "shadow-studio-captures"
FORMAT_VERSION = 1
ARRAYS, RECORD = "captures.npz", "captures.json"


class CaptureError(StudioError):
    """A capture set cannot be used (base class of the three below)."""


class CapturesNotFound(CaptureError):
    """The folder, or one of its two files, is not there."""


class CapturesCorrupt(CaptureError):
    """The files are unreadable, truncated, of another format or version, or disagree with each other."""


class CapturesMismatch(CaptureError):
    """The set is sound but made for another hand, rig or resolution than the one asked for."""


@dataclass
class CaptureSet:
    """Real shadows of measured poses (plain data; ``len()`` is the number of pairs)."""

    theta: np.ndarray  # (N, 21) float32 measured joint angles, rad
    masks: np.ndarray  # (N, R, R) uint8, 1 = shadow, in the window of ``rig``
    t: np.ndarray  # (N,) float64 capture times, s
    rig: dict  # the rig the photographs were rectified into (Rig.to_dict(): window, resolution, light, ...)
    hand_hash: str  # content hash of the hand URDF whose joint angles ``theta`` holds
    source: str = ""  # what made the set, in words (camera, session, or "rendered through a shifted rig")
    extra: dict = field(default_factory=dict)  # anything else worth keeping with the set (JSON types)

    def __post_init__(self) -> None:
        self.theta = np.ascontiguousarray(self.theta, dtype=np.float32).reshape(-1, 21)
        self.masks = np.ascontiguousarray(self.masks, dtype=np.uint8)
        self.t = np.ascontiguousarray(self.t, dtype=np.float64).reshape(-1)
        if not isinstance(self.rig, dict) or not {"resolution", "window"} <= set(self.rig):
            raise CapturesMismatch(f"a capture set's rig must be Rig.to_dict() (window, resolution), got {self.rig}")
        n, R = len(self.theta), int(self.rig["resolution"])
        if self.masks.shape != (n, R, R) or self.t.shape != (n,):
            raise CapturesMismatch(f"a capture set of {n} poses needs masks ({n}, {R}, {R}) and times ({n},) at the "
                                   f"rig's resolution, got {self.masks.shape} and {self.t.shape}")  # fmt: skip
        if self.masks.size and self.masks.max() > 1:
            raise CapturesMismatch("capture masks must be binary (1 = shadow, 0 = lit backdrop)")

    def __len__(self) -> int:
        return len(self.theta)

    @property
    def resolution(self) -> int:
        """Side of the masks, pixels."""
        return int(self.rig["resolution"])

    @property
    def window(self) -> float:
        """Side of the backdrop window the masks show, metres."""
        return float(self.rig["window"])

    @property
    def sha256(self) -> str:
        """Hash of the arrays (shapes and bytes): what a checkpoint records of the set it learnt from."""
        h = hashlib.sha256()
        for a in (self.theta, self.masks, self.t):
            h.update(repr((a.dtype.str, a.shape)).encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def subset(self, rows: np.ndarray) -> CaptureSet:
        """The pairs at ``rows`` (indices), in that order."""
        rows = np.asarray(rows, dtype=np.int64)
        return replace(self, theta=self.theta[rows], masks=self.masks[rows], t=self.t[rows])

    def record(self) -> dict:
        """What ``captures.json`` holds for this set."""
        return {"format": FORMAT_NAME, "version": FORMAT_VERSION, "resolution": self.resolution,
                "window_m": self.window, "rig": self.rig, "hand_hash": self.hand_hash, "source": self.source,
                "count": len(self), "sha256": self.sha256, "extra": self.extra}  # fmt: skip


def empty_captures(rig: dict, hand_hash: str, source: str = "") -> CaptureSet:
    """A set of no pairs for ``rig`` (its ``resolution`` sets the masks' side)."""
    R = int(rig["resolution"])
    return CaptureSet(np.zeros((0, 21)), np.zeros((0, R, R)), np.zeros(0), dict(rig), hand_hash, source)


def append_captures(cs: CaptureSet, theta: np.ndarray, masks: np.ndarray, t: np.ndarray) -> CaptureSet:
    """``cs`` with pairs ``theta (K, 21)``, ``masks (K, R, R)``, ``t (K,)`` added at the end (a new set)."""
    theta, masks = np.asarray(theta).reshape(-1, 21), np.asarray(masks).reshape(-1, cs.resolution, cs.resolution)
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    return replace(cs, theta=np.concatenate([cs.theta, theta]), masks=np.concatenate([cs.masks, masks]),
                   t=np.concatenate([cs.t, t]))  # fmt: skip


def save_captures(folder: str | Path, cs: CaptureSet) -> Path:
    """Write ``cs`` into ``folder`` (made if needed), arrays then record, each atomically; returns the folder."""
    folder = Path(folder)
    write_with(folder / ARRAYS, lambda f: np.savez_compressed(f, theta=cs.theta, masks=cs.masks, t=cs.t))
    write_json(folder / RECORD, cs.record())
    return folder


def load_captures(folder: str | Path, hand_hash: str | None = None) -> CaptureSet:
    """Read the capture set in ``folder`` (made for ``hand_hash`` when given). Raises :class:`CapturesNotFound`,
    :class:`CapturesCorrupt` or :class:`CapturesMismatch`, each saying what to do."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CapturesNotFound(f"{folder}: no capture set there (a folder with {RECORD} and {ARRAYS})")
    for name in (RECORD, ARRAYS):
        if not (folder / name).is_file():
            raise CapturesNotFound(f"{folder}: {name} is missing; capture the set again or copy the whole folder")
    try:
        rec = read_json(folder / RECORD, what="capture record")
    except JsonFileError as e:
        raise CapturesCorrupt(str(e)) from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT_NAME:
        raise CapturesCorrupt(f"{folder / RECORD}: not a shadow-studio capture record")
    if rec.get("version") != FORMAT_VERSION:
        raise CapturesCorrupt(f"{folder / RECORD}: capture format version {rec.get('version')!r}; this code reads "
                              f"{FORMAT_VERSION} (update shadow-studio)")  # fmt: skip
    if not isinstance(rec.get("rig"), dict) or not isinstance(rec.get("hand_hash"), str):
        raise CapturesCorrupt(f"{folder / RECORD}: the record has no rig or hand hash; capture the set again")
    try:
        with np.load(folder / ARRAYS, allow_pickle=False) as z:
            theta, masks, t = z["theta"], z["masks"], z["t"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise CapturesCorrupt(f"{folder / ARRAYS}: unreadable ({e.__class__.__name__}: {e}); "
                              "capture the set again or restore it from a copy") from None  # fmt: skip
    try:
        cs = CaptureSet(theta, masks, t, rec["rig"], rec["hand_hash"], str(rec.get("source", "")),
                        dict(rec.get("extra") or {}))  # fmt: skip
    except (CaptureError, ValueError, TypeError) as e:
        raise CapturesCorrupt(f"{folder}: {ARRAYS} does not fit {RECORD}: {e}") from None
    if len(cs) != rec.get("count") or cs.sha256 != rec.get("sha256"):
        raise CapturesCorrupt(f"{folder}: {ARRAYS} does not match {RECORD} ({len(cs)} pairs, record says "
                              f"{rec.get('count')}); the arrays were changed or only half copied")  # fmt: skip
    if rec.get("resolution") != cs.resolution or rec.get("window_m") != cs.window:
        raise CapturesCorrupt(f"{folder / RECORD}: its resolution and window disagree with its rig")
    if hand_hash is not None and cs.hand_hash != hand_hash:
        raise CapturesMismatch(f"{folder}: captured with hand {cs.hand_hash}, but the current hand is {hand_hash}; "
                               "capture the set again with this hand")  # fmt: skip
    return cs


def split(cs: CaptureSet, held_out_fraction: float = 0.1, seed: int = 0) -> tuple[CaptureSet, CaptureSet]:
    """``(train, held_out)``: ``round(held_out_fraction · N)`` pairs (at least one of each) held out at random from
    ``seed``, each part in capture order. The same set, fraction and seed give the same split."""
    if not 0 < held_out_fraction < 1:
        raise ValueError(f"held_out_fraction must be in (0, 1), got {held_out_fraction}")
    n = len(cs)
    if n < 2:
        raise CapturesMismatch(f"a capture set of {count(n, 'pair')} cannot be split: capture at least 2")
    k = min(n - 1, max(1, round(held_out_fraction * n)))
    order = np.random.default_rng(seed).permutation(n)
    return cs.subset(np.sort(order[k:])), cs.subset(np.sort(order[:k]))


def noisy(masks: np.ndarray, rng: np.random.Generator, edge_flip: float = 0.1, speckle: float = 1e-4) -> np.ndarray:
    """``masks (N, R, R)`` binarised as a camera would: each edge pixel (one whose 4-neighbours differ from it)
    flipped with probability ``edge_flip``, every pixel with ``speckle``."""
    m = masks.astype(bool)
    edge = np.zeros_like(m)
    edge[:, 1:] |= m[:, 1:] != m[:, :-1]
    edge[:, :-1] |= m[:, 1:] != m[:, :-1]
    edge[:, 1:, :] |= m[:, 1:, :] != m[:, :-1, :]
    edge[:, :-1, :] |= m[:, 1:, :] != m[:, :-1, :]
    flip = (edge & (rng.random(m.shape) < edge_flip)) | (rng.random(m.shape) < speckle)
    return (m ^ flip).astype(np.uint8)


def rendered_captures(
    n: int,
    rig: Rig,
    hand: Hand | None = None,
    seed: int = 0,
    rectified: Rig | None = None,
    edge_flip: float = 0.1,
    speckle: float = 1e-4,
) -> CaptureSet:
    """A stand-in for the camera: ``n`` self-exploration poses (``studio.sim.sampling``, from ``seed``) rendered
    through ``rig`` (the real rig: its light, roll, foam...) with :func:`noisy` binarisation noise, one pair a
    second. The set records ``rectified`` (the rig the studio believes in, whose window the photographs are
    rectified into; None: ``rig`` itself) and keeps ``rig`` in ``extra["true_rig"]``."""
    from studio.sim.hand import load_hand
    from studio.sim.sampling import sample_poses
    from studio.sim.shadow import ShadowRenderer

    hand = hand or load_hand()
    rng = np.random.default_rng(seed)
    theta, _ = sample_poses(hand, n, rng)
    renderer = ShadowRenderer(hand, rig)
    chunks = [noisy(renderer.render(theta[i : i + 256], check=False), rng, edge_flip, speckle)
              for i in range(0, n, 256)]  # fmt: skip
    masks = np.concatenate(chunks) if chunks else np.zeros((0, rig.resolution, rig.resolution))
    text = f"{n} poses rendered through extra.true_rig (seed {seed}, edge flips {edge_flip}, speckle {speckle})"
    recorded = (rectified or rig).with_resolution(rig.resolution).to_dict()
    return CaptureSet(theta, masks, np.arange(n, dtype=np.float64), recorded, hand.hash, text,
                      {"true_rig": rig.to_dict()})  # fmt: skip


class CaptureRecorder:
    """Adds pairs to the capture set in ``folder`` as a capture loop makes them, saving every ``save_every``.

    ``with CaptureRecorder(folder, rig, hand_hash) as rec: rec.append(theta, mask, t)`` continues a set already in
    ``folder`` (same rig and hand, else :class:`CapturesMismatch`) and saves what is left on leaving the block, even
    when the loop raised: an interruption loses at most the pairs since the last save.
    """

    def __init__(self, folder: str | Path, rig: dict, hand_hash: str, source: str = "", save_every: int = 25):
        if save_every < 1:
            raise ValueError(f"save_every must be ≥ 1, got {save_every}")
        self.folder, self.save_every = Path(folder), save_every
        if (self.folder / RECORD).exists() or (self.folder / ARRAYS).exists():
            self.captures = load_captures(self.folder, hand_hash)
            if self.captures.rig != rig:
                raise CapturesMismatch(f"{self.folder} holds captures rectified into another rig "
                                       f"({self.captures.rig}); use another folder")  # fmt: skip
            log.info("continuing %s at %d pairs", self.folder, len(self.captures))
        else:
            self.captures = empty_captures(rig, hand_hash, source)
        self._pending: list[tuple[np.ndarray, np.ndarray, float]] = []  # pairs not yet on disk

    def __len__(self) -> int:
        return len(self.captures) + len(self._pending)

    def append(self, theta: np.ndarray, mask: np.ndarray, t: float) -> int:
        """Add one pair (``theta (21,)`` rad, ``mask (R, R)`` 1 = shadow, time ``t`` s); returns the count."""
        R = self.captures.resolution
        theta, mask = np.asarray(theta, np.float32).reshape(21), np.asarray(mask, np.uint8)
        if mask.shape != (R, R) or mask.max(initial=0) > 1:
            raise CapturesMismatch(f"a capture mask must be binary ({R}, {R}), got {mask.shape}")
        self._pending.append((theta, mask, float(t)))
        if len(self._pending) >= self.save_every:
            self.save()
        return len(self)

    def save(self) -> CaptureSet:
        """Write every pair so far (nothing when none is new and the set is on disk); returns the set."""
        if self._pending:
            theta, masks, t = (np.stack(a) for a in zip(*self._pending))
            self.captures = append_captures(self.captures, theta, masks, t)
        if self._pending or not (self.folder / RECORD).exists():
            save_captures(self.folder, self.captures)
            self._pending = []
        return self.captures

    def __enter__(self) -> CaptureRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.save()
