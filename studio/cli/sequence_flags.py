"""The flags of a sequence imitation (``imitate-video``, ``evaluate-video``) and the :class:`SequenceConfig` they make.

``--preset cpu|paper`` picks :data:`CPU_SEQUENCE` (the default) or :data:`PAPER_SEQUENCE`; the budget flags
(``--first-batch/--first-iters``, ``--next-batch/--next-iters``, ``--refine-steps/--refine-restarts``,
``--sweep-starts/--sweep-draws/--sweep-passes`` for the seeds of keyframes searched from scratch) and the
sequence fields a verb exposes (``--mode``, ``--expressive``, ``--temporal``, ``--candidates``, ``--no-refine``) each
override one field of it, only when given: ``--help`` shows the CPU preset's values as the defaults, and ``--preset
paper --first-batch 8`` keeps every other paper size. ``--seed`` (default: the preset's seeds) seeds every search
and refinement. Types, defaults, help and ranges come from the config fields (:mod:`studio.cli.flags`)::

    add_sequence_flags(p, ("mode", "expressive", "temporal", "candidates", "refine_enabled"))
    cfg = sequence_config_from_args(args)
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Iterable

from studio.cli.flags import add_config_flags, dest_of, given, ranged
from studio.cli.still_flags import SWEEP_FIELDS
from studio.imitate.config import (
    CPU_SEQUENCE,
    MODES,
    PAPER_SEQUENCE,
    RefineConfig,
    SearchConfig,
    SequenceConfig,
    SweepConfig,
)

PRESETS = {"cpu": CPU_SEQUENCE, "paper": PAPER_SEQUENCE}  # --preset: the search/refine sizes
BUDGETS = (  # (flag prefix, the preset's field, its config class, the fields with flags)
    ("first-", "first", SearchConfig, ("batch", "iterations")),
    ("next-", "next", SearchConfig, ("batch", "iterations")),
    ("refine-", "refine", RefineConfig, ("steps", "restarts")),
    ("sweep-", "sweep", SweepConfig, SWEEP_FIELDS),
)


def add_sequence_flags(parser: argparse.ArgumentParser, fields: Iterable[str] = ("candidates",)) -> None:
    """``--preset``, the search/refine budget flags over it, flags for the :class:`SequenceConfig` ``fields`` (with
    their CPU-preset defaults; ``mode`` as ``--mode independent|sequential``, ``refine_enabled`` as
    ``--no-refine``) and ``--seed``."""
    parser.add_argument("--preset", choices=tuple(PRESETS), default="cpu",
                        help="search/refine budgets: cpu = CPU_SEQUENCE (minutes a sequence on 2 cores), paper = "
                             "PAPER_SEQUENCE (the paper's sizes, for a GPU); the budget flags override single "
                             "fields (default: cpu)")  # fmt: skip
    for prefix, name, cls, names in BUDGETS:
        add_config_flags(parser, cls, names, prefix=prefix, base=getattr(CPU_SEQUENCE, name),
                         base_name=f"CPU_SEQUENCE.{name}", aliases={"iterations": "iters"})  # fmt: skip
    fields = tuple(fields)
    if "refine_enabled" in fields:
        parser.add_argument("--no-refine", action="store_true",
                            help="keep the searched poses (no rendered-shadow refinement)")  # fmt: skip
    if "mode" in fields:
        parser.add_argument("--mode", choices=MODES, default=CPU_SEQUENCE.mode,
                            help=f"independent: each keyframe from scratch; sequential: from the previous keyframe's "
                                 f"pose (default: {CPU_SEQUENCE.mode})")  # fmt: skip
    plain = tuple(f for f in fields if f not in ("mode", "refine_enabled"))
    add_config_flags(parser, SequenceConfig, plain, base=CPU_SEQUENCE, base_name="CPU_SEQUENCE")
    parser.add_argument("--seed", type=ranged(int, "[0, ∞)"), default=None, metavar="N",
                        help="seed of the searches and refinements (default: the preset's)")  # fmt: skip


def _given_fields(args: argparse.Namespace, cls: type, prefix: str = "") -> dict:
    """The fields of ``cls`` whose ``--PREFIX-FIELD`` flag was on the command line, with their values."""
    dests = {f.name: dest_of(prefix, f.name) for f in dataclasses.fields(cls)}
    return {name: getattr(args, dest) for name, dest in dests.items() if given(args, dest)}


def sequence_config_from_args(args: argparse.Namespace) -> SequenceConfig:
    """``--preset``'s :class:`SequenceConfig` with every flag of :func:`add_sequence_flags` that was given applied
    over it (``--mode`` and ``--no-refine`` where the verb has them), and ``--seed`` on every search and
    refinement."""
    base = PRESETS[args.preset]
    seed = {} if args.seed is None else {"seed": args.seed}
    budgets = {
        name: dataclasses.replace(getattr(base, name), **_given_fields(args, cls, prefix), **seed)
        for prefix, name, cls, _ in BUDGETS
    }
    own = _given_fields(args, SequenceConfig)
    if "mode" in args:
        own["mode"] = args.mode
    if "no_refine" in args:
        own["refine_enabled"] = base.refine_enabled and not args.no_refine
    return dataclasses.replace(base, **own, **budgets)
