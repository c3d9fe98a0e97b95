"""The rig in meshcat: the light, the hand's light-blocking shell, and the backdrop textured with the current shadow.

    with ShadowScene() as scene:          # starts a local meshcat server (its JavaScript is bundled: offline)
        scene.set_pose(theta)             # links moved by FK, the backdrop re-textured with the rendered shadow
        html = scene.static_html()        # a self-contained snapshot (scene.render_static() in a notebook cell)

Scene tree under ``/meshcat/shadow_studio`` (the rig's world frame, +y up, turned so that meshcat's +z is up):
``light`` (a small sphere at the light) and ``light/rays`` (to the window's corners), ``hand/<link>`` (moved to
``T_world_link`` by :meth:`ShadowScene.set_pose`) holding ``hand/<link>/<k>`` pieces of the URDF's visual shell
(capsules as a cylinder and two spheres, spheres, boxes), and ``backdrop``, a thin box whose face towards the light
is the rig's image window at ``z = backdrop_z``, its texture the shadow (row 0 at +y, column 0 at -x) rendered by
:class:`~studio.sim.shadow.ShadowRenderer`. The camera (:meth:`ShadowScene.set_camera`; by default
:class:`SceneConfig`'s) frames the light, the hand and the backdrop with its shadow. meshcat 0.3.2's
``Visualizer.close()`` is broken (DESIGN §6): :meth:`ShadowScene.close` closes the zmq socket and stops the server
process itself. The server a scene starts is
:mod:`studio.review.meshcat_server` (meshcat's bridge with both its zmq socket and its web server on 127.0.0.1; the
stock one serves the viewer on every interface).
"""

from __future__ import annotations

import contextlib
import io
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import meshcat
import meshcat.geometry as mg
import numpy as np

from studio.review.meshcat_server import start_local_server
from studio.review.sheets import tint
from studio.sim.hand import Geometry, Hand, load_hand
from studio.sim.kinematics import fk_numpy
from studio.sim.shadow import Rig, ShadowRenderer, roll_matrix

log = logging.getLogger(__name__)

ROOT = "shadow_studio"  # the scene's node under meshcat's root
# a quarter turn about x, taking +y to +z: the rig's world (+y up) into meshcat's (+z up), and a meshcat cylinder
# (axis +y) onto a URDF capsule's axis (+z)
RX90 = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


@dataclass(frozen=True)
class SceneConfig:
    """How the rig is drawn in meshcat."""

    texture: int = 256  # pixels per side of the backdrop's texture (the shadow rendered in the rig's window)
    backdrop_thickness: float = 0.01  # m, thickness of the box standing in for the backdrop plane
    light_radius: float = 0.04  # m, radius of the light's sphere
    rays: bool = True  # draw the light's rays to the corners of the backdrop window
    shell_color: int = 0x3A3A3A  # RGB hex of the hand's foam shell
    light_color: int = 0xFFD23C  # RGB hex of the light and its rays
    zmq_url: str | None = None  # a running meshcat server to draw in (None: start one, stopped by close())
    # where the camera looks from and at (rig frame, m, +y up; meshcat's 75° vertical field of view): beside and
    # above the hand, nearer the backdrop than the light, looking at the hand, so that the light, the hand and the
    # whole backdrop window with its shadow are all in a view 1.8 to 3 times as wide as it is tall, the hand about
    # as large as that allows (a tenth of the view's height and more, not the 2 % speck a view of the whole rig makes)
    camera_eye: tuple[float, float, float] = (1.1, 0.75, -0.4)
    camera_target: tuple[float, float, float] = (0.0, 0.1, 0.0)
    axes: bool = False  # show meshcat's axes at the world origin (they sit on the hand's wrist)


