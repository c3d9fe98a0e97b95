"""A project's review in Rerun (studio.review.recording and its pieces): a project-like recording saved to ``.rrd``
and read back holds the frames on ``frame``, the show on ``show_time`` (hand transforms that compose to the FK, the
backdrop textured with the rendered shadow), a played show's commanded vs measured angles, and the blueprint; live
streams reach a running ``rerun`` process (a job's progress on ``opt_step``, the player's ``on_sample`` ticks) and a
viewer that connects to a served stream; a real Project logs through ``log_project``."""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from hardware.dry_run import play_on_emulator
from studio.motion.plan import Keyframes, plan_show
from studio.review.blueprint import part
from studio.review.frames import KeyframeReview
from studio.review.readback import read_recording, scalar_series
from studio.review.recording import ProjectRecording, ReviewError
from studio.review.rig3d import RigReview, show_instants
from studio.review.sheets import SHADOW, display, tint
from studio.sim.hand import load_hand
from studio.sim.kinematics import fk_numpy
from studio.sim.shadow import Rig, ShadowRenderer

HAND = load_hand()
J = HAND.joint_names.index
RIG = Rig(resolution=64)
CFG = RigReview(texture=48, show_hz=10.0)
RERUN = shutil.which("rerun")
needs_rerun = pytest.mark.skipif(RERUN is None, reason="the `rerun` command (rerun-sdk's viewer) is not on PATH")


def poses() -> tuple[np.ndarray, np.ndarray]:
    qa = HAND.rest_pose()
    qb = qa.copy()
    qb[[J("wrist"), J("index_pip"), J("middle_mcp_flex")]] = (0.4, 0.7, 0.5)
    return qa, qb


