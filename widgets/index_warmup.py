"""The retrieval index built in the background when the studio opens (the Optimise panel's line about it).

The searches' first answers come from a retrieval index over 200,000 poses, built once per machine and then cached
(:func:`studio.imitate.index_cache.cached_index`, ~40 s on two cores). When this machine has not built it yet, the
studio builds it as soon as it opens, as a job on the project's queue (:func:`studio.project.jobs.index_job`), so
the first optimisation does not wait for it; a line says what is happening. Whether it is cached takes seconds of
imports to tell, so that is found off the kernel's thread. One build per studio (``state.extras["index_job"]``).
"""

from __future__ import annotations

import html
import logging
import os
import threading
from collections.abc import Callable
from typing import Any

import ipywidgets as w

from studio.jobs import Job, JobEvent, JobState
from studio.project.jobs import index_job, index_needed
from widgets.state import StudioState
from widgets.words import stage

log = logging.getLogger(__name__)

_LOCK = threading.Lock()  # one background build per studio, whichever panel asks first
OFF_ENV = "SHADOW_STUDIO_NO_INDEX_WARMUP"  # "1": never build in the background (the test suite: each test's studio
# would start a build that its close cancels; the searches still build the index when they need it)


class IndexWarmup:
    """Starts the build when needed (:meth:`start`) and shows its progress on :attr:`line` (:meth:`draw`)."""

    def __init__(self, state: StudioState, retrieval: Any = None, on_known: Callable[[], None] | None = None):
        self.state = state
        self.retrieval = retrieval  # the RetrievalConfig to build (None: the searches' own)
        self.on_known = on_known  # called once it is known whether a build was needed
        self.job: Job | None = None  # the build (None: not needed, or not known yet)
        self.checked = threading.Event()  # set once it is known whether the index had to be built
        self.line = w.HTML("")

    def start(self) -> None:
        """Find out, off the kernel's thread, whether the index is cached; submit its build when it is not."""
        if os.environ.get(OFF_ENV) == "1":
            self.checked.set()
            return
        threading.Thread(target=self._check, name="index-warmup", daemon=True).start()

    def _check(self) -> None:
        extras = self.state.extras
        try:
            if extras.get("index_job") is None and index_needed(retrieval=self.retrieval):
                with _LOCK:
                    if extras.get("index_job") is None:
                        extras["index_job"] = self.state.queue.submit(index_job(retrieval=self.retrieval))
            self.job = extras.get("index_job")
        except Exception as e:  # no index now: the first search builds it, as it always could
            log.warning("the retrieval index could not be started in the background: %s", e)
        self.checked.set()
        if self.on_known is not None:
            self.on_known()

    def owns(self, job_id: int) -> bool:
        """Whether ``job_id`` is the build."""
        return self.job is not None and job_id == self.job.id

    @property
    def building(self) -> bool:
        """The build is queued or running (an optimisation started now waits behind it)."""
        return self.job is not None and not self.job.finished

    def draw(self, e: JobEvent) -> None:
        """One event of the build on :attr:`line` (widget trait sets only: any thread)."""
        if not e.final:
            share = f": {e.step / e.total:.0%}" if e.total else ""
            text = f"{stage(e.stage or 'index', e.total, e.item)}{share}"  # the kernels' compile, then the index
        elif e.state == JobState.DONE:
            text = "the retrieval index is ready (cached)"
        else:
            text = f"the retrieval index was not built ({e.state.value}): the first optimisation builds it"
        self.line.value = f"<span style='color:#555'>{html.escape(text)}</span>"
