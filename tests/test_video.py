"""studio.targets.video: every shared sequence loads, one square frame, reading footage, bad input is clear (the
sampling arithmetic: test_sampling.py; cleaning photographed shadows: test_cleanup.py)."""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from studio.errors import Progress, TargetError
from studio.targets.images import detect_polarity
from studio.targets.source import raw_frames
from studio.targets.video import (
    DEFAULT_VIDEO,
    SegmentationNeeded,
    VideoConfig,
    detect_kind,
    load_video,
    read_footage,
    sample_times,
    video_from_masks,
)

SMALL = VideoConfig(size=32)


def _blob_frames(n: int, h: int = 48, w: int = 64, dark_on_light: bool = True) -> list[np.ndarray]:
    """Grey frames ``(h, w)`` of a square blob moving right by 2 px a frame."""
    frames = []
    for i in range(n):
        f = np.full((h, w), 220 if dark_on_light else 10, np.uint8)
        f[14:30, 4 + 2 * i : 20 + 2 * i] = 20 if dark_on_light else 240
        frames.append(f)
    return frames


def _write_folder(folder: Path, frames: list[np.ndarray], suffix: str = ".png") -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, f in enumerate(frames):
        p = folder / f"frame{i}{suffix}"  # unpadded numbers: natural order must hold
        Image.fromarray(f).save(p, quality=95) if suffix == ".jpg" else Image.fromarray(f).save(p)
        paths.append(p)
    return paths


def _write_video(path: Path, frames: list[np.ndarray], fps: float = 10.0, fourcc: str = "mp4v") -> Path:
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened(), f"this OpenCV cannot write {fourcc}"
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if f.ndim == 2 else f)
    writer.release()
    return path


def _write_gif(path: Path, frames: list[np.ndarray], durations_ms: list[int]) -> Path:
    ims = [Image.fromarray(f) for f in frames]
    ims[0].save(path, save_all=True, append_images=ims[1:], duration=durations_ms, loop=0)
    return path


# --- real sequences ----------------------------------------------------------------------------------------------


def test_default_video_is_the_horse():
    video = load_video(DEFAULT_VIDEO)
    assert DEFAULT_VIDEO.name == "muybridge_horse.gif" and (DEFAULT_VIDEO.parent / "SOURCE.txt").is_file()
    assert video.kind == "shadow" and video.polarity == "dark"  # dark horse on a light ground
    assert np.isclose(video.fps, 10) and np.isclose(video.duration_s, 1.1) and video.n_source == 11
    assert np.allclose(video.times, [0, 0.3, 0.5, 0.8, 1.0]) and video.frame_index.tolist() == [0, 3, 5, 8, 10]
    assert video.masks.shape == (5, 128, 128) and video.frames.shape == (5, 128, 128, 3) and not video.skipped


def test_horse_silhouettes_are_clean():
    """Every frame of the horse: one piece (horse and rider), no ruled line or frame edge left in it, and the
    shadow is the dark part of the photograph."""
    video = load_video(DEFAULT_VIDEO, VideoConfig(hz=10))
    assert len(video.masks) == 11
    image_w = 296 * video.masks.shape[2] / video.box[2]  # the GIF's width in mask pixels
    for k, (mask, frame) in enumerate(zip(video.masks, video.frames)):
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        assert stats[1:, cv2.CC_STAT_AREA].max() >= 0.95 * mask.sum(), f"frame {k}: the horse is in pieces"
        assert np.ptp(np.nonzero(mask)[1]) < 0.88 * image_w, f"frame {k}: a rule across the frame is left"
        assert 0.06 < mask.mean() < 0.25, f"frame {k}: shadow share {mask.mean():.3f}"
        grey = frame.mean(axis=2)
        assert grey[mask > 0].mean() < 90 < grey[(mask == 0) & (grey > 0)].mean(), f"frame {k}: polarity"
        assert (grey[mask > 0] > 140).mean() < 0.05, f"frame {k}: backdrop between the legs filled in"


@pytest.mark.slow
def test_every_davis_mask_sequence_loads(shared_targets):
    sequences = sorted(p for p in (shared_targets / "davis").iterdir() if p.is_dir())
    assert len(sequences) >= 6
    for seq in sequences:
        n = len(list(seq.glob("*.png")))
        video = load_video(seq, SMALL)
        times, idx = sample_times(n / 24, 24, SMALL.hz)
        assert video.kind == "mask" and video.polarity == "bright", seq.name
        assert video.frame_index.tolist() == idx.tolist() and np.allclose(video.times, times), seq.name
        assert video.masks.shape == (len(idx), 32, 32) and not video.skipped, seq.name
        assert all(m.any() and not m.all() for m in video.masks), seq.name
        raw = np.asarray(Image.open(seq / f"{idx[1]:05d}.png").convert("L")) > 127  # masks as they are
        x, y, w, h = video.box
        assert raw[max(y, 0) : y + h, max(x, 0) : x + w].sum() == raw.sum(), f"{seq.name}: shadow outside the frame"


