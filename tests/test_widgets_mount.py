"""The Optimise tab's mount roll box: auto or degrees, set on the project (stale keyframes), said back in words; a
bad value is one message and changes nothing; undo brings the box back to what the project holds."""

from __future__ import annotations

import math

import pytest

from studio.project.project import Project
from studio.targets.images import DEFAULT_TARGET
from widgets.mount import MountControl
from widgets.state import StudioState


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "p.shadow", [DEFAULT_TARGET])
    return StudioState(project, None)


def test_the_roll_box_sets_the_project_roll_and_says_how_to_mount(state, hand):
    said = []
    control = MountControl(state, lambda text, error=False: said.append((text, error)))
    p = state.project
    assert control.box.value == "auto" and "chosen for the whole show" in control.line.value
    k = p.keyframes[0].id
    p.set_result(k, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(k)[0])
    control.box.value = "-30"
    assert control.apply() and p.mount.roll == pytest.approx(math.radians(-30)) and not p.mount.auto
    assert "30.0° clockwise" in control.line.value and p.stale_keyframes() == [k]
    assert said[-1] == ("mount roll set to -30: the keyframes are stale until optimised for it", False)
    control.box.value = "sideways"
    assert not control.apply() and said[-1][1] and "angle in degrees" in said[-1][0]
    assert p.mount.roll == pytest.approx(math.radians(-30))  # unchanged
    state.undo()
    control.refresh()
    assert control.box.value == "auto" and p.mount.auto and "chosen for the whole show" in control.line.value
