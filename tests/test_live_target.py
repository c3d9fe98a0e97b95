"""Live targets (studio.targets.live_target): camera frames → framed target masks, checked pixel by pixel."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from studio.targets.backdrop import backdrop_from_corners
from studio.targets.images import TargetConfig, load_target, shadow_box, square_frame
from studio.targets.live_target import LiveTarget, LiveTargetConfig, LiveTargets

H, W = 480, 854  # the camera's frame
R = 128


def _hand(h: int = H, w: int = W, cx: int = 420, cy: int = 250, s: float = 1.0) -> np.ndarray:
    """A hand-like blob ``(h, w)`` uint8 1 = hand: a palm, four fingers, a thumb and the wrist to the bottom edge."""
    m = np.zeros((h, w), np.uint8)
    cv2.ellipse(m, (cx, cy), (int(70 * s), int(85 * s)), 0, 0, 360, 1, -1)
    for k, angle in enumerate((-25, -8, 8, 25)):  # fingers fanned out, gaps between them
        a = np.deg2rad(angle)
        tip = (int(cx + 150 * s * np.sin(a)), int(cy - 60 * s - 110 * s * np.cos(a) + 10 * s * abs(k - 1.5)))
        cv2.line(m, (cx + int(40 * s * np.sin(a)), cy - int(40 * s)), tip, 1, int(22 * s))
    cv2.line(m, (cx - int(50 * s), cy + int(20 * s)), (cx - int(140 * s), cy - int(40 * s)), 1, int(26 * s))  # thumb
    cv2.rectangle(m, (cx - int(45 * s), cy + int(60 * s)), (cx + int(45 * s), h - 1), 1, -1)  # wrist, off the frame
    return m


def _wall(h: int = H, w: int = W, seed: int = 0) -> np.ndarray:
    """An unevenly lit light wall ``(h, w)`` float, grey levels: a lamp up and to the left, 250 down to ~140."""
    y, x = np.mgrid[0:h, 0:w]
    light = 1.0 - 0.45 * np.hypot((x - 0.2 * w) / w, (y - 0.1 * h) / h) / 1.1
    return 250 * light + np.random.default_rng(seed).normal(0, 3, (h, w))


def _photo(grey: np.ndarray) -> np.ndarray:
    """Grey levels ``(h, w)`` → a warm-tinted BGR uint8 camera frame."""
    return np.clip(grey[..., None] * np.array([0.85, 0.95, 1.0]), 0, 255).astype(np.uint8)


def _shadow_on_wall(blob: np.ndarray, ambient: float = 0.3, seed: int = 0) -> np.ndarray:
    """The photograph of ``blob``'s shadow on the uneven wall: the shadow keeps ``ambient`` of the light there."""
    wall = _wall(*blob.shape, seed=seed)
    return _photo(wall * np.where(cv2.GaussianBlur(blob.astype(np.float32), (0, 0), 1.5) > 0.5, ambient, 1.0))


def _framed(blob: np.ndarray) -> np.ndarray:
    return square_frame(blob, R, shadow_box(blob), TargetConfig.margin)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a.astype(bool) & b.astype(bool)).sum() / (a.astype(bool) | b.astype(bool)).sum())


def _check_mask(t: LiveTarget) -> np.ndarray:
    assert t.reason == "" and t.mask is not None, t.reason
    assert t.mask.shape == (R, R) and t.mask.dtype == np.uint8 and set(np.unique(t.mask)) <= {0, 1}
    return t.mask


def _check_none(t: LiveTarget, *words: str) -> None:
    assert t.mask is None and t.reason.startswith("no silhouette: "), t.reason
    assert all(w in t.reason for w in words), t.reason


