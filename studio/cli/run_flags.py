"""The flags of every verb that optimises keyframes or plans a show, defined once (DESIGN §5.2, §5.14).

- :func:`add_budget_flags`: ``--preset studio|paper`` (:data:`studio.imitate.config.PRESETS`, the same names on
  ``imitate``, ``imitate-video``, ``evaluate``, ``evaluate-video``, ``project run`` and ``demo``), then the budget
  flags that override single fields of it, only when given: ``--search-batch/--search-iterations`` (a keyframe
  searched from scratch: a still, a video's first keyframe, every keyframe when independent),
  ``--next-batch/--next-iterations`` (a keyframe that continues from the one before it; video verbs),
  ``--refine-method/-steps/-restarts/-popsize/-sigma0``, ``--sweep-starts/-draws/-passes``, the video verbs'
  ``--joint-generations/-window/-popsize/-sigma0/--joint-both-orders``, ``--candidates``,
  ``--retrieve/--no-retrieve``, ``--no-refine``, the video verbs' ``--mode``, ``--expressive``, ``--temporal``, and
  ``--seed`` (every search and refinement). ``--help`` shows the studio preset's values as the defaults.
- :func:`add_show_flags`: ``--allow-late``, the servo limits (``--velocity-scale``, ``--acceleration``,
  ``--jerk``) and how sources share the show clock (``--still-hold-s``, ``--gap-s``).
- :func:`add_engine_flags`: ``--model``, ``--device``, ``--threads``, ``--quiet`` and the CLIP flags.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from studio.cli.clip_flags import add_clip_arguments
from studio.cli.device_flags import add_device_flags
from studio.cli.flags import SEED_RANGE, add_config_flags, config_from_args, dest_of, given, ranged
from studio.cli.progress import add_quiet_flag
from studio.imitate.config import (
    METHODS,
    MODES,
    PRESET_WORDS,
    PRESETS,
    STUDIO,
    JointConfig,
    RefineConfig,
    SearchConfig,
    SequenceConfig,
    SweepConfig,
)
from studio.motion.limits import LimitsConfig
from studio.motion.timing import TimingConfig

BUDGETS = (  # (flag prefix, the SequenceConfig field, its config class, the fields with flags, video verbs only)
    ("search-", "first", SearchConfig, ("batch", "iterations"), False),
    ("next-", "next", SearchConfig, ("batch", "iterations"), True),
    ("refine-", "refine", RefineConfig, ("method", "steps", "restarts", "popsize", "sigma0"), False),
    ("sweep-", "sweep", SweepConfig, ("starts", "draws", "passes"), False),
    ("joint-", "joint", JointConfig, ("generations", "window", "popsize", "sigma0", "both_orders"), True),
)
VIDEO_FIELDS = ("mode", "expressive", "temporal", "keep_clock", "clock_margin")  # fields only a video uses
LIMITS = ("velocity_scale", "acceleration", "jerk")


def add_budget_flags(parser: argparse.ArgumentParser, video: bool = True, modes: bool = True) -> None:
    """``--preset`` and the budget flags over it (module doc); ``video``: with the flags of keyframes that follow
    one another (``--next-*``, and with ``modes`` ``--mode``, ``--expressive``, ``--temporal``)."""
    base = PRESETS[STUDIO]
    parser.add_argument("--preset", choices=tuple(PRESETS), default=STUDIO,
                        help="budgets of every keyframe: "
                             + ", ".join(f"{name} = {words}" for name, words in PRESET_WORDS.items())
                             + f"; the flags below override single fields (default: {STUDIO})")  # fmt: skip
    for prefix, name, cls, names, video_only in BUDGETS:
        if video or not video_only:
            add_config_flags(parser, cls, names, prefix=prefix, base=getattr(base, name), base_name=f"{STUDIO}")
    fields = ("candidates", "retrieve", *(VIDEO_FIELDS if video and modes else ()))
    add_config_flags(parser, SequenceConfig, [f for f in fields if f != "mode"], base=base, base_name=STUDIO)
    if video and modes:
        parser.add_argument("--mode", choices=MODES, default=base.mode,
                            help=f"independent: each keyframe from scratch; sequential: from the previous keyframe's "
                                 f"pose (default: {base.mode})")  # fmt: skip
    parser.add_argument("--no-refine", action="store_true",
                        help="keep the searched poses (no rendered-shadow refinement)")  # fmt: skip
    parser.add_argument("--seed", type=ranged(int, SEED_RANGE), default=None, metavar="N",
                        help="seed of every search and refinement (default: the preset's)")  # fmt: skip
    for action in parser._actions:
        if action.dest == "refine_method":
            action.choices = METHODS


def _given_fields(args: argparse.Namespace, cls: type, prefix: str = "") -> dict:
    """The fields of ``cls`` whose ``--PREFIX-FIELD`` flag was on the command line, with their values."""
    dests = {f.name: dest_of(prefix, f.name) for f in dataclasses.fields(cls)}
    return {name: getattr(args, dest) for name, dest in dests.items() if given(args, dest)}


def sequence_from_args(args: argparse.Namespace) -> SequenceConfig:
    """``--preset``'s :class:`SequenceConfig` with every budget flag that was given applied over it, and ``--seed``
    on every search and refinement."""
    base = PRESETS[args.preset]
    seed = {} if args.seed is None else {"seed": args.seed}
    budgets = {
        name: dataclasses.replace(getattr(base, name), **_given_fields(args, cls, prefix), **seed)
        for prefix, name, cls, _, _ in BUDGETS
    }
    own = _given_fields(args, SequenceConfig)
    if "mode" in args:
        own["mode"] = args.mode
    own["refine_enabled"] = base.refine_enabled and not args.no_refine
    return dataclasses.replace(base, **own, **budgets)


def add_show_flags(parser: argparse.ArgumentParser, allow_late: bool = False, layout: bool = True) -> None:
    """``--allow-late/--no-allow-late`` (default ``allow_late``), the servo limits and, with ``layout``, how sources
    share the show clock (``--still-hold-s``, ``--gap-s``)."""
    from studio.project.show_timing import ShowLayout

    add_config_flags(parser, TimingConfig, ("allow_late",), base=TimingConfig(allow_late=allow_late))
    add_config_flags(parser, LimitsConfig, LIMITS)
    if layout:
        add_config_flags(parser, ShowLayout)


def run_config_from_args(args: argparse.Namespace):
    """The :class:`~studio.project.run.RunConfig` of the budget and show flags."""
    from studio.motion.plan import PlanConfig
    from studio.project.run import RunConfig
    from studio.project.show_timing import ShowLayout

    return RunConfig(
        sequence=sequence_from_args(args), plan=PlanConfig(limits=config_from_args(args, LimitsConfig)),
        allow_late=args.allow_late, layout=config_from_args(args, ShowLayout),
    )  # fmt: skip


def add_engine_flags(parser: argparse.ArgumentParser, zero_threads: bool = False) -> None:
    """``--model``, ``--device``, ``--threads``, ``--quiet`` and the CLIP flags."""
    parser.add_argument("--model", type=Path, default=None, help="self-model checkpoint (default: the shipped model)")
    add_device_flags(parser, zero_threads)
    add_quiet_flag(parser)
    add_clip_arguments(parser)
