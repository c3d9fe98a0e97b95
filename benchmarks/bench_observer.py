"""Does a shadow read as its target? An independent observer names the class of held-out targets and of the
studio's shadows of them (issue 22's observer test).

The observer (:mod:`studio.evaluate.observer`) names a silhouette's class by its nearest neighbour in a gallery of
other images of the same classes, on descriptors the studio's losses never use (gradient-orientation histograms,
and the outline's Fourier magnitudes). Per set:

* ``mpeg7``: the queries are the second image of each MPEG-7 class (``*-2.gif``), the gallery images 3–20;
* ``asl``: the queries are signer 2's ``bot`` image of each letter, the gallery signer 1's five images a letter.

Each query is imitated as the studio does by default (roll auto: the roll chosen, the target imitated as the
rolled mount casts it, :class:`studio.imitate.framing.Framed`; shipped 128² model, no CLIP, one torch thread);
``--upright`` adds the paper's rig (roll 0). The JSON (last line) has, per set and descriptor, how often
the observer names the class of the targets and of the shadows, and ``shadow_over_target`` (the goal: 1.0), plus
each query's names and IoU loss.

    python benchmarks/bench_observer.py --set mpeg7 [--upright] [--limit N]
    python benchmarks/bench_observer.py --set asl
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "targets"


def held_out_sets(name: str) -> tuple[list[tuple[str, Path]], list[tuple[str, Path]]]:
    """``(gallery, queries)`` as ``(class, path)`` lists."""
    if name == "mpeg7":
        from studio.targets.images import image_class, image_number

        files = sorted((SHARED / "mpeg7").glob("*.gif"))
        gallery = [(image_class(p), p) for p in files if (image_number(p) or 0) >= 3]
        return gallery, [(image_class(p), p) for p in files if image_number(p) == 2]
    folder = SHARED / "asl"
    gallery = [(p.parent.name, p) for p in sorted(folder.glob("*/hand1_*"))]
    return gallery, [(p.parent.name, p) for p in sorted(folder.glob("*/hand2_*_bot_*"))]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("mpeg7", "asl"), default="mpeg7", help="which held-out set")
    ap.add_argument("--upright", action="store_true", help="also imitate on the paper's upright rig")
    ap.add_argument("--limit", type=int, default=0, help="only the first N queries (0: all)")
    args = ap.parse_args(argv)
    if not SHARED.is_dir():
        print(f"needs the shared targets at {SHARED}", file=sys.stderr)
        return 2

    import numpy as np

    from studio.evaluate.observer import DESCRIPTORS, Observer, ObserverConfig
    from studio.evaluate.table1 import score
    from studio.imitate.still import Imitator
    from studio.learn.threads import DEFAULT_THREADS, set_torch_threads
    from studio.sim.roll import file_deg
    from studio.targets.expressive import still_expressive
    from studio.targets.images import load_target

    set_torch_threads(DEFAULT_THREADS)  # the studio's own thread count (studio.learn.threads)
    gallery, queries = held_out_sets(args.set)
    queries = queries[: args.limit] if args.limit else queries
    side = 128
    g_masks = [load_target(p, size=side) for _, p in gallery]
    observers = {d: Observer([c for c, _ in gallery], g_masks, ObserverConfig(descriptor=d)) for d in DESCRIPTORS}
    rows = ["roll auto"] + (["upright"] if args.upright else [])
    per_query = []
    with Imitator() as im:
        for label, path in queries:
            target = im.load(path)
            exp = still_expressive(target)
            loss_fn = im.loss_fn(target, exp)
            rec = {"target": path.name, "class": label,
                   "target_named": {d: o.name(target) for d, o in observers.items()}}  # fmt: skip
            for row in rows:
                t0 = time.perf_counter()
                roll = 0.0
                if row == "roll auto":
                    choice = im.choose_roll(target[None])
                    roll = choice.roll
                got = im.imitate(target, exp, refine=True, roll=roll)
                shadow = got.shadow  # as the (rolled) mount casts it
                rec[row] = {"named": {d: o.name(shadow) for d, o in observers.items()},
                            "iou_loss": round(score(loss_fn, shadow)["iou_loss"], 4), "roll_deg": file_deg(roll),
                            "collision_free": bool(got.collision_free),
                            "seconds": round(time.perf_counter() - t0, 2)}  # fmt: skip
            per_query.append(rec)
            print(json.dumps(rec), flush=True)
    out: dict = {"set": args.set, "queries": len(per_query), "gallery": len(gallery),
                 "classes": len(observers["hog"].classes)}  # fmt: skip
    for d in DESCRIPTORS:
        target_acc = float(np.mean([r["target_named"][d] == r["class"] for r in per_query]))
        out[d] = {"target_named_right": round(target_acc, 3)}
        for row in rows:
            acc = float(np.mean([r[row]["named"][d] == r["class"] for r in per_query]))
            out[d][row] = {"shadow_named_right": round(acc, 3),
                           "shadow_over_target": round(acc / target_acc, 3) if target_acc else math.nan}  # fmt: skip
    for row in rows:
        out[row] = {"iou_loss": round(float(np.mean([r[row]["iou_loss"] for r in per_query])), 4),
                    "seconds": round(float(np.mean([r[row]["seconds"] for r in per_query])), 2),
                    "collision_free": all(r[row]["collision_free"] for r in per_query)}  # fmt: skip
    out["per_query"] = per_query
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