@pytest.mark.slow
def test_shared_video_files_load(shared_targets):
    horse = shared_targets / "video" / "muybridge-horse" / "horse-in-motion.gif"
    assert load_video(horse, SMALL).masks.shape == (5, 32, 32)
    bear = shared_targets / "video" / "bear-mp4" / "bear.mp4"
    f = raw_frames(bear)
    frames, times, idx, fps = f.frames, f.times, f.frame_index, f.fps
    assert fps == 30 and frames.shape == (11, 480, 854, 3) and idx.tolist() == sample_times(82 / 30, 30, 4)[1].tolist()
    assert np.allclose(times, idx / 30)
    with pytest.raises(SegmentationNeeded, match="colour footage.*segment.*bear.mp4") as err:
        load_video(bear, SMALL)  # raw colour video: never thresholded into garbage
    assert isinstance(err.value, TargetError) and err.value.footage.frames.shape == (11, 480, 854, 3)
    forced = load_video(bear, VideoConfig(size=32, kind="shadow"))
    assert forced.kind == "shadow" and len(forced.masks) + len(forced.skipped) == 11


def test_rgb_folder_needs_segmentation(shared_targets):
    dog = shared_targets / "davis-rgb" / "dog"
    with pytest.raises(SegmentationNeeded, match="box or mask"):
        load_video(dog, SMALL)
    f = raw_frames(dog, VideoConfig(hz=2))
    frames, fps = f.frames, f.fps
    assert fps == 24 and frames.shape[1:] == (480, 854, 3) and len(frames) == len(sample_times(60 / 24, 24, 2)[0])


# --- one square frame --------------------------------------------------------------------------------------------


def test_one_square_frame_for_a_moving_blob(tmp_path):
    folder = tmp_path / "blob"
    _write_folder(folder, _blob_frames(12))
    video = load_video(folder, VideoConfig(hz=24, size=40))
    assert video.masks.shape == (12, 40, 40) and video.kind == "shadow" and video.polarity == "dark"
    x, y, w, h = video.box
    assert w == h and x <= 4 and x + w >= 20 + 2 * 11 and y <= 14 and y + h >= 30  # the union of the blob boxes
    areas = video.masks.reshape(12, -1).sum(axis=1)
    assert areas.max() - areas.min() <= 0.15 * areas.max()  # the same blob, the same scale in every frame
    cols = np.array([np.nonzero(m)[1].mean() for m in video.masks])
    assert np.all(np.diff(cols) > 0) and cols[-1] - cols[0] > 10  # it moves, and the motion shows
    for m in video.masks:  # never cut by the frame
        assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
    dark = video.frames.mean(axis=3)  # the review frames are framed the same way
    assert dark[video.masks > 0].mean() < 60 < dark[video.masks == 0].mean()


def test_a_speck_of_a_subject_is_refused(tmp_path):
    """A subject a few pixels across in every frame has no outline to imitate: one clear error, not a block."""
    frames = [np.full((48, 64), 230, np.uint8) for _ in range(4)]
    for i, f in enumerate(frames):
        f[20:23, 30 + i : 33 + i] = 20  # a 3 × 3 speck drifting right: the union is 6 × 3
    _write_folder(tmp_path / "speck", frames)
    with pytest.raises(TargetError, match=r"only 6×3 pixels"):
        load_video(tmp_path / "speck", VideoConfig(hz=24, size=40))


def test_binary_masks_either_polarity(tmp_path):
    white = _write_folder(tmp_path / "white", [np.where(f < 128, 255, 0).astype(np.uint8) for f in _blob_frames(6)])
    black = _write_folder(tmp_path / "black", [np.where(f < 128, 0, 255).astype(np.uint8) for f in _blob_frames(6)])
    a = load_video(white[0].parent, VideoConfig(hz=24, size=32))
    b = load_video(black[0].parent, VideoConfig(hz=24, size=32))
    assert a.kind == b.kind == "mask" and (a.polarity, b.polarity) == ("bright", "dark")
    assert np.array_equal(a.masks, b.masks) and a.box == b.box


def test_video_from_masks_frames_segmented_masks(tmp_path):
    _write_folder(tmp_path / "f", [np.stack([f] * 3, axis=2) for f in _blob_frames(5)])
    footage = read_footage(tmp_path / "f", hz=24)
    masks = (footage.frames[..., 0] < 128).astype(np.uint8)
    masks[2] = 0  # segmentation lost the object in one frame: skipped and counted
    video = video_from_masks(footage, masks, VideoConfig(size=24))
    assert video.kind == "segmented" and video.frame_index.tolist() == [0, 1, 3, 4]
    assert video.skipped == [(2, "no shadow pixels")] and video.masks.shape == (4, 24, 24)


