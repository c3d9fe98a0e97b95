"""Table 1 spread over workers: every target one item of a :func:`studio.learn.fanout.fan_out`, each worker
holding its own imitator and baselines (loaded once), the rows gathered in the targets' order.

:func:`evaluate_spread` gives the same rows and records as :meth:`studio.evaluate.table1.Evaluator.run` in one
process (tests hold them equal, seconds aside): every method is seeded per target (the search and refinement by
their configs' seeds, Random by ``(seed, target index)``), so where a target runs does not change its result.
A worker loads the self-model, the inverse CNN, the Nearest Neighbour's training shards and CLIP itself: on a
cluster every path must exist on every machine.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from studio.errors import ProgressFn
from studio.evaluate.config import EvalConfig
from studio.evaluate.table1 import EvalResult, summarise
from studio.evaluate.table1_notes import table_notes
from studio.evaluate.worker_models import ModelRecipe
from studio.imitate.config import ImitateConfig, RefineConfig, SearchConfig, SweepConfig
from studio.imitate.retrieval import RetrievalConfig
from studio.learn.fanout import FanoutConfig, fan_out

__all__ = ["Table1Task", "evaluate_spread"]


@dataclass
class Table1Task:
    """What a worker needs to evaluate targets (a :mod:`studio.learn.fanout` task): paths and configs, all picklable.
    ``task((index, name, target (R, R)[, score_target (S, S)])) → (records, settings)``."""

    models: ModelRecipe  # the self-model and CLIP each worker loads
    inverse: str  # inverse-CNN checkpoint
    nn_data: str  # training shards of Random and Nearest Neighbour
    eval_cfg: EvalConfig = field(default_factory=EvalConfig)
    search: SearchConfig = field(default_factory=SearchConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    config: ImitateConfig = field(default_factory=ImitateConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)
    retrieval: RetrievalConfig | None = None  # the retrieval index (None: the imitator's default, cached per machine)
    _held: Any = field(default=None, init=False, repr=False, compare=False)  # (imitator, evaluator) once set up

    def __getstate__(self) -> dict:  # a worker gets the recipe, never this process's models
        return self.__dict__ | {"_held": None}

    def setup(self) -> None:
        from studio.evaluate.table1 import Evaluator
        from studio.imitate.still import Imitator

        model, clip = self.models.load()
        imitator = Imitator(model, clip=clip, search=self.search, refine=self.refine, config=self.config,
                            sweep=self.sweep, retrieval=self.retrieval)  # fmt: skip
        self._held = imitator, Evaluator(imitator, Path(self.inverse), Path(self.nn_data), self.eval_cfg)

    def check(self) -> None:
        """The baselines' files every worker loads, read here before any worker starts (the errors their setup
        would raise, said at once: a missing ``--nn-data`` folder, an unreadable inverse checkpoint)."""
        from studio.learn.checkpoint import read_checkpoint
        from studio.learn.shards import list_shards

        read_checkpoint(self.inverse, "inverse")
        list_shards(Path(self.nn_data))

    def close(self) -> None:
        if self._held is not None:
            imitator, evaluator = self._held
            evaluator.close()
            imitator.close()
            self._held = None

    def __call__(self, item: tuple) -> tuple[list[dict], dict]:
        if self._held is None:
            raise RuntimeError("Table1Task.setup() was not called")
        index, name, target, *scored = item
        evaluator = self._held[1]
        records = evaluator.evaluate_target(name, target, None, scored[0] if scored else None, index=index)
        return records, evaluator.settings()


def evaluate_spread(
    task: Table1Task,
    targets: list[tuple[str, np.ndarray] | tuple[str, np.ndarray, np.ndarray]],
    fanout: FanoutConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> EvalResult:
    """Table 1 over ``targets`` (as :meth:`~studio.evaluate.table1.Evaluator.run` takes them) on the workers
    ``fanout`` names. Reports stage "evaluate" as each target finishes (item: its name). ``cancel`` stops the
    workers; the table then holds the targets finished before it (in their order)."""
    task.check()
    items = [(i, *t) for i, t in enumerate(targets)]
    done = fan_out(task, items, fanout, progress, cancel, "evaluate", [t[0] for t in targets])
    records = [r for i in sorted(done) for r in done[i][0]]
    settings = next(iter(done.values()))[1] if done else {}
    rows = summarise(records)
    settings = settings | {"workers": fanout.where}
    return EvalResult(rows, records, table_notes(rows, settings, task.eval_cfg) if settings.get("search") else [],
                      settings)  # fmt: skip
