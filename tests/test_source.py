"""studio.targets.source: one reader for every face — what a source is, its raw frames, and its targets; raw
colour footage segmented densely (every source frame, then sampled), the same through a project."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from PIL import Image

from studio.errors import Progress, TargetError
from studio.targets.images import DEFAULT_TARGET, load_target
from studio.targets.source import open_source, raw_frames, read_first_mask, source_kind
from studio.targets.video import DEFAULT_VIDEO, SegmentationNeeded, VideoConfig


def _colour_clip(folder, n: int = 12, size=(64, 80)):
    """A red square moving right over a green textured ground, ``n`` frames."""
    folder.mkdir(parents=True, exist_ok=True)
    h, w = size
    ground = (np.random.default_rng(3).integers(0, 40, (h, w, 3)) + np.array([40, 140, 60])).astype(np.uint8)
    for i in range(n):
        frame = ground.copy()
        frame[20:44, 8 + 2 * i : 32 + 2 * i] = (220, 40, 40)
        Image.fromarray(frame).save(folder / f"{i:05d}.png")
    return folder


def test_what_a_source_is(tmp_path, sources):
    clip, ring = sources
    assert source_kind(clip) == "folder" and source_kind(ring) == "still" and source_kind(DEFAULT_VIDEO) == "video"
    assert source_kind(DEFAULT_TARGET) == "still"


def test_a_still_is_a_one_frame_video_framed_like_load_target():
    v = open_source(DEFAULT_TARGET, VideoConfig(size=64))
    assert v.kind == "still" and v.times.tolist() == [0.0] and v.masks.shape == (1, 64, 64)
    assert np.array_equal(v.masks[0], load_target(DEFAULT_TARGET, size=64))
    raw = raw_frames(DEFAULT_TARGET)
    assert raw.frames.shape[0] == 1 and raw.frames.shape[-1] == 3


def test_masks_and_shadow_footage_are_read_as_they_are(sources):
    clip, _ = sources
    v = open_source(clip, VideoConfig(size=32, fps=8, hz=8))
    assert v.kind == "mask" and len(v.masks) == 8 and v.masks.shape[1:] == (32, 32)
    horse = open_source(DEFAULT_VIDEO, VideoConfig(size=32))
    assert horse.kind == "shadow" and len(horse.masks) >= 4


def test_colour_footage_needs_its_object_and_is_segmented_densely(tmp_path):
    clip = _colour_clip(tmp_path / "colour")
    with pytest.raises(SegmentationNeeded, match="box or mask"):
        open_source(clip, VideoConfig(size=32, fps=12, hz=3))
    seen: list[Progress] = []
    v = open_source(clip, VideoConfig(size=32, fps=12, hz=3), box=(8, 20, 24, 24), progress=seen.append)
    assert v.kind == "segmented" and v.frame_index.tolist() == [0, 4, 8]  # sampled at 3 Hz …
    segmented = [p for p in seen if p.stage == "segment"]
    assert segmented and segmented[-1].total == 12  # … segmented through every source frame
    assert all(isinstance(p, Progress) for p in seen)
    assert v.masks.any(axis=(1, 2)).all()
    first = np.zeros((64, 80), np.uint8)
    first[20:44, 8:32] = 1
    Image.fromarray(first * 255).save(tmp_path / "first.png")
    by_mask = open_source(clip, VideoConfig(size=32, fps=12, hz=3), first_mask=tmp_path / "first.png")
    assert by_mask.kind == "segmented" and np.array_equal(read_first_mask(tmp_path / "first.png"), first)
    iou = (by_mask.masks & v.masks).sum() / max((by_mask.masks | v.masks).sum(), 1)
    assert iou > 0.8  # from a box or from a mask, the same object


def test_cancel_returns_a_cancelled_video(tmp_path):
    clip = _colour_clip(tmp_path / "colour")
    cancel = threading.Event()
    cancel.set()
    v = open_source(clip, VideoConfig(size=32, fps=12, hz=3), box=(8, 20, 24, 24), cancel=cancel)
    assert v.cancelled and len(v.masks) == 0


def test_bad_sources_say_what_is_wrong(tmp_path):
    with pytest.raises(TargetError, match="not found"):
        open_source(tmp_path / "none.gif")
    (tmp_path / "m.png").write_bytes(b"junk")
    with pytest.raises(TargetError, match="not a readable image"):
        read_first_mask(tmp_path / "m.png")


def test_a_project_reads_its_sources_through_open_source(tmp_path):
    """The project's frames and targets of raw footage are open_source's, to the pixel (one reader, every face)."""
    from studio.project.project import Project

    clip = _colour_clip(tmp_path / "colour")
    cfg = VideoConfig(size=32, fps=12, hz=3)
    p = Project.create(tmp_path / "c.shadow", sources=[clip], video=cfg, box=(8, 20, 24, 24))
    v = open_source(clip, cfg, box=(8, 20, 24, 24))
    assert [f.source_frame for f in p.frames] == v.frame_index.tolist()
    assert np.array_equal(p.state.targets, v.masks)
