"""The rig in meshcat (studio.review.scene): a real meshcat server builds the scene (light, every link's shell,
the backdrop), ``set_pose`` moves the links where FK puts them and re-textures the backdrop with the rendered
shadow, snapshots are self-contained HTML (no script fetched from anywhere), and ``close()`` stops the server."""

from __future__ import annotations

import base64
import re
import socket
from urllib.parse import urlparse

import cv2
import numpy as np
import psutil
import pytest
import umsgpack

from studio.review.scene import ROOT, SceneConfig, ShadowScene, pieces
from studio.review.sheets import tint
from studio.sim.hand import load_hand
from studio.sim.kinematics import fk_numpy
from studio.sim.shadow import Rig, ShadowRenderer

HAND = load_hand()
RIG = Rig()
CFG = SceneConfig(texture=64)
PREFIX = f"/meshcat/{ROOT}"


def commands(html: str) -> dict[tuple[str, str], dict]:
    """The scene a snapshot holds: its embedded meshcat commands by ``(type, path under the scene)``."""
    out = {}
    for blob in re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html):
        cmd = umsgpack.unpackb(base64.b64decode(blob))
        out[(cmd["type"], cmd["path"].removeprefix(PREFIX).removeprefix("/"))] = cmd
    return out


def matrix(cmd: dict) -> np.ndarray:
    return np.array(cmd["matrix"], dtype=float).reshape(4, 4).T  # meshcat sends column-major


def backdrop_texture(scene: dict) -> np.ndarray:
    url = scene[("set_object", "backdrop")]["object"]["images"][0]["url"]
    png = base64.b64decode(url.removeprefix("data:image/png;base64,"))
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


@pytest.fixture(scope="module")
def scene():
    s = ShadowScene(HAND, RIG, CFG)
    yield s
    s.close()


