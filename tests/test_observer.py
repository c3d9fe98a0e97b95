"""The independent observer (studio.evaluate.observer): its descriptors' invariances, naming synthetic shapes, and
naming the held-out MPEG-7 and ASL targets from galleries of other images (as bench_observer uses it)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from studio.evaluate.observer import Observer, ObserverConfig, describe
from studio.targets.image_sets import image_class, image_number
from studio.targets.images import load_target

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "targets"
HOG, FOURIER = ObserverConfig(descriptor="hog"), ObserverConfig(descriptor="fourier")


def shape(kind: str, size: int, at: tuple[int, int], side: int = 128, angle: float = 0.0) -> np.ndarray:
    """A filled silhouette ``(side, side)`` uint8: "disc", "bar" (4:1), "ell" (an L) or "cross"."""
    h = size // 2
    if kind == "disc":
        pts = [(h * np.cos(t), h * np.sin(t)) for t in np.linspace(0, 2 * np.pi, 64, endpoint=False)]
    elif kind == "bar":
        pts = [(-h, -h / 4), (h, -h / 4), (h, h / 4), (-h, h / 4)]
    elif kind == "ell":
        pts = [(-h, -h), (-h / 3, -h), (-h / 3, h / 3), (h, h / 3), (h, h), (-h, h)]
    else:
        q = h / 3
        pts = [
            (-q, -h),
            (q, -h),
            (q, -q),
            (h, -q),
            (h, q),
            (q, q),
            (q, h),
            (-q, h),
            (-q, q),
            (-h, q),
            (-h, -q),
            (-q, -q),
        ]
    c, s = np.cos(angle), np.sin(angle)
    poly = np.array([(at[0] + c * x - s * y, at[1] + s * x + c * y) for x, y in pts], np.int32)
    img = np.zeros((side, side), np.uint8)
    cv2.fillPoly(img, [poly], 1)
    return img


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_hog_ignores_place_and_size_but_sees_orientation():
    base = describe(shape("ell", 60, (50, 50)), HOG)
    assert cosine(base, describe(shape("ell", 90, (70, 60)), HOG)) > 0.95
    assert cosine(base, describe(shape("ell", 60, (50, 50), angle=np.pi / 2), HOG)) < 0.8  # turned: another shape


def test_fourier_ignores_place_size_and_turning():
    base = describe(shape("cross", 60, (50, 50)), FOURIER)
    for other in (shape("cross", 90, (70, 60)), shape("cross", 60, (64, 64), angle=0.4)):
        assert np.abs(describe(other, FOURIER) - base).max() < 0.02
    assert np.abs(describe(shape("bar", 60, (50, 50)), FOURIER) - base).max() > 0.05


@pytest.mark.parametrize("cfg", [HOG, FOURIER, ObserverConfig(k=3)], ids=["hog", "fourier", "hog-k3"])
def test_the_observer_names_new_instances_of_known_shapes(cfg):
    rng = np.random.default_rng(0)
    kinds = ("disc", "bar", "ell", "cross")

    def draw(kind):
        return shape(kind, int(rng.integers(40, 90)), tuple(int(v) for v in rng.integers(50, 78, 2)),
                     angle=float(rng.normal(0, 0.05)))  # fmt: skip

    gallery = [(k, draw(k)) for k in kinds for _ in range(3)]
    observer = Observer([k for k, _ in gallery], [m for _, m in gallery], cfg)
    assert observer.classes == sorted(kinds)
    assert [observer.name(draw(k)) for k in kinds for _ in range(2)] == [k for k in kinds for _ in range(2)]


def test_bad_observer_settings_and_galleries_are_refused():
    with pytest.raises(ValueError, match="descriptor"):
        ObserverConfig(descriptor="clip")
    with pytest.raises(ValueError, match="side a multiple of 8"):
        ObserverConfig(side=60)
    with pytest.raises(ValueError, match="one label per mask"):
        Observer(["a"], [])
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        describe(np.zeros((2, 8, 8), np.uint8))


@pytest.mark.skipif(not SHARED.is_dir(), reason=f"shared targets absent: {SHARED}")
def test_the_observer_names_held_out_targets_from_other_images():
    """bench_observer's observer: MPEG-7 images 3–20 name each class's 2nd image; signer 1 names signer 2's letters."""
    files = sorted((SHARED / "mpeg7").glob("*.gif"))
    gallery = [p for p in files if image_number(p) >= 3]
    observer = Observer([image_class(p) for p in gallery], [load_target(p, size=128) for p in gallery], HOG)
    queries = [p for p in files if image_number(p) == 2]
    assert len(queries) == 12  # camel-2.gif … rat-02.gif
    right = [observer.name(load_target(p, size=128)) == image_class(p) for p in queries]
    assert np.mean(right) >= 0.8, right  # 11 of 12 measured
    signer1 = sorted((SHARED / "asl").glob("*/hand1_*"))
    asl = Observer([p.parent.name for p in signer1], [load_target(p, size=128) for p in signer1], HOG)
    signer2 = sorted((SHARED / "asl").glob("*/hand2_*_bot_*"))
    assert np.mean([asl.name(load_target(p, size=128)) == p.parent.name for p in signer2]) >= 0.6  # 0.77 measured
