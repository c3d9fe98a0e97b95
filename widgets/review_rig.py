"""The rig in meshcat for the Review panel (mixed into :class:`widgets.review.ReviewPanel`): the scene started in a
thread of the panel's, then the pose of the frame in view, or the pose the show player plays, drawn in it as an
offline snapshot (:class:`widgets.scene_snapshot.SceneSnapshot`)."""

from __future__ import annotations

import time

import numpy as np

from studio.review.scene import ShadowScene


class ReviewRig:
    """The meshcat part of ``ReviewPanel`` (it provides ``state``, ``messages``, ``_lock``, ``closed``, ``scene``,
    ``scene_view``, ``scene_pose``, ``_scene_drawn``, ``rig_heading``, ``show_frame`` and ``_opened_one``)."""

    def _open_scene(self) -> None:
        """The meshcat scene (the panel's second opening thread), then the pose of the frame in view drawn in it."""
        try:
            scene = self.messages.run(ShadowScene)  # None: the panel says why
            with self._lock:
                if self.closed:  # closed while it opened
                    if scene is not None:
                        scene.close()
                    return
                self.scene = scene
                self.rig_heading.value = "<b>the rig</b>" if scene else "<b>the rig</b> (no 3-D scene: see below)"
                self.show_frame()
        finally:
            self._opened_one()

    def show_pose(self, theta: np.ndarray) -> bool:
        """Show ``theta (21,) rad`` in the meshcat scene (the hand as the show mounts it, its shadow on the
        backdrop) and redraw the snapshot; False when there is no scene or the pose is invalid (the panel says
        why)."""
        if self.scene is None or self.scene.closed:
            return False
        self.scene.set_roll(self.state.project.mount.roll)
        if self.messages.run(self.scene.set_pose, theta) is None:
            return False
        self.scene_pose = np.asarray(theta)
        self.scene_view.page = self.scene.static_html()
        self._scene_drawn = time.monotonic()
        return True
