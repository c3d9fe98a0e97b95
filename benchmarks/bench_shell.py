"""How the hand's light-blocking shell moves what the studio can cast: the held-out targets imitated as the studio
does by default, with the foam shell as the URDF draws it and thickened (or thinned) by each ``--foam-mm``.

The shell (the soft TPU skin of DESIGN §1, the visual geometry that casts the shadow) is the hand's, not the studio's:
a calibrated rig measures it (``Rig.foam``, :mod:`studio.learn.rig_fit`), and the renderer, the collision-free
retrieval index and the refinement draw with it. This asks what a hand with another skin would reach, on the same
targets and budgets: each query is imitated as the studio does by default (roll auto chosen for that shell, the
shipped 128² self-model, which learnt the URDF's shell, no CLIP), scored by the same image loss as Table 1 (its IoU
loss column), and named by the independent observer of ``bench_observer.py`` (HOG, a gallery of other images).

* ``--set mpeg7``: the second image of each MPEG-7 class (the issue's animals are 8 of the 12: ``animals`` in JSON);
* ``--set asl``: signer 2's ``bot`` image of each letter.

Every shell's figures are printed beside the URDF's shell (``--foam-mm 0``, measured first in the same run, always):
``iou_loss`` and its ratio, how many shadows the observer names right, seconds a target. JSON last.

    python benchmarks/bench_shell.py --set mpeg7 --foam-mm 5 10 20
    python benchmarks/bench_shell.py --set asl --foam-mm 10
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from bench_observer import SHARED, held_out_sets

ANIMALS = ("camel", "cattle", "deer", "dog", "elephant", "horse", "rat", "turtle")  # issue 22's MPEG-7 animals


def _shell(model, foam_mm: float):
    """``model`` drawing with its shell ``foam_mm`` thicker than the URDF's (a checkpoint's rig records it so)."""
    model.trained_rig = {**(getattr(model, "trained_rig", None) or {}), "foam": foam_mm / 1000.0}
    return model


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("mpeg7", "asl"), default="mpeg7", help="which held-out set")
    ap.add_argument(
        "--foam-mm",
        type=float,
        nargs="+",
        default=[5.0, 10.0],
        help="shells to try, mm thicker than the URDF's (the rig allows -5 to 50); 0 always runs first",
    )
    ap.add_argument("--limit", type=int, default=0, help="only the first N queries (0: all)")
    args = ap.parse_args(argv)
    if not SHARED.is_dir():
        print(f"needs the shared targets at {SHARED}", file=sys.stderr)
        return 2
    if any(not -5.0 <= f <= 50.0 for f in args.foam_mm):
        print("--foam-mm: each shell within -5 and 50 mm of the URDF's (what a rig may record)", file=sys.stderr)
        return 2

    import numpy as np

    from studio.evaluate.observer import Observer, ObserverConfig
    from studio.evaluate.table1 import score
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.learn.selfmodel import load_selfmodel
    from studio.learn.threads import DEFAULT_THREADS, set_torch_threads
    from studio.sim.roll import file_deg
    from studio.targets.expressive import still_expressive
    from studio.targets.images import load_target

    set_torch_threads(DEFAULT_THREADS)  # the studio's own thread count (studio.learn.threads)
    gallery, queries = held_out_sets(args.set)
    queries = queries[: args.limit] if args.limit else queries
    observer = Observer([c for c, _ in gallery], [load_target(p, size=128) for _, p in gallery], ObserverConfig("hog"))
    shells = [0.0] + [f for f in dict.fromkeys(args.foam_mm) if f != 0.0]
    out: dict = {"set": args.set, "queries": len(queries), "model": Path(DEFAULT_MODEL).name, "shells": {}}
    for foam in shells:
        model, _ = load_selfmodel(Path(DEFAULT_MODEL))
        per_query = []
        with Imitator(_shell(model, foam)) as im:
            t0 = time.perf_counter()
            im.retrieval_index()  # built (or read from the cache) for this shell: its seconds are not a target's
            index_s = time.perf_counter() - t0
            for label, path in queries:
                t0 = time.perf_counter()
                target = im.load(path)
                exp = still_expressive(target)
                roll = im.choose_roll(target[None]).roll
                got = im.imitate(target, exp, refine=True, roll=roll)
                rec = {"target": path.name, "class": label, "named": observer.name(got.shadow),
                       "iou_loss": round(score(im.loss_fn(target, exp), got.shadow)["iou_loss"], 4),
                       "roll_deg": file_deg(roll), "collision_free": bool(got.collision_free),
                       "seconds": round(time.perf_counter() - t0, 2)}  # fmt: skip
                per_query.append(rec)
                print(json.dumps({"foam_mm": foam, **rec}), flush=True)
        iou = [r["iou_loss"] for r in per_query]
        row = {"iou_loss": round(float(np.mean(iou)), 4),
               "named_right": sum(r["named"] == r["class"] for r in per_query),
               "seconds": round(float(np.mean([r["seconds"] for r in per_query])), 2), "index_s": round(index_s, 1),
               "collision_free": all(r["collision_free"] for r in per_query), "per_query": per_query}  # fmt: skip
        if args.set == "mpeg7":
            row["animals_iou_loss"] = round(
                float(np.mean([r["iou_loss"] for r in per_query if r["class"] in ANIMALS])), 4
            )
        out["shells"][f"{foam:g}"] = row
    base = out["shells"]["0"]
    print(f"{'shell':>14} {'IoU loss':>9} {'× URDF':>7}" + (f" {'animals':>8} {'×':>6}" if args.set == "mpeg7" else "")
          + f" {'named':>6} {'s/target':>9}")  # fmt: skip
    for key, row in out["shells"].items():
        row["ratio"] = round(row["iou_loss"] / base["iou_loss"], 3)
        line = f"{'URDF' if key == '0' else f'+{key} mm' if float(key) > 0 else f'{key} mm':>14} {row['iou_loss']:9.4f}"
        line += f" {row['ratio']:7.3f}"
        if args.set == "mpeg7":
            row["animals_ratio"] = round(row["animals_iou_loss"] / base["animals_iou_loss"], 3)
            line += f" {row['animals_iou_loss']:8.4f} {row['animals_ratio']:6.3f}"
        print(line + f" {row['named_right']:3d}/{len(queries):<2d} {row['seconds']:9.2f}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
