"""The Export panel driven without a browser: plan a tiny project's show as a job (allow late), write and validate
the show file, show-info, CSV, and play on the emulator (real pyserial over a pty) with progress and stop."""

from __future__ import annotations

import csv
import time

import numpy as np
import pytest
from studio.assets import asset

from hardware.emulator import ServoEmulator
from hardware.session import ServoSession
from studio.jobs import JobState
from studio.motion.show import load_show
from studio.motion.show_info import show_info_lines
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.project.show_timing import ShowLayout
from studio.sim.shadow import Rig, ShadowRenderer
from widgets.export import ExportConfig, ExportPanel, default_show_path, export_panel
from widgets.state import StudioState

STILL = asset("targets/asl_o.jpeg")


@pytest.fixture
def state(tmp_path, hand):
    """A one-still project whose keyframe has a result: a bent index finger and its rendered shadow."""
    project = Project.create(tmp_path / "export.shadow", sources=[STILL])
    pose = hand.rest_pose().copy()
    pose[hand.joint_names.index("index_pip")] = 0.8
    shadow = ShadowRenderer(hand, Rig(resolution=32)).render_one(pose)
    k = project.keyframes[0].id
    project.set_result(k, pose, {"total": 0.4}, shadow, inputs=project.keyframe_inputs(k))
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


def wait_for(job, timeout: float = 60.0) -> JobState:
    """The job's final state (its final event has reached every subscriber by then)."""
    assert job is not None
    return job.wait(timeout)


def test_plan_write_validate_info_and_csv(state, tmp_path):
    panel = ExportPanel(state, ExportConfig(layout=ShowLayout(still_hold_s=1.0)))
    assert "Export" in panel.widget.children[0].value and "no show planned" in panel.info.value
    assert panel.path.value == str(tmp_path / "export.show.json") == str(default_show_path(state))
    panel.write_button.click()  # nothing planned: a message, no file
    assert "no planned show" in panel.messages.text and not (tmp_path / "export.show.json").exists()
    panel.plan_button.click()
    job = panel.jobs[-1]
    assert wait_for(job) == JobState.DONE, job.error
    assert state.project.show is not None and state.project.history[-1] == "planned show"
    assert "planned a" in panel.messages.text and panel.progress.value == 1.0
    held = "keyframes:    1 keyframe at 2 marks on the show clock: 0.00 s (hold), "  # a still: held from its mark
    assert "title:        export" in panel.info.value and held in panel.info.value
    panel.write_button.click()
    show = load_show(tmp_path / "export.show.json")
    assert "validated" in panel.messages.text and np.allclose(show.positions, state.project.show.positions)
    shown = html_lines(panel.info.value)[1:]
    # what `shadow-studio show-info` prints, but for the lines an artist reads in the project's terms
    artist = ("keyframes:", "media:", "made from:", "late:", "ramp-in:", "limits:")
    assert [x for x in shown if not x.startswith(artist)] == [
        x for x in show_info_lines(show) if not x.startswith(artist)
    ]  # fmt: skip
    assert "made from:    asl_o.jpeg" in shown and "late:         none (every move fits the servos)" in shown
    assert "limits:       every pose within the calibration's soft limits: the hand plays it as planned" in shown
    assert not any(x.startswith("media:") for x in shown)  # never "media: -"
    panel.csv_path.value = str(tmp_path / "out.csv")
    panel.degrees.value = True
    panel.csv_button.click()
    rows = list(csv.reader((tmp_path / "out.csv").open()))
    assert rows[0] == ["t_s", *(f"{n}_deg" for n in show.joint_names)] and len(rows) == len(show.times) + 1
    j = show.joint_names.index("index_pip")
    assert float(rows[-1][1 + j]) == pytest.approx(np.degrees(0.8), abs=1e-6)
    (tmp_path / "export.show.json").write_text("{}")  # a broken file: validate lists its problems
    panel.validate_button.click()
    assert "not a show file" in panel.messages.text, panel.messages.text
    state.edit("set_keyframe_time", state.project.keyframes[0].id, 0.05)  # from home to the pose in 50 ms
    assert "stale" in panel.info.value
    panel.allow_late.value = False
    before = state.project.show
    assert wait_for(panel.plan()) == JobState.DONE and state.project.show is before  # nothing applied
    text = panel.messages.text
    assert "1 transition too fast" in text and "tick 'allow late transitions'" in text.lower(), text
    assert "home → frame 0 (home → k" in text and "given 0.05 s" in text and "--" not in text
    panel.allow_late.value = True
    assert wait_for(panel.plan()) == JobState.DONE
    assert "1 late transition stretched" in panel.messages.text
    assert "late:         1 transition too fast for the servos, stretched" in panel.info.value
    assert "home → frame 0 (home → k" in panel.info.value and "given 0.05 s" in panel.info.value
    state.undo()  # the stretched show, the keyframe time
    state.undo()
    state.undo()  # the show goes: CSV is refused with what to do, the info says so
    assert state.project.show is None and "no show planned" in panel.info.value
    panel.csv_button.click()
    assert "plan show" in panel.messages.text
    panel.close()


