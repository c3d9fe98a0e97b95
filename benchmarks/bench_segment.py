"""Segmentation of raw footage without downloaded weights, scored against the DAVIS 2016 ground truth.

For each sequence in ../shared/targets/davis-rgb (blackswan, camel, cows, dog: 854×480 JPEG frames 00000.jpg…)
the object is given as the box of its first ground-truth mask (../shared/targets/davis/<seq>/00000.png, same frame
names), ``segment_video`` (classical method, default ``SegmentConfig``, the same settings for every sequence)
segments every frame, and each frame that has a ground-truth mask is scored (stride 1, frame 0 included): region
similarity J = IoU, mean over the frames of a sequence, then over the sequences. The reference in the same run is
the trivial baseline that holds the first frame's box still (every frame's mask = the box filled), and ``ratio`` =
mean J / its mean J; the first *true* mask held still is printed too (an oracle first frame that never moves).
Printed: one line per sequence, then a JSON object last:
``{"sequences": {name: J}, "mean_J", "first_frame_J": {name: J}, "seconds_per_frame", "frames",
"reference": {"method", "sequences", "mean_J"}, "held_true_first_mask_J", "ratio", "work_size"}``.

    python benchmarks/bench_segment.py [--rgb DIR] [--masks DIR] [--sequences blackswan,dog] [--work-size 400]

Measured here (2 shared CPU cores, work size 400): blackswan 0.874, camel 0.687, cows 0.821, dog 0.627, mean J
0.752 against 0.325 for the held box (ratio 2.3) and 0.484 for the true first mask held still; the first frame alone
(from the box) 0.91 / 0.64 / 0.86 / 0.86; 0.05-0.08 s a frame (about 20 s for the 304 frames). The DAVIS 2016
paper's classical methods reach 0.55-0.70 from a first-frame *mask*. Not tuned on, the same defaults give 0.88 on
DAVIS bear (../shared/targets/video/bear-mp4 against davis/bear).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from PIL import Image

from studio.targets.segment import segment_video
from studio.targets.segment_config import SegmentConfig

SHARED = Path(__file__).resolve().parents[2] / "shared" / "targets"


def load_sequence(rgb_dir: Path, mask_dir: Path) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """RGB frames (N, H, W, 3) uint8 and the ground truth {frame index: (H, W) bool} matched by file stem."""
    paths = sorted(p for p in rgb_dir.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    frames = np.stack([np.asarray(Image.open(p).convert("RGB")) for p in paths])
    index = {p.stem: i for i, p in enumerate(paths)}
    truth = {}
    for m in sorted(mask_dir.glob("*.png")):
        if m.stem in index:
            truth[index[m.stem]] = np.asarray(Image.open(m).convert("L")) > 127
    return frames, truth


def box_of(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


def jaccard(pred: np.ndarray, truth: np.ndarray) -> float:
    union = np.logical_or(pred, truth).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred, truth).sum() / union)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rgb", default=str(SHARED / "davis-rgb"), help="folder of RGB sequences")
    ap.add_argument("--masks", default=str(SHARED / "davis"), help="folder of ground-truth mask sequences")
    ap.add_argument("--sequences", default="blackswan,camel,cows,dog", help="comma-separated names")
    ap.add_argument("--work-size", type=int, default=SegmentConfig.work_size, help="longest side segmented at (px)")
    args = ap.parse_args()
    cfg = replace(SegmentConfig(method="classical"), work_size=args.work_size)
    scores, first, held, held_mask, seconds, n_frames = {}, {}, {}, {}, 0.0, 0
    for name in args.sequences.split(","):
        frames, truth = load_sequence(Path(args.rgb) / name, Path(args.masks) / name)
        box = box_of(truth[min(truth)])
        t0 = time.perf_counter()
        masks = segment_video(frames, box=box, cfg=cfg)
        seconds += time.perf_counter() - t0
        n_frames += len(frames)
        x, y, w, h = box
        still = np.zeros(frames.shape[1:3], bool)
        still[y : y + h, x : x + w] = True
        scores[name] = float(np.mean([jaccard(masks[i] > 0, g) for i, g in truth.items()]))
        first[name] = jaccard(masks[min(truth)] > 0, truth[min(truth)])
        held[name] = float(np.mean([jaccard(still, g) for g in truth.values()]))
        held_mask[name] = float(np.mean([jaccard(truth[min(truth)], g) for g in truth.values()]))
        print(
            f"{name:10s} {len(truth):3d} frames scored  J {scores[name]:.3f}  (first frame {first[name]:.3f}; "
            f"held box {held[name]:.3f}, held true first mask {held_mask[name]:.3f})",
            flush=True,
        )
    mean_j, mean_ref = float(np.mean(list(scores.values()))), float(np.mean(list(held.values())))
    rounded = lambda d: {k: round(v, 4) for k, v in d.items()}  # noqa: E731
    result = {
        "sequences": rounded(scores),
        "mean_J": round(mean_j, 4),
        "first_frame_J": rounded(first),
        "seconds_per_frame": round(seconds / max(n_frames, 1), 4),
        "frames": n_frames,
        "reference": {
            "method": "first box held still",
            "sequences": rounded(held),
            "mean_J": round(mean_ref, 4),
        },
        "held_true_first_mask_J": round(float(np.mean(list(held_mask.values()))), 4),
        "ratio": round(mean_j / mean_ref, 3) if mean_ref > 0 else None,
        "work_size": cfg.work_size,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
