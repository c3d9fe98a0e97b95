"""The flags of a still imitation (``imitate``, ``evaluate``) and the three configs they make.

``--method studio`` (the default) starts from the studio's presets: retrieval first answer, a block sweep of its
best poses, the search seeded by them and scored on the renderer, CMA-ES refinement (``STUDIO_SEARCH``, ``CPU_REFINE``,
``ImitateConfig()``, ``SweepConfig()``); ``--method paper`` from the paper's: a sampled search batch, the self-model's
best, 8 hill-climbing chains × 1000 steps (``CPU_SEARCH``, ``PAPER_REFINE``, ``PAPER_IMITATE``, ``PAPER_SWEEP``).
Each ``--search-*``, ``--refine-*``, ``--sweep-*``, ``--candidates``, ``--retrieve`` or ``--select`` flag given on
the command line then overrides its field of the chosen preset.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import NamedTuple

from studio.cli.flags import add_config_flags, dest_of, given
from studio.imitate.config import (
    CPU_REFINE,
    CPU_SEARCH,
    METHODS,
    PAPER_IMITATE,
    PAPER_REFINE,
    PAPER_SWEEP,
    STUDIO_SEARCH,
    ImitateConfig,
    RefineConfig,
    SearchConfig,
    SweepConfig,
)


class Preset(NamedTuple):
    search: SearchConfig
    refine: RefineConfig
    imitate: ImitateConfig
    sweep: SweepConfig


PRESETS = {
    "studio": Preset(STUDIO_SEARCH, CPU_REFINE, ImitateConfig(), SweepConfig()),
    "paper": Preset(CPU_SEARCH, PAPER_REFINE, PAPER_IMITATE, PAPER_SWEEP),
}
REFINE_FIELDS = ("method", "steps", "restarts", "popsize", "sigma0")
SWEEP_FIELDS = ("starts", "draws", "passes")


def add_still_flags(parser: argparse.ArgumentParser) -> None:
    """``--method``, the search, refinement and candidate flags (defaults shown are the studio preset's)."""
    parser.add_argument(
        "--method", choices=tuple(PRESETS), default="studio",
        help="presets: studio (retrieval, block sweep, seeded search, CMA-ES refinement) or paper (sampled "
             "search, the paper's hill climbing 8 × 1000); the flags below override single fields (default: studio)",
    )  # fmt: skip
    add_config_flags(parser, SearchConfig, ("batch", "iterations"), prefix="search-", base=STUDIO_SEARCH,
                     base_name="STUDIO_SEARCH", aliases={"iterations": "iters"})  # fmt: skip
    add_config_flags(parser, RefineConfig, REFINE_FIELDS, prefix="refine-", base=CPU_REFINE,
                     base_name="CPU_REFINE")  # fmt: skip
    add_config_flags(parser, SweepConfig, SWEEP_FIELDS, prefix="sweep-", base=SweepConfig(), base_name="SweepConfig()")
    add_config_flags(parser, ImitateConfig, ("candidates", "retrieve", "select"))
    for action in parser._actions:
        if action.dest == "refine_method":
            action.choices = METHODS
        elif action.dest == "select":
            action.choices = ("rendered", "model")


def _pick(args: argparse.Namespace, cls: type, prefix: str, base, **overrides):
    given_values = {
        f.name: getattr(args, dest_of(prefix, f.name))
        for f in dataclasses.fields(cls)
        if given(args, dest_of(prefix, f.name))
    }
    return dataclasses.replace(base, **(given_values | overrides))


def still_configs(args: argparse.Namespace, seed: int) -> Preset:
    """The chosen preset with the flags given on the command line applied; ``seed`` for search and refinement."""
    preset = PRESETS[args.method]
    return Preset(
        _pick(args, SearchConfig, "search-", preset.search, seed=seed),
        _pick(args, RefineConfig, "refine-", preset.refine, seed=seed),
        _pick(args, ImitateConfig, "", preset.imitate),
        _pick(args, SweepConfig, "sweep-", preset.sweep, seed=seed),
    )