def test_detect_kind():
    rng = np.random.default_rng(0)
    grey = np.repeat(rng.integers(0, 256, (3, 8, 8, 1), dtype=np.uint8), 3, axis=3)
    assert detect_kind(grey) == "shadow"
    assert detect_kind(np.where(grey > 127, 255, 0).astype(np.uint8)) == "mask"
    assert detect_kind(rng.integers(0, 256, (3, 8, 8, 3), dtype=np.uint8)) == "colour"
    assert detect_polarity(np.stack(_blob_frames(3))) == "dark"
    assert detect_polarity(np.stack(_blob_frames(3, dark_on_light=False))) == "bright"


@pytest.mark.parametrize("suffix,fourcc", [(".mp4", "mp4v"), (".avi", "MJPG"), (".mov", "mp4v"), (".webm", "VP80")])
def test_video_files_through_opencv(tmp_path, suffix, fourcc):
    path = _write_video(tmp_path / f"blob{suffix}", _blob_frames(20), fps=10, fourcc=fourcc)
    video = load_video(path, VideoConfig(hz=4, size=32))
    assert np.isclose(video.fps, 10) and video.frame_index.tolist() == [0, 3, 5, 8, 10, 13, 15, 18]
    assert np.allclose(video.times, video.frame_index / 10) and not video.skipped
    cols = [np.nonzero(m)[1].mean() for m in video.masks]
    assert np.all(np.diff(cols) > 0)


def test_gif_clock_is_the_sum_of_its_durations(tmp_path):
    path = _write_gif(tmp_path / "g.gif", _blob_frames(20), [50] * 10 + [150] * 10)  # 0.5 s + 1.5 s
    footage = read_footage(path, hz=4)
    assert np.isclose(footage.duration_s, 2.0) and np.isclose(footage.fps, 10) and footage.n_source == 20
    starts = np.concatenate([[0], np.cumsum([0.05] * 10 + [0.15] * 10)[:-1]])
    assert np.allclose(footage.times, starts[footage.frame_index])
    assert footage.frame_index.tolist() == [0, 5, 10, 12, 13, 15, 17, 18]  # fast frames then slow ones


def test_progress_and_cancel(tmp_path):
    _write_folder(tmp_path / "f", _blob_frames(12))
    seen = []
    load_video(tmp_path / "f", VideoConfig(hz=24, size=24), progress=seen.append)
    assert all(isinstance(p, Progress) for p in seen)  # the one protocol of every long engine call
    assert {p.stage for p in seen} == {"read", "binarise", "frame"} and Progress("read", 12, 12) in seen
    cancel = threading.Event()

    def stop(p: Progress) -> None:
        if p.stage == "read" and p.step == 3:
            cancel.set()

    video = load_video(tmp_path / "f", VideoConfig(hz=24, size=24), progress=stop, cancel=cancel)
    assert video.cancelled and len(video.masks) == 3 and video.frame_index.tolist() == [0, 1, 2]
    video = load_video(tmp_path / "f", VideoConfig(hz=24, size=24), cancel=cancel)  # set before it starts
    assert video.cancelled and video.masks.shape == (0, 24, 24)


# --- bad input ---------------------------------------------------------------------------------------------------


def test_missing_and_unsupported(tmp_path):
    with pytest.raises(TargetError, match="not found.*nope.mp4"):
        load_video(tmp_path / "nope.mp4")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(TargetError, match="unsupported video type .txt.*notes.txt"):
        load_video(tmp_path / "notes.txt")


