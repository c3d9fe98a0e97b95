"""Crease pockets (studio.targets.pockets): a crease's shade opening to the outside through a neck is filled as
skin, a real gap and a soft edge stay, footage keeps its penumbra, and the fast decision (no recount of the image's
holes per pocket) equals the slow reference that counts them all again."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from studio.targets.images import load_target
from studio.targets.pockets_reference import fill_pockets_slowly

SHARED = Path(__file__).resolve().parents[2] / "shared" / "targets"


def _lit_hand(side: int = 300) -> np.ndarray:
    """A bright palm (grey 200) with two fingers on a black cut-out backdrop (0): the fingers' gap is true black."""
    g = np.zeros((side, side), np.uint8)
    g[120:260, 60:240] = 200  # palm
    g[30:120, 70:120] = 200  # finger 1
    g[30:120, 170:220] = 200  # finger 2: a 50-pixel black gap between them, open at the top
    return g


def test_a_crease_pocket_under_a_side_light_is_skin_and_a_real_gap_stays():
    """A crease's shade (mid-dark, shadowness 5–25, with odd black pixels) that opens to the outside through a neck
    is skin: filled. The true-black gap between two fingers stays open, and so does a soft edge along the outline."""
    from studio.targets.images import TargetConfig, mask_from_grey

    g = _lit_hand()
    g[150:200, 100:200] = 15  # the crease's shade, a pocket in the palm …
    g[150:152, 150:200] = 2  # … with a few near-black pixels in it
    g[170:178, 200:240] = 15  # … and its 8-pixel neck to the outside on the right
    plain = mask_from_grey(g, TargetConfig(pocket_reach=0.0))
    filled = mask_from_grey(g)
    assert plain[150:200, 100:200].sum() == 0 and plain[170:178, 200:240].sum() == 0  # the notch, plainly
    assert filled[150:200, 100:200].all() and filled[170:178, 200:236].all()  # skin, up to the reach of the outside
    assert filled[30:120, 120:170].sum() == 0  # the fingers' black gap stays open
    soft = _lit_hand()
    soft[118:120, 120:170] = 15  # a soft edge: mid-dark along the outline between the fingers, two pixels deep
    assert mask_from_grey(soft)[118:120, 120:170].sum() == 0
    assert np.array_equal(mask_from_grey(_lit_hand()), mask_from_grey(_lit_hand(), TargetConfig(pocket_reach=0.0)))


def test_footage_of_a_shadow_keeps_its_penumbra_gaps_open():
    """A shadow has no skin: the mid-dark in a frame of shadow footage is penumbra, a real gap's, and stays open
    where a still's loader, with the same levels, would fill it as a crease pocket."""
    from studio.targets.images import TargetConfig, mask_from_grey
    from studio.targets.video import VideoConfig, shadow_mask

    g = _lit_hand()
    g[150:200, 100:200] = 110  # mid-dark for footage's levels: under its threshold (128), over its core (0.75 ×)
    g[170:178, 200:240] = 110
    shadow = 255 - g  # a dark shadow on a bright backdrop
    cfg = VideoConfig()
    still = TargetConfig(polarity="dark", threshold=cfg.threshold, backdrop_level=cfg.backdrop_level)
    assert mask_from_grey(shadow, still)[150:200, 100:200].all()
    assert shadow_mask(shadow, "dark", cfg)[150:200, 100:200].sum() == 0


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/targets is not here (the shared data set)")
def test_side_lit_letters_lose_their_crease_notches_and_binary_shapes_are_unchanged():
    """Signer 2's `q` under a light from the right: its crease's shade was cut out of the letter as a notch; now it
    is skin (the mask only grows, by ≥ 5 %). Binary silhouettes have no mid-dark pixels: not one pixel changes."""
    from studio.targets.images import TargetConfig

    off = TargetConfig(pocket_reach=0.0)
    q = SHARED / "asl/q/hand2_q_right_seg_1_cropped.jpeg"
    plain, filled = load_target(q, cfg=off), load_target(q)
    assert np.all(filled >= plain) and filled.sum() >= 1.05 * plain.sum()
    for name in ("camel-2.gif", "horse-2.gif", "deer-2.gif", "Heart-2.gif"):
        path = SHARED / "mpeg7" / name
        assert np.array_equal(load_target(path, size=128), load_target(path, size=128, cfg=off)), name


def test_pocket_settings_out_of_range_are_refused():
    from studio.targets.images import TargetConfig

    for bad in ({"pocket_reach": -0.1}, {"pocket_reach": 2.0}, {"pocket_neck": 1.5}):
        with pytest.raises(ValueError, match="pocket_reach and pocket_neck"):
            TargetConfig(**bad)


