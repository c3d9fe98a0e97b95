"""The notebook's hardware panels use one calibration, the studio's (widgets.calibration_file: the Rig panel's file in
the project's folder, else the shipped one): Export's play and real-vs-sim refuse a show for another mount roll in one
line, as ``play --calibration`` does; Export's limits line and the Jog sliders follow its soft limits, read again when
the Rig panel saves; a file that cannot be read stops what would drive the servos (Jog, Export, Live, Rig), saying
why."""

from __future__ import annotations

import html
import math
import re
from dataclasses import replace

import pytest
from studio.assets import asset

from hardware.calibration import load_calibration, save_calibration
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.sim.shadow import Rig, ShadowRenderer
from widgets.export import ExportPanel
from widgets.jog import JogPanel
from widgets.live import LivePanel
from widgets.real_vs_sim import RealVsSimView
from widgets.rig import RigPanel
from widgets.state import StudioState


@pytest.fixture
def state(tmp_path, hand):
    """A still's project at roll 0 with one result (index_pip 0.8 rad) and its planned show."""
    p = Project.create(tmp_path / "cal.shadow", [asset("targets/asl_o.jpeg")], roll=0)
    pose = hand.rest_pose().copy()
    pose[hand.joint_names.index("index_pip")] = 0.8
    kf = p.keyframes[0].id
    p.set_result(kf, pose, {"total": 0.3}, ShadowRenderer(hand, Rig(resolution=32)).render_one(pose),
                 inputs=p.keyframe_inputs(kf))  # fmt: skip
    s = StudioState(p, queue_for(p))
    panel = ExportPanel(s)
    assert panel.plan().wait(60).value == "done"
    panel.close()
    yield s
    s.close()


def write(state, hand, roll_deg=None, **upper) -> None:
    """The studio's calibration file: the shipped one at ``roll_deg``, joints' soft upper limits as given (rad)."""
    cal = load_calibration(None, hand)
    joints = tuple(replace(j, upper=upper[j.name]) if j.name in upper else j for j in cal.joints)
    roll = None if roll_deg is None else math.radians(roll_deg)
    save_calibration(replace(cal, joints=joints, roll=roll), state.project.path / "calibration.yaml")


def info(panel: ExportPanel) -> str:
    return html.unescape(re.sub("<[^>]+>", "", panel.info.value))


def test_export_and_real_vs_sim_refuse_a_show_for_another_roll_than_the_studios_calibration(state, hand):
    live = LivePanel(state)
    assert live.roll.value == 0.0
    write(state, hand, roll_deg=30.0)
    state.changed("hardware")  # what the Rig panel's "Save to calibration" says: Live's roll box follows the rig
    assert live.roll.value == 30.0
    live.close()
    panel = ExportPanel(state)
    try:
        assert panel.play() is None and not panel.jobs  # refused before any servo is opened
        said = panel.messages.text
        assert "wants the hand mounted at roll +0.0° but the calibration" in said and "+30.0°" in said, said
        assert str(state.project.path / "calibration.yaml") in said
        camera = RealVsSimView(state, panel)
        camera.camera.value, camera.true_rig.value = "virtual", str(state.project.path / "rig.yaml")
        assert camera.play() is None and "records the rig at +30.0°" in camera.messages.text
        write(state, hand, roll_deg=0.0)  # the rig recorded at the show's roll: it plays
        job = panel.play()
        assert job is not None and job.wait(60).value == "done", job.error
    finally:
        panel.close()


def test_the_limits_line_and_the_jog_sliders_follow_the_studios_calibration_when_the_rig_panel_saves(state, hand):
    panel, jog = ExportPanel(state), JogPanel(state)
    pip = hand.joint_names.index("index_pip")
    try:
        assert "limits:       every pose within the calibration's soft limits" in info(panel)
        assert jog.sliders[pip].max == pytest.approx(math.degrees(load_calibration(None, hand).upper[pip]))
        write(state, hand, index_pip=0.3)
        state.changed("hardware")  # what the Rig panel's "Save to calibration" says
        assert "1 joint beyond the calibration's soft limits (index_pip by 28.6°)" in info(panel), info(panel)
        assert jog.sliders[pip].max == pytest.approx(math.degrees(0.3)) and jog.cal.joints[pip].upper == 0.3
        assert jog.connect() and jog.session.calibration.joints[pip].upper == 0.3  # the servos it drives
        jog.disconnect()
        (state.project.path / "calibration.yaml").write_text("format: nope\n")  # broken: nothing is driven
        assert not jog.connect() and jog.session is None
        assert "could not connect" in jog.message.value and "not a calibration file" in jog.message.value
        assert "fix it, or move it away to use the shipped calibration" in jog.message.value
        state.changed("hardware")
        assert "calibration:  " in info(panel) and "not a calibration file" in info(panel)
        assert panel.play() is None and "not a calibration file" in panel.messages.text
        with pytest.raises(Exception, match="not a calibration file"):
            LivePanel(state)._calibration()  # the live session is refused, the runner says why
        rig = RigPanel(state)  # it starts from the shipped one (and says so), but calibrates on none but the file's
        assert "not a calibration file" in rig.messages.text and "using the shipped calibration" in rig.messages.text
        assert rig.calibrate() is False and not rig.running
        assert "could not calibrate" in rig.messages.text and "fix it, or move it away" in rig.messages.text
    finally:
        jog.close()
        panel.close()
