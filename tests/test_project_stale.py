"""When a project's results are stale (studio.project.inputs: what a result was computed from): a changed source,
weights, paint or keyframe membership make them stale, time and hold do not; a project saved before the loader
filled crease pockets keeps its masks and results current."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from project_support import VIDEO, blob, make, rest_show  # the project tests' own helpers, beside this file

from studio.project.project import Project, ProjectError


def test_results_go_stale_when_their_source_changes(tmp_path, sources, hand):
    p = make(tmp_path, sources)
    for kf in p.keyframes:
        p.set_result(kf.id, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(kf.id)[0])
    p.set_show(rest_show(hand), inputs=p.show_inputs())
    assert p.stale_keyframes() == [] and p.pending_keyframes() == [] and not p.is_show_stale()
    video_kfs = [kf.id for kf in p.keyframes if p.frames[kf.representative].source == 0]
    frame = np.asarray(Image.open(sources[0] / "00003.png"))
    Image.fromarray(np.roll(frame, 5, axis=1)).save(sources[0] / "00003.png")  # the artist re-exported a frame
    q = Project.open(p.path)
    assert q.changed_sources == [0] and q.stale_keyframes() == video_kfs and q.pending_keyframes() == video_kfs
    assert q.is_show_stale() and q.summary()["sources"][0]["changed"]
    with pytest.raises(ProjectError, match="stale"):
        q.export_show(tmp_path / "show.json")
    q.reload_sources()  # re-read: the new hash is the source's, the old results stay stale
    assert not q.changed_sources and q.sources[0].sha256 != p.sources[0].sha256
    still_k = next(kf.id for kf in q.keyframes if q.frames[kf.representative].source == 1)
    assert not q.is_stale(still_k) and still_k in q.results
    assert q.stale_keyframes() == [kf.id for kf in q.keyframes if kf.id in q.results and kf.id != still_k] != []


def test_results_go_stale_when_weights_masks_or_membership_change(tmp_path, sources, hand, rng):
    p = make(tmp_path, sources)
    big = max(p.keyframes, key=lambda kf: len(kf.members))
    k = big.id
    inputs = p.keyframe_inputs(k)
    p.set_result(k, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(k)[0], inputs=inputs)
    assert not p.is_stale(k)
    p.set_weights(w_iou=0.5)
    assert p.is_stale(k) and p.stale_keyframes() == [k] and k in p.pending_keyframes()
    p.set_weights(w_iou=0.4)  # back as it was: current again
    assert not p.is_stale(k)
    p.set_hold(k, True)  # time and hold shape the show, not the pose
    p.set_keyframe_time(k, 2.0)
    assert not p.is_stale(k)
    p.paint(big.representative, additions=blob(rng))  # the representative's expressive mask
    assert p.is_stale(k)
    p.undo()
    other = next(m for m in big.members if m != big.representative)
    p.add_keyframe(other)  # membership
    assert p.is_stale(k)
    p.undo()
    assert not p.is_stale(k)
    p.set_threshold(still=40.0)  # a still's threshold does not touch a video's keyframes
    assert not p.is_stale(k)
    # a result computed while the inputs changed is kept, but stale
    p.set_result(k, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(k)[0], inputs="0" * 64)
    assert p.is_stale(k) and p.results[k].inputs == "0" * 64


def test_a_project_from_before_crease_pockets_keeps_its_masks_and_results(tmp_path, sources, hand):
    """A project saved before the loader filled crease pockets (its still settings without the pocket fields) made
    its masks without them: it opens with them off and its results stay current. A new project fills them."""
    from studio.project.project_format import DOC
    from studio.targets.images import TargetConfig

    assert make(tmp_path, sources, "new.shadow").state.still.pocket_reach > 0
    p = Project.create(tmp_path / "p.shadow", sources=[str(s) for s in sources], video=VIDEO,
                       still=TargetConfig(pocket_reach=0.0))  # fmt: skip
    for kf in p.keyframes:
        p.set_result(kf.id, hand.rest_pose(), {"total": 0.1}, p.keyframe_masks(kf.id)[0])
    doc = json.loads((p.path / DOC).read_text())
    del doc["settings"]["still"]["pocket_reach"], doc["settings"]["still"]["pocket_neck"]  # as an older release wrote
    (p.path / DOC).write_text(json.dumps(doc))
    old = Project.open(p.path)
    assert old.state.still.pocket_reach == 0.0 and old.pending_keyframes() == [] and old.stale_keyframes() == []
    doc["settings"]["still"]["pocket_reach"] = 0.01  # the same masks, read as made with pockets filled: the still's
    (p.path / DOC).write_text(json.dumps(doc))  # keyframe is stale, the clip's (footage settings) are not
    still = [kf.id for kf in p.keyframes if p.sources[p.frames[kf.representative].source].kind == "still"]
    assert len(still) == 1 and Project.open(p.path).stale_keyframes() == still
