"""One still target end to end in one call (``studio.imitate_still``): the notebook's and the README's first step.

For many targets keep an :class:`~studio.imitate.still.Imitator`: it loads the model once.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn
from studio.imitate.config import RefineConfig, SearchConfig
from studio.imitate.still import Imitator
from studio.imitate.still_result import ImitationResult
from studio.learn.threads import DEFAULT_THREADS, torch_threads
from studio.sim.roll import parse_roll
from studio.targets.expressive import still_expressive
from studio.targets.images import TargetConfig


def imitate_still(
    target: np.ndarray | str | Path,
    model_path: Path | None = None,
    search: SearchConfig | None = None,
    refine: RefineConfig | None = None,
    target_cfg: TargetConfig | None = None,
    device: str | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    threads: int | None = DEFAULT_THREADS,
    roll: str | float = "auto",
) -> ImitationResult:
    """One still target end to end with the shipped model (or ``model_path``), CLIP off, holes as expressive region,
    on a mount rolled about the light axis by ``roll``: ``"auto"`` (the studio's default, as on every face: the roll
    under which the hand casts the target's outline best, :meth:`Imitator.choose_roll`, stages "index" and "roll"),
    or degrees (0: the paper's upright rig). ``result.roll`` (rad) is the mount the pose was chosen for: plan its
    show with ``Keyframes.at(..., roll=result.roll)`` so that the show file says how to mount the hand. ``progress``
    and ``cancel`` as :meth:`Imitator.imitate` (its stages, its partial result; cancelled while the roll is chosen:
    an upright, cancelled result).

    ``target`` is an image path (loaded with ``target_cfg``) or a mask ``(R, R)`` framed at the model's resolution
    (``load_target(path, size=R)``). ``threads``: torch CPU threads for this call, restored after
    (:data:`~studio.learn.threads.DEFAULT_THREADS`; None leaves torch's setting). For many targets keep an
    :class:`Imitator` instead: it loads the model once. A ValueError for a roll that is neither.
    """
    rad = parse_roll(roll)  # a bad roll is said before the model loads
    with torch_threads(threads):
        return _imitate_still(target, model_path, search, refine, target_cfg, device, progress, cancel, rad)


def _imitate_still(target, model_path, search, refine, target_cfg, device, progress, cancel, roll) -> ImitationResult:
    with Imitator(model_path=model_path, search=search, refine=refine, device=device) as imitator:
        if isinstance(target, (str, Path)):
            mask = imitator.load(Path(target), target_cfg)
        else:
            mask = np.asarray(target)
            r = imitator.resolution
            if mask.shape != (r, r):
                raise ValueError(
                    f"target mask is {mask.shape}; this model works at ({r}, {r}): load_target(path, size={r})"
                )
        if roll is None:  # auto: chosen on the outline, as a project's run chooses it
            choice = imitator.choose_roll(mask[None], progress=progress, cancel=cancel)
            roll = 0.0 if choice is None else choice.roll
        return imitator.imitate(mask, still_expressive(mask), progress=progress, cancel=cancel, roll=roll)
