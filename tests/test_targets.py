"""studio.targets.images: real targets load cleanly, openings survive hole filling, bad files raise TargetError."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image
from studio.assets import shipped_samples

from studio.errors import StudioError, TargetError
from studio.targets.holes import fill_holes, find_holes
from studio.targets.image_sets import find_target_files
from studio.targets.images import (
    DEFAULT_TARGET,
    SAMPLE_DIR,
    TargetConfig,
    keep_largest_components,
    load_target,
    mask_from_grey,
    shadow_box,
    square_box,
    square_frame,
)

LETTERS = "abcdefghijklmnopqrstuvwxyz"


def _components(mask: np.ndarray) -> int:
    return cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)[0] - 1


def _check_mask(mask: np.ndarray, name: str) -> None:
    assert mask.dtype == np.uint8 and mask.ndim == 2, name
    assert set(np.unique(mask)) <= {0, 1}, name
    assert 0.01 < mask.mean() < 0.95, f"{name}: shadow fraction {mask.mean():.3f}"
    assert 1 <= _components(mask) <= TargetConfig().max_components, name


@pytest.mark.slow
@pytest.mark.parametrize("letter", LETTERS)
def test_every_asl_file_loads(shared_targets: Path, letter: str) -> None:
    files = sorted((shared_targets / "asl" / letter).glob("*.jpeg"))
    assert len(files) >= 5
    for f in files:
        mask = load_target(f)
        _check_mask(mask, f.name)
        holes = find_holes(mask)
        if letter != "o":  # crease holes of fists and fingers are filled; only the "o" has a real opening here
            assert not holes.any(), f"{f.name}: {int(holes.sum())} hole pixels left"


def test_asl_o_keeps_its_opening(shared_targets: Path) -> None:
    files = sorted((shared_targets / "asl" / "o").glob("*.jpeg"))
    opened = 0
    for f in files:
        mask = load_target(f)
        holes = find_holes(mask)
        if holes.any():
            opened += 1
            assert holes.sum() > 0.03 * mask.sum(), f.name
    assert opened >= 7  # 8 of the 10 "o" images show the backdrop through the ring (2 are closed fists)
    mask = load_target(shared_targets / "asl" / "o" / "hand1_o_bot_seg_1_cropped.jpeg")
    assert find_holes(mask).sum() > 0.05 * mask.sum()


@pytest.mark.slow
def test_every_mpeg7_file_loads(shared_targets: Path) -> None:
    files = sorted((shared_targets / "mpeg7").glob("*.gif"))
    assert len(files) >= 200
    for f in files:
        _check_mask(load_target(f), f.name)


def test_davis_frames_load(shared_targets: Path) -> None:
    for seq in sorted(p for p in (shared_targets / "davis").iterdir() if p.is_dir()):
        f = sorted(seq.glob("*.png"))[0]
        _check_mask(load_target(f), f"{seq.name}/{f.name}")


def test_bundled_samples_load() -> None:
    files = find_target_files(SAMPLE_DIR)
    assert DEFAULT_TARGET in files and len(files) >= 5
    assert (SAMPLE_DIR / "SOURCE.txt").is_file()
    assert sum(f.stat().st_size for f in files) < 200_000
    for f in files:
        framed = load_target(f, size=64)
        assert framed.shape == (64, 64) and framed.any()
    assert find_holes(load_target(DEFAULT_TARGET)).any()
    samples = shipped_samples()  # the Targets panel's list: every shipped still and video, by file name
    assert {DEFAULT_TARGET.name, "muybridge_horse.gif"} <= set(samples) and {f.name for f in files} <= set(samples)
    assert all(path.is_file() and path.name == name for name, path in samples.items())


def _ring(size: int = 200, r_out: int = 70, r_in: int = 28) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[:size, :size]
    d = np.hypot(yy - size / 2, xx - size / 2)
    return (d < r_out).astype(np.uint8), (d < r_in).astype(np.uint8)


def _save(tmp_path: Path, name: str, grey: np.ndarray) -> Path:
    path = tmp_path / name
    Image.fromarray(grey.astype(np.uint8)).save(path)
    return path


def test_ring_keeps_hole_and_pepper_holes_fill(tmp_path: Path, rng) -> None:
    disk, hole = _ring()
    ring = disk - hole
    band = np.argwhere((ring == 1) & (cv2.erode(ring, np.ones((7, 7), np.uint8)) == 1))
    pepper = ring.copy()
    for y, x in band[rng.choice(len(band), 40, replace=False)]:
        pepper[y : y + 2, x : x + 2] = 0
    assert find_holes(pepper).sum() > hole.sum()
    for polarity, grey in (("bright", pepper * 255), ("dark", (1 - pepper) * 255)):
        mask = load_target(_save(tmp_path, f"ring_{polarity}.png", grey))
        np.testing.assert_array_equal(mask, ring, err_msg=polarity)
        np.testing.assert_array_equal(find_holes(mask), hole)


def test_eye_survives_and_min_hole_area_is_a_choice(tmp_path: Path) -> None:
    body = np.zeros((240, 320), np.uint8)
    cv2.ellipse(body, (160, 120), (120, 70), 0, 0, 360, 1, -1)
    eye = np.zeros_like(body)
    cv2.circle(eye, (220, 100), 10, 1, -1)  # about 1.2 % of the body (default min 1.5 %): the config decides
    animal = body * (1 - eye)
    share = eye.sum() / animal.sum()
    path = _save(tmp_path, "animal.bmp", animal * 255)
    keep = TargetConfig(min_hole_area=0.5 * share)
    np.testing.assert_array_equal(find_holes(load_target(path, cfg=keep)), eye)
    fill = TargetConfig(min_hole_area=2 * share)
    assert not find_holes(load_target(path, cfg=fill)).any()
    pixels = TargetConfig(min_hole_area=float(eye.sum() - 1))  # ≥ 1: an absolute area in pixels
    np.testing.assert_array_equal(find_holes(load_target(path, cfg=pixels)), eye)


def test_dark_crease_fills_but_black_opening_stays() -> None:
    """A grey hand (skin 160): a crease of dark skin (grey 12) fills, a same-size opening onto black (0) stays."""
    grey = np.zeros((200, 200), np.uint8)
    cv2.rectangle(grey, (20, 20), (180, 180), 160, -1)
    cv2.circle(grey, (60, 60), 18, 12, -1)  # crease: below the threshold 25 but not backdrop-black
    cv2.circle(grey, (140, 140), 18, 0, -1)  # opening: the backdrop shows through
    mask = mask_from_grey(grey)
    holes = find_holes(mask)
    assert holes[140, 140] == 1 and holes[60, 60] == 0
    assert mask[60, 60] == 1


def test_alpha_channel_is_the_shape(tmp_path: Path) -> None:
    disk, _ = _ring(64, 20, 0)
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[..., :3] = 200  # colour says nothing; the alpha channel holds the shape
    rgba[..., 3] = disk * 255
    path = tmp_path / "cutout.png"
    Image.fromarray(rgba, "RGBA").save(path)
    np.testing.assert_array_equal(load_target(path), disk)


def test_sixteen_bit_png(tmp_path: Path) -> None:
    disk, _ = _ring(64, 20, 0)
    path = tmp_path / "deep.png"
    Image.fromarray(disk.astype(np.uint16) * 40000).save(path)
    np.testing.assert_array_equal(load_target(path), disk)


def test_otsu_threshold_on_a_grey_photo() -> None:
    grey = np.full((100, 100), 190, np.uint8)  # light wall
    grey[30:70, 20:60] = 70  # a darker shape
    noise = np.random.default_rng(1).integers(-15, 16, grey.shape)
    grey = np.clip(grey + noise, 0, 255).astype(np.uint8)
    mask = mask_from_grey(grey, TargetConfig(threshold=None))
    expected = np.zeros_like(mask)
    expected[30:70, 20:60] = 1
    np.testing.assert_array_equal(mask, expected)


def test_components_keep_largest_drop_specks() -> None:
    m = np.zeros((100, 100), np.uint8)
    m[10:50, 10:50] = 1  # 1600
    m[60:90, 60:80] = 1  # 600 (share 0.375)
    m[5, 90] = m[95, 5] = 1  # specks
    kept = keep_largest_components(m, 3, 0.1)
    assert _components(kept) == 2 and kept[5, 90] == 0
    assert _components(keep_largest_components(m, 1)) == 1
    assert keep_largest_components(m, 3, 0.5).sum() == 1600


def test_holes_touching_the_border_are_not_holes() -> None:
    m = np.ones((50, 50), np.uint8)
    m[20:30, 0:10] = 0  # a notch open to the left border
    m[20:30, 20:30] = 0  # a real hole
    holes = find_holes(m)
    assert holes.sum() == 100 and holes[25, 25] == 1 and holes[25, 5] == 0
    np.testing.assert_array_equal(fill_holes(m, min_hole_area=101.0), m | holes)


@settings(max_examples=25, deadline=None)
@given(
    h=st.integers(8, 60),
    w=st.integers(8, 60),
    top=st.integers(0, 30),
    left=st.integers(0, 30),
    size=st.sampled_from([32, 64]),
)
def test_square_frame_keeps_aspect_and_centres(h: int, w: int, top: int, left: int, size: int) -> None:
    m = np.zeros((100, 100), np.uint8)
    m[top : top + h, left : left + w] = 1
    framed = square_frame(m, size, shadow_box(m), margin=0.1)
    r0, r1, c0, c1 = shadow_box(framed)
    fh, fw = r1 - r0, c1 - c0
    assert max(fh, fw) == pytest.approx(size / 1.2, abs=1 + size / max(h, w))  # margin rounded to whole pixels
    # the aspect is kept: each side is the box's side at the frame's own scale, within half a pixel at either edge
    # (a scale read back from the framed longer side would carry that side's rounding into the other: 41 × 45 at 32)
    scale = size / square_box([shadow_box(m)], 0.1)[2]
    assert abs(fh - h * scale) <= 1.0 and abs(fw - w * scale) <= 1.0
    tol = 1 + 0.5 * size / max(h, w)  # the shorter side can sit half a source pixel off centre
    assert abs((r0 + r1) / 2 - size / 2) <= tol and abs((c0 + c1) / 2 - size / 2) <= tol


def test_square_frame_whole_image_pads_to_square() -> None:
    m = np.zeros((50, 100), np.uint8)
    m[:, :50] = 1
    framed = square_frame(m, 20)
    assert framed.shape == (20, 20)
    assert framed[5:15, :10].all() and not framed[:5].any() and not framed[15:].any() and not framed[:, 10:].any()


def test_load_target_frames_to_size(shared_targets: Path) -> None:
    f = shared_targets / "asl" / "v" / "hand1_v_bot_seg_1_cropped.jpeg"
    framed = load_target(f, size=128)
    assert framed.shape == (128, 128)
    r0, r1, c0, c1 = shadow_box(framed)
    assert max(r1 - r0, c1 - c0) == pytest.approx(128 / 1.2, abs=2)
    whole = load_target(f, size=100, cfg=TargetConfig(frame="image"))
    assert whole.shape == (100, 100)


def _bad_files(tmp_path: Path) -> dict[str, tuple[Path, str, TargetConfig]]:
    ok = tmp_path / "ok.png"
    Image.fromarray((_ring()[0] * 255).astype(np.uint8)).save(ok)
    text = tmp_path / "notes.png"
    text.write_text("not an image at all")
    truncated = tmp_path / "cut.png"
    truncated.write_bytes(ok.read_bytes()[:200])
    jpeg = tmp_path / "cut.jpeg"
    Image.fromarray((_ring()[0] * 255).astype(np.uint8)).save(jpeg)
    jpeg.write_bytes(jpeg.read_bytes()[:300])
    auto = TargetConfig()
    return {
        "missing": (tmp_path / "nope.png", "not found", auto),
        "folder": (tmp_path, "not a file", auto),
        "text": (text, "not an image", auto),
        "truncated png": (truncated, "unreadable", auto),
        "truncated jpeg": (jpeg, "unreadable", auto),
        "black": (_save(tmp_path, "black.png", np.zeros((40, 40))), "empty", auto),
        "white": (_save(tmp_path, "white.png", np.full((40, 40), 255)), "empty", auto),
        "white forced bright": (tmp_path / "white.png", "one flat grey level", TargetConfig(polarity="bright")),
        "mid grey": (_save(tmp_path, "grey.png", np.full((40, 40), 128)), "one flat grey level", auto),
        "white, fixed level": (tmp_path / "white.png", "one flat grey level", TargetConfig(auto_otsu=False)),
        "flat otsu": (tmp_path / "black.png", "empty", TargetConfig(threshold=None)),
    }


def test_bad_targets_raise_target_error_naming_the_file(tmp_path: Path) -> None:
    for case, (path, words, cfg) in _bad_files(tmp_path).items():
        with pytest.raises(TargetError) as err:
            load_target(path, cfg=cfg)
        assert words in str(err.value), case
        assert str(path) in str(err.value), case
        assert isinstance(err.value, StudioError)


def test_a_speck_is_refused_not_blown_up_into_a_block(tmp_path: Path) -> None:
    """A shape a few pixels across has no outline: framing would fill the whole frame with it. It is refused, named;
    one just wide enough still frames, with backdrop around it."""
    speck = np.full((100, 100), 255)
    speck[50:52, 40:45] = 0  # 5 × 2 pixels
    path = _save(tmp_path, "speck.png", speck)
    with pytest.raises(TargetError, match=r"only 5×2 pixels .*\(at least 8 pixels across\)") as err:
        load_target(path, size=64)
    assert str(path) in str(err.value)
    assert load_target(path).sum() == 10  # unframed, the mask is as it is
    speck[50:52, 40:48] = 0  # 8 pixels across
    framed = load_target(_save(tmp_path, "wider.png", speck), size=64)
    assert 0 < framed.mean() < 0.5


def test_config_rejects_nonsense() -> None:
    with pytest.raises(ValueError):
        TargetConfig(polarity="sideways")
    with pytest.raises(ValueError):
        TargetConfig(threshold=300)
    with pytest.raises(TargetError):
        find_target_files("/no/such/folder")


def test_grey_backdrop_chooses_otsu_by_itself() -> None:
    """On a grey wall the fixed level 25 would make everything shadow: the loader splits by Otsu instead."""
    grey = np.full((120, 160), 175, np.uint8)  # light-grey wall: shadowness 80 > 25
    cv2.ellipse(grey, (80, 60), (50, 30), 0, 0, 360, 40, -1)  # a dark shape
    expected = np.zeros_like(grey)
    cv2.ellipse(expected, (80, 60), (50, 30), 0, 0, 360, 1, -1)
    np.testing.assert_array_equal(mask_from_grey(grey), expected)
    with pytest.raises(TargetError, match="every pixel is shadow"):
        mask_from_grey(grey, TargetConfig(auto_otsu=False))  # the fixed level, as asked: the wall is shadow


def test_muybridge_horse_first_frame_loads_with_defaults(shared_targets: Path, tmp_path: Path) -> None:
    folder = shared_targets / "video" / "muybridge-horse"
    gifs = sorted(folder.glob("*.gif")) if folder.is_dir() else []
    if not gifs:
        pytest.skip(f"no Muybridge horse GIF in {folder}")
    with Image.open(gifs[0]) as im:  # the first frame, as a plain grey PNG (no palette, no transparency)
        im.seek(0)
        frame = np.asarray(im.convert("L"))
    path = _save(tmp_path, "horse_000.png", frame)
    border = np.concatenate([frame[0], frame[-1], frame[:, 0], frame[:, -1]])
    assert np.median(border) > 128  # a light wall, the dark horse on it: the fixed level alone fails here
    mask = load_target(path)
    _check_mask(mask, path.name)
    assert 0.08 < mask.mean() < 0.4, f"shadow fraction {mask.mean():.3f}"
    touched = [bool(mask[0].any()), bool(mask[-1].any()), bool(mask[:, 0].any()), bool(mask[:, -1].any())]
    assert not all(touched), "the shadow touches all four borders: the wall became shadow"
    _, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    r0, r1, c0, c1 = shadow_box(mask)
    assert stats[1:, cv2.CC_STAT_AREA].max() > 0.8 * mask.sum()  # one horse-and-rider piece, not speckle
    assert (c1 - c0) > 0.6 * mask.shape[1] and (r1 - r0) > 0.5 * mask.shape[0]  # the horse spans the frame
    np.testing.assert_array_equal(load_target(gifs[0]), mask)  # the GIF itself loads to the same mask


def test_numbered_images_name_their_class_and_number() -> None:
    """MPEG-7's names, padded or not: the class before the last ``-``, the number after it."""
    from studio.targets.image_sets import first_per_class, image_class, image_number

    files = ("camel-1.gif", "camel-12.gif", "rat-03.gif", "rat-01.gif", "two-part-name-7.png", "o.jpeg")
    names = [Path(n) for n in files]
    assert [image_class(p) for p in names] == ["camel", "camel", "rat", "rat", "two-part-name", "o"]
    assert [image_number(p) for p in names] == [1, 12, 3, 1, 7, None]
    assert first_per_class(names, 1) == [names[0], names[2], names[4], names[5]]
