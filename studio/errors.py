"""Typed errors that users can meet; each message says what is wrong and what to do."""

from __future__ import annotations


class StudioError(Exception):
    """Base class of every error the CLI reports as one clear line (no traceback)."""


class Cancelled(StudioError):
    """A long engine call stopped because its cancel event was set and has nothing worth returning (planning a show:
    half a plan is no show). Calls that can return what they finished return it instead; a job that ends with this
    is reported ``cancelled``, not failed."""


class ShardError(StudioError):
    """A dataset shard is missing, truncated, corrupt, or was made for another hand or rig."""


class ClosedError(StudioError):
    """An object was used after ``close()`` (or the end of its ``with`` block) released what it held."""


class TargetError(StudioError):
    """A target or footage file is missing, unreadable, not an image or video, or holds no usable shadow."""
