"""The paper's Table 1 (DESIGN §4): every method on a list of still targets, measured the same way.

Each method gives a pose and its shadow: Random and Nearest Neighbour a training image (a rendered shadow of a
training pose), the inverse CNN and ours the exact renderer's shadow of their pose (ours before and after
refinement). One :class:`~studio.imitate.losses.ImageLoss` per target scores every method's shadow. The
expressive region of a still target is its holes (:func:`studio.targets.holes.find_holes`): for a target without holes
the expressive terms are NaN, and the Exp. columns are means over the targets that have holes. Rows are plain
JSON-able dicts (NaN → None); :func:`write_table` writes them as Markdown and CSV.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from studio.errors import ClosedError
from studio.evaluate.baselines import BaselineOutput, InverseBaseline, NearestNeighbour, RandomImage, TrainingSet
from studio.evaluate.config import EvalConfig
from studio.evaluate.report import csv_text, markdown_table, write_report
from studio.imitate.losses import ImageLoss
from studio.imitate.still import Imitator
from studio.learn.inverse import InverseCNN
from studio.progress import ProgressFn, report, staged, stopped
from studio.sim.roll import file_deg
from studio.sim.shadow import ShadowRenderer
from studio.targets.expressive import still_expressive

PAPER_RIG = ("Random", "Inverse CNN", "Nearest Neighbour", "Ours, first answer", "Ours w/o refinement", "Ours")
ROLLED = ("Ours, {roll}, first answer", "Ours, {roll}")  # ours again on a rolled mount (EvalConfig.roll)
METHODS = PAPER_RIG + tuple(m.format(roll="roll auto") for m in ROLLED)  # the rows at the default settings
LOSS_COLUMNS = {  # Table 1 header → loss component (studio.imitate.config.COMPONENTS)
    "Total": "total", "Base": "base", "CLIP": "clip", "MAE": "mae", "IoU loss": "iou_loss",
    "Exp. IoU": "exp_iou", "Exp. CLIP": "exp_clip",
}  # fmt: skip
EXTRA_COLUMNS = {"In collision (%)": "collide_pct", "Seconds / target": "seconds"}


@dataclass
class EvalResult:
    """Table 1 and what it was computed from (plain data)."""

    rows: list[dict]  # one per method (METHODS order): method, the loss keys, collide_pct, seconds, counts
    records: list[dict]  # one per (target, method): target, method, loss components, collides, seconds
    notes: list[str]  # how the table was measured (printed under it)
    settings: dict = field(default_factory=dict)  # model, losses, search and refinement settings


@torch.no_grad()
def score(loss_fn, shadow: np.ndarray) -> dict[str, float]:
    """Loss components of one shadow ``(H, W)`` under a target's :class:`ImageLoss` (NaN = not computed)."""
    _, comps = loss_fn(torch.from_numpy(np.asarray(shadow, dtype=np.float32)[None]))
    return {k: float(v[0]) for k, v in comps.items()}


def summarise(records: list[dict]) -> list[dict]:
    """Per-method means over targets (NaN-aware: each loss over the targets where it was computed), methods in the
    order they first appear."""
    rows = []
    for method in dict.fromkeys(r["method"] for r in records):
        recs = [r for r in records if r["method"] == method]
        if not recs:
            continue
        row: dict = {"method": method, "targets": len(recs)}
        for key in LOSS_COLUMNS.values():
            vals = np.array([r[key] for r in recs], dtype=float)
            vals = vals[~np.isnan(vals)]
            row[key] = float(vals.mean()) if len(vals) else None
        row["expressive_targets"] = int(sum(not math.isnan(r["exp_iou"]) for r in recs))
        row["collide_pct"] = 100.0 * float(np.mean([r["collides"] for r in recs]))
        row["seconds"] = float(np.mean([r["seconds"] for r in recs]))
        rows.append(row)
    return rows


