"""The paper's Table 2 (DESIGN §4): the video ablation, six rows over a set of sequences, measured the same way.

Rows: Independent / Sequential (:data:`studio.imitate.config.MODES`) × Base / +Exp / +Exp+Temp (the expressive
and temporal switches of :class:`~studio.imitate.config.SequenceConfig`). Each sequence is prepared once
(:func:`~studio.evaluate.sequences.prepare_sequence`: sampled frames, expressive masks, keyframes, in
first-appearance order) and the same keyframe targets go to all six rows, with the same seeds.

Every row is scored by one measure,
:attr:`KeyframeResult.evaluation <studio.imitate.sequence_result.KeyframeResult>`: the rendered shadow of each
keyframe's final pose against its target, *with* the expressive term on the keyframe's
expressive region even in the Base rows that do not optimise it (as the paper's table shows Exp. columns for
every row). The table's **Total** is ``L_base + L_expr`` of that measure (``KeyframeResult.total("image")``); the
temporal term is left out of it (the transition test's Δθ bounds judge the motion, and the first keyframe has
none). Loss columns are means over all keyframes of all sequences (NaN-aware: CLIP columns are n/a without CLIP).
Transition success (:mod:`studio.imitate.transitions`) is counted over the K − 1 transitions of each sequence and
summed over sequences. Rows, records (one per sequence and row) and keyframes are JSON-able dicts (NaN → None);
:func:`write_table` writes Markdown, CSVs and the settings through :mod:`studio.evaluate.report`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn, report, staged, stopped
from studio.evaluate.report import csv_text, markdown_table, nan_to_none, write_report
from studio.evaluate.sequences import PreparedSequence
from studio.evaluate.table1 import LOSS_COLUMNS
from studio.evaluate.table2_notes import table_notes
from studio.imitate.config import MODES, SequenceConfig
from studio.imitate.sequence import SequenceImitator
from studio.imitate.transitions import TransitionConfig
from studio.motion.limits import JointLimits, LimitsConfig
from studio.motion.reach import clock_boxes, reach_pairs
from studio.motion.video_timing import transition_times, video_keyframes
from studio.sim.roll import roll_deg

log = logging.getLogger(__name__)

EXTRA_COLUMNS = {"Transitions": "transitions_text", "Success (%)": "success_pct",
                 "Success, L_total (%)": "success_image_pct", "Late": "late", "Mean Δθ (rad)": "mean_step",
                 "Seconds / sequence": "seconds"}  # fmt: skip
DIGITS = {"success_pct": 1, "success_image_pct": 1, "late": 0, "mean_step": 3, "seconds": 1}
LOSS_KEYS = (*LOSS_COLUMNS.values(), "expr", "temporal")  # kept per keyframe (Total = base + expr, module doc)


@dataclass(frozen=True)
class Row:
    """One row of Table 2: a mode and the two switches."""

    name: str  # "Independent Base", …, "Sequential +Exp+Temp"
    mode: str  # "independent" | "sequential"
    expressive: bool  # optimises L_expr
    temporal: bool  # optimises L_temp
    clock: bool = False  # keeps every transition within the servos' reach at the video's clock (studio.motion.reach)
    roll: bool = False  # one mount roll for the whole sequence, chosen by roll auto (studio.imitate.roll_search)

    def config(self, base: SequenceConfig) -> SequenceConfig:
        return replace(base, mode=self.mode, expressive=self.expressive, temporal=self.temporal, keep_clock=self.clock)


PAPER_ROWS = tuple(
    Row(f"{mode.title()} {label}", mode, exp, temp)
    for mode in MODES
    for label, exp, temp in (("Base", False, False), ("+Exp", True, False), ("+Exp+Temp", True, True))
)  # the paper's six rows: its rig (roll 0), poses chosen without the servos' clock
STUDIO_ROW = Row("Studio: sequential +Exp+Temp, roll auto, clock", "sequential", True, True, clock=True, roll=True)
ROWS = (*PAPER_ROWS, STUDIO_ROW)


def _mean(values) -> float | None:
    v = np.asarray([np.nan if x is None else x for x in values], dtype=float)
    v = v[~np.isnan(v)]
    return float(v.mean()) if len(v) else None


def summarise(records: list[dict], keyframes: list[dict], rows: Sequence[Row] = ROWS) -> list[dict]:
    """Per-row summary: loss means over keyframes, transitions summed over sequences, seconds per sequence."""
    out = []
    for row in rows:
        recs = [r for r in records if r["row"] == row.name]
        if not recs:
            continue
        kfs = [k for k in keyframes if k["row"] == row.name]
        # the switches as optimises_*: "expr" and "temporal" are loss keys (the measured terms)
        s = {"row": row.name, "mode": row.mode, "optimises_expr": row.expressive, "optimises_temp": row.temporal,
             "sequences": len(recs), "keyframes": len(kfs)}  # fmt: skip
        s |= {key: _mean(k[key] for k in kfs) for key in LOSS_KEYS}
        for key in ("success", "transitions", "success_image"):
            s[key] = int(sum(r[key] for r in recs))
        n = s["transitions"]
        s["transitions_text"] = f"{s['success']}/{n}"
        s["success_pct"] = 100.0 * s["success"] / n if n else None
        s["success_image_pct"] = 100.0 * s["success_image"] / n if n else None
        s["mean_step"] = _mean(x for r in recs for x in r["mean_steps"])
        s["in_collision"] = int(sum(not k["collision_free"] for k in kfs))
        lates = [r["late"] for r in recs if r.get("late") is not None]
        s["late"] = int(sum(lates)) if lates else None
        s["seconds"] = float(np.mean([r["seconds"] for r in recs]))
        out.append(s)
    return out


@dataclass
class Table2Result:
    """Table 2 and what it was computed from (plain data)."""

    rows: list[dict]  # one per row (ROWS order) with at least one finished sequence
    records: list[dict]  # one per (sequence, row): loss means, transitions, seconds
    keyframes: list[dict]  # one per (sequence, row, keyframe): the evaluation components, pose, collision
    notes: list[str]  # how the table was measured (printed under it)
    settings: dict = field(default_factory=dict)  # sampling, keyframes, sequence budgets, losses, transition test
    cancelled: bool = False  # the cancel event stopped it: only the (sequence, row) runs finished before it


class VideoEvaluator:
    """Runs the rows of Table 2 on prepared sequences with one :class:`SequenceImitator` (the caller's)."""

    def __init__(self, seq: SequenceImitator, cfg: SequenceConfig, transition: TransitionConfig | None = None,
                 rows: Sequence[Row] = ROWS, limits: LimitsConfig | None = None):  # fmt: skip
        self.seq, self.cfg, self.rows = seq, cfg, tuple(rows)
        self.transition = transition or TransitionConfig()
        self.limits = limits or LimitsConfig()  # the servos' limits: the clock rows keep, the late count plans with

    def evaluate(self, s: PreparedSequence, row: Row, progress: ProgressFn | None = None, cancel=None):
        """One (sequence, row) run → ``(record, keyframe dicts)``, or None when cancelled half-way. ``progress`` gets
        the sequence's stages ("keyframe k/K: search", ...) with item "sequence · row"."""
        name = f"{s.name} · {row.name}"
        steps = staged(progress, "", item=name)
        t0 = time.perf_counter()
        masks, expressive, roll = s.masks, s.expressive, 0.0
        if row.roll:  # one mount for the whole sequence, its shadows scored as it casts them
            choice = self.seq.imitator.choose_roll(s.masks, progress=steps, cancel=cancel)
            if choice is None:
                return None
            roll = choice.roll
        box_for = pairs = None
        if row.clock:  # within the servos' reach at the video's clock, one after another and then together
            limits = JointLimits.from_hand(self.seq.imitator.hand, self.limits)
            times = transition_times(self._timing(s))
            box_for = clock_boxes(times, limits, self.cfg.clock_margin)
            pairs = reach_pairs(times, limits, self.cfg.clock_margin)
        result = self.seq.imitate(
            masks, expressive, steps, cancel, cfg=row.config(self.cfg), box_for=box_for, roll=roll, pairs=pairs
        )
        if result.cancelled:
            return None
        seconds = time.perf_counter() - t0  # choosing the roll and the poses (planning the check below is not in it)
        late = self._late(s, result.thetas, cancel)
        rep = result.transitions(self.transition)
        image = result.transitions(replace(self.transition, total="image"))
        kfs = []
        for k in result.keyframes:
            rep_frame = int(s.representatives[k.index])
            comps = {key: k.evaluation[key] for key in LOSS_KEYS} | {"total": k.total("image")}  # Total: module doc
            kfs.append({"sequence": s.name, "row": row.name, "keyframe": k.index, "frame": rep_frame,
                        "time": float(s.times[rep_frame]), **comps, "total_full": k.evaluation["total"],
                        "collision_free": k.collision_free, "seconds": k.seconds,
                        "theta": [float(x) for x in k.theta]})  # fmt: skip
        record = {"sequence": s.name, "row": row.name, "frames": s.frames, "keyframes": len(kfs),
                  **{key: _mean(k[key] for k in kfs) for key in LOSS_KEYS},
                  "success": rep.count, "transitions": rep.total, "success_image": image.count,
                  "ok": rep.ok.tolist(), "mean_steps": rep.mean_step.tolist(),
                  "mean_step": _mean(rep.mean_step.tolist()),
                  "max_step": float(rep.max_step.max()) if rep.total else None,
                  "in_collision": int(sum(not k["collision_free"] for k in kfs)),
                  "late": late, "roll_deg": roll_deg(roll), "seconds": seconds}  # fmt: skip
        total = math.nan if record["total"] is None else record["total"]
        log.info("%s: %d/%d transitions, total %.4f, %.1f s", name, rep.count, rep.total, total, result.seconds)
        return record, kfs

    def _timing(self, s: PreparedSequence, thetas: np.ndarray | None = None):
        """The sequence on the video's clock (:func:`~studio.motion.video_timing.video_keyframes`; placeholder
        poses when only the clock is wanted)."""
        poses = np.zeros((len(s.representatives), self.seq.imitator.hand.dof)) if thetas is None else thetas
        end = s.end_s if s.end_s > s.times[-1] else float(s.times[-1]) + 1.0
        return video_keyframes(s.times, s.assignment, poses, end)

    def _late(self, s: PreparedSequence, thetas: np.ndarray, cancel) -> int | None:
        """Transitions of the sequence's show too fast for the servos at the video's clock (the planner's late
        segments, stretched); None when it could not be planned (a keyframe in collision)."""
        from studio.motion.errors import PlanError
        from studio.motion.plan import PlanConfig, plan_show
        from studio.motion.timing import TimingConfig

        if len(thetas) < 2:
            return 0
        cfg = PlanConfig(timing=TimingConfig(allow_late=True), limits=self.limits)
        try:
            show = plan_show(self.seq.imitator.hand, self._timing(s, thetas).keyframes, cfg, cancel=cancel).show
        except PlanError as e:
            log.warning("%s: the show could not be planned (%s)", s.name, e)
            return None
        return len(show.provenance.get("late_segments", []))

    def run(
        self,
        sequences: Sequence[PreparedSequence],
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
    ) -> Table2Result:
        """Every row on every sequence, sequence by sequence. Stage "evaluate-video" at the start and after each run
        (step: runs done, item: "sequence · row"), the run's stages between (:meth:`evaluate`). Setting ``cancel``
        stops within a search or refinement step; the run it interrupts is left out."""
        records, keyframes, total, cancelled = [], [], len(sequences) * len(self.rows), False
        report(progress, "evaluate-video", 0, total)
        for s in sequences:
            for row in self.rows:
                out = None if stopped(cancel) else self.evaluate(s, row, progress, cancel)
                if out is None:
                    cancelled = True
                    break
                records.append(out[0])
                keyframes += out[1]
                report(progress, "evaluate-video", len(records), total, item=f"{s.name} · {row.name}")
            if cancelled:
                break
        rows = summarise(records, keyframes, self.rows)
        return Table2Result(rows, records, keyframes, self.notes(sequences, records, total), self.settings(sequences),
                            cancelled)  # fmt: skip

    def settings(self, sequences: Sequence[PreparedSequence]) -> dict:
        return {
            "resolution": self.seq.imitator.resolution, "losses": self.seq.loss_cfg.to_dict(),
            "clip": getattr(self.seq.imitator.clip, "name", None), "sequence": asdict(self.cfg),
            "transition": asdict(self.transition), "rows": [asdict(r) for r in self.rows],
            "sequences": [{"name": s.name, "source": str(s.source), "frames": s.frames,
                           "keyframes": len(s.representatives), "representatives": s.representatives.tolist(),
                           "assignment": s.assignment.tolist(), "prepare_seconds": round(s.seconds, 2)}
                          for s in sequences],
        }  # fmt: skip

    def notes(self, sequences: Sequence[PreparedSequence], records: list[dict], runs: int) -> list[str]:
        """How the table was measured, in words (:func:`~studio.evaluate.table2_notes.table_notes`)."""
        return table_notes(self.cfg, self.transition, self.seq.loss_cfg, self.rows, sequences, len(records), runs)


def to_markdown(rows: list[dict], notes: Sequence[str] = ()) -> str:
    """Table 2 as a Markdown table (best Total in bold) followed by its notes."""
    return markdown_table("Row", rows, {**LOSS_COLUMNS, **EXTRA_COLUMNS}, "row", DIGITS, "total", notes)


FILES = ("table2.md", "table2.csv", "per_sequence.csv", "per_keyframe.csv", "settings.json")  # what write_table writes


def write_table(result: Table2Result, out: Path) -> dict[str, str]:
    """Write ``table2.md``, ``table2.csv`` (one row per row), ``per_sequence.csv``, ``per_keyframe.csv`` and
    ``settings.json``; returns their paths."""
    keys = ["row", *LOSS_KEYS, "success", "transitions", "success_pct", "success_image", "success_image_pct",
            "mean_step", "in_collision", "late", "seconds", "sequences", "keyframes"]  # fmt: skip
    rec_keys = ["sequence", "row", "frames", "keyframes", *LOSS_KEYS, "success", "transitions", "success_image",
                "mean_step", "max_step", "in_collision", "late", "roll_deg", "seconds"]  # fmt: skip
    kf_keys = ["sequence", "row", "keyframe", "frame", "time", *LOSS_KEYS, "total_full", "collision_free", "seconds"]
    texts = {
        "markdown": (FILES[0], to_markdown(result.rows, result.notes)),
        "csv": (FILES[1], csv_text(keys, result.rows)),
        "per_sequence": (FILES[2], csv_text(rec_keys, result.records)),
        "per_keyframe": (FILES[3], csv_text(kf_keys, result.keyframes)),
    }
    return write_report(out, texts, result.settings)


def json_rows(rows: list[dict]) -> list[dict]:
    """Rows for JSON: NaN → None."""
    return [{k: nan_to_none(v) for k, v in r.items()} for r in rows]
