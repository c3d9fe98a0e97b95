"""What the job tests share (tests/test_jobs.py, tests/test_project_jobs.py): a target, two search budgets (one
that ends at once, one that never does) and a subscriber that records every event."""

from __future__ import annotations

import threading

from studio.assets import asset

from studio.imitate.config import SearchConfig

TARGET = asset("targets/asl_v.jpeg")
TINY = SearchConfig(batch=4, iterations=20, lr=0.08, log_every=5)
LONG = SearchConfig(batch=4, iterations=1_000_000, lr=0.08, log_every=1)


class Recorder:
    """A subscriber keeping every event, with a flag raised on the first one of a given stage."""

    def __init__(self, stage: str | None = None):
        self.events, self.stage, self.seen = [], stage, threading.Event()

    def __call__(self, e) -> None:
        self.events.append(e)
        if self.stage is not None and e.stage == self.stage:
            self.seen.set()
