"""How a source becomes targets, on the command line: the flags of ``project new``, ``imitate``, ``imitate-video``
and ``evaluate``, defined once, and the :class:`~studio.project.pipeline.SourceSettings` they make.

- videos: ``--hz``, ``--fps`` (a frame folder's rate), ``--threshold`` (grey level of shadow footage), ``--size``;
- stills: ``--still-threshold`` (a fixed level, always used: Otsu does not take over on a bright backdrop) and
  ``--still-pocket-reach`` (0: crease pockets left as they are);
- both: ``--otsu`` (Otsu's level wherever no fixed level is given: ``--still-threshold 60 --otsu`` fixes the
  stills and thresholds the videos by Otsu) and ``--tau`` (keyframes by shape);
- raw colour footage: ``--box X,Y,W,H`` or ``--first-mask PNG``, the object in the first frame;
- the mount: ``--roll auto|DEG`` (auto: the studio picks one roll for the whole show).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args, given
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig


def parse_box(text: str) -> tuple[int, int, int, int]:
    """``"x,y,w,h"`` (source pixels) → a box; an argparse error otherwise."""
    try:
        box = tuple(int(v) for v in text.split(","))
    except ValueError:
        box = ()
    if len(box) != 4 or box[2] < 1 or box[3] < 1 or box[0] < 0 or box[1] < 0:
        raise argparse.ArgumentTypeError(f"expected x,y,w,h in source pixels (w, h ≥ 1), got {text!r}")
    return box  # type: ignore[return-value]


def add_source_flags(
    parser: argparse.ArgumentParser, video: bool = True, still: bool = True, size: bool = False
) -> None:
    """The flags of the module doc that apply: ``video`` (sampling, threshold, keyframes, segmentation), ``still``
    (``--still-threshold``, ``--still-pocket-reach``), ``size`` (``--size``: a project's frame side; other verbs
    work at the model's)."""
    if video:
        add_config_flags(parser, VideoConfig, ("hz", "fps", "threshold", *(("size",) if size else ())))
    if still:
        add_config_flags(parser, TargetConfig, ("threshold", "pocket_reach"), prefix="still-")
    parser.add_argument("--otsu", action="store_true", help="Otsu's threshold instead of a fixed level")
    add_roll_flag(parser)
    if video:
        add_config_flags(parser, KeyframeConfig, ("tau",))
        seg = parser.add_mutually_exclusive_group()
        seg.add_argument("--box", type=parse_box, default=None, metavar="X,Y,W,H",
                         help="raw colour footage: the object's box in the first frame, source pixels; it is "
                              "segmented through the video")  # fmt: skip
        seg.add_argument("--first-mask", type=Path, default=None, metavar="PNG",
                         help="raw colour footage: the object's mask in the first frame (white or nonzero = object, "
                              "the source's size), segmented through the video")  # fmt: skip


def roll_arg(text: str) -> str | float:
    """``auto`` or an angle in degrees in [-360, 360] (:func:`studio.sim.roll.parse_roll`); an argparse error
    otherwise."""
    from studio.sim.roll import parse_roll

    try:
        if parse_roll(text) is None:
            return "auto"
        deg = float(text)
    except ValueError:
        deg = float("inf")
    if not -360 <= deg <= 360:  # not an angle, or more than a turn (a slip of the keyboard)
        raise argparse.ArgumentTypeError(f"expected auto or an angle in degrees in [-360, 360], got {text!r}")
    return deg


def add_roll_flag(parser: argparse.ArgumentParser) -> None:
    """``--roll auto|DEG``: the hand's mount roll about the light axis (DESIGN §1)."""
    parser.add_argument("--roll", type=roll_arg, default="auto", metavar="auto|DEG",
                        help="the hand's mount roll about the light axis: auto (the studio picks one for the whole "
                             "show; default) or degrees, counter-clockwise as the audience sees it (0: upright, the "
                             "paper's rig)")  # fmt: skip


def still_config_from_args(args: argparse.Namespace) -> TargetConfig:
    """``--still-threshold N`` (a fixed level, always used) or ``--otsu``; neither: the defaults (Otsu by itself on a
    backdrop that is not dark)."""
    fixed = "still_threshold" in args and given(args, "still_threshold")
    if args.otsu and not fixed:
        return config_from_args(args, TargetConfig, prefix="still-", threshold=None)
    return config_from_args(args, TargetConfig, prefix="still-", auto_otsu=not fixed)


def video_config_from_args(args: argparse.Namespace, **overrides) -> VideoConfig:
    """The :class:`VideoConfig` of the video flags (``--otsu`` without ``--threshold``: Otsu's level), then
    ``overrides``."""
    fixed = "threshold" in args and given(args, "threshold")
    extra = {"threshold": None} if args.otsu and not fixed else {}
    return config_from_args(args, VideoConfig, **(extra | overrides))


def source_settings_from_args(args: argparse.Namespace, **video_overrides):
    """The :class:`~studio.project.pipeline.SourceSettings` of these flags (``video_overrides``: e.g. the model's
    frame ``size``)."""
    from studio.imitate.config import LossConfig
    from studio.project.pipeline import SourceSettings

    return SourceSettings(
        video=video_config_from_args(args, **video_overrides), still=still_config_from_args(args),
        clustering=KeyframeConfig(tau=args.tau) if "tau" in args else KeyframeConfig(), weights=LossConfig(),
        box=getattr(args, "box", None), first_mask=getattr(args, "first_mask", None),
        roll=getattr(args, "roll", "auto"),
    )  # fmt: skip