def test_the_scene_holds_the_light_every_shell_piece_and_the_backdrop(scene):
    held = commands(scene.static_html())
    light = matrix(held[("set_transform", "light")])
    np.testing.assert_allclose(light[:3, 3], RIG.light)
    assert ("set_object", "light/rays") in held
    for link in HAND.link_names:
        n = sum(len(pieces(g)) for g in HAND.visuals[link])
        assert n > 0 and all(("set_object", f"hand/{link}/{k}") in held for k in range(n)), link
        assert ("set_object", f"hand/{link}/{n}") not in held
    box = matrix(held[("set_transform", "backdrop")])
    assert box[2, 3] + CFG.backdrop_thickness / 2 == pytest.approx(RIG.backdrop_z)  # its lit face is the backdrop
    geometry = held[("set_object", "backdrop")]["object"]["geometries"][0]
    assert (geometry["width"], geometry["height"]) == pytest.approx((RIG.window, RIG.window))
    # the root turns the rig's +y (up) into meshcat's +z (up)
    np.testing.assert_allclose(matrix(held[("set_transform", "")])[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-12)


def test_capsules_are_a_cylinder_along_the_capsule_axis_and_two_end_spheres():
    g = next(g for g in HAND.visuals["index_proximal"] if g.kind == "capsule")
    (cyl, T_cyl), (s1, T1), (s2, T2) = pieces(g)
    axis = g.T_link_geom[:3, :3] @ [0, 0, 1]
    np.testing.assert_allclose(T_cyl[:3, :3] @ [0, 1, 0], axis, atol=1e-12)  # meshcat cylinders run along +y
    np.testing.assert_allclose(T1[:3, 3] - T2[:3, 3], axis * g.length, atol=1e-12)
    assert cyl.height == g.length and cyl.radiusTop == s1.radius == s2.radius == g.radius


def test_set_pose_moves_the_links_to_their_fk_poses_and_retextures_the_backdrop(scene):
    before = commands(scene.static_html())
    rest_shadow = scene.shadow.copy()
    theta = HAND.rest_pose()
    theta[[HAND.joint_names.index(n) for n in ("wrist", "index_mcp_flex", "thumb_mcp_abd")]] = (0.6, 0.9, 0.5)
    shadow = scene.set_pose(theta)
    after = commands(scene.static_html())
    fk = fk_numpy(HAND, theta)[0]
    moved = 0
    for k, link in enumerate(HAND.link_names):
        np.testing.assert_allclose(matrix(after[("set_transform", f"hand/{link}")]), fk[k], atol=1e-6, err_msg=link)
        moved += not np.allclose(matrix(before[("set_transform", f"hand/{link}")]), fk[k], atol=1e-6)
    assert moved >= len(HAND.link_names) - 2  # everything past the wrist moved
    expected = ShadowRenderer(HAND, RIG.with_resolution(CFG.texture)).render_one(theta)
    np.testing.assert_array_equal(shadow, expected)
    np.testing.assert_array_equal(backdrop_texture(after), tint(expected))
    assert not np.array_equal(backdrop_texture(before), backdrop_texture(after)) and not np.array_equal(
        rest_shadow, shadow
    )
    with pytest.raises(ValueError, match="outside its limits"):
        scene.set_pose(HAND.upper + 1.0)


def project_ndc(eye: np.ndarray, target: np.ndarray, points: np.ndarray, aspect: float, fov_deg: float = 75.0):
    """``points (P, 3)`` (rig frame, +y up) in normalised device coordinates of a three.js perspective camera at
    ``eye`` looking at ``target`` (x, y in [-1, 1] on screen) → ``(P, 2)``, and their depths ``(P,)``."""
    f = (target - eye) / np.linalg.norm(target - eye)
    r = np.cross(f, [0.0, 1.0, 0.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = points - eye
    z = d @ f
    t = np.tan(np.radians(fov_deg) / 2)
    return np.stack([(d @ r) / z / (t * aspect), (d @ u) / z / t], axis=1), z


def test_the_camera_frames_the_light_the_hand_and_the_backdrop(scene):
    """From where the snapshot's camera looks, in a view 1.8 to 3 times as wide as tall (meshcat's 75° vertical
    field of view), the light, every link of the hand and the backdrop's corners are in view, the hand at least
    8 % of the view's height (the whole-rig view it replaces made it about 2 %), the backdrop's lit face towards
    the camera; meshcat's axes (on the wrist) are hidden."""
    held = commands(scene.static_html())
    orbit = matrix(held[("set_transform", "Cameras/default")])[:3, 3]  # meshcat's world, +z up
    offset = np.asarray(held[("set_property", "Cameras/default/rotated/<object>")]["value"], float)
    target = np.array([orbit[0], orbit[2], -orbit[1]])  # the rig's frame (+y up)
    eye = target + offset  # the camera's own axes (three.js, +y up) are the rig's
    np.testing.assert_allclose((tuple(eye), tuple(target)), (CFG.camera_eye, CFG.camera_target), atol=1e-12)
    assert held[("set_property", "Axes")]["value"] is False
    h, z = RIG.window / 2, RIG.backdrop_z
    corners = np.array([[-h, h, z], [h, h, z], [h, -h, z], [-h, -h, z]])
    links = fk_numpy(HAND, scene.theta)[0][:, :3, 3]
    points = np.vstack([np.asarray(RIG.light)[None], corners, links])
    for aspect in (1.8, 3.0):
        ndc, depth = project_ndc(eye, target, points, aspect)
        assert (depth > 0.1).all() and (np.abs(ndc) < 0.95).all(), (aspect, ndc.round(2))
        assert np.ptp(ndc[5:, 1]) / 2 >= 0.08, np.ptp(ndc[5:, 1]) / 2  # the hand's share of the view's height
    assert eye[2] > RIG.backdrop_z  # on the light's side of the backdrop: its shadow faces the camera


def test_snapshots_are_self_contained(scene):
    html = scene.static_html()
    assert not re.findall(r"<script[^>]+src=", html) and not re.findall(r"<link[^>]+href=", html)
    assert len(html) > 300_000  # meshcat's viewer (three.js) is inline
    cell = scene.render_static(height=300)
    assert "meshcat-pane" in cell.data and "octet-binary;base64," in cell.data and "height: 300px" in cell.data


def test_close_stops_the_server():
    with ShadowScene(HAND, RIG, CFG) as s:
        pid, port = s.server_pid, urlparse(s.url).port
        assert psutil.pid_exists(pid) and psutil.Process(pid).is_running()
        with socket.create_connection(("127.0.0.1", port), timeout=2):
            pass
    assert not psutil.pid_exists(pid)
    with pytest.raises(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
        pass
    s.close()  # idempotent


def test_the_server_stops_by_itself_when_its_studio_is_killed():
    """A studio killed without its exit handlers (a kernel killed, an abort) must not leave the server holding its
    ports: it sees its parent gone and stops within seconds."""
    import subprocess
    import sys
    import time

    script = (
        "import os\n"
        "from studio.review.meshcat_server import start_local_server\n"
        "proc, _, _ = start_local_server()\n"
        "print(proc.pid, flush=True)\n"
        "os._exit(0)  # no atexit: the server is left to itself\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    pid = int(out.stdout.split()[-1])
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and psutil.pid_exists(pid) and psutil.Process(pid).status() != "zombie":
        time.sleep(0.1)
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == "zombie", "the server outlived its studio"


def listening(pid: int) -> set[tuple[str, int]]:
    """``(address, port)`` of every TCP socket that process ``pid`` listens on."""
    return {(c.laddr.ip, c.laddr.port) for c in psutil.Process(pid).net_connections("tcp") if c.status == "LISTEN"}


def test_the_server_listens_on_localhost_only(scene):
    """Both the zmq socket and the viewer's web server (meshcat's own binds 0.0.0.0 and [::]): 127.0.0.1 only, so
    another machine cannot reach the scene, whatever address it tries."""
    socks = listening(scene.server_pid)
    web, zmq = urlparse(scene.url).port, urlparse(scene.vis.window.zmq_url).port
    assert socks == {("127.0.0.1", web), ("127.0.0.1", zmq)}, socks
    inet = (socket.AF_INET, socket.AF_INET6)
    ips = [a.address for addrs in psutil.net_if_addrs().values() for a in addrs if a.family in inet]
    outside = [ip for ip in ips if not ip.startswith(("127.", "::1", "fe80"))]
    for address in outside:  # the machine's other addresses: nothing answers there
        with pytest.raises(OSError), socket.create_connection((address, web), timeout=1):
            pass
