"""How the hand's light-blocking shell moves what the studio can cast: the held-out targets imitated as the studio
does by default, with the foam shell as the URDF draws it and thickened (or thinned) by each ``--foam-mm``.

The shell (the soft TPU skin of DESIGN §1, the visual geometry that casts the shadow) is the hand's, not the studio's:
a calibrated rig measures it (``Rig.foam``, :mod:`studio.learn.rig_fit`), and the renderer, the collision-free
retrieval index and the refinement draw with it. This asks what a hand with another skin would reach, on the same
targets and budgets: each query is imitated as the studio does by default (roll auto chosen for that shell, the
shipped 128² self-model, which learnt the URDF's shell, no CLIP), scored by the same image loss as Table 1 (its IoU
loss column), and named by the independent observer of ``bench_observer.py`` (HOG, a gallery of other images).

* ``--set mpeg7``: the second image of each MPEG-7 class (the issue's animals are 8 of the 12: ``animals`` in JSON);
* ``--set asl``: signer 2's ``bot`` image of each letter;
* ``--set davis``: Table 2's studio row on the six shared DAVIS mask sequences (sequential +Exp+Temp, roll auto, the
  video's clock): Total, IoU loss, transitions on the studio's and on the paper's literal reading, late ones.

Every shell's figures are printed beside the URDF's shell (``--foam-mm 0``, measured first in the same run, always):
``iou_loss`` (``total`` for davis) and its ratio, how many shadows the observer names right, seconds a target. JSON
last.

    python benchmarks/bench_shell.py --set mpeg7 --foam-mm 5 10 20
    python benchmarks/bench_shell.py --set asl --foam-mm 10
    python benchmarks/bench_shell.py --set davis --foam-mm 5 10
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from bench_observer import ANIMALS, SHARED, held_out_sets


def _shell(model, foam_mm: float):
    """``model`` drawing with its shell ``foam_mm`` thicker than the URDF's (a checkpoint's rig records it so)."""
    model.trained_rig = {**(getattr(model, "trained_rig", None) or {}), "foam": foam_mm / 1000.0}
    return model


def _still_rows(name: str, shells: list[float], limit: int) -> dict:
    """Per shell (mm): the held-out stills of ``name`` imitated by default, scored, named; each query printed."""
    import numpy as np

    from studio.evaluate.observer import Observer, ObserverConfig
    from studio.evaluate.table1 import score
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.learn.selfmodel import load_selfmodel
    from studio.sim.roll import file_deg
    from studio.targets.expressive import still_expressive
    from studio.targets.images import load_target

    gallery, queries = held_out_sets(name)
    queries = queries[:limit] if limit else queries
    observer = Observer([c for c, _ in gallery], [load_target(p, size=128) for _, p in gallery], ObserverConfig("hog"))
    rows = {}
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
        row = {"iou_loss": round(float(np.mean([r["iou_loss"] for r in per_query])), 4),
               "named_right": f"{sum(r['named'] == r['class'] for r in per_query)}/{len(per_query)}",
               "seconds": round(float(np.mean([r["seconds"] for r in per_query])), 2), "index_s": round(index_s, 1),
               "collision_free": all(r["collision_free"] for r in per_query), "per_query": per_query}  # fmt: skip
        if any(r["class"] in ANIMALS for r in per_query):
            row["animals_iou_loss"] = round(
                float(np.mean([r["iou_loss"] for r in per_query if r["class"] in ANIMALS])), 4
            )
        rows[f"{foam:g}"] = row
    return rows


def _video_rows(shells: list[float]) -> dict:
    """Per shell (mm): Table 2's studio row on the six shared DAVIS mask sequences."""
    from studio.evaluate.sequences import gather_sequences, prepare_sequence
    from studio.evaluate.table2 import STUDIO_ROW, VideoEvaluator
    from studio.imitate.config import PRESETS, STUDIO, LossConfig
    from studio.imitate.sequence import SequenceImitator
    from studio.imitate.still import DEFAULT_MODEL
    from studio.imitate.transitions import TransitionConfig
    from studio.learn.selfmodel import load_selfmodel
    from studio.targets.video import VideoConfig

    cfg, rows = PRESETS[STUDIO], {}
    side = load_selfmodel(Path(DEFAULT_MODEL))[0].cfg.resolution
    seqs = [prepare_sequence(p, VideoConfig(size=side), None, p.name) for p in gather_sequences([SHARED / "davis"])]
    loss_cfg = LossConfig(use_clip=False, crop_size=side)  # the sequences and the loss are the same for every shell
    for foam in shells:
        model, _ = load_selfmodel(Path(DEFAULT_MODEL))
        with SequenceImitator(_shell(model, foam), cfg, loss_cfg=loss_cfg) as seq:
            (r,) = VideoEvaluator(seq, cfg, TransitionConfig(), rows=[STUDIO_ROW]).run(seqs).rows
        rows[f"{foam:g}"] = {"total": round(r["total"], 4), "iou_loss": round(r["iou_loss"], 4),
                             "exp_iou": round(r["exp_iou"], 4), "success": f"{r['success']}/{r['transitions']}",
                             "success_literal": f"{r['success_image']}/{r['transitions']}", "late": r["late"],
                             "in_collision": r["in_collision"], "seconds": round(r["seconds"], 2)}  # fmt: skip
        print(json.dumps({"foam_mm": foam, **rows[f"{foam:g}"]}), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("mpeg7", "asl", "davis"), default="mpeg7", help="which targets")
    ap.add_argument(
        "--foam-mm",
        type=float,
        nargs="+",
        default=[5.0, 10.0],
        help="shells to try, mm thicker than the URDF's (the rig allows -5 to 50); 0 always runs first",
    )
    ap.add_argument("--limit", type=int, default=0, help="only the first N held-out stills (0: all)")
    args = ap.parse_args(argv)
    if not SHARED.is_dir():
        print(f"needs the shared targets at {SHARED}", file=sys.stderr)
        return 2
    if any(not -5.0 <= f <= 50.0 for f in args.foam_mm):
        print("--foam-mm: each shell within -5 and 50 mm of the URDF's (what a rig may record)", file=sys.stderr)
        return 2

    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.threads import DEFAULT_THREADS, set_torch_threads

    set_torch_threads(DEFAULT_THREADS)  # the studio's own thread count (studio.learn.threads)
    shells = [0.0] + [f for f in dict.fromkeys(args.foam_mm) if f != 0.0]
    video = args.set == "davis"
    rows = _video_rows(shells) if video else _still_rows(args.set, shells, args.limit)
    key = "total" if video else "iou_loss"
    cols = [key] + (["animals_iou_loss"] if "animals_iou_loss" in rows["0"] else [])
    extra = ["iou_loss", "exp_iou", "success", "success_literal", "late"] if video else ["named_right", "seconds"]
    print(f"{'shell':>10}" + "".join(f" {c:>16} {'×':>6}" for c in cols) + "".join(f" {c:>15}" for c in extra))
    for foam, row in rows.items():
        line = f"{'URDF' if foam == '0' else f'{float(foam):+g} mm':>10}"
        for c in cols:
            row[f"{c}_ratio"] = round(row[c] / rows["0"][c], 3)  # against the URDF's shell, measured in this run
            line += f" {row[c]:16.4f} {row[f'{c}_ratio']:6.3f}"
        print(line + "".join(f" {row[c]!s:>15}" for c in extra))
    print(json.dumps({"set": args.set, "model": Path(DEFAULT_MODEL).name, "shells": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