class Evaluator:
    """Runs every method of Table 1 on targets; holds the imitator and the baselines between targets.

    The imitator stays the caller's (close it yourself); ``close()`` (or the end of a ``with`` block) closes the
    baselines made here.
    """

    def __init__(
        self,
        imitator: Imitator,
        inverse: InverseCNN | Path,
        training: TrainingSet | Path,
        cfg: EvalConfig | None = None,
    ):
        from studio.learn.inverse import load_inverse

        self.cfg = cfg or EvalConfig()
        self.imitator = imitator
        inv = inverse if isinstance(inverse, InverseCNN) else load_inverse(Path(inverse), imitator.hand)[0]
        data = training if isinstance(training, TrainingSet) else TrainingSet.load(Path(training), imitator.hand)
        self.random = RandomImage(data, self.cfg.seed)
        self.inverse = InverseBaseline(inv, imitator.renderer, imitator.refiner.world)
        t0 = time.perf_counter()
        self.nn = NearestNeighbour(data, imitator.loss_cfg, self.cfg.nn)
        self.nn_setup_seconds = time.perf_counter() - t0  # aligning the training images, once per run
        self.training_size = len(data)
        side = self.cfg.score_resolution or imitator.resolution
        self.score_renderer = None  # renders every method's pose at the scoring side when it is not the model's
        self.score_loss_cfg = replace(imitator.loss_cfg, crop_size=side)
        if side != imitator.resolution:
            self.score_renderer = ShadowRenderer(imitator.hand, imitator.renderer.rig.with_resolution(side))

    @property
    def score_resolution(self) -> int:
        """Side, pixels, at which the table's shadows are rendered and scored."""
        return self.score_loss_cfg.crop_size

    def close(self) -> None:
        """Close the inverse baseline (its collision world is the imitator's, which stays open; idempotent)."""
        self.inverse.close()

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def evaluate_target(
        self, name: str, target: np.ndarray, cancel: threading.Event | None = None,
        score_target: np.ndarray | None = None, progress: ProgressFn | None = None, index: int = 0,
    ) -> list[dict]:  # fmt: skip
        """One record per method for one ``(R, R)`` target mask (at the model's side ``R``). With a scoring side
        other than the model's, ``score_target`` is the same target framed at that side (``(S, S)``): every
        method's pose is rendered and scored there (Random and Nearest Neighbour: their training pose's shadow).
        ``progress`` gets our imitation's stages (:meth:`~studio.imitate.still.Imitator.imitate`). ``index``: the
        target's place in the run (Random draws from the seed ``(seed, index)``, so a target scores the same
        wherever it runs)."""
        if self.inverse.closed:
            raise ClosedError("this Evaluator was closed; make a new one (or evaluate inside its `with` block)")
        expressive = still_expressive(target)
        loss_fn = self.imitator.loss_fn(target, expressive)
        ours = self.imitator.imitate(target, expressive, refine=True, progress=progress, cancel=cancel)
        before_refine = ours.seconds - ours.timings["refine"]  # retrieval, sweep and search
        unrefined = BaselineOutput(ours.unrefined_theta, ours.unrefined_shadow, ours.unrefined_collides,
                                   before_refine)  # fmt: skip
        final = BaselineOutput(ours.theta, ours.shadow, not ours.collision_free, ours.seconds)
        outputs = {
            "Random": self.random.query(index),
            "Inverse CNN": self.inverse.query(target),
            "Nearest Neighbour": self.nn.query(target, loss_fn),
        }
        if ours.first is not None:  # the retrieval's best pose: what the studio shows first
            theta = ours.first.theta[0]
            collides = bool(self.imitator.refiner.world.in_collision(theta)[0])
            shadow = self.imitator.renderer.render_one(theta)
            outputs["Ours, first answer"] = BaselineOutput(theta, shadow, collides, ours.timings["first_answer"])
        outputs |= {"Ours w/o refinement": unrefined, "Ours": final}
        if self.cfg.roll_rows is not None and not stopped(cancel):
            outputs |= self._rolled(target, expressive, progress, cancel)
        if self.score_renderer is not None:
            if score_target is None or score_target.shape != (self.score_resolution,) * 2:
                raise ValueError(f"scoring at {self.score_resolution}² needs the target framed at that side")
            loss_fn = ImageLoss(score_target, self.score_loss_cfg, self.imitator.clip, still_expressive(score_target))
            for out in outputs.values():
                out.shadow = self._renderer(out.roll, self.score_resolution).render_one(out.theta)
        records = []
        for method, out in outputs.items():
            rec = {"target": name, "method": method, **score(loss_fn, out.shadow), "roll_deg": file_deg(out.roll)}
            rec |= {"collides": out.collides, "seconds": out.seconds, "theta": [float(x) for x in out.theta]}
            records.append(rec)
        return records

    def _renderer(self, roll: float, side: int) -> ShadowRenderer:
        """The renderer of the mount rolled by ``roll`` rad at ``side`` pixels (the imitator's at roll 0)."""
        rig = self.imitator.renderer.rig.with_resolution(side)
        if not roll and side == self.imitator.resolution:
            return self.imitator.renderer
        return ShadowRenderer(self.imitator.hand, rig.with_roll(roll))

    def _rolled(self, target, expressive, progress, cancel) -> dict[str, BaselineOutput]:
        """Ours on the rolled mount (``cfg.roll``: chosen by ``--roll auto`` for this target, or given): the target
        imitated as that mount casts it (:class:`~studio.imitate.framing.Framed`), every shadow rendered so. Seconds
        include choosing the roll."""
        t0 = time.perf_counter()
        im = self.imitator
        if self.cfg.roll == "auto":
            choice = im.choose_roll(target[None], progress=progress, cancel=cancel)
            roll = 0.0 if choice is None else choice.roll
        else:
            roll = math.radians(float(self.cfg.roll))
        t_roll = time.perf_counter() - t0
        got = im.imitate(target, expressive, refine=True, progress=progress, cancel=cancel, roll=roll)
        rolled = self._renderer(roll, im.resolution)
        names = [m.format(roll=self.cfg.roll_rows) for m in ROLLED]
        out = {names[1]: BaselineOutput(got.theta, got.shadow, not got.collision_free, t_roll + got.seconds,
                                        roll=roll)}  # fmt: skip
        if got.first is not None:
            theta = got.first.theta[0]
            collides = bool(im.refiner.world.in_collision(theta)[0])
            first = BaselineOutput(theta, rolled.render_one(theta), collides, t_roll + got.timings["first_answer"],
                                   roll=roll)  # fmt: skip
            out = {names[0]: first} | out
        return out

    def run(
        self,
        targets: Sequence[tuple],
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
    ) -> EvalResult:
        """Evaluate ``(name, (R, R) mask)`` targets (``(name, mask, (S, S) mask)`` when scoring at another side
        ``S``, :meth:`evaluate_target`). Reports stage "evaluate" at the start and after each target (step: targets
        done, item: the target's name) and, in between, the target's imitation stages ("retrieve", "sweep",
        "search", "refine", with the target's name as item). ``cancel`` stops within a search or refinement step;
        the table then holds the targets finished before it."""
        records: list[dict] = []
        report(progress, "evaluate", 0, len(targets))
        for i, (name, target, *scored) in enumerate(targets):
            if stopped(cancel):
                break
            steps = staged(progress, "", item=name)
            records += self.evaluate_target(name, target, cancel, scored[0] if scored else None, steps, index=i)
            report(progress, "evaluate", i + 1, len(targets), item=name)
        rows = summarise(records)
        return EvalResult(rows, records, self.notes(rows), self.settings())

    def settings(self) -> dict:
        im = self.imitator
        return {
            "resolution": im.resolution, "score_resolution": self.score_resolution,
            "losses": self.score_loss_cfg.to_dict(), "clip": getattr(im.clip, "name", None),
            "search": asdict(im.search_cfg), "refine": asdict(im.refine_cfg), "imitate": asdict(im.cfg),
            "retrieval": asdict(im.retrieval_cfg) if im.cfg.retrieve else None,
            "sweep": asdict(im.sweep_cfg) if im.cfg.retrieve and im.sweep_cfg.starts else None,
            "training_images": self.training_size,
            "nn": asdict(self.cfg.nn), "nn_setup_seconds": round(self.nn_setup_seconds, 2), "roll": self.cfg.roll,
        }  # fmt: skip

    def notes(self, rows: list[dict]) -> list[str]:
        """How the table was measured (:func:`table_notes` of these settings)."""
        return table_notes(rows, self.settings(), self.cfg)