def html_lines(value: str) -> list[str]:
    """The lines inside the info's <pre>."""
    import html

    body = value.split(">", 1)[1].rsplit("</pre>", 1)[0]
    return html.unescape(body).splitlines()


def test_plan_without_results_says_what_to_do(tmp_path):
    project = Project.create(tmp_path / "empty.shadow", sources=[STILL])
    state = StudioState(project, queue_for(project))
    try:
        panel = export_panel(state)
        panel.plan_button.click()
        assert panel.jobs == [] and "no result for keyframe" in panel.messages.text
        panel.play_button.click()
        assert "no show planned" in panel.messages.text
    finally:
        state.close()


@pytest.mark.slow
def test_play_on_the_emulator_with_progress_and_stop(state):
    panel = ExportPanel(state, ExportConfig(layout=ShowLayout(still_hold_s=3.0)))
    assert wait_for(panel.plan()) == JobState.DONE
    seen: list = []
    state.queue.subscribe(seen.append)
    job = panel.play()
    assert job is not None and job.kind == "play" and not panel.stop_button.disabled
    deadline = time.monotonic() + 30
    while not any(e.job_id == job.id and e.stage == "play" and e.step > 20 for e in seen):
        assert time.monotonic() < deadline and not job.finished, job.error
        time.sleep(0.02)
    assert panel.progress.description == "play" and 0 < panel.progress.value < 1
    panel.stop_button.click()
    assert wait_for(job, 5.0) == JobState.CANCELLED
    assert "stopped" in panel.messages.text and panel.stop_button.disabled
    panel.target.value = "port"
    panel.play_button.click()  # no port typed: a message
    assert "serial port" in panel.messages.text and len(panel.jobs) == 2
    panel.port.value = "/dev/does-not-exist"
    panel.play_button.click()
    assert "cannot open servo bus" in panel.messages.text and len(panel.jobs) == 2
    panel.target.value = "emulator"
    short = ExportPanel(state, ExportConfig(layout=ShowLayout(still_hold_s=0.5)))
    assert wait_for(short.plan()) == JobState.DONE
    played = short.play()
    assert wait_for(played, 30.0) == JobState.DONE, played.error
    assert played.result.ok and "played" in short.messages.text and short.progress.value == 1.0
    with ServoEmulator(range(1, 22)) as hand_at_port:  # a hand at a port: the panel opens a session of its own
        short.target.value, short.port.value = "port", hand_at_port.port
        played = short.play()
        assert wait_for(played, 30.0) == JobState.DONE, played.error
        assert played.result.ok and short._sessions == {}
        with ServoSession(hand_at_port.port, ids=[1]) as again:  # closed when the job ended: the port is free
            assert again.read_back()[1] is not None
        # the panel closed mid-show: the show stops and the panel's servos are closed (no one else would)
        panel.target.value, panel.port.value = "port", hand_at_port.port
        long = panel.play()
        deadline = time.monotonic() + 30
        while not (long.state == JobState.RUNNING and long.step > 5):
            assert time.monotonic() < deadline and not long.finished, long.error
            time.sleep(0.02)
        session = panel._sessions[long]
        panel.close()
        assert long.state == JobState.CANCELLED and not session.is_open and panel._sessions == {}
        assert session.report.stopped and session.report.torque == "held"  # the player's default: torque held
        with ServoSession(hand_at_port.port, ids=[1]) as again:  # the port is free again
            assert again.read_back()[1] is not None
    short.close()


