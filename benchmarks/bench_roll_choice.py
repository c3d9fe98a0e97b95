"""Is roll auto's choice what holds the stills back? Each target imitated in full at every one of the roll search's
best candidate rolls, and three ways of choosing among them compared.

For each target (``--set mpeg7``, the default: the ``--images`` of camel, cattle, deer, dog, elephant, horse, rat
and turtle; ``--set asl``: signer 1's ``dif`` image of each letter, which neither Table 1 nor the held-out rows
use), the roll search's refined candidates (:func:`studio.imitate.roll_search.choose_roll`: the chosen roll
first, then the other refined angles by their exact first-answer loss) are each imitated in full (as that
rolled mount casts it; shipped model, no CLIP, the studio's torch threads) and the rolled mount's shadow scored
against the target as it is. Printed last, as JSON, the mean IoU loss when the roll is:

* ``chosen``: roll auto's choice (what the studio does: the best candidates ranked again by a quick sweep,
  ``RollSearchConfig.swept``; ``roll_seconds``: the whole roll search, a target);
* ``first_answer``: the candidate whose exact first-answer loss is lowest (the choice before the sweep pass);
* ``after_sweep``: the candidate whose best loss after the imitation's full block sweep is lowest (a later
  choice, at the cost of a full sweep per candidate);
* ``oracle``: the candidate whose full imitation scored best (hindsight: the most any choice among them can give).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from bench_observer import ANIMALS, SHARED


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, nargs="+", default=[3, 4], help="which image of each animal (1–20)")
    ap.add_argument("--top", type=int, default=3, help="candidate rolls imitated in full per target")
    ap.add_argument("--set", choices=("mpeg7", "asl"), default="mpeg7", help="which targets (module doc)")
    ap.add_argument("--limit", type=int, default=0, help="only the first N targets (0: all)")
    args = ap.parse_args(argv)
    if not (SHARED / args.set).is_dir():
        print(f"needs the shared targets at {SHARED / args.set}", file=sys.stderr)
        return 2

    import numpy as np

    from studio.evaluate.table1 import score
    from studio.imitate.roll_search import RollSearchConfig
    from studio.imitate.still import Imitator
    from studio.learn.threads import DEFAULT_THREADS, set_torch_threads
    from studio.targets.expressive import still_expressive
    from studio.targets.image_sets import image_class, image_number

    set_torch_threads(DEFAULT_THREADS)  # the studio's own thread count (studio.learn.threads)
    if args.set == "asl":
        paths = sorted((SHARED / "asl").glob("*/hand1_*_dif_*"))
    else:
        numbered = {(image_class(p), image_number(p)): p for p in (SHARED / "mpeg7").glob("*.gif")}  # "camel-3"
        paths = [numbered[a, i] for i in args.images for a in ANIMALS if (a, i) in numbered]
    paths = paths[: args.limit] if args.limit > 0 else paths
    if not paths:
        print(f"no {args.set} target matches (MPEG-7 images run 1–20): {SHARED / args.set}", file=sys.stderr)
        return 2
    per_target = []
    with Imitator() as im:
        for path in paths:
            target = im.load(path)
            exp = still_expressive(target)
            loss_fn = im.loss_fn(target, exp)
            t0 = time.perf_counter()
            choice = im.choose_roll(target[None], RollSearchConfig(top=max(3, args.top)))
            roll_s = time.perf_counter() - t0
            rows = []
            first_answer = min(range(len(choice.candidates[: args.top])), key=lambda i: choice.candidates[i][1])
            for i, (deg, exact) in enumerate(choice.candidates[: args.top]):
                got = im.imitate(target, exp, refine=True, roll=math.radians(deg))
                shadow = got.shadow  # as the rolled mount casts it
                rows.append({"deg": round(deg, 2), "exact_first_answer": round(exact, 4),
                             "quick_sweep": round(choice.swept[i], 4) if i < len(choice.swept) else None,
                             "after_sweep": round(float(got.swept.loss[0]), 4) if got.swept is not None else None,
                             "iou_loss": round(score(loss_fn, shadow)["iou_loss"], 4)})  # fmt: skip
            rec = {"target": path.name, "candidates": rows, "first_answer": first_answer,
                   "roll_seconds": round(roll_s, 2)}  # fmt: skip
            per_target.append(rec)
            print(json.dumps(rec), flush=True)
    chosen = [r["candidates"][0]["iou_loss"] for r in per_target]
    first = [r["candidates"][r["first_answer"]]["iou_loss"] for r in per_target]
    oracle = [min(c["iou_loss"] for c in r["candidates"]) for r in per_target]
    swept = [min((c for c in r["candidates"] if c["after_sweep"] is not None), key=lambda c: c["after_sweep"],
                 default=r["candidates"][0])["iou_loss"] for r in per_target]  # fmt: skip
    out = {"set": args.set, "targets": len(per_target), "top": args.top, "iou_loss": {
        "chosen": round(float(np.mean(chosen)), 4), "first_answer": round(float(np.mean(first)), 4),
        "after_sweep": round(float(np.mean(swept)), 4), "oracle": round(float(np.mean(oracle)), 4)},
        "roll_seconds": round(float(np.mean([r["roll_seconds"] for r in per_target])), 2)}  # fmt: skip
    out["oracle_gain"] = round(out["iou_loss"]["chosen"] - out["iou_loss"]["oracle"], 4)
    out["per_target"] = per_target
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
