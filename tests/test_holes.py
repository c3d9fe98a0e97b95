"""Holes of a framed target (studio.targets.holes): framing keeps the source's openings and adds none."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from studio.targets.footage import Footage
from studio.targets.holes import find_holes, threshold_keeping_gaps
from studio.targets.images import load_target, square_frame
from studio.targets.video import VideoConfig, video_from_masks

SHARED = Path(__file__).resolve().parents[2] / "shared" / "targets"


def _u_shape(gap: int, side: int = 640) -> np.ndarray:
    """A thick U whose arms bend in until ``gap`` source pixels apart: open to the outside through that gap."""
    m = np.zeros((side, side), np.uint8)
    m[100:540, 100:180] = 1  # left arm
    m[100:540, 460:540] = 1  # right arm
    m[460:540, 100:540] = 1  # bottom
    m[100:180, 100 : 320 - gap // 2] = 1  # left lip
    m[100:180, 320 + gap - gap // 2 : 540] = 1  # right lip: a gap of ``gap`` pixels at the top
    return m


def _ring(side: int = 640) -> np.ndarray:
    m = np.zeros((side, side), np.uint8)
    cv2.circle(m, (320, 320), 220, 1, -1)
    cv2.circle(m, (320, 320), 120, 0, -1)
    return m


def _plain(mask: np.ndarray, size: int) -> np.ndarray:
    """The framing before holes were kept: area average, half coverage."""
    return (cv2.resize(mask.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA) >= 0.5).astype(np.uint8)


def test_a_gap_narrower_than_a_frame_pixel_stays_open():
    u = _u_shape(gap=6)  # 6 source pixels: less than half a 20-pixel frame pixel at 32²
    assert not find_holes(u).any()
    plain = _plain(u, 32)
    assert find_holes(plain).sum() > 50  # the plain threshold closes the gap: a false hole
    cover = cv2.resize(u.astype(np.float32), (32, 32), interpolation=cv2.INTER_AREA)
    kept = threshold_keeping_gaps(cover, np.zeros_like(cover))
    assert not find_holes(kept).any()
    changed = kept != plain
    rows, cols = np.nonzero(changed)  # the lip (source rows 100–180: frame rows 5–8), crossed where the gap is
    assert np.all(kept[changed] == 0) and set(rows) == {5, 6, 7, 8} and np.all(np.abs(cols - 16) <= 1)
    assert np.all(cover[changed] < 1.0)  # every pixel opened is partly backdrop at the source
    np.testing.assert_array_equal(square_frame(u, 32), kept)


def test_a_real_opening_is_kept_and_a_mask_without_false_holes_is_unchanged():
    ring = _ring()
    framed = square_frame(ring, 32)
    np.testing.assert_array_equal(framed, _plain(ring, 32))
    assert find_holes(framed).sum() > 20
    u = _u_shape(gap=200)  # wide open: nothing to mend
    np.testing.assert_array_equal(square_frame(u, 32), _plain(u, 32))


def test_random_shapes_gain_no_hole_in_framing():
    """Unions of random discs and bars, framed far smaller: every framed hole lies over a source hole, and every
    pixel that differs from the plain threshold was opened (backdrop now) and is partly backdrop at the source."""
    rng = np.random.default_rng(3)
    false_before = 0
    for _ in range(40):
        m = np.zeros((400, 400), np.uint8)
        for _ in range(rng.integers(3, 9)):
            x, y = (int(v) for v in rng.integers(60, 340, 2))
            if rng.random() < 0.5:
                cv2.circle(m, (x, y), int(rng.integers(15, 70)), 1, -1)
            else:
                cv2.line(m, (x, y), tuple(int(v) for v in rng.integers(60, 340, 2)), 1, int(rng.integers(3, 12)))
        source_holes = find_holes(m)
        size = int(rng.choice([24, 32, 48]))
        cover = cv2.resize(m.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
        hole_cover = cv2.resize(source_holes.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
        plain = (cover >= 0.5).astype(np.uint8)
        kept = threshold_keeping_gaps(cover, hole_cover)
        n, labels = cv2.connectedComponents(find_holes(kept), connectivity=4)
        assert all((hole_cover[labels == i] > 0).any() for i in range(1, n))
        changed = kept != plain
        assert np.all(kept[changed] == 0) and np.all(cover[changed] < 1.0)
        false_before += int(changed.any())
    assert false_before >= 3  # the draw has shapes whose plain framing closed a gap


def test_video_frames_keep_their_gaps():
    masks = np.stack([_u_shape(6), _u_shape(8), _ring()])
    n = len(masks)
    footage = Footage(source=Path("u"), fps=4.0, hz=4.0, duration_s=n / 4, n_source=n, times=np.arange(n) / 4,
                      frame_index=np.arange(n), frames=np.zeros(masks.shape + (3,), np.uint8))  # fmt: skip
    video = video_from_masks(footage, masks, VideoConfig(size=32, keep_frames=False))
    assert not find_holes(video.masks[0]).any() and not find_holes(video.masks[1]).any()
    assert find_holes(video.masks[2]).any()  # the ring's opening is real


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/targets is not here (the shared data set)")
def test_held_out_targets_have_only_their_openings():
    """Of the held-out targets whose plain 128² framing had holes, only the ASL "o" has an opening in its image."""
    for name in ("mpeg7/horse-2.gif", "mpeg7/elephant-2.gif", "mpeg7/dog-2.gif", "mpeg7/cattle-2.gif",
                 "asl/h/hand2_h_bot_seg_1_cropped.jpeg"):  # fmt: skip
        assert not find_holes(load_target(SHARED / name, size=128)).any(), name
    assert find_holes(load_target(SHARED / "asl/o/hand2_o_bot_seg_1_cropped.jpeg", size=128)).sum() > 500


def test_the_targets_panel_previews_a_stored_mask_with_its_gaps():
    """The Targets panel's "stored" preview frames a mask as the project stores it (its gap open), while its raw
    threshold preview shows the plain half-coverage square (the gap closed)."""
    from studio.targets.images import TargetConfig
    from widgets.target_preview import frame_preview

    grey = (_u_shape(6) * 255).astype(np.uint8)
    shown = frame_preview(grey, (0, 0, 640, 640), 32, "bright", 127.0, "mask", VideoConfig(), TargetConfig())
    assert find_holes(shown.mask).any() and shown.stored is not None and not find_holes(shown.stored).any()
    assert int((shown.stored != shown.mask).sum()) <= 6
