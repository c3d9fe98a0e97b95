"""The Keyframes panel's live count: keyframes at many τ from one merge order (``studio.targets.keyframes.
merge_order``) against clustering again at each τ (:func:`recluster`: embedding, then merging until τ, what the panel
did before), measured in the same run on the shared DAVIS mask sequences at every frame (24 fps) and on a long
synthetic clip.

    python benchmarks/bench_keyframe_count.py [--davis ../shared/targets/davis] [--taus 50] [--frames 240]

For each sequence: seconds to count at ``--taus`` values of τ evenly over [0, 1] both ways (the counts checked
equal), the merge order's one-off cost and one count from it (what a slider step costs once the order is known).
The synthetic clip is ``--frames`` frames of 256² of a shape that turns, grows and travels (skipped with 0). Last line
JSON: {"sequences": {name: {"frames", "reference_s", "fast_s", "order_s", "count_us", "speedup", "same"}},
"speedup_min"}.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from studio.targets.expressive import expressive_masks
from studio.targets.keyframes import KeyframeConfig, embed, merge_order, most_different_iou
from studio.targets.merging import merge_clusters
from studio.targets.video import VideoConfig, load_video

DAVIS = Path(__file__).resolve().parents[2] / "shared" / "targets" / "davis"


def synthetic(frames: int, side: int = 256) -> np.ndarray:
    """``(frames, side, side)`` uint8: an ellipse with a head that travels a loop, turns and changes its width."""
    out = np.zeros((frames, side, side), np.uint8)
    for i in range(frames):
        a = 2 * np.pi * i / 60
        cx, cy = int(side / 2 + side / 4 * np.cos(a)), int(side / 2 + side / 8 * np.sin(2 * a))
        axes = (int(side / 8 + side / 16 * np.sin(a)), side // 10)
        cv2.ellipse(out[i], (cx, cy), axes, i * 3 % 180, 0, 360, 1, -1)
        cv2.circle(out[i], (cx + int(side / 10 * np.cos(3 * a)), cy - side // 10), side // 20, 1, -1)
    return out


def recluster(expressive: np.ndarray, tau: float, masks: np.ndarray) -> int:
    """The reference: the keyframes at ``tau`` by clustering again (embed, merge until the closest pair is less
    similar than ``tau``, two kept when the shape changes through the clip), as the panel counted before."""
    cfg = KeyframeConfig(tau=tau)
    e = embed(expressive, cfg, masks)
    k = len(merge_clusters(e, tau))
    return 2 if k == 1 and len(e) > 1 and most_different_iou(expressive, cfg, masks) < cfg.one_iou else k


def measure(masks: np.ndarray, taus: np.ndarray) -> dict:
    """Both ways of counting keyframes at every τ of ``taus`` on the expressive masks of ``masks (N, S, S)``."""
    expressive = expressive_masks(masks)
    start = time.perf_counter()
    reference = [recluster(expressive, float(t), masks) for t in taus]
    reference_s = time.perf_counter() - start
    start = time.perf_counter()
    order = merge_order(expressive, KeyframeConfig(), masks)
    order_s = time.perf_counter() - start
    fast = [order.count(float(t)) for t in taus]
    fast_s = time.perf_counter() - start
    one = time.perf_counter()
    order.count(0.5)
    count_us = (time.perf_counter() - one) * 1e6
    return {"frames": len(masks), "reference_s": round(reference_s, 3), "fast_s": round(fast_s, 3),
            "order_s": round(order_s, 3), "count_us": round(count_us, 1),
            "speedup": round(reference_s / max(fast_s, 1e-9), 1), "same": fast == reference}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--davis", default=str(DAVIS), help="folder of DAVIS mask sequences (one folder each)")
    parser.add_argument("--taus", type=int, default=50, help="values of τ counted, evenly over [0, 1]")
    parser.add_argument("--frames", type=int, default=240, help="frames of the synthetic clip (0: none)")
    args = parser.parse_args()
    taus = np.linspace(0.0, 1.0, args.taus)
    rows: dict[str, dict] = {}
    root = Path(args.davis)
    for folder in sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []:
        rows[folder.name] = measure(load_video(folder, VideoConfig(hz=24.0)).masks, taus)
    if args.frames:
        rows[f"synthetic {args.frames}"] = measure(synthetic(args.frames), taus)
    if not rows:
        raise SystemExit(f"nothing to measure: no DAVIS folders under {root} and --frames 0")
    print(f"| sequence | frames | {args.taus} τ, reference s | merge order s | then a count µs | fast s | speedup "
          "| same |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['frames']} | {r['reference_s']} | {r['order_s']} | {r['count_us']} | {r['fast_s']} | "
              f"{r['speedup']}× | {r['same']} |")  # fmt: skip
    speedups = [r["speedup"] for r in rows.values()]
    print(json.dumps({"sequences": rows, "speedup_min": min(speedups), "same": all(r["same"] for r in rows.values())}))


if __name__ == "__main__":
    main()
