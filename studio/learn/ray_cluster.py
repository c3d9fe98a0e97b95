"""The Ray side of :func:`studio.learn.fanout.fan_out`: a Ray to run on, and one actor per worker fed item by item.

The only module that imports Ray (DESIGN §3), and only when a fan-out asks for it. ``cfg.ray == "local"`` starts a
Ray on this machine for the run (``num_cpus`` = what the actors reserve; no dashboard; Ray 2.60's own servers listen
on every interface whatever the node address, README "The network") and
shuts it down after; an address (``"auto"``, ``"10.0.0.5:6379"``) joins a running cluster (``ray start --head`` on
one machine, ``ray start --address HEAD:6379`` on the others) and leaves it running. A Ray already initialised in
this process (a notebook, the tests' shared local Ray) is used as it is and left running.

Actors are set up once (their task's ``setup()``: models loaded once per worker) and each is handed the next item as
soon as it returns one, so uneven items keep every worker busy. ``cancel`` kills the actors (running items stop at
once). The workers import ``studio`` from their own Python: on a cluster, install the project on every machine and
keep data on a path every machine sees.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import ray

from studio.errors import StudioError, stopped

__all__ = ["RayUnavailable", "ray_for", "run_on_ray"]

log = logging.getLogger(__name__)
POLL_S = 0.2  # how often the driver looks at ``cancel`` while items run, s
CONNECT_S = 5.0  # how long a cluster's HOST:PORT gets to answer before the run is refused, s


class RayUnavailable(StudioError):
    """No Ray to run on: the address did not answer, or a local Ray did not start."""


class _Host:
    """An actor holding one set-up task."""

    def __init__(self, task: Any):
        task.setup()
        self.task = task

    def run(self, item: Any) -> Any:
        return self.task(item)


@contextlib.contextmanager
def ray_for(address: str, cpus: float, gpus: float) -> Iterator[None]:
    """Ray initialised for a fan-out (module doc); a Ray this context started is shut down at its end."""
    if ray.is_initialized():
        yield
        return
    local = address == "local"
    if not local:
        _answers(address)
    try:
        if local:
            ray.init(num_cpus=max(1, round(cpus)), num_gpus=round(gpus) if gpus else None, include_dashboard=False,
                     dashboard_host="127.0.0.1", logging_level=logging.WARNING, log_to_driver=False,
                     configure_logging=False)  # fmt: skip
        else:
            ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False, configure_logging=False)
    except (ConnectionError, RuntimeError, ValueError) as e:
        what = "start a local Ray" if local else f"join the Ray cluster at {address}"
        raise RayUnavailable(f"could not {what}: {e} (start one with `ray start --head`, or use --ray local)") from e
    try:
        yield
    finally:
        ray.shutdown()


def _answers(address: str) -> None:
    """Refuse a ``HOST:PORT`` where nothing answers, in one line and within ``CONNECT_S`` (Ray itself would retry
    for minutes, printing warnings); "auto" and other forms are left to Ray."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or "://" in address:
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_S).close()
    except OSError as e:
        raise RayUnavailable(f"could not join the Ray cluster at {address}: nothing answers there ({e}); start one "
                             "with `ray start --head`, or give --ray alone for a local Ray") from e  # fmt: skip


def run_on_ray(
    task: Any,
    items: list[Any],
    take: Callable[[], int | None],
    cfg: Any,
    finished: Callable[[int, Any], None],
    cancel: threading.Event | None,
    failed: Callable[[Sequence[Any], int, BaseException], Exception],
) -> None:
    """``task`` over ``items`` (growing as results bring follow-ups; ``take()`` hands out the next one's index, None
    when none is left now) on ``cfg.workers`` actors (module doc); ``finished(i, result)`` as each returns, then
    every idle actor is fed."""
    n = cfg.workers
    with ray_for(cfg.ray, n * cfg.cpus_per_worker, n * cfg.gpus_per_worker):
        host = ray.remote(num_cpus=cfg.cpus_per_worker, num_gpus=cfg.gpus_per_worker)(_Host)
        actors = [host.remote(task) for _ in range(n)]
        flying: dict[Any, tuple[int, Any]] = {}
        idle = list(actors)

        def feed() -> None:
            while idle and (i := take()) is not None:
                actor = idle.pop(0)
                flying[actor.run.remote(items[i])] = (i, actor)

        try:
            feed()
            while flying and not stopped(cancel):
                ready, _ = ray.wait(list(flying), num_returns=1, timeout=POLL_S)
                for ref in ready:
                    i, actor = flying.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayError as e:
                        cause = getattr(e, "cause", None) or e
                        raise failed(items, i, cause) from e
                    finished(i, result)
                    idle.append(actor)
                feed()
        finally:
            for actor in actors:
                ray.kill(actor)
