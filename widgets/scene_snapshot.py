"""The rig scene in the Review tab: meshcat snapshots swapped without a blank moment (anywidget,
``scene_snapshot.js``).

A snapshot (:meth:`studio.review.scene.ShadowScene.static_html`) is a whole offline meshcat page (its JavaScript
inline, about 1 MB): it opens with no server, also where the kernel runs on another machine. Written into a plain
HTML widget, every new snapshot replaced the iframe on show, and the page showed meshcat's empty default scene (sky,
grid, axes) while the new one loaded and replayed its commands: a blank moment at every pose change, so while a show
played the scene was blank most of the time. Here the browser loads each new snapshot in an iframe of its own, hidden
over the one on show, and swaps them only once the new one has loaded and drawn its first frames; a snapshot that
arrives while one loads waits for it and then replaces it (the newest waits, older ones are dropped), so the scene
keeps up with the pose as fast as the browser draws it and is never blank.
"""

from __future__ import annotations

from pathlib import Path

import anywidget
import traitlets as t

HERE = Path(__file__).parent


class SceneSnapshot(anywidget.AnyWidget):
    """The meshcat snapshot on show (module doc): set ``page`` to a new snapshot to show it."""

    _esm = HERE / "scene_snapshot.js"
    page = t.Unicode("").tag(sync=True)  # the snapshot: a whole meshcat page (ShadowScene.static_html); "" none
    height = t.Int(420).tag(sync=True)  # px of the view (as wide as the output area; the artist can resize it)
