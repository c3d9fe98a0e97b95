"""How Table 2 was measured, in words (the notes printed under it), from the evaluator's configs: the same text
wherever the sequences ran (one process or spread, :mod:`studio.evaluate.table2_task`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from studio.imitate.config import LossConfig, SequenceConfig
from studio.imitate.transitions import TransitionConfig


def table_notes(
    cfg: SequenceConfig, t: TransitionConfig, lc: LossConfig, rows: Sequence[Any], sequences: Sequence[Any],
    finished: int, runs: int,
) -> list[str]:  # fmt: skip
    """The notes of a table of ``rows`` (:class:`~studio.evaluate.table2.Row`; the studio's: the one with the clock
    or the roll) over ``sequences`` (prepared: ``name``, ``frames``, ``representatives``), ``finished`` of ``runs``
    (sequence, row) runs done, measured with ``cfg`` (the sequence budgets), ``t`` (transition success) and ``lc``
    (the losses)."""
    studio = next((r for r in rows if r.clock or r.roll), None)
    n_frames = sum(s.frames for s in sequences)
    n_key = sum(len(s.representatives) for s in sequences)
    reading = {"base": "L_base", "image": "L_base + L_expr", "full": "L_base + L_expr + L_temp"}[t.total]
    notes = [
        f"{len(sequences)} sequences ({', '.join(s.name for s in sequences)}): {n_frames} sampled frames → "
        f"{n_key} keyframes, {n_key - len(sequences)} transitions; each sequence's frames, expressive masks and "
        f"keyframes computed once and shared by the six rows, keyframes optimised in order of first appearance.",
        "Every row scored by the same measure: each keyframe's rendered shadow against its target, with the "
        "expressive term on its expressive region (moving ∪ holes) also in the Base rows, which do not optimise "
        "it. Total = Base + expressive term (L_base + L_expr; the temporal term is not in it). Loss columns: "
        "means over keyframes; lower is better.",
        f"Transitions: success when both endpoints' {reading} ≤ {t.max_total:g}, mean|Δθ| ≤ {t.max_mean_step:g} "
        f"and max|Δθ| ≤ {t.max_step:g} rad (paper: 34.5 % independent → 86.2 % sequential +Exp+Temp). "
        "Mean Δθ: mean over joints of |θ_{k+1} − θ_k|, averaged over the transitions.",
        f"Search: first keyframe (every keyframe when independent) {cfg.first.batch} × {cfg.first.iterations}"
        + (", seeded by the retrieval's best poses after the block sweep (as a still)" if cfg.retrieve else "")
        + "; "
        f"later keyframes (sequential) {cfg.next.batch} × {cfg.next.iterations} from the previous pose + "
        f"N(0, {cfg.next.init_noise:g} rad); refinement {cfg.refine.restarts} × {cfg.refine.steps} steps from "
        f"each of the {cfg.candidates} best distinct search results"
        + (" (off)" if not cfg.refine_enabled else "")
        + ", keeping the temporal term in the +Temp rows. Seconds: wall time per sequence on this machine.",
    ]
    notes.append(
        "Success: the studio's reading (both endpoints' L_base ≤ the bound); Success, L_total: the paper's "
        "literal one (L_base + L_expr ≤ the bound). Late: transitions of each sequence's show too fast for the "
        "servos at the video's clock (planned with the servo limits, stretched; n/a: not planned)."
    )
    if studio is not None:
        notes.append(
            f"{studio.name}: the studio's method. One mount roll per sequence chosen by roll auto on the "
            "keyframe targets, every pose scored as that mount casts it; every keyframe kept within the "
            f"servos' rest-to-rest reach of every posed keyframe in {cfg.clock_margin:g} × the time each "
            "transition on the way between them has (studio.motion.reach.reach_distances), in retrieval, "
            "sweep, search and refinement"
            + _joint_note(cfg)
            + ". The six rows above are the paper's: upright rig, poses chosen without the clock."
        )  # fmt: skip
    if not lc.use_clip:
        notes.append(
            "CLIP off (no local CLIP weights, or turned off): CLIP and Exp. CLIP not computed (n/a); "
            "Base = 0.06·MAE + 0.4·IoU loss."
        )
    if finished < runs:
        notes.append(f"Cancelled: {finished} of {runs} (sequence, row) runs finished; only those are shown.")
    return notes


def _joint_note(cfg: SequenceConfig) -> str:
    """What the studio row does once its keyframes are posed one after another (:class:`JointConfig`)."""
    j = cfg.joint
    orders = "whichever order of posing them, first to last or last to first, sums lower"
    if j.generations:
        return (f"; then the keyframes refined together within that reach ({j.generations} CMA-ES generations of "
                f"{j.popsize} per window of {j.window}, studio.imitate.joint_refine"
                + (f", from {orders}" if j.both_orders else "") + ")")  # fmt: skip
    return f"; then the keyframes posed last to first too, keeping {orders}" if j.both_orders else ""
