"""Segmentation of raw footage without downloaded weights, scored against the DAVIS 2016 ground truth, on the clips
it was tuned on and under conditions it was not (a held-out view).

Clips: the four DAVIS RGB sequences in ../shared/targets/davis-rgb (blackswan, camel, cows, dog: 854×480 JPEG
frames, ground truth in ../shared/targets/davis/<seq>, same frame names) and DAVIS bear as an H.264 MP4
(../shared/targets/video/bear-mp4/bear.mp4, decoded by OpenCV, against davis/bear), which no setting was ever tuned
on. Every clip runs ``segment_video`` (classical method, default ``SegmentConfig``, the same settings everywhere)
under each condition:

* ``box``: the first ground-truth mask's box, every frame (what the defaults were chosen on);
* ``mask``: the first ground-truth mask itself;
* ``loose``: the box grown by ``LOOSE`` of its width and height on each side (an artist's quick box);
* ``stride2``, ``stride4``: every 2nd / 4th frame only, from the box — large displacement between frames, as in
  fast motion (a running dog, a jumping horse);
* ``occlude``: a vertical band of background texture (``OCCLUDER`` × the object's width) sweeps across the frame in
  front of the object (in at the left edge at 15 % of the clip, over the object's centre at 50 %, out at the right
  edge at 85 %), hiding part of it; truth = the object's visible part;
* ``exit``: a window ``WINDOW`` of the frame wide pans so that the object leaves it halfway (its centre reaches the
  window's edge) and comes back; frames and truth are cropped to the window.

Score: region similarity J = IoU per frame with a ground-truth mask (frame 0 included; a frame whose truth is empty
scores 1 for an empty answer, else 0), mean per clip. The reference measured in the same run is the first box held
still (per condition: its box on the condition's frames) and ``ratio`` = mean J / its mean J. Printed: one line
per clip and condition, a summary per condition (mean over the four tuned clips, the worst clip, the mean over the
held-out clips: bear and any clip named that is not one of the four), then a JSON object last:
``{"conditions": {cond: {"sequences": {clip: J}, "mean_J", "min_J", "bear_J", "held_out_mean_J",
"reference": {clip: J}, "reference_mean_J", "ratio"}}, "sequences", "mean_J", "first_frame_J", "reference", "ratio"
(the box condition on the four, as before), "seconds_per_frame", "frames", "work_size"}``. ``--against OLD.json``
(a previous run's JSON line) adds per-clip changes and lists every clip and condition that lost more than 0.01 J.

    python benchmarks/bench_segment.py [--conditions box,stride4] [--sequences blackswan,dog,bear] [--work-size 400]
    python benchmarks/bench_segment.py --sequences goat,horsejump-high --rgb DAVIS/JPEGImages/480p \
        --masks DAVIS/Annotations/480p   # held-out clips in the DAVIS layout (RGB and masks by the same stems)

Measured here (2 shared CPU cores, work size 400), before → after this method's robustness work: see
``studio/targets/segment.py``'s docstring.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from studio.targets.images import crop_square
from studio.targets.segment import segment_video
from studio.targets.segment_config import SegmentConfig
from studio.targets.source import open_source
from studio.targets.video import VideoConfig

SHARED = Path(__file__).resolve().parents[2] / "shared" / "targets"
TUNED = ("blackswan", "camel", "cows", "dog")  # clips the defaults were chosen on
HELD_OUT = ("bear",)  # never tuned on (an MP4); every clip not in TUNED counts as held out
CONDITIONS = ("box", "mask", "loose", "stride2", "stride4", "occlude", "exit")
LOOSE = 0.2  # the loose box: grown by this share of its width and height on each side
OCCLUDER = 0.4  # the occluding band's width, × the object's width in frame 0
WINDOW = 0.6  # the exit condition's window width, × the frame width (at least 1.2 × the object's width)

Clip = tuple[np.ndarray, dict[int, np.ndarray]]  # frames (N, H, W, 3) uint8, truth {frame index: (H, W) bool}


def load_sequence(rgb_dir: Path, mask_dir: Path) -> Clip:
    """RGB frames (N, H, W, 3) uint8 and the ground truth {frame index: (H, W) bool} matched by file stem."""
    paths = sorted(p for p in rgb_dir.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    frames = np.stack([np.asarray(Image.open(p).convert("RGB")) for p in paths])
    index = {p.stem: i for i, p in enumerate(paths)}
    return frames, {index[m.stem]: _truth(m) for m in sorted(mask_dir.glob("*.png")) if m.stem in index}


def load_mp4(path: Path, mask_dir: Path) -> Clip:
    """Every frame of a video file (OpenCV) and the ground truth matched by frame number (00000.png = frame 0)."""
    cap, frames = cv2.VideoCapture(str(path)), []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    cap.release()
    truth = {int(m.stem): _truth(m) for m in sorted(mask_dir.glob("*.png")) if m.stem.isdigit()}
    return np.stack(frames), {i: g for i, g in truth.items() if i < len(frames) and g.shape == frames[0].shape[:2]}


def _truth(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("L")) > 127


def box_of(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


def jaccard(pred: np.ndarray, truth: np.ndarray) -> float:
    union = np.logical_or(pred, truth).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred, truth).sum() / union)


def strided(clip: Clip, step: int) -> Clip:
    """Every ``step``-th frame (the truth re-indexed)."""
    frames, truth = clip
    return frames[::step], {i // step: g for i, g in truth.items() if i % step == 0}


def _centres(truth: dict[int, np.ndarray], n: int) -> np.ndarray:
    """The object's centroid x (px) in each of n frames, interpolated where the truth is missing or empty."""
    known = {i: float(np.nonzero(g)[1].mean()) for i, g in truth.items() if g.any()}
    ks = sorted(known)
    return np.interp(np.arange(n), ks, [known[k] for k in ks])


