"""The Weights panel (widgets.weights) driven in Python: sliders edit the project's weights (undoable), reset
restores the paper's defaults, and the CLIP sliders are disabled with the reason while no CLIP weights are set."""

from __future__ import annotations

import pytest
from studio.assets import asset

from studio.imitate.config import LossConfig
from studio.project.project import Project
from widgets.state import StudioState
from widgets.weights import CLIP_FIELDS, SLIDERS, paper_weights, weights_panel


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "still.shadow", sources=[asset("targets/asl_o.jpeg")])
    s = StudioState(project, None)
    yield s


def test_paper_defaults_are_the_loss_configs():
    assert paper_weights() == {"w_mae": 0.06, "w_iou": 0.4, "w_clip": 0.02, "w_exp_iou": 1.0, "w_exp_clip": 0.05,
                               "w_temporal": 0.2}  # fmt: skip
    assert [s.label for s in SLIDERS] == ["MAE", "IoU", "CLIP", "Exp. IoU", "Exp. CLIP", "temporal"]


def test_sliders_edit_the_project_weights_and_undo_restores_them(state):
    panel = weights_panel(state)
    assert "Weights" in panel.widget.children[0].value
    assert {n: s.value for n, s in panel.sliders.items()} == pytest.approx(paper_weights())
    assert all(not s.continuous_update for s in panel.sliders.values())  # a drag is one edit, on release
    panel.sliders["w_iou"].value = 0.8
    assert state.project.weights.w_iou == pytest.approx(0.8)
    assert state.project.history == ["loss weights"]
    assert Project.open(state.project.path).weights.w_iou == pytest.approx(0.8)  # saved
    panel.sliders["w_temporal"].value = 0.5
    assert state.project.weights.w_temporal == pytest.approx(0.5) and len(state.project.history) == 2
    assert state.undo()
    assert state.project.weights.w_temporal == pytest.approx(0.2)
    assert panel.sliders["w_temporal"].value == pytest.approx(0.2)  # the panel follows the undo
    assert state.undo()
    assert state.project.weights == LossConfig() and panel.sliders["w_iou"].value == pytest.approx(0.4)
    assert not state.project.can_undo  # the panel's own redraw made no edit


def test_reset_restores_the_paper_defaults_in_one_edit(state):
    panel = weights_panel(state)
    panel.sliders["w_mae"].value = 0.3
    panel.sliders["w_exp_iou"].value = 2.5
    panel.reset.click()
    assert state.project.weights == LossConfig()
    assert {n: s.value for n, s in panel.sliders.items()} == pytest.approx(paper_weights())
    assert state.project.history == ["loss weights"] * 3
    state.undo()
    assert state.project.weights.w_mae == pytest.approx(0.3) and panel.sliders["w_exp_iou"].value == 2.5
    before = list(state.project.history)
    state.redo()
    panel.reset.click()  # already the defaults: nothing recorded
    assert state.project.history == [*before, "loss weights"]


def test_clip_sliders_are_disabled_with_the_reason_until_weights_are_configured(state, tmp_path):
    panel = weights_panel(state)
    if panel.clip_disabled_reason is None:
        pytest.skip("CLIP weights are in this machine's cache: the sliders are rightly enabled")
    assert all(panel.sliders[n].disabled for n in CLIP_FIELDS)
    assert not panel.sliders["w_iou"].disabled
    assert "no local CLIP weights" in panel.clip_reason.value and "never downloaded" in panel.clip_reason.value
    state.extras["clip_weights"] = str(tmp_path / "absent.safetensors")
    panel.sync()
    assert panel.sliders["w_clip"].disabled and "absent.safetensors does not exist" in panel.clip_reason.value
    weights = tmp_path / "clip.safetensors"
    weights.write_bytes(b"a local checkpoint")
    state.extras["clip_weights"] = str(weights)
    panel.sync()
    assert not any(panel.sliders[n].disabled for n in CLIP_FIELDS) and panel.clip_reason.value == ""
    panel.sliders["w_exp_clip"].value = 0.1
    assert state.project.weights.w_exp_clip == pytest.approx(0.1)


def test_the_clip_reason_says_what_an_artist_does_never_code_or_a_flag(state, tmp_path, monkeypatch):
    from widgets.app import CLIP_ENV

    panel = weights_panel(state)
    if panel.clip_disabled_reason is None:
        pytest.skip("CLIP weights are in this machine's cache: there is no reason to show")
    shown = panel.clip_reason.value
    assert "box below" in shown and "Use these weights" in shown and CLIP_ENV in shown
    assert "extras" not in shown and "state." not in shown and "--" not in shown
    state.extras["clip_weights"] = str(tmp_path / "given.safetensors")  # $SHADOW_STUDIO_CLIP_WEIGHTS, at open
    again = weights_panel(state)
    assert again.clip_path.value == str(tmp_path / "given.safetensors")  # the box shows what the studio was given
    assert "box below" in again.clip_reason.value and "extras" not in again.clip_reason.value
    again.clip_path.value = ""
    again.clip_use.click()
    assert "type the path of a CLIP weights file" in again.messages.text


def test_clip_weights_load_aside_and_a_missing_file_is_answered_at_once(state, tmp_path, monkeypatch):
    """ "Use these weights": a missing file is refused at once, loading nothing; a file is loaded in the panel's
    thread (the click returns while it loads, the button rests and the panel says so), and one that is no CLIP
    checkpoint is then refused in words, the CLIP terms left as they were."""
    import threading

    import studio.imitate.clip_loss as clip_loss

    panel = weights_panel(state)
    panel.clip_path.value = str(tmp_path / "absent.safetensors")
    panel.clip_use.click()
    assert panel.loading is None and "absent.safetensors does not exist" in panel.messages.text
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a checkpoint")
    release, real = threading.Event(), clip_loss.find_clip

    def held(*args, **kwargs):
        release.wait(30)
        return real(*args, **kwargs)

    monkeypatch.setattr(clip_loss, "find_clip", held)
    panel.clip_path.value = str(bad)
    try:
        panel.clip_use.click()  # returns while the load is held
        assert panel.clip_use.disabled and "loading the CLIP weights bad.safetensors" in panel.messages.text
    finally:
        release.set()
    panel.loading.join(60)
    assert not panel.loading.is_alive() and not panel.clip_use.disabled and state.extras.get("clip") is None
    assert "loading" not in panel.messages.text and "Traceback" not in panel.messages.text, panel.messages.text
