"""The retrieval index kept once per machine: ``studio.home.cache_dir()/retrieval/index-<key>.npz``, built by one
process at a time.

:func:`cached_index` returns the index from this process, else from its file, else builds it (~30 s for 200,000
poses on 2 cores) and saves it. Several processes may want it at once on a fresh machine: the two workers of
``project run --workers 2``, the notebook's first-use job beside a terminal's run, the test suite's workers. The build
is therefore done under :func:`studio.home.cache_lock` on ``index-<key>.npz.lock`` beside the file: the first
process builds, every other one waits for it (saying so once, stage "index" with the item :data:`WAITING`; a cancel
still stops it), then loads what it saved, so the machine builds each index once.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

from studio.errors import ProgressFn, report
from studio.home import cache_dir, cache_lock
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex, index_key
from studio.learn.fanout import FanoutConfig
from studio.sim.shadow import ShadowRenderer

__all__ = ["cached_index", "index_path", "is_cached"]

log = logging.getLogger(__name__)
WAITING = "waiting for another process or job building it"  # the "index" stage's item while this one waits

_MEMO: dict[str, RetrievalIndex] = {}  # one index per key per process (the studio, evaluate and jobs share it)


def index_path(renderer: ShadowRenderer, cfg: RetrievalConfig | None = None, folder: Path | None = None) -> Path:
    """Where :func:`cached_index` keeps the index for ``renderer``'s hand and rig: ``folder`` (default
    ``cache_dir()/retrieval``) / ``index-<key>.npz``."""
    key = index_key(renderer.hand, renderer, cfg or RetrievalConfig())
    return Path(folder or cache_dir() / "retrieval") / f"index-{key}.npz"


def is_cached(renderer: ShadowRenderer, cfg: RetrievalConfig | None = None, folder: Path | None = None) -> bool:
    """Whether :func:`cached_index` would find the index without building it (in this process, or its file)."""
    cfg = cfg or RetrievalConfig()
    return index_key(renderer.hand, renderer, cfg) in _MEMO or index_path(renderer, cfg, folder).is_file()


def cached_index(
    renderer: ShadowRenderer,
    cfg: RetrievalConfig | None = None,
    folder: Path | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    fanout: FanoutConfig | None = None,
) -> RetrievalIndex | None:
    """The index for ``renderer``'s hand and rig: from this process, else from ``folder`` (default
    ``cache_dir()/retrieval``), else built (logged; stage "index", :meth:`RetrievalIndex.build`) and saved there, by
    one process at a time (module doc). None when ``cancel`` stopped the build or the wait for another process's
    build (nothing is saved or kept; the next call builds again). A build is spread as ``fanout`` says (the same
    index)."""
    cfg = cfg or RetrievalConfig()
    key = index_key(renderer.hand, renderer, cfg)
    if key in _MEMO:
        return _MEMO[key]
    path = index_path(renderer, cfg, folder)
    index = RetrievalIndex.load(path, key)
    if index is None:
        waited: list[bool] = []

        def on_wait() -> None:
            waited.append(True)
            log.info("another process or job is building the retrieval index %s; waiting for it", path.name)
            report(progress, "index", 0, cfg.size, item=WAITING)

        with cache_lock(path.with_name(path.name + ".lock"), cancel, on_wait) as mine:
            if not mine:
                log.info("waiting for the retrieval index cancelled")
                return None
            if waited:
                report(progress, "index", cfg.size, cfg.size, item=WAITING)
            index = RetrievalIndex.load(path, key)  # another process may have built it while this one waited
            if index is None:
                index = _build(renderer, cfg, path, progress, cancel, fanout)
                if index is None:
                    return None
    _MEMO[key] = index
    return index


def _build(
    renderer: ShadowRenderer,
    cfg: RetrievalConfig,
    path: Path,
    progress: ProgressFn | None,
    cancel: threading.Event | None,
    fanout: FanoutConfig | None,
) -> RetrievalIndex | None:
    """Build the index and save it to ``path``; None when cancelled (nothing saved)."""
    log.info("building the retrieval index once: %d collision-free poses → %s", cfg.size, path)
    t0 = time.perf_counter()
    index = RetrievalIndex.build(renderer, cfg, progress=progress, cancel=cancel, fanout=fanout)
    if index is None:
        log.info("retrieval index build cancelled; nothing saved")
        return None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        index.save(path)
    except OSError as exc:  # a read-only cache is no reason to fail: the index lives in this process
        log.warning("could not save the retrieval index to %s (%s); it will be rebuilt next time", path, exc)
    log.info("retrieval index built in %.1f s", time.perf_counter() - t0)
    return index