def test_going_around_a_pocket_is_checked_against_counting_the_backdrop_s_pieces():
    """fill_pockets' first shortcut (near the pocket, the backdrop around it is one piece, so filling it splits
    nothing) against the slow reference: counting the backdrop's 4-connected pieces before and after, on random
    masks and pockets, looking only at the pocket's box or a few pixels more."""
    from studio.targets.pockets import _one_piece_near

    rng = np.random.default_rng(7)
    said = {True: 0, False: 0}
    for _ in range(400):
        mask = (rng.random((20, 20)) < rng.uniform(0.2, 0.6)).astype(np.uint8)
        mask[0], mask[-1], mask[:, 0], mask[:, -1] = 1, 1, 1, 1  # pockets stay off the border, as in fill_pockets
        r, c = rng.integers(1, 15, 2)
        window = np.zeros_like(mask)
        window[r : r + rng.integers(1, 5), c : c + rng.integers(1, 5)] = 1
        n, parts, stats, _ = cv2.connectedComponentsWithStats(window & (1 - mask), connectivity=4)
        if n < 2:
            continue
        x, y, w, h = stats[1, :4]
        pocket = (parts[y - 1 : y + h + 1, x - 1 : x + w + 1] == 1).astype(np.uint8)  # its box, one pixel around
        filled = mask | (parts == 1).astype(np.uint8)
        pieces = cv2.connectedComponents(1 - mask, connectivity=4)[0]
        if cv2.connectedComponents(1 - filled, connectivity=4)[0] == pieces - 1:  # the pocket was a whole piece
            continue
        ok = _one_piece_near(pocket, filled, y - 1, x - 1, int(rng.choice([0, 1, 3])))
        said[ok] += 1
        if ok:
            assert cv2.connectedComponents(1 - filled, connectivity=4)[0] == pieces
    assert said[True] > 20 and said[False] > 20, said  # both answers were checked


def test_pockets_are_filled_exactly_as_the_slow_reference_fills_them(monkeypatch):
    """On random shapes with random mid-dark shade beside them, fill_pockets (pockets that may close an opening
    decided from the holes beside each, counted once) equals the reference that counts every hole of the image again
    for each pocket; pockets that enclose a crease (filled) and ones that would close an opening (refused) both
    occur, so a fast path that always said yes, or always no, fails."""
    import studio.targets.pockets as pockets

    enclosing = []
    real = pockets._enclosed
    monkeypatch.setattr(pockets, "_enclosed", lambda *a: enclosing.append(len(real(*a)[0])) or real(*a))
    rng = np.random.default_rng(1)
    refused = 0
    for case in range(200):
        side = int(rng.integers(40, 90))
        field = cv2.GaussianBlur(rng.random((side, side)).astype(np.float32), (0, 0), rng.uniform(1.5, 4))
        mask = (field > np.quantile(field, rng.uniform(0.4, 0.75))).astype(np.uint8)
        mask[[0, -1]], mask[:, [0, -1]] = 0, 0
        mid = cv2.GaussianBlur(rng.random((side, side)).astype(np.float32), (0, 0), rng.uniform(0.7, 2.5))
        mid = mid > np.quantile(mid, rng.uniform(0.3, 0.7))
        shade = np.where(mask > 0, 200, np.where(mid, 15, 0)).astype(np.float32)
        args = (mask, shade, 5.0, rng.uniform(0.02, 0.08), 0.25, rng.choice([0.015, 0.05, 3.0]), 0.3)
        want, n = fill_pockets_slowly(*args)
        refused += n
        assert np.array_equal(pockets.fill_pockets(*args), want), case
    assert refused > 50 and sum(k > 0 for k in enclosing) - refused > 50, (refused, len(enclosing))


def test_mid_dark_specks_over_the_backdrop_leave_the_crease_filled_and_the_gap_open():
    """A photo whose black backdrop is sprinkled with mid-dark specks (a dark cloth): the crease pocket is still
    filled, the fingers' black gap stays open, and the specks add next to nothing to the shape."""
    from studio.targets.images import mask_from_grey

    g = _lit_hand()
    g[150:200, 100:200] = 15
    g[170:178, 200:240] = 15
    g = cv2.resize(g, (600, 600), interpolation=cv2.INTER_NEAREST)
    clean = mask_from_grey(g)
    rng = np.random.default_rng(0)
    noisy = np.where((g == 0) & (rng.random(g.shape) < 0.02), 12, g).astype(np.uint8)
    got = mask_from_grey(noisy)
    assert got[300:400, 200:400].all() and got[60:240, 250:330].sum() == 0
    assert abs(int(got.sum()) - int(clean.sum())) < 0.002 * clean.sum()
