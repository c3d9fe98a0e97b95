"""The ``keyframes`` verb: a DAVIS sequence's clusters, one line each and a JSON summary last, and their contact sheet
(one row per keyframe, its representative first); a τ outside [0, 1] is refused in one line."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest


@pytest.mark.slow
def test_keyframes_verb_end_to_end(shared_targets, tmp_path):
    src = shared_targets / "davis" / "blackswan"
    out = tmp_path / "kf"
    r = subprocess.run(
        [sys.executable, "-m", "studio.cli", "keyframes", str(src), "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    summary = json.loads(lines[-1])
    n, k = summary["frames"], summary["keyframes"]
    assert len(summary["assignment"]) == n and len(summary["representatives"]) == k
    assert sorted(set(summary["assignment"])) == list(range(k))
    assert summary["assignment"][0] == 0
    assert len(lines) - 1 >= k  # one line per cluster before the JSON
    sheet = cv2.imread(summary["sheet"])
    counts = np.bincount(summary["assignment"])
    rows = int(sum(-(-c // 16) for c in counts))  # one row per keyframe, wrapped after 16 tiles of 96 px + 4 px gap
    assert sheet is not None and sheet.shape == (rows * 100 - 4, min(counts.max(), 16) * 100 - 4, 3)
    assert (sheet[..., 0] != sheet[..., 2]).any()  # the expressive tint is there


def test_sheet_rows_put_the_representative_first():
    from studio.review.sheets import REPRESENTATIVE, keyframe_sheet

    masks = np.zeros((5, 16, 16), np.uint8)
    masks[:, 4:12, 4:12] = 1
    img = keyframe_sheet(masks, masks, [[0, 2, 3], [1, 4]], [2, 4], tile=20, columns=2)
    assert img.shape == (3 * 24 - 4, 2 * 24 - 4, 3)  # rows: [2, 0], [3], [4, 1]
    framed = [tuple(img[r * 24, c * 24]) for r in range(3) for c in range(2)]
    assert framed[0] == REPRESENTATIVE and framed[4] == REPRESENTATIVE  # row starts of keyframes 0 and 1
    assert framed[1] != REPRESENTATIVE and framed[5] != REPRESENTATIVE


def test_keyframes_verb_refuses_a_bad_tau(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "studio.cli", "keyframes", str(tmp_path), "--tau", "1.5"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr and "tau" in r.stderr
