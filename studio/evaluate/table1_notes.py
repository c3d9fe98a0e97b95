"""How Table 1 was measured, in words (the notes printed under it), from :meth:`Evaluator.settings
<studio.evaluate.table1.Evaluator.settings>`: the same text wherever the targets ran (one process or spread,
:mod:`studio.evaluate.table1_task`)."""

from __future__ import annotations

from studio.errors import count
from studio.evaluate.config import EvalConfig


def _method_note(st: dict) -> str:
    """Our method in words, from the evaluator's settings."""
    s, r, c, w = st["search"], st["refine"], st["imitate"], st["sweep"] or {"starts": 0}
    sweep = (
        f"a block sweep of its {w['starts']} best poses ({w['draws']} draws per finger, {w['wrist_draws']} for the "
        f"wrist, up to {w['passes']} passes), "
        if w["starts"]
        else ""
    )
    if r["method"] == "hill":
        refine = f"hill climbing, {r['restarts']} chains × {r['steps']} steps"
    else:
        refine = f"CMA-ES, {count(r['restarts'], 'run')} × {r['steps']} generations of {r['popsize']}"
    first = (
        f"retrieval over {st['retrieval']['size']} collision-free self-exploration shadows (Ours, first answer: "
        f"its best pose), " + sweep + "its best distinct poses seeding the search, "
        if c["retrieve"]
        else "sampled initial poses, "
    )
    pick = "scored on the renderer" if c["select"] == "rendered" else "ranked by the self-model's loss"
    return (
        f"{first}gradient search batch {s['batch']} × {s['iterations']} iterations ({pick}), refinement ({refine}) "
        f"from each of the {c['candidates']} best distinct poses."
    )


def table_notes(rows: list[dict], st: dict, cfg: EvalConfig) -> list[str]:
    """How the table was measured, from the evaluator's settings ``st`` (wherever the targets ran)."""
    n = rows[0]["targets"] if rows else 0
    k = rows[0]["expressive_targets"] if rows else 0
    side = st["score_resolution"]
    shadows = (
        "the training image itself; the others: the rendered shadow of their pose"
        if side == st["resolution"]
        else f"their training pose's; every shadow rendered at {side}², the target framed at {side}²"
    )
    notes = [
        f"{n} targets at {st['resolution']}²; every method's shadow (Random, Nearest Neighbour: {shadows}) scored "
        f"by the same image loss on {side}² aligned crops. Lower is better.",
        f"Exp. IoU / Exp. CLIP: the expressive region of a still target is its holes; means over the {k} of {n} "
        f"targets that have holes (n/a: none has). Total = Base + expressive term for those targets, Base alone "
        f"for the others.",
        "In collision: share of each method's poses whose skeleton penetrates itself (Ours w/o refinement: the "
        "searched poses before refinement). Seconds: wall time per target on this machine.",
        f"Random and Nearest Neighbour draw from {st['training_images']} training images (aligning them once per "
        f"run took {st['nn_setup_seconds']:.1f} s, not in the per-target seconds; Random's draw for target i comes "
        f"from the seed (seed, i)); ours: {_method_note(st)}",
    ]
    if cfg.roll_rows is not None:
        how = ("one roll per target chosen on the retrieval index (coarse 15° grid, refined to ~0.25° on the "
               "renderer), its time in the seconds" if cfg.roll == "auto" else "the given roll")  # fmt: skip
        notes.append(
            f"Ours, {cfg.roll_rows}: the hand's mount rolled about the light axis ({how}); the target is "
            "imitated as above, every pose rendered as the rolled mount casts it and scored against the target "
            "as it is (only the self-model's search sees the target turned into the hand's frame). The rows "
            "above are the paper's upright rig (roll 0)."
        )
    if not st["losses"]["use_clip"]:
        notes.append(
            "CLIP off (no local CLIP weights, or turned off): CLIP and Exp. CLIP not computed (n/a); "
            "Base = 0.06·MAE + 0.4·IoU loss."
        )
    return notes
