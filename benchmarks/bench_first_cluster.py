"""A clip's first clustering in a fresh interpreter (a project made, the Keyframes count as the studio opens, a
``video`` run): the studio's own PCA (``studio.targets.keyframes.pca``) against scikit-learn's
``PCA(svd_solver="full")``, what the clustering used before, measured in the same run; the clusters checked equal.

    python benchmarks/bench_first_cluster.py [--davis ../shared/targets/davis] [--repeats 3] [--frames 240]

Each case's expressive masks are written to a file first; each timing is one fresh ``python`` that imports the
clustering, reads the file and clusters it at the default τ (the median of ``--repeats``), so it counts the imports
the first clustering pays (scikit-learn's is about 1.2 s) and not the interpreter's start. Cases: the bundled horse
at the studio's default sampling, the shared DAVIS bear at 4 Hz (when ``--davis`` is there) and a synthetic clip of
``--frames`` frames of 256² (0: none). Last line JSON: {"cases": {name: {"frames", "reference_s", "studio_s",
"speedup", "same"}}, "speedup_min"}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from studio.targets.expressive import expressive_masks
from studio.targets.video import DEFAULT_VIDEO, VideoConfig, load_video

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_keyframe_count import DAVIS, synthetic  # noqa: E402 - this folder's helpers

RUN = """
import json, sys, time
start = time.perf_counter()
import numpy as np
import studio.targets.keyframes as keyframes
if sys.argv[2] == "reference":  # what embed used before: scikit-learn's PCA
    def pca(x, y, n):
        from sklearn.decomposition import PCA
        return PCA(n_components=n, svd_solver="full").fit(x).transform(y)
    keyframes.pca = pca
data = np.load(sys.argv[1])
c = keyframes.cluster_keyframes(data["expressive"], keyframes.KeyframeConfig(), data["masks"])
print(json.dumps({"s": time.perf_counter() - start, "members": c.members, "reps": c.representatives.tolist()}))
"""


def first_cluster(file: Path, way: str) -> dict:
    """One fresh interpreter's first clustering of the masks in ``file``, ``way`` "studio" or "reference"."""
    done = subprocess.run([sys.executable, "-c", RUN, str(file), way], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure(masks: np.ndarray, folder: Path, name: str, repeats: int) -> dict:
    """Both ways, ``repeats`` times each, alternating, on ``masks (N, S, S)``."""
    file = folder / f"{name}.npz"
    np.savez(file, masks=masks, expressive=expressive_masks(masks))
    runs: dict[str, list[dict]] = {"reference": [], "studio": []}
    for _ in range(repeats):
        for way in runs:
            runs[way].append(first_cluster(file, way))
    ref_s = statistics.median(r["s"] for r in runs["reference"])
    ours_s = statistics.median(r["s"] for r in runs["studio"])
    same = all((r["members"], r["reps"]) == (runs["reference"][0]["members"], runs["reference"][0]["reps"])
               for r in runs["reference"] + runs["studio"])  # fmt: skip
    return {"frames": len(masks), "reference_s": round(ref_s, 3), "studio_s": round(ours_s, 3),
            "speedup": round(ref_s / max(ours_s, 1e-9), 2), "same": same}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--davis", type=Path, default=DAVIS, help="the shared DAVIS mask sequences (bear is used)")
    parser.add_argument("--repeats", type=int, default=3, help="fresh interpreters per way and case (the median)")
    parser.add_argument("--frames", type=int, default=240, help="frames of the synthetic clip (0: none)")
    args = parser.parse_args()
    cases = {"horse (bundled, default sampling)": load_video(DEFAULT_VIDEO, VideoConfig()).masks}
    if (args.davis / "bear").is_dir():
        cases["bear (DAVIS, 4 Hz)"] = load_video(args.davis / "bear", VideoConfig(hz=4.0)).masks
    if args.frames > 0:
        cases[f"synthetic {args.frames}"] = synthetic(args.frames)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, masks) in enumerate(cases.items()):
            rows[name] = measure(masks, Path(tmp), f"case{i}", args.repeats)
    print("| case | frames | scikit-learn's PCA (s) | the studio's (s) | × | same clusters |")
    print("|---|---:|---:|---:|---:|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['frames']} | {r['reference_s']:.2f} | {r['studio_s']:.2f} | {r['speedup']:.2f} | "
              f"{r['same']} |")  # fmt: skip
    print(json.dumps({"cases": rows, "speedup_min": min(r["speedup"] for r in rows.values())}))


if __name__ == "__main__":
    main()
