"""Where the engine's torch work runs: ``--device`` and ``--threads``, and :func:`torch_threads` that applies it.

One torch thread is far faster than torch's default when the 2 CPU cores are shared, and close to it otherwise, so
``--threads`` defaults to 1 everywhere; the table verbs also take 0 for torch's own default."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator

from studio.cli.flags import ranged


def add_device_flags(parser: argparse.ArgumentParser, zero_threads: bool = False) -> None:
    """``--device cpu|cuda`` (for the self-model and CLIP) and ``--threads N`` (≥ 1; ≥ 0 with ``zero_threads``,
    0 = torch's default)."""
    parser.add_argument("--device", default=None,
                        help="cpu or cuda, for the self-model and CLIP (default: cuda when present)")  # fmt: skip
    lowest = "0 = torch's default" if zero_threads else "≥ 1"
    parser.add_argument("--threads", type=ranged(int, "[0, ∞)" if zero_threads else "[1, ∞)"), default=1, metavar="N",
                        help=f"torch CPU threads (default: 1, fastest on shared cores; {lowest})")  # fmt: skip


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with torch on ``n`` CPU threads (0: torch's default), the previous count restored after."""
    import torch

    previous = torch.get_num_threads()
    if n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
