"""The mount roll where people meet it: the project keeps it (auto or degrees), every file records it, the hardware
refuses a show made for another roll, and the faces choose it (``--roll auto``) and show the rolled shadow."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from hardware.calibration import default_calibration, load_calibration, save_calibration
from hardware.errors import MountMismatch
from hardware.show_checks import beyond_soft_limits, check_mount, soft_limit_text
from studio.motion.show import Show, load_show
from studio.project.project import Project
from studio.project.project_format import DOC
from studio.project.state import Mount, ProjectError
from studio.sim.shadow import Rig, ShadowRenderer, iou
from studio.targets.video import VideoConfig

VIDEO = VideoConfig(hz=4.0, fps=8.0, size=64)


def make(tmp_path, sources, roll="auto") -> Project:
    return Project.create(tmp_path / "p.shadow", sources=[str(s) for s in sources], video=VIDEO, roll=roll)


def test_a_new_project_chooses_its_roll_and_an_old_one_stays_upright(tmp_path, sources, hand):
    p = make(tmp_path, sources)
    assert p.mount == Mount(auto=True, chosen=False) and p.summary()["mount"]["how"].startswith("roll auto")
    for kf in p.keyframes:
        p.set_result(kf.id, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(kf.id)[0])
    assert p.pending_keyframes() == []
    doc = json.loads((p.path / DOC).read_text())
    assert doc["mount"] == {"auto": True, "roll_deg": 0.0, "chosen": False, "upright_loss": None, "loss": None}
    del doc["mount"]  # a project saved before the mount roll existed: its results were optimised upright
    (p.path / DOC).write_text(json.dumps(doc))
    old = Project.open(p.path)
    assert old.mount == Mount() and old.pending_keyframes() == [] and old.summary()["mount"]["roll_deg"] == 0.0


def test_a_new_roll_makes_every_keyframe_stale_and_survives_reopening(tmp_path, sources, hand):
    p = make(tmp_path, sources, roll=0)
    assert p.mount == Mount(auto=False, roll=0.0)
    for kf in p.keyframes:
        p.set_result(kf.id, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(kf.id)[0])
    p.set_roll(-30)
    assert p.stale_keyframes() == [kf.id for kf in p.keyframes]
    p.undo()
    assert p.mount.roll == 0.0 and p.stale_keyframes() == []
    p.redo()
    q = Project.open(p.path)
    assert q.mount.roll == pytest.approx(math.radians(-30)) and not q.mount.auto
    assert "30.0° clockwise" in q.summary()["mount"]["how"]
    q.set_chosen_roll(math.radians(12.5), loss=0.1, upright_loss=0.2)
    assert q.mount.auto and q.mount.chosen and q.stale_keyframes() == [kf.id for kf in q.keyframes]
    with pytest.raises(ProjectError, match="an angle in degrees"):
        q.set_roll("sideways")


def test_show_and_calibration_record_the_roll_and_a_rig_at_another_is_refused(tmp_path, hand):
    show = Show.from_samples(hand, np.array([0.0, 1.0]), np.zeros((2, hand.dof)), roll=math.radians(30))
    cal = default_calibration(hand)
    check_mount(show.roll, cal)  # a calibration that does not record the rig plays any show
    save_calibration(cal.__class__(cal.joints, cal.hand_hash, math.radians(0.0)), tmp_path / "cal.yaml")
    upright = load_calibration(tmp_path / "cal.yaml", hand)
    assert upright.roll == 0.0 and "rig:" in (tmp_path / "cal.yaml").read_text()
    with pytest.raises(MountMismatch, match=r"roll \+30.0° .* records the rig at \+0.0°"):
        check_mount(show.roll, upright, tmp_path / "cal.yaml")
    check_mount(math.radians(0.3), upright)  # within half a degree
    (tmp_path / "bad.yaml").write_text((tmp_path / "cal.yaml").read_text().replace("roll_deg: 0.0", "roll_deg: x"))
    with pytest.raises(Exception, match="roll_deg"):
        load_calibration(tmp_path / "bad.yaml", hand)


def test_every_face_asks_one_mount_rule_across_the_half_turn(hand):
    """The Live panel's check and the player's check_mount are one rule: a calibration at -179.9° accepts a roll of
    179.8° (0.3° apart across the half turn) in both, and both refuse 10° against 11°, each in its own words."""
    from widgets.live_view import check_roll

    cal = default_calibration(hand)
    at = lambda deg: cal.__class__(cal.joints, cal.hand_hash, math.radians(deg))  # noqa: E731
    check_mount(math.radians(179.8), at(-179.9))
    check_roll(179.8, at(-179.9))
    with pytest.raises(MountMismatch, match=r"records the rig at \+11.0°"):
        check_mount(math.radians(10.0), at(11.0))
    with pytest.raises(ValueError, match=r"set the roll to 11.0°"):
        check_roll(10.0, at(11.0))
    check_roll(10.0, cal)  # a calibration that records no roll accepts every roll


def test_play_refuses_a_show_for_another_mount_in_one_line(tmp_path, hand, in_process):
    from hardware.calibration import save_calibration as save

    cal = default_calibration(hand)
    save(cal.__class__(cal.joints, cal.hand_hash, 0.0), tmp_path / "cal.yaml")
    show = Show.from_samples(hand, np.array([0.0, 0.5]), np.zeros((2, hand.dof)), roll=math.radians(-45))
    from studio.motion.show import save_show

    save_show(show, tmp_path / "show.json")
    r = in_process("play", tmp_path / "show.json", "--dry-run", "--calibration", tmp_path / "cal.yaml")
    assert r.returncode != 0 and "Traceback" not in r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert "-45.0°" in line and "records the rig at +0.0°" in line and "calibrate --roll" in line


@pytest.mark.slow
def test_a_still_at_a_set_roll_casts_its_shadow_rolled_through_every_file(tmp_path, sources, in_process, hand):
    """``imitate --roll 30``: the pose is chosen for the rolled mount; the result's shadow, the show and the
    keyframes file record the roll, and ``plan`` keeps it."""
    _, still = sources
    tiny = ["--search-batch", "8", "--search-iterations", "10", "--refine-steps", "10", "--refine-restarts", "1",
            "--candidates", "1", "--sweep-draws", "32", "--sweep-passes", "1"]  # fmt: skip
    r = in_process("imitate", still, "--out", tmp_path / "o", "--no-clip", "--quiet", "--roll", "30", *tiny)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["roll_deg"] == 30.0 and "30.0° counter-clockwise" in summary["mount"]
    project = Project.open(tmp_path / "o" / f"{still.stem}.shadow")
    kf = project.keyframes[0]
    result = project.results[kf.id]
    rolled = ShadowRenderer(hand, Rig(resolution=result.shadow.shape[0], roll=math.radians(30)))
    assert iou(rolled.render_one(result.theta(hand.joint_names)), result.shadow) == 1.0
    show = load_show(tmp_path / "o" / "show.json")
    assert show.roll == pytest.approx(math.radians(30))
    doc = json.loads((tmp_path / "o" / "keyframes.json").read_text())
    assert doc["roll_deg"] == 30.0
    planned = in_process("plan", tmp_path / "o" / "keyframes.json", "--out", tmp_path / "again.json")
    assert planned.returncode == 0, planned.stderr[-2000:]
    assert load_show(tmp_path / "again.json").roll == pytest.approx(math.radians(30))
    info = in_process("show-info", tmp_path / "again.json")
    assert "mount:        mount the hand rolled 30.0° counter-clockwise" in info.stdout


@pytest.mark.slow
def test_roll_auto_is_chosen_once_for_the_whole_show(tmp_path, sources, hand):
    from studio.imitate.config import CPU_SEQUENCE, RefineConfig, SearchConfig, SweepConfig
    from studio.project.run import RunConfig

    seq = CPU_SEQUENCE.__class__(
        first=SearchConfig(batch=8, iterations=10, lr=0.08), next=SearchConfig(batch=4, iterations=5, lr=0.08),
        refine=RefineConfig(**{**CPU_SEQUENCE.refine.__dict__, "steps": 10, "restarts": 1}), candidates=1,
        sweep=SweepConfig(**{**CPU_SEQUENCE.sweep.__dict__, "draws": 32, "passes": 1}),
    )  # fmt: skip
    clip, _ = sources
    p = Project.create(tmp_path / "v.shadow", sources=[str(clip)], video=VIDEO)
    report = p.run(RunConfig(sequence=seq, allow_late=True))
    assert report.roll_chosen and p.mount.auto and p.mount.chosen, report.message
    assert "chose the mount roll" in report.message and report.summary()["roll_deg"] == round(
        math.degrees(p.mount.roll), 1
    )
    assert p.show.roll == p.mount.roll and p.mount.loss <= p.mount.upright_loss
    again = p.run(RunConfig(sequence=seq, allow_late=True))
    assert not again.roll_chosen and again.optimised == [] and again.show == "current"


def test_the_review_and_the_scene_show_the_hand_mounted_rolled(tmp_path, hand):
    """Rerun: the root link turned by the show's roll, the backdrop's texture the rolled mount's shadow (pixels);
    meshcat: the links where the rolled FK puts them, the backdrop the rolled shadow."""
    from studio.review.readback import read_recording
    from studio.review.recording import ProjectRecording
    from studio.review.rig3d import RigReview, tint
    from studio.review.scene import ShadowScene
    from studio.sim.sampling import sample_poses

    theta = sample_poses(hand, 1, np.random.default_rng(5))[0][0]
    roll = math.radians(90)
    show = Show.from_samples(hand, np.array([0.0, 1.0]), np.stack([theta, theta]), roll=roll)
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_show(show)
    rec = read_recording(tmp_path / "r.rrd")
    col = "Transform3D:rotation_axis_angle"
    root = [row for b in rec[f"/world/pose/{hand.root}"]["batches"] for row in b.column(col).to_pylist()][-1]
    assert root[0]["angle"] == pytest.approx(roll)  # the last static mount is the one drawn
    side = RigReview().texture
    rolled = ShadowRenderer(hand, Rig(resolution=side, roll=roll)).render_one(theta)
    upright = ShadowRenderer(hand, Rig(resolution=side)).render_one(theta)
    batch = next(b for b in rec["/world/backdrop"]["batches"] if "Mesh3D:albedo_texture_buffer" in b.schema.names)
    buffer = batch.column("Mesh3D:albedo_texture_buffer").to_pylist()[0][0]
    texture = np.array(buffer, np.uint8).reshape(side, side, 3)
    np.testing.assert_array_equal(texture, tint(rolled))
    assert not np.array_equal(texture, tint(upright))
    with ShadowScene() as scene:
        scene.set_roll(roll)
        shadow = scene.set_pose(theta)
    assert iou(shadow, ShadowRenderer(hand, Rig(resolution=shadow.shape[0], roll=roll)).render_one(theta)) == 1.0


def test_the_joints_beyond_the_soft_limits_are_named_farthest_first_and_counted(hand):
    """One line, the four farthest joints named in degrees and the rest counted; none beyond: no line. A calibration
    that does not map a joint of the show leaves it out."""
    cal = load_calibration(None, hand)
    q = np.tile(hand.rest_pose(), (3, 1))
    assert beyond_soft_limits(q, hand.joint_names, cal) == [] and soft_limit_text([]) is None
    names = ["index_pip", "middle_pip", "ring_pip", "pinky_pip", "thumb_pip", "wrist"]
    for k, name in enumerate(names):
        j = hand.joint_names.index(name)
        q[1, j] = cal.upper[j] + 0.001 * (k + 1)  # wrist farthest, index_pip nearest
    beyond = beyond_soft_limits(q, hand.joint_names, cal)
    assert [n for n, _ in beyond] == names[::-1] and beyond[0][1] == pytest.approx(0.006)
    text = soft_limit_text(beyond)
    assert text.startswith("the show asks 6 joints beyond the calibration's soft limits (wrist by 0.3°, thumb_pip")
    assert "middle_pip" not in text and "ring_pip by 0.2° and 2 more)" in text
    assert text.endswith("its shadow differs from the planned one")
    assert "1 joint beyond" in soft_limit_text(beyond[:1])
    fewer = replace(cal, joints=tuple(j for j in cal.joints if j.name != "wrist"))
    assert [n for n, _ in beyond_soft_limits(q, hand.joint_names, fewer)] == names[-2::-1]
