"""The shard file format of self-exploration data: one compressed ``.npz`` per shard.

Each shard holds ``n`` samples:
- ``masks``: ``(n, ceil(H*W/8))`` uint8, each shadow bit-packed row-major (``np.packbits``), 1 = shadow;
- ``theta``: ``(n, 21)`` float32 joint angles, rad, in the hand's joint order;
- ``mode``: ``(n,)`` int8 sampler mode (0 uniform, 1 one finger, 2 two fingers);
- ``collides``: ``(n,)`` bool, the pose's skeleton self-collides;
- ``meta``: a JSON string with the format version, the rig (dict + hash), the hand hash, joint names, the
  resolution, the shard index and the seed.
Writes are atomic (``studio.atomic``), so a shard on disk is either complete or absent.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from studio.atomic import write_with
from studio.errors import ShardError

SHARD_FORMAT = 1
SHARD_KEYS = ("masks", "theta", "mode", "collides", "meta")


@dataclass
class Shard:
    """One shard in memory."""

    theta: np.ndarray  # (n, 21) float32 rad
    masks_packed: np.ndarray  # (n, ceil(H*W/8)) uint8 bit-packed shadows
    mode: np.ndarray  # (n,) int8 sampler mode
    collides: np.ndarray  # (n,) bool skeleton self-collision
    meta: dict  # format, rig, rig_hash, hand_hash, joint_names, resolution, index, seed

    @property
    def resolution(self) -> int:
        return int(self.meta["resolution"])

    def __len__(self) -> int:
        return len(self.theta)

    def masks(self, rows: slice | np.ndarray | None = None) -> np.ndarray:
        """Unpacked shadows ``(n, H, W)`` uint8 (optionally only ``rows``)."""
        packed = self.masks_packed if rows is None else self.masks_packed[rows]
        r = self.resolution
        return np.unpackbits(packed, axis=1, count=r * r).reshape(-1, r, r)


def pack_masks(masks: np.ndarray) -> np.ndarray:
    """``(n, H, W)`` {0,1} → ``(n, ceil(H*W/8))`` uint8."""
    n = masks.shape[0]
    return np.packbits(masks.reshape(n, -1).astype(bool), axis=1)


def write_shard(path: Path, shard: Shard) -> None:
    """Write atomically (``studio.atomic``): a partially written shard never appears under ``path``."""
    write_with(
        path,
        lambda f: np.savez_compressed(
            f,
            masks=shard.masks_packed,
            theta=shard.theta.astype(np.float32),
            mode=shard.mode.astype(np.int8),
            collides=shard.collides.astype(bool),
            meta=np.array(json.dumps(shard.meta, sort_keys=True)),
        ),
    )


def read_shard(path: Path, expect_hand_hash: str | None = None, expect_rig_hash: str | None = None) -> Shard:
    """Read and validate one shard; any problem raises :class:`ShardError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise ShardError(f"{path}: shard file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in SHARD_KEYS if k not in z.files]
            if missing:
                raise ShardError(f"{path}: not a shadow-studio shard (missing {missing})")
            data = {k: z[k] for k in SHARD_KEYS}
    except ShardError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise ShardError(f"{path}: unreadable or truncated shard ({e.__class__.__name__}: {e})") from None
    try:
        meta = json.loads(str(data["meta"]))
    except json.JSONDecodeError as e:
        raise ShardError(f"{path}: shard metadata is not valid JSON ({e})") from None
    if meta.get("format") != SHARD_FORMAT:
        raise ShardError(f"{path}: shard format {meta.get('format')} is not the supported {SHARD_FORMAT}")
    theta, masks = data["theta"], data["masks"]
    n, r = len(theta), int(meta.get("resolution", 0))
    expected_bytes = (r * r + 7) // 8
    if theta.ndim != 2 or masks.shape != (n, expected_bytes) or len(data["mode"]) != n or len(data["collides"]) != n:
        raise ShardError(f"{path}: inconsistent array shapes (theta {theta.shape}, masks {masks.shape})")
    if not np.isfinite(theta).all():
        raise ShardError(f"{path}: joint angles contain NaN/inf")
    if expect_hand_hash and meta.get("hand_hash") != expect_hand_hash:
        raise ShardError(
            f"{path}: made for hand {meta.get('hand_hash')}, not the current hand {expect_hand_hash}; "
            "collect new data for this hand"
        )
    if expect_rig_hash and meta.get("rig_hash") != expect_rig_hash:
        raise ShardError(f"{path}: made for rig {meta.get('rig_hash')}, not {expect_rig_hash}")
    return Shard(theta, masks, data["mode"], data["collides"], meta)


def shard_path(folder: Path, index: int) -> Path:
    return Path(folder) / f"shard_{index:05d}.npz"


def list_shards(folder: Path) -> list[Path]:
    """The shard files of a dataset folder, in index order (``ShardError`` if there are none)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ShardError(f"{folder}: dataset folder not found (make one with `shadow-studio collect`)")
    paths = sorted(folder.glob("shard_*.npz"))
    if not paths:
        raise ShardError(f"{folder}: no shard files (shard_*.npz) in this folder")
    return paths