@pytest.fixture
def horse(tmp_path, hand):
    """The bundled horse at 8 Hz: 9 frames, 3 keyframes (one reached twice), each with a pose of its own."""
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import DEFAULT_VIDEO, VideoConfig

    project = Project.create(tmp_path / "horse.shadow", [DEFAULT_VIDEO], video=VideoConfig(size=48, hz=8.0),
                             clustering=KeyframeConfig(tau=0.42), roll=0)  # fmt: skip
    renderer = ShadowRenderer(hand, Rig(resolution=32))
    for i, kf in enumerate(project.keyframes):
        pose = hand.rest_pose().copy()
        pose[hand.joint_names.index("index_pip")] = 0.6 + 0.4 * i
        pose[hand.joint_names.index("middle_pip")] = 0.9 * (i % 2)
        project.set_result(
            kf.id, pose, {"total": 0.3}, renderer.render_one(pose), inputs=project.keyframe_inputs(kf.id)
        )
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


@pytest.mark.slow
def test_the_show_is_described_in_the_projects_terms_with_its_late_moves_and_its_ramp_in(horse, hand):
    p = horse.project
    assert len(p.keyframes) == 3 and len(p.frames) == 9
    kf, pip = p.keyframes[-1], hand.joint_names.index("index_pip")
    pose = np.array([p.results[kf.id].pose[n] for n in hand.joint_names])
    pose[pip] = hand.upper[pip] - 0.01  # 0.04 rad beyond the shipped calibration's soft limit (0.05 inside the URDF's)
    p.set_result(kf.id, pose, {"total": 0.3}, p.results[kf.id].shadow, inputs=p.keyframe_inputs(kf.id))
    panel = ExportPanel(horse)
    try:
        assert wait_for(panel.plan(), 120) == JobState.DONE
        lines = html_lines(panel.info.value)
        assert len(p.show.keyframes) > 3  # the planner's keyframes: every run of a keyframe, not the artist's count
        marks = f"keyframes:    3 keyframes at {len(p.show.keyframes)} marks on the show clock: 0.00 s (hold), "
        assert next(x for x in lines if x.startswith("keyframes:")).startswith(marks)  # the artist's count, the marks
        media = next(x for x in lines if x.startswith("media:"))
        assert "muybridge_horse.gif (video) plays beside it from 0.00 s" in media  # what the show was made from
        late = [x.strip() for x in lines[lines.index(next(x for x in lines if x.startswith("late:"))) + 1 :]]
        n = len(p.show.provenance["late_segments"])
        assert n > 0 and f"late:         {n} transition" in panel.info.value
        listed = [x for x in late if x.startswith("frame") and "needs" in x and "given" in x]
        assert len(listed) == n and all("(k" in x and " → k" in x for x in listed), late
        ramp = next(x for x in lines if x.startswith("ramp-in:"))
        said = float(ramp.split()[1])
        assert said > 0.3 and "before the show starts" in ramp
        played = panel.play()
        assert wait_for(played, 60) == JobState.DONE, played.error
        ticks = played.result.ramp_ticks
        rate = panel.cfg.player.rate_hz if panel.cfg.player else 40.0
        assert said == pytest.approx(ticks / rate, abs=0.006)  # what the player did: the same ramp
        limits = next(x for x in lines if x.startswith("limits:"))
        assert "1 joint beyond the calibration's soft limits (index_pip by 2.3°)" in limits, limits
        r = played.result  # what the player did: it stopped that joint, and only that one, at its limit
        assert [r.joint_names[j] for j in np.flatnonzero(r.clipped_limit.any(0))] == ["index_pip"]
        assert np.abs(r.requested - r.sent).max() == pytest.approx(0.04, abs=1e-4)
        assert "99999" not in panel.info.value and "(s)" not in panel.messages.text
    finally:
        panel.close()
