"""CLIP on the command line: ``--clip-weights``, ``--clip-model`` and ``--no-clip``, and the encoder they ask for.

The flags are added without importing torch or open_clip (a verb's parser stays quick); :func:`clip_from_args`
loads the weights only when a command runs (:func:`studio.imitate.clip_loss.load_clip`: local files only).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

    from studio.imitate.clip_loss import ClipImageEncoder


def add_clip_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--clip-weights PATH``, ``--clip-model NAME`` and ``--no-clip`` to a verb's parser."""
    parser.add_argument("--clip-weights", type=Path, default=None, help="local CLIP checkpoint file (never downloaded)")
    parser.add_argument("--clip-model", default="ViT-B-32", help="open_clip model name of the weights")
    parser.add_argument("--no-clip", action="store_true", help="leave the CLIP loss terms out (recorded in outputs)")


def clip_from_args(args: argparse.Namespace, device: str | torch.device = "cpu") -> ClipImageEncoder | None:
    """The encoder the options of :func:`add_clip_arguments` ask for; None with ``--no-clip``."""
    if args.no_clip:
        return None
    from studio.imitate.clip_loss import load_clip

    return load_clip(args.clip_model, weights=args.clip_weights, device=device)
