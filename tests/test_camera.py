"""hardware.camera: a camera read in its own thread (files and folders played as cameras, fake sources, errors)."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from hardware.camera import Camera, Frame
from hardware.errors import CameraAbsent, CameraEnded, CameraError, CameraStalled, HardwareError
from studio.errors import ClosedError


def _frame(level: int, size: tuple[int, int] = (48, 64)) -> np.ndarray:
    return np.full((*size, 3), level, np.uint8)


@pytest.fixture
def video(tmp_path):
    """A 12-frame 64×48 mp4 at 40 fps; frame k is grey level 20 k."""
    path = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 40.0, (64, 48))
    assert writer.isOpened()
    for k in range(12):
        writer.write(_frame(20 * k))
    writer.release()
    return path


def _level(frame: Frame) -> int:
    return int(round(frame.image.mean() / 20))


class FakeCapture:
    """A source with VideoCapture's methods: ``n`` frames, then it stalls (read blocks) until released."""

    def __init__(self, n: int = 3, gray: bool = False, fps: float | None = None, ignore_release: bool = False):
        self.n, self.gray, self.fps, self.ignore_release = n, gray, fps, ignore_release
        self.k = 0
        self.released = threading.Event()
        self.hang = threading.Event()

    def isOpened(self) -> bool:
        return not self.released.is_set()

    def read(self):
        if self.k >= self.n:
            (self.hang if self.ignore_release else self.released).wait()
            return False, None
        self.k += 1
        time.sleep(0.01)
        img = np.full((24, 32), 20 * self.k, np.uint8)
        return True, img if self.gray else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)

    def get(self, prop):
        if self.fps is None:
            raise RuntimeError("no such property")
        return self.fps

    def release(self):
        self.released.set()


def test_a_video_file_plays_at_its_own_rate_then_ends(video):
    with Camera(video) as cam:
        assert cam.fps == pytest.approx(40.0) and "video file" in cam.name
        first = cam.latest()
        assert first.image.shape == (48, 64, 3) and first.image.dtype == np.uint8
        assert not first.image.flags.writeable
        seen = [first]
        while True:
            try:
                seen.append(cam.wait_newer(seen[-1], timeout_s=1.0))
            except CameraEnded as e:
                assert "ended" in str(e)
                break
        assert cam.ended
        indices = [f.index for f in seen]
        assert indices == sorted(indices) and indices[-1] == 11
        assert [_level(f) for f in seen] == [f.index for f in seen]  # frame k shows grey 20 k
        span = seen[-1].t - seen[0].t
        assert span >= (indices[-1] - indices[0]) / 40.0 * 0.8  # not as fast as it decodes
        assert cam.latest().index == 11  # an ended file keeps its last frame


def test_a_looping_file_starts_again(video):
    with Camera(video, loop=True, fps=400) as cam:
        frame = cam.wait_newer(15, timeout_s=3.0)
        assert frame.index > 15 and not cam.ended
        assert _level(frame) == frame.index % 12


def test_a_frame_folder_plays_in_natural_order(tmp_path):
    for k in (1, 2, 10, 3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), _frame(20 * k))
    (tmp_path / "notes.txt").write_text("not a frame")
    with Camera(str(tmp_path), fps=100) as cam:
        assert "frame folder" in cam.name and cam.fps == 100
        levels = [_level(cam.latest())]
        with pytest.raises(CameraEnded):
            while True:
                levels.append(_level(cam.wait_newer(cam.latest(), timeout_s=1.0)))
    assert levels[-1] == 10 and levels == sorted(levels)


def test_missing_sources_say_what_is_missing(tmp_path, capfd):
    with pytest.raises(CameraAbsent, match="video file not found: .*nope.mp4"):
        Camera(tmp_path / "nope.mp4").open()
    with pytest.raises(CameraAbsent, match="no frames in frame folder"):
        Camera(tmp_path).open()
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    with pytest.raises(CameraAbsent, match="cannot open video file"):
        Camera(tmp_path / "bad.mp4").open()
    cam = Camera("97")  # a digit string is a device index
    assert cam.source == 97 and cam.name == "camera 97"
    capfd.readouterr()
    with pytest.raises(CameraAbsent, match="no camera at index 97"):
        cam.open()
    assert "WARN" not in capfd.readouterr().err  # OpenCV's backends' probing is not the artist's to read
    with pytest.raises(CameraAbsent, match="not a camera source"):
        Camera(object()).open()
    assert issubclass(CameraAbsent, HardwareError) and issubclass(CameraStalled, HardwareError)


def test_a_stalling_source_is_reported_and_closing_releases_it(monkeypatch):
    monkeypatch.setattr(Camera, "JOIN_S", 0.2)  # how long close() waits before releasing a source stuck in read()
    fake = FakeCapture(n=3, gray=True, fps=25.0)
    cam = Camera(fake, stall_s=0.3).open()
    assert cam.fps == 25.0
    frame = cam.wait_newer(1, timeout_s=2.0)
    assert frame.index == 2 and frame.image.shape == (24, 32, 3)  # grey became BGR
    with pytest.raises(CameraStalled, match=r"FakeCapture gave no frame newer than frame 2 within 0\.2 s"):
        cam.wait_newer(frame, timeout_s=0.2)
    time.sleep(0.35)
    with pytest.raises(CameraStalled, match=r"FakeCapture has given no new frame for 0\.\d s"):
        cam.latest()
    t = time.monotonic()
    cam.close()  # the reader is blocked in read(): close releases the source, which unblocks it
    assert time.monotonic() - t < 1.0 and fake.released.is_set()
    assert cam._thread is None
    cam.close()  # twice is fine
    with pytest.raises(ClosedError):
        cam.latest()


def test_close_never_raises_even_when_the_source_hangs(monkeypatch):
    fake = FakeCapture(n=1, ignore_release=True)
    cam = Camera(fake).open()
    cam.latest()
    monkeypatch.setattr(Camera, "JOIN_S", 0.05)
    t = time.monotonic()
    cam.close()
    assert time.monotonic() - t < 1.0
    fake.hang.set()  # let the stuck thread go


def test_wait_newer_by_time_and_errors_from_the_source():
    fake = FakeCapture(n=1000)
    with Camera(fake) as cam:
        assert fake.fps is None and cam.fps is None  # get() may fail: no rate known
        moment = time.monotonic()
        frame = cam.wait_newer(moment, timeout_s=2.0)
        assert frame.t > moment
        with pytest.raises(TypeError):
            cam.wait_newer("soon")

    class Broken(FakeCapture):
        def read(self):
            raise OSError("driver gone")

    with Camera(Broken(), stall_s=1.0) as cam, pytest.raises(CameraError, match="driver gone"):
        cam.latest()
    with pytest.raises(ClosedError, match="not open"):
        Camera(FakeCapture()).latest()