def occluded(clip: Clip) -> Clip:
    """A band of background texture passing in front of the object (module doc); truth = what stays visible."""
    frames, truth = clip
    n, h, w = frames.shape[:3]
    x, _, bw, _ = box_of(truth[min(truth)])
    band = max(8, int(OCCLUDER * bw))
    far = 0 if x + bw / 2 > w / 2 else w - band  # the texture: the frame-0 strip on the side away from the object
    texture = frames[0][:, far : far + band].copy()
    centres, out, seen = _centres(truth, n), frames.copy(), {}
    for t in range(n):
        # in from the left edge at 15 % of the clip, over the object's centre at 50 %, out at the right edge at 85 %
        c = np.interp(t / max(n - 1, 1), (0.15, 0.5, 0.85), (-band, centres[t], w + band), left=-w, right=2 * w)
        x0 = int(round(c - band / 2))
        a, b = max(0, x0), min(w, x0 + band)
        if b > a:
            out[t][:, a:b] = texture[:, a - x0 : b - x0]
        if t in truth:
            g = truth[t].copy()
            g[:, a:b] = False
            seen[t] = g
    return out, seen


def exiting(clip: Clip) -> Clip:
    """A panning window the object leaves halfway and comes back into (module doc); frames and truth cropped."""
    frames, truth = clip
    n, h, w = frames.shape[:3]
    bw = box_of(truth[min(truth)])[2]
    win = min(w, max(int(WINDOW * w), int(1.2 * bw)))
    centres = _centres(truth, n)
    push = np.sin(np.pi * np.arange(n) / max(n - 1, 1)) * win / 2
    wanted = [centres - win / 2 + d * push for d in (1, -1)]  # the object pushed out of the left or right edge
    # the direction the frame's own edges clip least (so that the object really leaves the window)
    best = min(wanted, key=lambda o: float(np.abs(np.clip(o, 0, w - win) - o).sum()))
    offset = np.clip(np.round(best), 0, w - win).astype(int)
    crop = np.stack([frames[t][:, offset[t] : offset[t] + win] for t in range(n)])
    return crop, {t: g[:, offset[t] : offset[t] + win] for t, g in truth.items()}


