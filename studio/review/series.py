"""What a review logs whole and logs again after every edit, each version replacing the last in the viewer: each
frame's loss after a keyframe is optimised again, which keyframe each frame plays, the keyframes' and the show's
log lines, the servo angles of the latest playback.

Rerun keeps every row ever logged. Its plots draw every row of the range in view and average rows that share a
time: a frame's loss logged as 0.2 and, after an edit, as 0.8 was drawn at 0.5 (seen in the viewer); its text log
lists every row, so each edit repeated every keyframe's line. :class:`VersionedLog` logs version 0 of an entity at
its path and version n at ``PATH/vN``, and hides the version before by logging its archetype ``cleared()`` as
static data, which shadows every row that entity has on every timeline (a static ``Clear`` does not: the plot still
draws them). A series keeps its legend name (``total``, not ``v3``) and one colour in every version. What equals the
version on show is not logged again (the notebook logs the whole project after every edit, most of it unchanged, and
each version is one more entity in the viewer's streams). A recording read back names the version on show:
:func:`studio.review.readback.shown_series`.
"""

from __future__ import annotations

import hashlib
import zlib
from collections.abc import Sequence

import numpy as np
import rerun as rr

from studio.imitate.config import COMPONENTS

# colours of the series (RGB): a loss component by its place in COMPONENTS, anything else by a hash of its path
PALETTE = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)  # fmt: skip


def version_path(path: str, version: int) -> str:
    """The entity of ``version`` of what is logged at ``path``: the path itself for version 0, ``PATH/vN`` after."""
    return path if version == 0 else f"{path}/v{version}"


def series_colour(path: str) -> tuple[int, int, int]:
    """The colour of the series at ``path`` in every version (a loss component's by its name)."""
    leaf = path.rstrip("/").rpartition("/")[2]
    if leaf in COMPONENTS:
        return PALETTE[COMPONENTS.index(leaf) % len(PALETTE)]
    return PALETTE[zlib.crc32(path.encode()) % len(PALETTE)]


def digest(*arrays: np.ndarray | None) -> bytes:
    """A 16-byte digest of ``arrays`` (their dtypes, shapes and bytes; None counts as one value)."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = None if a is None else np.ascontiguousarray(a)
        h.update(b"none" if a is None else f"{a.dtype}{a.shape}".encode() + a.tobytes())
    return h.digest()


class VersionedLog:
    """The entities of one recording that are logged whole, each version replacing the last (module doc).

    Not thread-safe: one logger owns it (a :class:`~studio.review.recording.ProjectRecording` and its callers)."""

    def __init__(self, rec: rr.RecordingStream):
        self.rec = rec
        self._last: dict[str, tuple[int, type | None]] = {}  # path → (its last version, its archetype; None: no rows)
        self._content: dict[str, bytes] = {}  # path → a digest of what its last version holds

    def paths(self) -> list[str]:
        """The paths of everything logged so far (shown or hidden)."""
        return list(self._last)

    def shown(self, path: str) -> str | None:
        """The entity of the version of ``path`` on show (None: none logged, or the last one had no rows)."""
        version, kind = self._last.get(path, (-1, None))
        return version_path(path, version) if kind is not None else None

    def _same(self, path: str, indexes: Sequence[rr.TimeColumn], *content: np.ndarray) -> bool:
        """Whether the version of ``path`` logged last holds exactly this (then nothing is logged); else remember it."""
        times = [np.asarray(c.as_arrow_array()) for c in indexes]
        key = digest(np.array([c.timeline_name() for c in indexes]), *times, *content)
        if self._content.get(path) == key:
            return True
        self._content[path] = key
        return False

    def _next(self, path: str, kind: type, rows: int) -> str | None:
        """Hide the version of ``path`` on show and name the next (None when it has no rows: nothing is shown)."""
        previous, (version, shown_kind) = self.shown(path), self._last.get(path, (-1, None))
        if previous is not None:
            self.rec.log(previous, shown_kind.cleared(), static=True)
        self._last[path] = (version + 1, kind if rows else None)
        return version_path(path, version + 1) if rows else None

    def scalars(
        self,
        path: str,
        indexes: Sequence[rr.TimeColumn],
        values: np.ndarray,
        name: str | None = None,
        points: bool = False,
    ) -> str | None:
        """The series at ``path``: ``values (T,)`` at the times of ``indexes`` (one ``rr.TimeColumn`` per timeline,
        each ``(T,)``), replacing its last version; ``name`` for the legend (default: the path's last part);
        ``points``: drawn as a dot per row, no line between them (a value that steps, such as a keyframe number,
        would otherwise be drawn sloping between two frames).
        Returns the entity on show (None when ``values`` is empty: the series is then hidden)."""
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if self._same(path, indexes, np.array(["scalars", name or "", str(points)]), values):
            return self.shown(path)
        entity = self._next(path, rr.Scalars, len(values))
        if entity is not None:
            label = name or path.rstrip("/").rpartition("/")[2]
            colour = [series_colour(path)]
            style = rr.SeriesPoints(names=label, colors=colour, marker_sizes=[2.5]) if points else (
                rr.SeriesLines(names=label, colors=colour))  # fmt: skip
            self.rec.log(entity, style, static=True)
            self.rec.send_columns(entity, indexes=list(indexes), columns=rr.Scalars.columns(scalars=values))
        return entity

    def text(
        self, path: str, indexes: Sequence[rr.TimeColumn], lines: Sequence[str], level: str = "INFO"
    ) -> str | None:
        """The log lines at ``path``: ``lines (T,)`` at the times of ``indexes``, replacing the last version's.
        Returns the entity on show (None when there are no lines)."""
        if self._same(path, indexes, np.array(["text", level, *lines])):
            return self.shown(path)
        entity = self._next(path, rr.TextLog, len(lines))
        if entity is not None:
            columns = rr.TextLog.columns(text=list(lines), level=[level] * len(lines))
            self.rec.send_columns(entity, indexes=list(indexes), columns=columns)
        return entity
