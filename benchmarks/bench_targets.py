"""Loading still targets: the crease-pocket step (``studio.targets.pockets``) against its slow reference, measured in
the same run, on phone-sized photos and on the shared ASL letters.

    python benchmarks/bench_targets.py [--megapixels 12] [--noise 6] [--asl ../shared/targets/asl]

The photos are the bundled ASL stills (``assets/targets/asl_*.jpeg``) enlarged to ``--megapixels`` with ±``--noise``
grey levels of sensor noise, so that their outlines carry dozens of pockets; the shared letters (skipped when the
folder is absent) are loaded at their own size. For each set: seconds to fill the pockets (fast, reference: the
same masks, checked), and to load the whole still with the step and without it. Last line JSON: {"photos":
{"fast_s", "reference_s", "speedup", "load_s", "load_without_pockets_s", "same"}, "asl": {...}}.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np
from studio.assets import asset

from studio.targets.image_sets import find_target_files
from studio.targets.images import (
    TargetConfig,
    keep_largest_components,
    mask_from_grey,
    read_grey,
    shadowness,
    threshold_level,
)
from studio.targets.pockets import fill_pockets
from studio.targets.pockets_reference import fill_pockets_slowly


def photo(path: Path, megapixels: float, noise: int, rng: np.random.Generator) -> np.ndarray:
    """The still at ``path`` enlarged to ``megapixels`` (its aspect kept) with uniform grey noise, ``(H, W)`` uint8."""
    grey = read_grey(path)
    scale = (megapixels * 1e6 / grey.size) ** 0.5
    big = cv2.resize(grey, (round(grey.shape[1] * scale), round(grey.shape[0] * scale)), interpolation=cv2.INTER_CUBIC)
    return np.clip(big.astype(int) + rng.integers(-noise, noise + 1, big.shape), 0, 255).astype(np.uint8)


def pocket_inputs(grey: np.ndarray, cfg: TargetConfig) -> tuple:
    """What the loader hands the pocket step: (mask, shade, core level, its settings)."""
    shade = shadowness(grey, cfg.polarity)
    level = threshold_level(shade, cfg)
    mask = keep_largest_components((shade > level).astype(np.uint8), cfg.max_components, cfg.min_component_share)
    return (mask, shade, cfg.backdrop_level * level, cfg.pocket_reach, cfg.pocket_neck, cfg.min_hole_area,
            cfg.min_core_share)  # fmt: skip


def measure(greys: list[np.ndarray]) -> dict:
    cfg, off = TargetConfig(), TargetConfig(pocket_reach=0.0)
    fast = reference = load = plain = 0.0
    same = True
    for grey in greys:
        args = pocket_inputs(grey, cfg)
        t = time.perf_counter()
        got = fill_pockets(*args)
        fast += time.perf_counter() - t
        t = time.perf_counter()
        want, _ = fill_pockets_slowly(*args)
        reference += time.perf_counter() - t
        same &= bool(np.array_equal(got, want))
        t = time.perf_counter()
        mask_from_grey(grey, cfg)
        load += time.perf_counter() - t
        t = time.perf_counter()
        mask_from_grey(grey, off)
        plain += time.perf_counter() - t
    n = len(greys)
    return {"images": n, "fast_s": round(fast / n, 3), "reference_s": round(reference / n, 3),
            "speedup": round(reference / max(fast, 1e-9), 1), "load_s": round(load / n, 3),
            "load_without_pockets_s": round(plain / n, 3), "same": same}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--megapixels", type=float, default=12.0, help="size of the enlarged photos")
    ap.add_argument("--noise", type=int, default=6, help="± grey levels of sensor noise on the photos")
    ap.add_argument("--asl", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "targets" / "asl")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    stills = sorted(Path(asset("targets/asl_o.jpeg")).parent.glob("asl_*.jpeg"))
    out = {"photos": measure([photo(p, args.megapixels, args.noise, rng) for p in stills])}
    print(f"{len(stills)} photos at {args.megapixels:g} MP: {out['photos']}", flush=True)
    if args.asl.is_dir():
        letters = [p for folder in sorted(args.asl.iterdir()) if folder.is_dir() for p in find_target_files(folder)]
        out["asl"] = measure([read_grey(p) for p in letters])
        print(f"shared ASL letters: {out['asl']}", flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
