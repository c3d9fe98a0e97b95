"""The compiled kernels' first run after an install, said and paid up front.

numba compiles the renderer's, the compiled loss's and the retrieval index's kernels the first time they run after an
install (about 20 s on two cores) and keeps them in its disk cache (``cache=True``), so every later run loads them
in a fraction of a second. Without a word, the first imitation on a fresh machine simply took twice as long.
:func:`kernels_compiled` says whether that compilation has happened; :func:`compile_kernels` runs each kernel once,
on a tiny input of the types an imitation passes, through the same public paths
(:class:`~studio.sim.shadow.ShadowRenderer`, :class:`~studio.imitate.rendered_loss.RenderedLoss`,
:class:`~studio.imitate.retrieval.RetrievalIndex`). An :class:`~studio.imitate.still.Imitator` calls
:func:`compile_first` before its first roll search or imitation: a log line and the stage "compile" say why the
first run waits.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn, report
from studio.home import cache_lock
from studio.imitate.config import LossConfig
from studio.imitate.index_chunks import pack_crops
from studio.imitate.losses import ImageLoss
from studio.imitate.rendered_loss import PARALLEL_FROM, RenderedLoss
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
from studio.sim.raster import SERIAL_BELOW
from studio.sim.shadow import ShadowRenderer

log = logging.getLogger(__name__)

STAGE = "compile"  # the progress stage while the kernels compile
WAITING = "waiting for another process compiling them"  # the stage's item while another process compiles
MESSAGE = (
    "first run after this install: compiling the renderer's and the losses' kernels (about 20 s on two cores, "
    "once; numba keeps them on disk for every later run)"
)


def _kernels() -> list:
    """The numba dispatchers an imitation runs (each with its own disk cache)."""
    from studio.imitate import rendered_loss, retrieval
    from studio.sim import raster

    return [
        raster.render_into, raster.render_into_serial, rendered_loss._scores_parallel, rendered_loss._scores_serial,
        rendered_loss.crop_batch, retrieval._best_rows, raster.fk_batch_serial, raster.fk_batch,
    ]  # fmt: skip


def kernels_compiled() -> bool:
    """Whether every kernel of an imitation has compiled code in numba's disk cache (its index file there). True
    when numba's cache is laid out in a way not known here: then nothing is said, and the kernels compile as they
    always did."""
    for kernel in _kernels():
        try:
            index = kernel._cache._cache_file._index_path  # numba's own record of what it has compiled
        except AttributeError:
            return True
        if not os.path.exists(index):
            return False
    return True


def compile_kernels(renderer: ShadowRenderer, loss_cfg: LossConfig) -> float:
    """Run each kernel once with the types an imitation passes: compiled now, or loaded from numba's disk cache.
    Returns the seconds it took."""
    t0 = time.perf_counter()
    hand = renderer.hand
    pose = (hand.lower + hand.upper) / 2  # (21,) rad: the middle of every joint's range
    one = renderer.render_one(pose)  # the serial kernel
    poses = np.tile(pose, (max(PARALLEL_FROM, SERIAL_BELOW), 1))
    many = renderer.render(poses)  # the threaded kernel
    renderer.fk(poses[:1])  # FK of a few poses (the collision checks' frames) …
    renderer.fk(poses)  # … and of many
    loss = RenderedLoss(ImageLoss(one, replace(loss_cfg, use_clip=False), None, one))  # the compiled loss: no CLIP
    loss(many[:1])  # the serial score
    loss(many)  # the threaded score
    cfg = RetrievalConfig()
    bits = pack_crops(many[:4], cfg.crop, cfg.pad)  # the crops of the index's build
    RetrievalIndex(np.tile(pose, (4, 1)).astype(np.float32), bits, cfg, "compile").best(one[None], loss_cfg)
    return time.perf_counter() - t0


def compile_first(renderer: ShadowRenderer, loss_cfg: LossConfig, progress: ProgressFn | None = None) -> None:
    """Compile the kernels now when this install has not yet, saying so (log line, stage "compile"); nothing when
    it has. One process of the machine compiles at a time (:func:`studio.home.cache_lock` beside numba's cache):
    another one that starts meanwhile waits for it, saying so, and then loads the kernels from the disk cache."""
    if kernels_compiled():
        return
    lock = _lock_path()
    with contextlib.nullcontext(True) if lock is None else cache_lock(lock, on_wait=lambda: _waiting(progress)):
        if kernels_compiled():  # another process compiled them while this one waited
            report(progress, STAGE, 1, 1)
            return
        log.info(MESSAGE)
        report(progress, STAGE, 0, 1)
        seconds = compile_kernels(renderer, loss_cfg)
        log.info("the kernels are compiled (%.1f s)", seconds)
        report(progress, STAGE, 1, 1)


def _waiting(progress: ProgressFn | None) -> None:
    log.info("another process is compiling the renderer's and the losses' kernels; waiting for it")
    report(progress, STAGE, 0, 1, item=WAITING)


def _lock_path() -> Path | None:
    """The compile's lock file, in numba's cache folder of the first kernel (None: its layout is not known here)."""
    try:
        return Path(_kernels()[0]._cache._cache_file._index_path).parent / "studio-kernels.lock"
    except AttributeError:
        return None
