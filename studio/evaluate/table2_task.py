"""Table 2 spread over workers: every (sequence, row) run one item of a :func:`studio.learn.fanout.fan_out`, each worker
holding its own sequence imitator (the self-model loaded once), the runs gathered in the table's order.

:func:`evaluate_video_spread` gives the same records as :meth:`studio.evaluate.table2.VideoEvaluator.run` in one
process (seconds aside): a run is seeded by its configs, so where it runs does not change it. The sequences are
prepared once by the caller and sent with their runs; a worker loads the self-model and CLIP itself (on a cluster
every path must exist on every machine).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from studio.errors import ProgressFn
from studio.evaluate.sequences import PreparedSequence
from studio.evaluate.table2 import ROWS, Row, Table2Result, VideoEvaluator, summarise
from studio.evaluate.worker_models import ModelRecipe
from studio.imitate.config import SequenceConfig
from studio.imitate.transitions import TransitionConfig
from studio.learn.fanout import FanoutConfig, fan_out

__all__ = ["Table2Task", "evaluate_video_spread"]


@dataclass
class Table2Task:
    """What a worker needs to run Table 2's rows (a :mod:`studio.learn.fanout` task): a path and configs, all picklable.
    ``task((sequence, row)) → (record, keyframe dicts)``."""

    models: ModelRecipe  # the self-model and CLIP each worker loads
    cfg: SequenceConfig  # the sequence budgets (the preset and the budget flags)
    transition: TransitionConfig = field(default_factory=TransitionConfig)
    rows: tuple[Row, ...] = ROWS
    _held: Any = field(default=None, init=False, repr=False, compare=False)  # (imitator, evaluator) once set up

    def __getstate__(self) -> dict:  # a worker gets the recipe, never this process's models
        return self.__dict__ | {"_held": None}

    def setup(self) -> None:
        from studio.imitate.config import LossConfig
        from studio.imitate.sequence import SequenceImitator

        model, clip = self.models.load()
        loss_cfg = LossConfig(use_clip=clip is not None, crop_size=model.cfg.resolution)
        seq = SequenceImitator(model, self.cfg, loss_cfg=loss_cfg, clip=clip)
        self._held = seq, VideoEvaluator(seq, self.cfg, self.transition, self.rows)

    def close(self) -> None:
        if self._held is not None:
            self._held[0].close()
            self._held = None

    def __call__(self, item: tuple[PreparedSequence, Row]) -> tuple[dict, list[dict]]:
        if self._held is None:
            raise RuntimeError("Table2Task.setup() was not called")
        s, row = item
        out = self._held[1].evaluate(s, row)
        if out is None:  # only a cancel ends a run early, and workers are never handed one
            raise RuntimeError(f"{s.name} · {row.name} stopped without a result")
        return out


def evaluate_video_spread(
    evaluator: VideoEvaluator,
    task: Table2Task,
    sequences: list[PreparedSequence],
    fanout: FanoutConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> Table2Result:
    """Table 2's runs on the workers ``fanout`` names; ``evaluator`` (this process's, with the same configs as
    ``task``) only writes the notes and settings. Stage "evaluate-video" as each run finishes (item: "sequence ·
    row"). ``cancel`` stops the workers: the table holds the runs finished before it (``cancelled``)."""
    items = [(s, row) for s in sequences for row in evaluator.rows]
    names = [f"{s.name} · {row.name}" for s, row in items]
    done = fan_out(task, items, fanout, progress, cancel, "evaluate-video", names)
    records = [done[i][0] for i in sorted(done)]
    keyframes = [k for i in sorted(done) for k in done[i][1]]
    rows = summarise(records, keyframes, evaluator.rows)
    settings = evaluator.settings(sequences) | {"workers": fanout.where}
    return Table2Result(rows, records, keyframes, evaluator.notes(sequences, records, len(items)), settings,
                        len(done) < len(items))  # fmt: skip