def test_hand_shadow_on_an_unevenly_lit_wall() -> None:
    blob = _hand()
    frame = _shadow_on_wall(blob)
    wall = frame[..., 2].astype(int)
    assert wall[20, 150] - wall[H - 20, W - 20] > 80  # really uneven: the far corner is much darker
    live = LiveTargets()
    assert live.polarity == "auto"
    t = live(frame)
    mask = _check_mask(t)
    assert _iou(mask, _framed(blob)) >= 0.9
    assert abs(t.share - blob.mean()) < 0.01 and 0 < t.seconds < 1
    assert live.polarity == "dark"  # the light border decided it
    assert mask[R // 2 + 10, R // 2] == 1  # the palm's centre


def test_bright_shape_on_black() -> None:
    blob = _hand(s=0.8)
    grey = np.where(blob > 0, 220.0, 15.0) + np.random.default_rng(1).normal(0, 4, blob.shape)
    live = LiveTargets()
    mask = _check_mask(live(np.clip(grey, 0, 255).astype(np.uint8)))  # a grey (H, W) frame
    assert _iou(mask, _framed(blob)) >= 0.9
    assert live.polarity == "bright"


@pytest.mark.parametrize("polarity", ["auto", "dark", "bright"])
def test_blank_and_black_frames_give_no_silhouette(polarity: str) -> None:
    live = LiveTargets(LiveTargetConfig(polarity=polarity))
    for level in (255, 0):
        t = live(np.full((H, W, 3), level, np.uint8))
        _check_none(t, "flat grey level")
        assert t.share == 0
    noisy_black = np.clip(np.random.default_rng(2).normal(8, 3, (H, W)), 0, 255).astype(np.uint8)
    _check_none(live(noisy_black))
    if polarity != "bright":  # (a light wall is no backdrop for a bright shape: "bright" means shapes on black)
        _check_none(live(_photo(_wall())))  # an empty, unevenly lit wall: its dark side is no shadow
    assert live.polarity == polarity  # no silhouette decides nothing


def test_empty_uneven_wall_names_the_contrast() -> None:
    t = LiveTargets(LiveTargetConfig(polarity="dark"))(_photo(_wall()))
    _check_none(t, "nothing is clearly darker than the wall", "contrast")


def test_shadow_over_nearly_everything_and_a_speck() -> None:
    everything = np.ones((H, W), np.uint8)
    everything[:, :50] = 0  # a lit strip at the left edge
    t = LiveTargets(LiveTargetConfig(polarity="dark"))(_shadow_on_wall(everything))
    _check_none(t, "covers")
    assert t.share > 0.6
    speck = np.zeros((H, W), np.uint8)
    cv2.circle(speck, (400, 200), 8, 1, -1)  # 0.05 % of the frame
    _check_none(LiveTargets()(_shadow_on_wall(speck)), "too small")


def test_polarity_is_decided_once_and_kept() -> None:
    live = LiveTargets()
    mid = np.full((H, W), 128, np.uint8)  # an ambiguous border (grey 128): a frame, but no decision
    cv2.circle(mid, (400, 240), 80, 20, -1)
    _check_mask(live(mid))
    assert live.polarity == "auto"
    _check_mask(live(_shadow_on_wall(_hand())))
    assert live.polarity == "dark"
    for _ in range(3):  # a bright shape on black now: the polarity stays, the black reads as a huge shadow
        shape = np.zeros((H, W), np.uint8)
        cv2.circle(shape, (400, 240), 80, 230, -1)
        _check_none(live(shape), "covers")
        live(mid)
        assert live.polarity == "dark"


def _window_blob(n: int = 512) -> np.ndarray:
    """The hand's shadow in the window's own pixels ``(n, n)`` (row 0 = top as the audience sees it)."""
    return _hand(n, n, cx=260, cy=260, s=0.9)


def test_backdrop_homography_rectifies_the_window() -> None:
    n = 512
    corners = np.array([[250.0, 60.0], [640.0, 90.0], [620.0, 440.0], [230.0, 420.0]])  # TL, TR, BR, BL (x, y)
    window_px = np.array([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]], np.float32)
    M = cv2.getPerspectiveTransform(window_px, corners.astype(np.float32))  # window pixels → camera pixels
    blob = _window_blob(n)
    in_camera = cv2.warpPerspective(blob.astype(np.float32), M, (W, H), flags=cv2.INTER_LINEAR)
    frame = _photo(_wall() * np.where(in_camera > 0.5, 0.35, 1.0))
    live = LiveTargets(H_backdrop_camera=backdrop_from_corners(corners, 0.6), window_m=0.6)
    assert live.polarity == "dark"
    mask = _check_mask(live(frame))
    assert _iou(mask, _framed(blob)) >= 0.9
    # the shadow outside the window is not the window's: a frame with the shadow off the window has none
    off = np.zeros((H, W), np.uint8)
    cv2.circle(off, (100, 240), 60, 1, -1)
    _check_none(live(_shadow_on_wall(off)), "shadow window")


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((H, W, 3), np.float32),
        np.zeros((H, W, 4), np.uint8),
        np.zeros((H, W, 3), np.int16),
        np.zeros(10, np.uint8),
        np.zeros((1, W, 3), np.uint8),
        [[0, 255], [255, 0]],
    ],
)
def test_bad_frames_raise_value_error(bad) -> None:
    with pytest.raises(ValueError, match="live frame"):
        LiveTargets()(bad)


def test_config_is_validated() -> None:
    assert LiveTargetConfig().margin == TargetConfig.margin
    for kw in (
        {"polarity": "light"},
        {"resolution": 4},
        {"work_size": 8},
        {"min_share": 0.7},
        {"max_share": 1.5},
        {"max_components": 0},
        {"margin": -0.1},
        {"min_contrast": 1.0},
    ):
        with pytest.raises(ValueError):
            LiveTargetConfig(**kw)
    with pytest.raises(ValueError, match="homography"):
        LiveTargets(H_backdrop_camera=np.eye(2))


def test_davis_mask_frames_match_load_target(shared_targets: Path) -> None:
    files = sorted((shared_targets / "davis" / "bear").glob("*.png"))
    if not files:
        pytest.skip(f"no DAVIS bear masks in {shared_targets / 'davis' / 'bear'}")
    live, seconds = LiveTargets(), []
    for k, f in enumerate(files):
        frame = cv2.imread(str(f))
        assert frame.shape == (H, W, 3)
        t = live(frame)
        seconds.append(t.seconds)
        if k % 10 == 0:
            assert _iou(_check_mask(t), load_target(f, R)) >= 0.95, f.name
    assert live.polarity == "bright"
    print(f"\nDAVIS bear masks: {1000 * np.mean(seconds):.2f} ms per {W}×{H} frame ({len(files)} frames)")


def test_bear_mp4_every_frame_gives_a_mask_or_a_reason(shared_targets: Path) -> None:
    path = shared_targets / "video" / "bear-mp4" / "bear.mp4"
    if not path.is_file():
        pytest.skip(f"no bear MP4 at {path}")
    cap = cv2.VideoCapture(str(path))
    live, results = LiveTargets(), []
    t0 = time.perf_counter()
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        t = live(frame)
        if t.mask is None:
            _check_none(t)
        else:
            _check_mask(t)
        results.append(t)
    cap.release()
    assert len(results) > 50
    shares = [t.share for t in results]
    print(
        f"\nbear MP4: {1000 * np.mean([t.seconds for t in results]):.2f} ms per frame ({len(results)} frames, "
        f"{time.perf_counter() - t0:.2f} s with decoding), {sum(t.mask is not None for t in results)} masks, "
        f"share {min(shares):.3f}-{max(shares):.3f}, polarity {live.polarity}"
    )
