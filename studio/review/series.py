"""Scalar series that a later version replaces in the viewer: each frame's loss after a keyframe is optimised again,
which keyframe each frame plays after the keyframes change, the servo angles of the latest playback.

Rerun keeps every row ever logged, and its plots draw every row of the range in view, averaging rows that share a
time: a frame's loss logged as 0.2 and, after an edit, as 0.8 is drawn at 0.5 (seen in the viewer), so a series
logged again at the same times showed neither version. :class:`ScalarSeries` logs version 0 of a series at its
path and version n at ``PATH/vN``, and hides the version before by logging an empty ``Scalars`` to it as static
data, which shadows every row that entity has on every timeline (a static ``Clear`` does not: the plot still draws
them). Each version carries the series' name for the legend (``total``, not ``v3``) and one colour, the same in
every version. A recording read back names the version on show: :func:`studio.review.readback.shown_series`.
"""

from __future__ import annotations

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
    """The entity of ``version`` of the series at ``path``: the path itself for version 0, ``PATH/vN`` after."""
    return path if version == 0 else f"{path}/v{version}"


def series_colour(path: str) -> tuple[int, int, int]:
    """The colour of the series at ``path`` in every version (a loss component's by its name)."""
    leaf = path.rstrip("/").rpartition("/")[2]
    if leaf in COMPONENTS:
        return PALETTE[COMPONENTS.index(leaf) % len(PALETTE)]
    return PALETTE[zlib.crc32(path.encode()) % len(PALETTE)]


class ScalarSeries:
    """The scalar series of one recording, each sent whole and replacing its previous version (module doc).

    Not thread-safe: one logger owns it (a :class:`~studio.review.recording.ProjectRecording` and its callers)."""

    def __init__(self, rec: rr.RecordingStream):
        self.rec = rec
        self._last: dict[str, tuple[int, bool]] = {}  # path → (its last version, whether that one has rows)

    def paths(self) -> list[str]:
        """The paths of every series sent so far (shown or hidden)."""
        return list(self._last)

    def shown(self, path: str) -> str | None:
        """The entity of the version of ``path`` on show (None: none sent, or the last one had no rows)."""
        version, drawn = self._last.get(path, (-1, False))
        return version_path(path, version) if drawn else None

    def send(
        self, path: str, indexes: Sequence[rr.TimeColumn], values: np.ndarray, name: str | None = None
    ) -> str | None:
        """The series at ``path``: ``values (T,)`` at the times of ``indexes`` (one ``rr.TimeColumn`` per timeline,
        each ``(T,)``), hiding its previous version; ``name`` for the legend (default: the path's last part).
        Returns the entity written (None when ``values`` is empty: the series is then hidden)."""
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        previous = self.shown(path)
        if previous is not None:
            self.rec.log(previous, rr.Scalars(np.zeros(0)), static=True)
        version = self._last.get(path, (-1, False))[0] + 1
        self._last[path] = (version, len(values) > 0)
        if not len(values):
            return None
        entity = version_path(path, version)
        label = name or path.rstrip("/").rpartition("/")[2]
        self.rec.log(entity, rr.SeriesLines(names=label, colors=[series_colour(path)]), static=True)
        self.rec.send_columns(entity, indexes=list(indexes), columns=rr.Scalars.columns(scalars=values))
        return entity