def _method_note(st: dict) -> str:
    """Our method in words, from :meth:`Evaluator.settings`."""
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
        refine = f"CMA-ES, {r['restarts']} run(s) × {r['steps']} generations of {r['popsize']}"
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
    """How the table was measured, from :meth:`Evaluator.settings` ``st`` (wherever the targets ran)."""
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


DIGITS = {"collide_pct": 1, "seconds": 1}  # decimals of the non-loss columns (losses: 3)


def to_markdown(rows: list[dict], notes: Sequence[str] = ()) -> str:
    """Table 1 as a Markdown table (best Total in bold) followed by its notes."""
    return markdown_table("Method", rows, {**LOSS_COLUMNS, **EXTRA_COLUMNS}, "method", DIGITS, "total", notes)


FILES = ("table1.md", "table1.csv", "per_target.csv", "settings.json")  # what write_table writes into its folder


def write_table(result: EvalResult, out: Path) -> dict[str, str]:
    """Write ``table1.md``, ``table1.csv`` (one row per method), ``per_target.csv`` and ``settings.json`` (model,
    losses with ``use_clip``, search, refinement, Nearest Neighbour); returns their paths."""
    keys = ["method", *LOSS_COLUMNS.values(), "collide_pct", "seconds", "targets", "expressive_targets"]
    rec_keys = ["target", "method", *LOSS_COLUMNS.values(), "collides", "seconds", "roll_deg"]
    texts = {
        "markdown": (FILES[0], to_markdown(result.rows, result.notes)),
        "csv": (FILES[1], csv_text(keys, result.rows)),
        "per_target": (FILES[2], csv_text(rec_keys, result.records)),
    }
    return write_report(out, texts, result.settings)
