"""Typed errors that users can meet; each message says what is wrong and what to do."""

from __future__ import annotations


class StudioError(Exception):
    """Base class of every error the CLI reports as one clear line (no traceback)."""


class ShardError(StudioError):
    """A dataset shard is missing, truncated, corrupt, or was made for another hand or rig."""


class ClosedError(StudioError):
    """An object was used after ``close()`` (or the end of its ``with`` block) released what it held."""


class TargetError(StudioError):
    """A target or footage file is missing, unreadable, not an image or video, or holds no usable shadow."""