def _translate(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


def pieces(g: Geometry) -> list[tuple[mg.Geometry, np.ndarray]]:
    """meshcat geometries ``(geometry, T_link_piece (4, 4))`` for one URDF shell piece."""
    if g.kind == "capsule":
        half = np.array([0.0, 0.0, g.length / 2])
        return [
            (mg.Cylinder(g.length, g.radius), g.T_link_geom @ RX90),
            (mg.Sphere(g.radius), g.T_link_geom @ _translate(half)),
            (mg.Sphere(g.radius), g.T_link_geom @ _translate(-half)),
        ]
    if g.kind == "sphere":
        return [(mg.Sphere(g.radius), g.T_link_geom)]
    return [(mg.Box(list(g.size)), g.T_link_geom)]


def texture_png(shadow: np.ndarray) -> bytes:
    """PNG bytes of ``shadow (R, R)`` (1 = shadow) as the backdrop shows it: dark shadow on a grey backdrop."""
    ok, png = cv2.imencode(".png", cv2.cvtColor(tint(np.asarray(shadow)), cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError(f"cannot encode a {np.shape(shadow)} shadow as PNG")
    return png.tobytes()


class ShadowScene:
    """The rig in a meshcat viewer (module doc); a context manager that stops the server it started."""

    def __init__(self, hand: Hand | None = None, rig: Rig | None = None, cfg: SceneConfig | None = None):
        self.hand = hand or load_hand()
        self.rig = rig or Rig()
        self.cfg = cfg or SceneConfig()
        self.renderer = ShadowRenderer(self.hand, self.rig.with_resolution(self.cfg.texture))
        server, zmq_url = None, self.cfg.zmq_url
        if zmq_url is None:  # our own server: both its listeners on 127.0.0.1 (meshcat's web server is not)
            server, zmq_url, _ = start_local_server()
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints its URL; library code stays quiet
                self.vis = meshcat.Visualizer(zmq_url=zmq_url)
        except BaseException:
            if server is not None:
                server.kill()
                server.wait()
            raise
        self.vis.window.server_proc = server  # what close() stops (meshcat's own field for the server it starts)
        self.owns_server = server is not None
        self.closed = False
        self.theta: np.ndarray | None = None  # (21,) rad, the pose shown
        self.shadow: np.ndarray | None = None  # (R, R) uint8, the shadow on the backdrop
        self.camera: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # (eye, target), rig frame, m
        try:
            self._build()
            self.set_pose(self.hand.rest_pose())
        except BaseException:
            self.close()
            raise
        log.info("meshcat scene at %s", self.url)

    @property
    def url(self) -> str:
        """The live viewer's address (a local web page)."""
        return self.vis.url()

    @property
    def server_pid(self) -> int | None:
        """Process id of the meshcat server this scene started (None when drawing in someone else's)."""
        proc = self.vis.window.server_proc
        return None if proc is None else proc.pid

    def _build(self) -> None:
        cfg, rig, root = self.cfg, self.rig, self.vis[ROOT]
        root.set_transform(RX90)
        light = np.asarray(rig.light, dtype=float)
        root["light"].set_object(mg.Sphere(cfg.light_radius), mg.MeshBasicMaterial(color=cfg.light_color))
        root["light"].set_transform(_translate(light))
        if cfg.rays:
            h, z = rig.window / 2, rig.backdrop_z
            corners = np.array([[-h, h, z], [h, h, z], [h, -h, z], [-h, -h, z]]) - light  # in the light's frame
            ends = np.concatenate([[np.zeros(3), c] for c in corners]).T.astype(np.float32)  # (3, 8) segments
            rays = mg.LineSegments(mg.PointsGeometry(ends), mg.LineBasicMaterial(color=cfg.light_color))
            root["light/rays"].set_object(rays)
        shell = mg.MeshLambertMaterial(color=cfg.shell_color)
        for link in self.hand.link_names:
            k = 0
            for g in self.hand.visuals.get(link, ()):
                for geom, T in pieces(g):
                    node = root[f"hand/{link}/{k}"]
                    node.set_object(geom, shell)
                    node.set_transform(T)
                    k += 1
        box = _translate([0.0, 0.0, rig.backdrop_z - cfg.backdrop_thickness / 2])
        root["backdrop"].set_transform(box)
        self.set_camera(cfg.camera_eye, cfg.camera_target)
        self.vis["/Axes"].set_property("visible", cfg.axes)

    def set_camera(self, eye: Sequence[float], target: Sequence[float]) -> None:
        """Look from ``eye`` at ``target`` (both in the rig's frame, m; +y up): the viewer's camera orbits
        ``target``. meshcat puts the orbit centre at the origin of ``/Cameras/default`` and the camera at
        ``/Cameras/default/rotated/<object>``'s ``position``, in three.js axes (+y up), which are the rig's."""
        t, e = np.asarray(target, dtype=float), np.asarray(eye, dtype=float)
        camera = self.vis["/Cameras/default"]
        camera.set_transform(_translate(RX90[:3, :3] @ t))  # the orbit centre, in meshcat's world
        camera["rotated/<object>"].set_property("position", (e - t).tolist())
        self.camera = (tuple(e), tuple(t))

    def set_pose(self, theta: np.ndarray) -> np.ndarray:
        """Show joint angles ``theta (21,) rad``: every link moved to its FK pose, the backdrop textured with the
        pose's shadow. Returns that shadow ``(R, R)`` uint8 (1 = shadow). Invalid angles raise ``ValueError``."""
        th = self.hand.check_theta(theta)[0]
        T_world_link = roll_matrix(self.rig.roll) @ fk_numpy(self.hand, th[None])[0]  # the hand as it is mounted
        root = self.vis[ROOT]
        for link, T in zip(self.hand.link_names, T_world_link):
            root[f"hand/{link}"].set_transform(T)
        shadow = self.renderer.render(th[None], check=False)[0]
        self.set_backdrop(shadow)
        self.theta = th
        return shadow

    def set_roll(self, roll: float) -> None:
        """Mount the hand rolled by ``roll`` rad about the light axis (the next :meth:`set_pose` shows it so, and
        its shadow as that mount casts it)."""
        if roll != self.rig.roll:
            self.rig = self.rig.with_roll(roll)
            self.renderer = ShadowRenderer(self.hand, self.rig.with_resolution(self.cfg.texture))

    def set_backdrop(self, shadow: np.ndarray) -> None:
        """Texture the backdrop with ``shadow (R, R)`` (1 = shadow), e.g. a target to compare with."""
        side, t = self.rig.window, self.cfg.backdrop_thickness
        texture = mg.ImageTexture(mg.PngImage(texture_png(shadow)))
        self.vis[ROOT]["backdrop"].set_object(mg.Box([side, side, t]), mg.MeshBasicMaterial(map=texture))
        self.shadow = np.asarray(shadow)

    def static_html(self) -> str:
        """A self-contained HTML page of the scene as it is now (meshcat's JavaScript inline: opens offline)."""
        return self.vis.static_html()

    def render_static(self, height: int = 400):
        """The snapshot as a notebook cell's output (an ``IPython.display.HTML`` iframe, still orbitable)."""
        return self.vis.render_static(height=height)

    def close(self) -> None:
        """Stop talking to meshcat and stop the server this scene started (idempotent)."""
        if self.closed:
            return
        self.closed = True
        window = self.vis.window
        with contextlib.suppress(Exception):
            window.zmq_socket.close(linger=0)
        proc = window.server_proc if self.owns_server else None
        if proc is not None:
            if proc.poll() is None:
                proc.kill()
            proc.wait(timeout=10)
            for pipe in (proc.stdout, proc.stderr):
                if pipe is not None:
                    pipe.close()

    def __enter__(self) -> ShadowScene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # a forgotten scene does not leave its server running
        with contextlib.suppress(Exception):
            self.close()
