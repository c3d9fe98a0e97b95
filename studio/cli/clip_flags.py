"""CLIP on the command line: ``--clip-weights``, ``--clip-model`` and ``--no-clip``, and the one CLIP rule.

The rule is every face's (:func:`studio.imitate.clip_loss.find_clip`): the CLIP terms are on when local weights
are given (``--clip-weights PATH``) or found in a local cache, off otherwise (``--no-clip`` turns them off even
then); one log line says which at the start. The flags are added without importing torch or open_clip (a
verb's parser stays quick); the weights load only when a command runs.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

    from studio.imitate.clip_loss import ClipImageEncoder

log = logging.getLogger("shadow-studio")


def add_clip_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--clip-weights PATH``, ``--clip-model NAME`` and ``--no-clip`` to a verb's parser."""
    parser.add_argument("--clip-weights", type=Path, default=None, metavar="PATH",
                        help="a local CLIP checkpoint (never downloaded; default: one found in the local caches, "
                             "else the CLIP terms are off)")  # fmt: skip
    parser.add_argument("--clip-model", default="ViT-B-32", help="open_clip model name of the weights")
    parser.add_argument("--no-clip", action="store_true", help="leave the CLIP loss terms out even when weights exist")


def clip_from_args(args: argparse.Namespace, device: str | torch.device = "cpu") -> ClipImageEncoder | None:
    """The encoder the CLIP rule gives for these options (None: the terms are off); says which on stderr once."""
    from studio.imitate.clip_loss import find_clip

    clip, line = find_clip(args.clip_weights, args.clip_model, enabled=not args.no_clip, device=device)
    log.info(line)
    return clip