@pytest.fixture(scope="module")
def scene_data():
    """A tiny project's worth of plain data: 6 frames of 2 keyframes (A A B B A B), a planned 1.2 s show and its
    playback on the emulator."""
    qa, qb = poses()
    sa, sb = ShadowRenderer(HAND, RIG).render(np.stack([qa, qb]))
    targets = np.stack([sa, sa, sb, sb, sa, sb])
    expressive = targets.copy()
    expressive[:, : RIG.resolution // 2] = 0
    keyframes = [
        KeyframeReview(7, 0, (0, 1, 4), qa, sa, None, {"total": 0.125, "clip": math.nan}),
        KeyframeReview(9, 2, (2, 3, 5), qb, sb, sb * 0.9, {"total": 0.25}, stale=True),
    ]
    show = plan_show(HAND, Keyframes.at([0.3, 1.2], [qa, qb]), title="tiny").show
    return targets, expressive, keyframes, show


@pytest.fixture(scope="module")
def played(scene_data):
    return play_on_emulator(scene_data[3])


@pytest.fixture(scope="module")
def saved(tmp_path_factory, scene_data, played):
    targets, expressive, keyframes, show = scene_data
    path = tmp_path_factory.mktemp("review") / "review.rrd"
    with ProjectRecording(path, rig=RIG, cfg=CFG) as review:
        which = review.log_frames(targets, expressive, keyframes, times=np.arange(6) / 4)
        shadows = review.log_show(show)
        ramp = review.log_playback(played)
    return path, read_recording(path), which, shadows, ramp


def rows(recording: dict, entity: str, timeline: str) -> list[dict]:
    """Every row of ``entity`` that has ``timeline``, as ``{column: value}``, sorted by that time."""
    out = []
    for batch in recording[entity]["batches"]:
        if timeline not in batch.schema.names:
            continue
        data = [n for n in batch.schema.names if not pa.types.is_temporal(batch.schema.field(n).type)]
        cols = {n: batch.column(n).to_pylist() for n in data if n != timeline}
        times = batch.column(timeline).cast("int64").to_pylist()
        out += [{"t": t, **{n: cols[n][i] for n in cols}} for i, t in enumerate(times)]
    return sorted(out, key=lambda r: r["t"])


@pytest.mark.slow
def test_frames_are_on_the_frame_timeline(saved, scene_data):
    _, rec, which, _, _ = saved
    targets, _, keyframes, _ = scene_data
    assert which.tolist() == [0, 0, 1, 1, 0, 1]
    for entity in ("/images/target", "/images/expressive", "/frames/keyframe", "/loss/frame/total"):
        assert "frame" in rec[entity]["timelines"], entity
        assert len(rows(rec, entity, "frame")) == len(targets), entity
    assert [v for _, v in scalar_series(rec, "/frames/keyframe", "frame")] == which.tolist()
    assert [v for _, v in scalar_series(rec, "/loss/frame/total", "frame")] == [0.125, 0.125, 0.25, 0.25, 0.125, 0.25]
    assert "/loss/frame/clip" not in rec  # a NaN component is not computed, never drawn as a value
    # a keyframe's shadows are logged where the frame's keyframe changes: frames 0, 2, 4, 5
    assert [r["t"] for r in rows(rec, "/images/rendered", "frame")] == [0, 2, 4, 5]
    predicted = [r["t"] for r in rows(rec, "/images/self_model", "frame") if r.get("Image:buffer")]
    assert predicted == [2, 5]  # only keyframe 9 has a prediction: frames 0 and 4 clear it
    lines = [r["TextLog:text"][0] for r in rows(rec, "/log/keyframes", "frame")]
    assert len(lines) == 2 and "id 7" in lines[0] and "stale" in lines[1] and "stale" not in lines[0]


def test_show_time_carries_the_hand_whose_transforms_compose_to_the_fk(saved, scene_data):
    _, rec, _, _, _ = saved
    show = scene_data[3]
    # the hand's shell and skeleton come from the URDF, static, each piece in its link's frame
    geometry = [e for e in rec if e.startswith("/world/hand/") and "/visual_geometries/" in e]
    assert {e.split("/visual_geometries/")[1].split("/")[0] for e in geometry} == set(HAND.link_names)
    assert all(rec[e]["static"] for e in geometry)
    assert rec["/world/light"]["static"] and rec["/world/backdrop/edge"]["static"]
    # one transform per joint and show sample; composed along the chain they put every link where FK does
    i = len(show.times) * 3 // 4
    T = {HAND.root: np.eye(4)}
    for joint in HAND.joints:
        r = rows(rec, f"/world/pose/{part(joint.name)}", "show_time")
        assert len(r) == len(show.times)
        row = r[i]
        assert row["t"] == pytest.approx(show.times[i] * 1e9, abs=1)
        assert (row["Transform3D:parent_frame"][0], row["Transform3D:child_frame"][0]) == (joint.parent, joint.child)
        local = np.eye(4)
        local[:3, :3] = Rotation.from_quat(row["Transform3D:quaternion"][0]).as_matrix()
        local[:3, 3] = row["Transform3D:translation"][0]
        T[joint.child] = T[joint.parent] @ local
    fk = fk_numpy(HAND, show.positions[i])[0]
    for k, link in enumerate(HAND.link_names):
        np.testing.assert_allclose(T[link], fk[k], atol=1e-5, err_msg=link)
    # the root link's frame is the world's
    root = rec[f"/world/pose/{part(HAND.root)}"]["batches"][0].to_pylist()[0]
    assert (root["Transform3D:parent_frame"], root["Transform3D:child_frame"]) == (["tf#/world"], [HAND.root])


def test_the_backdrop_carries_the_rendered_shadow_at_each_instant(saved, scene_data):
    _, rec, _, shadows, _ = saved
    show = scene_data[3]
    instants = show_instants(show, CFG.show_hz)
    backdrop = rows(rec, "/world/backdrop", "show_time")
    assert [r["t"] for r in backdrop] == [round(t * 1e9) for t in instants]
    renderer = ShadowRenderer(HAND, RIG.with_resolution(CFG.texture))
    for k in (0, len(instants) - 1):
        row = backdrop[k]
        fmt = row["Mesh3D:albedo_texture_format"][0]
        assert (fmt["width"], fmt["height"]) == (CFG.texture, CFG.texture)
        texture = np.array(row["Mesh3D:albedo_texture_buffer"][0], np.uint8).reshape(CFG.texture, CFG.texture, 3)
        expected = renderer.render_one(show.sample(instants[k]))
        np.testing.assert_array_equal(shadows[k], expected)
        np.testing.assert_array_equal(texture, tint(expected))  # the texture is that instant's shadow
        assert (texture == SHADOW).all(axis=-1).sum() == expected.sum() > 0
    assert not np.array_equal(shadows[0], shadows[-1])  # the show moves, and so does its shadow
    corners = np.array(backdrop[0]["Mesh3D:vertex_positions"])
    np.testing.assert_allclose(corners[:, 2], RIG.backdrop_z)
    np.testing.assert_allclose(np.ptp(corners[:, :2], axis=0), [RIG.window, RIG.window])
    # texture row 0 at +y and column 0 at -x, as the shadow images (Rerun's uv origin is the top-left)
    h = RIG.window / 2
    uv = np.stack([(corners[:, 0] + h) / RIG.window, (h - corners[:, 1]) / RIG.window], 1)
    np.testing.assert_allclose(np.array(backdrop[0]["Mesh3D:vertex_texcoords"]), uv, atol=1e-6)
    # on the frame timeline the backdrop shows each frame's keyframe shadow where it changes
    assert [r["t"] for r in rows(rec, "/world/backdrop", "frame")] == [0, 2, 4, 5]


def test_played_show_has_commanded_vs_measured_series(saved, played):
    path, rec, _, _, ramp = saved
    assert played.ok
    dt = 1 / 40
    assert ramp == pytest.approx(played.ramp_ticks * dt)
    for j, name in enumerate(played.joint_names):
        commanded = scalar_series(rec, f"/servo/{part(name)}/commanded", "show_time")
        assert [t for t, _ in commanded] == pytest.approx(list(played.t - ramp), abs=1e-9)
        assert [v for _, v in commanded] == pytest.approx(list(played.sent[:, j]))
        measured = scalar_series(rec, f"/servo/{part(name)}/measured", "play_time")
        mine = played.measured_joint == j
        assert [v for _, v in measured] == pytest.approx(list(played.measured_rad[mine]))
    moving = part("index_pip")
    assert max(v for _, v in scalar_series(rec, f"/servo/{moving}/measured", "play_time")) > 0.3  # it really moved
    assert "completed" in rows(rec, "/log/playback", "play_time")[0]["TextLog:text"][0]


def test_the_file_holds_the_project_blueprint(saved):
    from rerun.chunk import RrdReader

    blueprints = RrdReader(str(saved[0])).blueprints()
    assert [b.application_id for b in blueprints] == ["shadow_studio"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _viewer(out: Path, *args: str) -> tuple[subprocess.Popen, int]:
    """A headless `rerun` saving what it receives to ``out`` (a stand-in for a running viewer)."""
    port = _free_port()
    proc = subprocess.Popen([RERUN, "--port", str(port), "--save", str(out), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    return proc, port


def _received(proc: subprocess.Popen, out: Path, entity: str, timeout: float = 15.0) -> dict:
    """Wait until ``out`` holds ``entity``, then stop the viewer and read the file."""
    deadline = time.monotonic() + timeout
    found = False
    while time.monotonic() < deadline and not found:
        time.sleep(0.2)
        try:
            found = out.exists() and entity in read_recording(out)
        except Exception:  # the file is being written
            pass
    proc.send_signal(signal.SIGINT)
    proc.wait(10)
    assert found, f"{entity} never reached the viewer"
    return read_recording(out)


@pytest.mark.slow
@needs_rerun
def test_live_stream_reaches_a_running_viewer(tmp_path, scene_data):
    from studio.jobs import Job, JobQueue

    def engine(report, cancel):  # a job's search then refinement, reporting as the engine does
        for step in range(0, 31, 5):
            report("search", step, 30, 1.0 / (1 + step), np.eye(16, dtype=np.uint8))
        for step in range(0, 11, 5):
            report("refine", step, 10, 0.03 - 0.001 * step)
        return "done"

    proc, port = _viewer(tmp_path / "live.rrd")
    try:
        for _ in range(400):  # until it listens (a loaded machine takes seconds to start the viewer)
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.05)
        review = ProjectRecording(url=f"rerun+http://127.0.0.1:{port}/proxy", rig=RIG, cfg=CFG)
        with JobQueue() as queue:
            queue.subscribe(review.job_progress({1: "keyframe 3"}))
            assert queue.run(Job("imitate-keyframe", engine)).result == "done"
        hook = review.playback_hook()
        result = play_on_emulator(scene_data[3], on_sample=hook)
        review.log_show(scene_data[3])
        review.close()
        rec = _received(proc, tmp_path / "live.rrd", "/log/show")
    finally:
        proc.kill()
    search = scalar_series(rec, "/loss/keyframe_3/search", "opt_step")
    refine = scalar_series(rec, "/loss/keyframe_3/refine", "opt_step")
    assert [t for t, _ in search] == list(range(0, 31, 5)) and search[-1][1] == pytest.approx(1 / 31)
    assert [t for t, _ in refine] == [30, 35, 40]  # refinement follows on where the search ended
    assert "opt_step" in rec["/images/rendered"]["timelines"]
    assert any("done" in r["TextLog:text"][0] for r in rows(rec, "/log/jobs", "opt_step"))
    ticks = scalar_series(rec, f"/servo/{part('index_pip')}/commanded", "play_time")
    assert hook.samples == len(result.t) == len(ticks)
    assert [v for _, v in ticks] == pytest.approx(list(result.sent[:, J("index_pip")]))
    assert len(rows(rec, f"/world/pose/{part('wrist')}", "show_time")) == len(scene_data[3].times)


@needs_rerun
def test_a_served_stream_reaches_a_viewer_that_connects(tmp_path):
    review = ProjectRecording(serve=True, rig=RIG, cfg=CFG)
    try:
        assert review.server_url.startswith("rerun+http://127.0.0.1:")
        qa, _ = poses()
        review.log_frames(np.zeros((1, 8, 8), np.uint8), np.zeros((1, 8, 8), np.uint8), [KeyframeReview(0, 0, (0,))])
        review.flush()
        proc, _ = _viewer(tmp_path / "served.rrd", review.server_url)
        try:
            rec = _received(proc, tmp_path / "served.rrd", "/images/target")
        finally:
            proc.kill()
        assert "frame" in rec["/images/target"]["timelines"]
    finally:
        review.close()


@pytest.mark.slow
def test_a_review_needs_a_sink_a_listening_viewer_and_says_what_the_notebook_needs(tmp_path):
    with pytest.raises(ReviewError, match="path="):
        ProjectRecording()
    start = time.monotonic()
    with pytest.raises(ReviewError, match="no Rerun viewer is listening"):  # at once, not after rerun's 5 s wait
        ProjectRecording(url=f"rerun+http://127.0.0.1:{_free_port()}/proxy", rig=RIG)
    assert time.monotonic() - start < 2.0
    with pytest.raises(ReviewError, match="notebook=True"):
        ProjectRecording(tmp_path / "a.rrd", rig=RIG).show_notebook()
    review = ProjectRecording(notebook=True, rig=RIG)
    try:
        try:
            import rerun_notebook  # noqa: F401
        except ImportError:
            with pytest.raises(ReviewError, match="rerun-notebook"):
                review.show_notebook()
        else:
            assert review.show_notebook() is not None
    finally:
        review.close()


@pytest.mark.slow
def test_notebook_viewer_assets_are_inline_unless_the_user_chose():
    code = "import studio.review.recording, os, sys; print(os.environ['RERUN_NOTEBOOK_ASSET'])"
    env = {k: v for k, v in os.environ.items() if k != "RERUN_NOTEBOOK_ASSET"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "inline", out.stderr
    env["RERUN_NOTEBOOK_ASSET"] = "serve-local"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "serve-local", out.stderr


def test_log_project_reads_a_real_project(tmp_path):
    from studio.project.project import Project
    from studio.targets.video import VideoConfig

    folder = tmp_path / "clip"
    folder.mkdir()
    yy, xx = np.mgrid[:64, :64]
    for i in range(6):  # a body and an arm that swings between two places
        m = (yy - 40) ** 2 + (xx - 32) ** 2 < 12**2
        m |= (yy - 18) ** 2 + (xx - (20 if (i // 2) % 2 else 44)) ** 2 < 6**2
        Image.fromarray(m.astype(np.uint8) * 255).save(folder / f"{i:05d}.png")
    project = Project.create(tmp_path / "p.shadow", sources=[str(folder)], video=VideoConfig(size=32, fps=8.0, hz=8.0))
    first = project.keyframes[0]
    qa, qb = poses()
    shadow = ShadowRenderer(HAND, Rig(resolution=32)).render_one(qb)
    project.set_result(first.id, qb, {"total": 0.5}, shadow, inputs=project.keyframe_inputs(first.id))
    with ProjectRecording(tmp_path / "p.rrd", rig=RIG, cfg=CFG) as review:
        which = review.log_project(project, self_model=lambda th: np.full((len(th), 16, 16), 0.5))
    rec = read_recording(tmp_path / "p.rrd")
    assert which.tolist() == project.assignment().tolist()
    assert len(rows(rec, "/images/target", "frame")) == len(project.frames)
    assert [v for _, v in scalar_series(rec, "/frames/keyframe", "frame")] == which.tolist()
    changes = [k for k in range(len(which)) if k == 0 or which[k] != which[k - 1]]
    mine = [k for k in changes if which[k] == 0]  # where the optimised keyframe (the first to appear) starts playing
    assert first.members[0] == 0 and len(project.keyframes) > 1
    for entity in ("/images/rendered", "/images/self_model"):
        assert [r["t"] for r in rows(rec, entity, "frame") if r.get("Image:buffer")] == mine, entity
    wrist = {r["t"]: r for r in rows(rec, f"/world/pose/{part('wrist')}", "frame")}
    assert sorted(wrist) == changes  # the hand changes pose where the frames' keyframe does
    for k in changes:  # the optimised keyframe's pose, or the rest pose for one not optimised yet
        angle = qb[J("wrist")] if which[k] == 0 else 0.0
        assert Rotation.from_quat(wrist[k]["Transform3D:quaternion"][0]).magnitude() == pytest.approx(abs(angle))
    assert len(rows(rec, "/log/keyframes", "frame")) == len(project.keyframes)


def test_the_self_model_view_shows_the_shadow_as_the_rolled_mount_casts_it(tmp_path):
    """The self-model draws the upright hand's shadow; on a mount rolled by 25° the review shows it turned by the roll,
    as the rendered view and the audience see it (a view upright beside a rolled one would read as a wrong pose)."""
    from studio.assets import asset

    from studio.project.project import Project
    from studio.sim.roll import turn

    project = Project.create(tmp_path / "o.shadow", sources=[asset("targets/asl_o.jpeg")], roll=25.0)
    kf = project.keyframes[0]
    _, qb = poses()
    rig = Rig(resolution=project.state.targets.shape[-1], roll=project.mount.roll)
    project.set_result(kf.id, qb, {"total": 0.5}, ShadowRenderer(HAND, rig).render_one(qb),
                       inputs=project.keyframe_inputs(kf.id))  # fmt: skip
    upright = np.zeros((32, 32), np.float32)
    upright[4:12, 4:28] = 1.0  # a bar across the top: turned, it slants
    with ProjectRecording(tmp_path / "o.rrd", rig=RIG, cfg=CFG) as review:
        review.log_project(project, self_model=lambda th: np.repeat(upright[None], len(th), axis=0))
    logged = rows(read_recording(tmp_path / "o.rrd"), "/images/self_model", "frame")
    drawn = [r for r in logged if r.get("Image:buffer")]
    assert len(drawn) == 1 and math.radians(25.0) == pytest.approx(project.mount.roll)
    shown = np.asarray(drawn[0]["Image:buffer"][0], np.uint8)
    assert np.array_equal(shown, display(turn(upright, project.mount.roll)).ravel())
    assert not np.array_equal(shown, display(upright).ravel())