def test_truncated_and_junk_video_files(tmp_path):
    full = _write_video(tmp_path / "full.mp4", _blob_frames(20)).read_bytes()
    (tmp_path / "cut.mp4").write_bytes(full[: len(full) // 2])  # the index (moov) is at the end: nothing plays
    with pytest.raises(TargetError, match="no readable frames.*cut.mp4"):
        load_video(tmp_path / "cut.mp4", SMALL)
    (tmp_path / "junk.mp4").write_bytes(b"not a video" * 50)
    with pytest.raises(TargetError, match="no readable frames.*junk.mp4"):
        load_video(tmp_path / "junk.mp4", SMALL)
    avi = _write_video(tmp_path / "full.avi", _blob_frames(20), fourcc="MJPG").read_bytes()
    (tmp_path / "cut.avi").write_bytes(avi[: len(avi) // 2])  # plays half: never a silently shorter show
    with pytest.raises(TargetError, match=r"ends after \d+ of the 20 frames.*truncated.*cut.avi"):
        load_video(tmp_path / "cut.avi", VideoConfig(hz=10, size=32))


def test_corrupt_frame_in_a_video_is_skipped_and_counted(tmp_path, caplog):
    data = bytearray(_write_video(tmp_path / "ok.avi", _blob_frames(20), fourcc="MJPG").read_bytes())
    jpegs = [i for i in range(len(data) - 1) if data[i : i + 2] == b"\xff\xd8"]
    assert len(jpegs) == 20
    data[jpegs[8] : jpegs[8] + 200] = bytes(200)  # frame 8's JPEG data gone
    (tmp_path / "bad.avi").write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING):
        video = load_video(tmp_path / "bad.avi", VideoConfig(hz=10, size=32))
    assert [i for i, _ in video.skipped] == [8] and len(video.masks) == 19 and 8 not in video.frame_index
    assert video.frame_index.tolist() == [i for i in range(20) if i != 8]
    assert "skipped 1 of 20" in caplog.text
    cols = [np.nonzero(m)[1].mean() for m in video.masks]
    assert np.all(np.diff(cols) > 0)  # the frames after the bad one are still the right ones


def test_broken_gifs(tmp_path):
    data = _write_gif(tmp_path / "g.gif", _blob_frames(20), [100] * 20).read_bytes()
    (tmp_path / "cut.gif").write_bytes(data[: len(data) // 2])
    with pytest.raises(TargetError, match="GIF cut off or corrupt at frame.*cut.gif"):
        load_video(tmp_path / "cut.gif", SMALL)
    (tmp_path / "junk.gif").write_bytes(b"GIF89a" + b"\x00" * 5)
    with pytest.raises(TargetError, match="junk.gif"):
        load_video(tmp_path / "junk.gif", SMALL)


def test_folder_with_corrupt_jpegs(tmp_path, caplog):
    paths = _write_folder(tmp_path / "one", [np.stack([f] * 3, axis=2) for f in _blob_frames(12)], ".jpg")
    paths[5].write_bytes(paths[5].read_bytes()[:300])  # truncated in the middle of its data
    with caplog.at_level(logging.WARNING):
        video = load_video(tmp_path / "one", VideoConfig(hz=24, size=32))
    assert len(video.skipped) == 1 and video.skipped[0][0] == 5 and "frame5.jpg" in video.skipped[0][1]
    assert len(video.masks) == 11 and 5 not in video.frame_index and "skipped 1 of 12" in caplog.text
    for p in paths[1:5]:  # four of twelve bad: more than a quarter
        p.write_bytes(b"garbage")
    with pytest.raises(TargetError, match="5 of 12 sampled frames are unreadable.*one"):
        load_video(tmp_path / "one", VideoConfig(hz=24, size=32))


def test_bad_folders(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(TargetError, match="no image files.*empty"):
        load_video(tmp_path / "empty")
    frames = _blob_frames(6)
    frames[3] = cv2.resize(frames[3], (80, 60))
    _write_folder(tmp_path / "mixed", frames)
    with pytest.raises(TargetError, match="mixed sizes: frame3.png is 80×60, frame0.png is 64×48"):
        load_video(tmp_path / "mixed")
    (tmp_path / "garbage").mkdir()
    for i in range(3):
        (tmp_path / "garbage" / f"{i}.png").write_bytes(b"garbage")
    with pytest.raises(TargetError, match="no readable frames.*garbage"):
        load_video(tmp_path / "garbage")
    _write_folder(tmp_path / "blank", [np.full((48, 64), 200, np.uint8)] * 4)
    with pytest.raises(TargetError, match="no sampled frame has any shadow.*blank"):
        load_video(tmp_path / "blank")


def test_rate_above_the_source(tmp_path):
    _write_folder(tmp_path / "f", _blob_frames(6))
    with pytest.raises(TargetError, match="30 Hz is above.*24 fps.*at 24 Hz or less"):
        load_video(tmp_path / "f", VideoConfig(hz=30))
    assert len(load_video(tmp_path / "f", VideoConfig(hz=30, fps=30, size=24)).masks) == 6
    gif = _write_gif(tmp_path / "g.gif", _blob_frames(10), [100] * 10)
    with pytest.raises(TargetError, match="12 Hz is above.*10 fps.*g.gif"):
        load_video(gif, VideoConfig(hz=12))
    mp4 = _write_video(tmp_path / "v.mp4", _blob_frames(10), fps=10)
    with pytest.raises(TargetError, match="20 Hz is above.*10 fps.*v.mp4"):
        load_video(mp4, VideoConfig(hz=20))
    with pytest.raises(ValueError):
        VideoConfig(hz=0)
