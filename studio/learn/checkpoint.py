"""The one checkpoint format of every trained network (the self-model and the inverse CNN), DESIGN §5.12.

A checkpoint is a ``torch.save``'d dict of plain types and tensors (readable with ``weights_only=True``)::

    {"format": "shadow-studio-checkpoint", "version": 1,
     "kind": "selfmodel" | "inverse",       # which network: a loader refuses the other kind
     "config": {...},                       # the network's architecture (its config dataclass as a dict)
     "hand_hash": "5569672ac0143923",       # the hand it was trained for: a loader refuses another hand
     "rig": {...},                          # rig of the training shadows (window, light, backdrop, resolution)
     "metrics": {...}, "train": {...},      # held-out metrics; the training config
     "state_dict": {...},                   # the weights, CPU tensors
     "extra": {...}}                        # resume state: step, elapsed_s (+ optimizer while training runs)

Writes are atomic (``studio.atomic``). A network module declares its ``kind`` and builds itself from a config dict;
:func:`save_model` and :func:`load_model` do the rest for either.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import torch

from studio.atomic import write_with
from studio.errors import StudioError
from studio.sim.hand import Hand, load_hand
from studio.sim.shadow import Rig

FORMAT_NAME = "shadow-studio-checkpoint"
FORMAT_VERSION = 1  # the version this code writes and reads
KINDS = {"selfmodel": "self-model", "inverse": "inverse-CNN"}  # kind → what it is, in words


class CheckpointError(StudioError):
    """A checkpoint is missing, unreadable, of another kind, or made for another hand. ``kind`` is the kind that was
    wanted ("selfmodel", "inverse"), so that a face can say how it makes one (the message names no command)."""

    def __init__(self, message: str, kind: str | None = None):
        super().__init__(message)
        self.kind = kind


class Network(Protocol):
    """What a checkpointed network provides (``SelfModel``, ``InverseCNN``)."""

    kind: str  # a key of KINDS
    cfg: Any  # its architecture dataclass
    hand: Hand  # the hand it is built for

    @classmethod
    def config_from_dict(cls, d: dict) -> Any: ...


@dataclass
class Checkpoint:
    """A checkpoint file's content (see the module docstring)."""

    kind: str  # "selfmodel" or "inverse"
    config: dict  # architecture, as its config dataclass's ``asdict``
    hand_hash: str  # content hash of the hand URDF it was trained for
    rig: dict  # rig geometry of the training shadows
    state_dict: dict[str, torch.Tensor] = field(default_factory=dict)  # weights (emptied once loaded into a model)
    metrics: dict = field(default_factory=dict)  # e.g. {"test_mae": ..., "val_mae": ..., "steps": ...}
    train: dict = field(default_factory=dict)  # the training config (``asdict`` of it)
    extra: dict = field(default_factory=dict)  # resume state: "step", "elapsed_s", "optimizer" (while training)


def _describe(kind: str) -> str:
    return KINDS.get(kind, repr(kind))


def save_checkpoint(path: str | Path, ckpt: Checkpoint) -> Path:
    """Write ``ckpt`` atomically to ``path`` (folders created); returns the path."""
    if ckpt.kind not in KINDS:
        raise ValueError(f"checkpoint kind must be one of {list(KINDS)}, got {ckpt.kind!r}")
    blob = {"format": FORMAT_NAME, "version": FORMAT_VERSION} | asdict(ckpt)
    blob["state_dict"] = {k: v.detach().cpu() for k, v in ckpt.state_dict.items()}
    return write_with(path, lambda f: torch.save(blob, f))


def read_checkpoint(path: str | Path, kind: str, hand_hash: str | None = None) -> Checkpoint:
    """Read a checkpoint of ``kind`` (trained for ``hand_hash`` when given); any problem raises
    :class:`CheckpointError` saying what to do."""
    path = Path(path)
    what = _describe(kind)
    if not path.is_file():
        raise CheckpointError(f"{path}: {what} checkpoint not found: train one there", kind)
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for corrupt files
        raise CheckpointError(f"{path}: unreadable checkpoint ({e.__class__.__name__}: {e})", kind) from None
    if not isinstance(blob, dict) or blob.get("format") != FORMAT_NAME or "state_dict" not in blob:
        raise CheckpointError(f"{path}: not a shadow-studio checkpoint", kind)
    if blob.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: checkpoint version {blob.get('version')!r}; this code reads "
                              f"{FORMAT_VERSION} (update shadow-studio or retrain it)", kind)  # fmt: skip
    if blob.get("kind") != kind:
        other = _describe(blob.get("kind"))
        raise CheckpointError(f"{path}: a checkpoint of the {other}, not of the {what}", kind)
    if hand_hash is not None and blob.get("hand_hash") != hand_hash:
        raise CheckpointError(
            f"{path}: trained for hand {blob.get('hand_hash')}, but the current hand is {hand_hash}; retrain it", kind
        )
    fields = ("config", "hand_hash", "rig", "state_dict", "metrics", "train", "extra")
    return Checkpoint(kind, **{k: blob[k] for k in fields if k in blob})


def same_config(a: dict, b: dict) -> bool:
    """Two architecture dicts are equal as JSON (tuples and lists alike)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def model_checkpoint(model: Network, rig: dict, metrics: dict | None = None, train: dict | None = None,
                     extra: dict | None = None) -> Checkpoint:  # fmt: skip
    """The checkpoint of ``model``'s current weights (its kind, config and hand come from the model)."""
    return Checkpoint(model.kind, asdict(model.cfg), model.hand.hash, dict(rig), model.state_dict(),
                      dict(metrics or {}), dict(train or {}), dict(extra or {}))  # fmt: skip


def save_model(path: str | Path, model: Network, rig: dict, metrics: dict | None = None,
               train: dict | None = None, extra: dict | None = None) -> Path:  # fmt: skip
    """Atomically save ``model`` (weights, kind, config, hand hash) with the rig and metrics to ``path``."""
    return save_checkpoint(path, model_checkpoint(model, rig, metrics, train, extra))


def load_model(path: str | Path, cls: type, hand: Hand | None = None, device: str | None = None):
    """Load a ``cls`` network (``SelfModel``, ``InverseCNN``) for ``hand`` (default: the shipped hand) on ``device``
    (None: CUDA when present), in eval mode; returns ``(model, checkpoint)`` (its ``state_dict`` emptied).
    Refuses a checkpoint of another kind or hand."""
    hand = hand or load_hand()
    ckpt = read_checkpoint(path, cls.kind, hand.hash)
    try:
        model = cls(cls.config_from_dict(ckpt.config), hand)
        model.load_state_dict(ckpt.state_dict)
    except (TypeError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"{path}: its weights do not fit its architecture ({e}); retrain it", cls.kind) from None
    ckpt.state_dict = {}
    model.trained_rig = dict(ckpt.rig)  # the rig of its training shadows: what its renderers and index draw with
    dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
    return model.to(dev).eval(), ckpt


def model_rig(rig: dict | None, resolution: int) -> Rig:
    """The rig a network's checkpoint records (:attr:`Checkpoint.rig`; None or empty: nominal) at ``resolution``,
    unrolled: the renderer that searches and refines beside that network draws with it (a calibrated rig's light,
    backdrop, mount offset and foam), and the retrieval index is keyed by it."""
    return Rig.from_dict(rig or {}).with_resolution(resolution).with_roll(0.0)
