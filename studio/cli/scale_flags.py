"""``--workers N``, ``--ray [ADDRESS]`` and the Ray actors' resources: how a verb spreads its work
(:class:`studio.learn.fanout.FanoutConfig`), defined once for every verb that fans out."""

from __future__ import annotations

import argparse

from studio.cli.flags import add_config_flags, config_from_args
from studio.learn.fanout import FanoutConfig


def add_fanout_flags(parser: argparse.ArgumentParser) -> None:
    """The fan-out flags, in their own group."""
    g = parser.add_argument_group("spreading the work")
    add_config_flags(g, FanoutConfig, ("workers", "cpus_per_worker", "gpus_per_worker"))
    g.add_argument("--ray", nargs="?", const="local", default="", metavar="ADDRESS",
                   help="run the workers as Ray actors: alone, on a local Ray started for the run; with an "
                        "address ('auto', HOST:6379), on that cluster (default: no Ray)")  # fmt: skip


def fanout_from_args(args: argparse.Namespace) -> FanoutConfig:
    """The :class:`FanoutConfig` the flags ask for."""
    return config_from_args(args, FanoutConfig, ray=(args.ray or "").strip())


def models_from_args(args: argparse.Namespace):
    """The self-model and CLIP each worker loads (a spread table or project run), as the engine flags say."""
    from studio.evaluate.worker_models import ModelRecipe
    from studio.imitate.still import DEFAULT_MODEL

    return ModelRecipe(str(args.model or DEFAULT_MODEL), args.device, args.threads or 1, args.clip_weights,
                       args.clip_model, not args.no_clip)  # fmt: skip
