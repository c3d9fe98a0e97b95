"""Where the engine's torch work runs: ``--device`` and ``--threads``, applied by
:func:`studio.learn.threads.torch_threads`.

``--threads`` defaults to :data:`studio.learn.threads.DEFAULT_THREADS` everywhere (2 on a 2-core machine, measured
there); the table verbs also take 0 for torch's own default. ``--threads`` is bounded
by :data:`MAX_THREADS` (``TrainerConfig.threads``' range, stated once), and ``--device`` is checked as it is read
(:func:`device_arg`): ``cuda`` on a machine without a GPU is one line, at once, not an internal error an hour later.
"""

from __future__ import annotations

import argparse

from studio.cli.flags import field_docs, ranged
from studio.errors import plural
from studio.learn.config import TrainerConfig
from studio.learn.threads import DEFAULT_THREADS

MAX_THREADS = int(field_docs(TrainerConfig)["threads"].range.hi)  # more threads than this only slow torch down
DEVICES = ("cpu", "cuda")  # what --device names (cuda:N picks one GPU)


def device_arg(text: str) -> str:
    """``cpu``, ``cuda`` or ``cuda:N`` when that GPU is there; an argparse error (one line) otherwise."""
    name, _, index = text.strip().lower().partition(":")
    if name not in DEVICES or (index and (name != "cuda" or not index.isdigit())):
        raise argparse.ArgumentTypeError(f"expected cpu or cuda (cuda:N for one GPU), got {text!r}")
    if name == "cuda":
        import torch

        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise argparse.ArgumentTypeError(f"{text}: this machine has no CUDA GPU that torch can use; use cpu")
        if index and int(index) >= count:
            gpus = f"{count} CUDA {plural('GPU', count)}"
            raise argparse.ArgumentTypeError(f"{text}: {gpus} here: cuda:0 to cuda:{count - 1}")
    return text.strip().lower()


def add_device_flags(parser: argparse.ArgumentParser, zero_threads: bool = False) -> None:
    """``--device cpu|cuda`` (for the self-model and CLIP) and ``--threads N`` (≥ 1; ≥ 0 with ``zero_threads``,
    0 = torch's default)."""
    parser.add_argument("--device", type=device_arg, default=None,
                        help="cpu or cuda, for the self-model and CLIP (default: cuda when present)")  # fmt: skip
    lowest = "0 = torch's default" if zero_threads else "≥ 1"
    parser.add_argument("--threads", type=ranged(int, f"[{int(not zero_threads)}, {MAX_THREADS}]"),
                        default=DEFAULT_THREADS, metavar="N",
                        help=f"torch CPU threads (default: {DEFAULT_THREADS}, measured fastest here; {lowest}, "
                             f"≤ {MAX_THREADS})")  # fmt: skip