def loosened(box: tuple[int, int, int, int], shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """``box`` grown by ``LOOSE`` × its size on each side, clipped to the frame ``shape`` (H, W)."""
    x, y, bw, bh = box
    gx, gy = int(LOOSE * bw), int(LOOSE * bh)
    x0, y0, x1, y1 = max(0, x - gx), max(0, y - gy), min(shape[1], x + bw + gx), min(shape[0], y + bh + gy)
    return x0, y0, x1 - x0, y1 - y0


def condition(clip: Clip, name: str) -> tuple[Clip, dict]:
    """The clip under condition ``name`` and the keyword arguments that give ``segment_video`` its first frame."""
    if name.startswith("stride"):
        clip = strided(clip, int(name[6:]))
    elif name == "occlude":
        clip = occluded(clip)
    elif name == "exit":
        clip = exiting(clip)
    frames, truth = clip
    first = truth[min(truth)]
    if name == "mask":
        return clip, {"first_mask": first.astype(np.uint8)}
    box = box_of(first)
    return clip, {"box": loosened(box, first.shape) if name == "loose" else box}


def held_box(clip: Clip, kwargs: dict) -> float:
    """J of the reference: the first box (or the first mask's box) held still."""
    frames, truth = clip
    x, y, w, h = kwargs["box"] if "box" in kwargs else box_of(kwargs["first_mask"])
    still = np.zeros(frames.shape[1:3], bool)
    still[y : y + h, x : x + w] = True
    return float(np.mean([jaccard(still, g) for g in truth.values()]))


def run(clips: dict[str, Callable[[], Clip]], conditions: list[str], cfg: SegmentConfig, segment=segment_video) -> dict:
    """Score ``segment(frames, box=…|first_mask=…, cfg=cfg)`` on every clip under every condition (module doc)."""
    res = {c: {"sequences": {}, "reference": {}, "first": {}} for c in conditions}
    seconds, n_frames = 0.0, 0
    for name, load in clips.items():
        base = load()
        for cond in conditions:
            (frames, truth), kwargs = condition(base, cond)
            t0 = time.perf_counter()
            masks = segment(frames, cfg=cfg, **kwargs)
            seconds += time.perf_counter() - t0
            n_frames += len(frames)
            j = float(np.mean([jaccard(masks[i] > 0, g) for i, g in truth.items()]))
            ref = held_box((frames, truth), kwargs)
            first = jaccard(masks[min(truth)] > 0, truth[min(truth)])
            r = res[cond]
            r["sequences"][name], r["reference"][name], r["first"][name] = j, ref, first
            print(
                f"{name:10s} {cond:8s} {len(truth):3d} frames scored  J {j:.3f}  (first frame {first:.3f}; "
                f"held box {ref:.3f})",
                flush=True,
            )
    return {"results": res, "seconds": seconds, "frames": n_frames}


def summary(results: dict) -> dict:
    """The JSON object of the module doc from :func:`run`'s results."""
    rounded = lambda d: {k: round(v, 4) for k, v in d.items()}  # noqa: E731
    out = {}
    for cond, r in results.items():
        tuned = [r["sequences"][k] for k in r["sequences"] if k in TUNED]
        ref = [r["reference"][k] for k in r["reference"] if k in TUNED]
        held = [r["sequences"][k] for k in r["sequences"] if k not in TUNED]
        mean, mean_ref = (round(float(np.mean(v)), 4) if v else None for v in (tuned, ref))  # None: no tuned clip
        out[cond] = {
            "sequences": rounded(r["sequences"]),
            "mean_J": mean,
            "min_J": round(min(tuned), 4) if tuned else None,
            "bear_J": round(r["sequences"]["bear"], 4) if "bear" in r["sequences"] else None,
            "held_out_mean_J": round(float(np.mean(held)), 4) if held else None,  # clips never tuned on
            "first_frame_J": rounded(r["first"]),
            "reference": rounded(r["reference"]),
            "reference_mean_J": mean_ref,
            "ratio": round(mean / mean_ref, 3) if mean is not None and mean_ref else None,
        }
    return out


def both_paths(sources: dict[str, tuple[Path, Callable[[], Clip]]]) -> dict:
    """J of the project path, the direct path and the sampled-only path per clip (module doc, "Both paths")."""
    vc = VideoConfig()
    out: dict[str, dict[str, float]] = {"project": {}, "direct": {}, "sampled_only": {}}
    for name, (path, load) in sources.items():
        frames, truth = load()
        box = box_of(truth[min(truth)])
        video = open_source(path, vc, box=box)
        dense = segment_video(frames, box=box)
        sampled = [int(i) for i in video.frame_index]
        sparse = segment_video(frames[sampled], box=box)
        framed = lambda m, b=video.box: crop_square(m.astype(np.float32), b, vc.size) >= 0.5  # noqa: E731
        scores: dict[str, list[float]] = {k: [] for k in out}
        for k, i in enumerate(sampled):
            if i not in truth:
                continue
            g = framed(truth[i])
            scores["project"].append(jaccard(video.masks[k] > 0, g))
            scores["direct"].append(jaccard(framed(dense[i]), g))
            scores["sampled_only"].append(jaccard(framed(sparse[k]), g))
        for k, v in scores.items():
            out[k][name] = round(float(np.mean(v)), 4)
        print(
            f"{name:10s} paths: project {out['project'][name]:.3f}  direct {out['direct'][name]:.3f}  "
            f"sampled only {out['sampled_only'][name]:.3f}  ({len(scores['project'])} sampled frames scored)",
            flush=True,
        )
    out["mean"] = {k: round(float(np.mean(list(v.values()))), 4) for k, v in list(out.items())}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rgb", default=str(SHARED / "davis-rgb"), help="folder of RGB sequences")
    ap.add_argument("--masks", default=str(SHARED / "davis"), help="folder of ground-truth mask sequences")
    ap.add_argument("--bear", default=str(SHARED / "video" / "bear-mp4" / "bear.mp4"), help="the held-out MP4")
    ap.add_argument("--sequences", default=",".join(TUNED + HELD_OUT), help="comma-separated names")
    ap.add_argument("--conditions", default=",".join(CONDITIONS), help=f"comma-separated, of {', '.join(CONDITIONS)}")
    ap.add_argument("--work-size", type=int, default=SegmentConfig.work_size, help="longest side segmented at (px)")
    ap.add_argument("--against", default=None, help="a previous run's JSON (file): per-clip changes and losses")
    ap.add_argument("--no-paths", action="store_true", help="leave out the project-path comparison")
    args = ap.parse_args()
    cfg = replace(SegmentConfig(method="classical"), work_size=args.work_size)
    conditions = [c for c in args.conditions.split(",") if c]
    if unknown := set(conditions) - set(CONDITIONS):
        ap.error(f"unknown conditions {sorted(unknown)}: choose from {', '.join(CONDITIONS)}")
    clips, sources = {}, {}
    for name in args.sequences.split(","):
        if name != "bear" and not ((Path(args.rgb) / name).is_dir() and (Path(args.masks) / name).is_dir()):
            ap.error(f"clip {name!r}: needs its RGB frames in {Path(args.rgb) / name} and its masks in "
                     f"{Path(args.masks) / name} (DAVIS layout: same file stems)")  # fmt: skip
        if name == "bear":
            clips[name] = lambda: load_mp4(Path(args.bear), Path(args.masks) / "bear")
            sources[name] = (Path(args.bear), clips[name])
        else:
            clips[name] = lambda name=name: load_sequence(Path(args.rgb) / name, Path(args.masks) / name)
            sources[name] = (Path(args.rgb) / name, clips[name])
    ran = run(clips, conditions, cfg)
    conds = summary(ran["results"])
    for cond, c in conds.items():
        print(
            f"{cond:8s} mean J {c['mean_J']} over the tuned clips (worst {c['min_J']}), held out "
            f"{c['held_out_mean_J']} (bear {c['bear_J']}), held box {c['reference_mean_J']} (ratio {c['ratio']})"
        )
    result = {"conditions": conds, "seconds_per_frame": round(ran["seconds"] / max(ran["frames"], 1), 4)}
    result["frames"], result["work_size"] = ran["frames"], cfg.work_size
    if "box" in conds:
        box = conds["box"]
        plain = {k: v for k, v in box["sequences"].items() if k in TUNED}
        result |= {"sequences": plain, "mean_J": box["mean_J"], "first_frame_J": box["first_frame_J"]}
        result |= {"reference": {"method": "first box held still", "mean_J": box["reference_mean_J"]}}
        result["ratio"] = box["ratio"]
    if not args.no_paths:
        result["paths"] = both_paths(sources)
    if args.against:
        result["changes"] = compare(json.loads(Path(args.against).read_text().strip().splitlines()[-1]), conds)
    print(json.dumps(result))


def compare(old: dict, new: dict) -> dict:
    """Per condition and clip, new J − old J; prints every clip and condition that lost more than 0.01."""
    changes = {}
    for cond, c in new.items():
        before = old.get("conditions", {}).get(cond, {}).get("sequences", {})
        changes[cond] = {k: round(v - before[k], 4) for k, v in c["sequences"].items() if k in before}
        for k, d in changes[cond].items():
            if d < -0.01:
                print(f"LOSS {cond:8s} {k:10s} {before[k]:.3f} → {c['sequences'][k]:.3f} ({d:+.3f})")
    return changes


if __name__ == "__main__":
    main()
