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

from studio.errors import ClosedError, ProgressFn, report, staged, stopped
from studio.evaluate.baselines import BaselineOutput, InverseBaseline, NearestNeighbour, RandomImage, TrainingSet
from studio.evaluate.config import EvalConfig
from studio.evaluate.report import csv_text, markdown_table, write_report
from studio.evaluate.table1_notes import table_notes
from studio.imitate.losses import ImageLoss
from studio.imitate.still import Imitator
from studio.learn.inverse import InverseCNN
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
