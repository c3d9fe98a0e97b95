"""How big a show and a keyframes file may be: the bounds every reader of them checks, stated once (DESIGN §5.12).

A show is planned on the path's 40 Hz grid, timed with Ruckig and sampled at ``rate_hz``, so its memory and time grow
with its duration times its rate. The bounds keep the largest file the studio accepts within this machine (2 CPU
cores, about 24 GiB shared): an hour-long show at 40 Hz is 144,000 samples (~60 MB of JSON, ~25 MB as arrays) and
plans in minutes; a keyframe at ``t: 1e7`` asked for 67 GB of path points before it was refused.

``show.schema.json`` states the same numbers (``tests/test_show.py`` holds them together).
"""

from __future__ import annotations

import math
import numbers
from typing import Any

MAX_SHOW_S = 3600.0  # longest show, s: an hour (a longer performance is several shows)
MAX_RATE_HZ = 1000.0  # highest sample rate of a show, Hz (the servo bus plays 40; a rate is a count per second)
MAX_SAMPLES = 400_000  # most samples in a show file (an hour at 100 Hz with room for the keyframes' own samples)
MAX_SHOW_BYTES = 256 * 2**20  # largest show file read (MAX_SAMPLES rows are ~180 MB of JSON)
MAX_KEYFRAMES = 10_000  # most keyframes planned at once (each is a timed, collision-checked segment: ~0.1 s each)
MAX_SOURCE_FRAME = 10_000_000  # largest source frame index a keyframe may name (a day of video at 100 fps)
MAX_OFFSET_S = 86_400.0  # largest |media offset|, s (a day)
MAX_LIMIT = 1e6  # largest velocity (rad/s), acceleration (rad/s²) or jerk (rad/s³) a show file may state


def is_number(x: Any) -> bool:
    """Whether ``x`` is a JSON number (int or float, numpy's too), not a bool or a string that reads as one."""
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and type(x).__name__ != "bool_"


def number_problem(name: str, x: Any, lo: float, hi: float, unit: str = "") -> str | None:
    """One sentence when ``x`` is not a finite number in ``[lo, hi]`` (None when it is): ``"t is '2.5', a string;
    it must be a number of seconds in [0, 3600]"``."""
    unit = f" {unit}" if unit else ""
    want = f"a number{unit} in [{fmt(lo)}, {fmt(hi)}]"
    if not is_number(x):
        kind = "a string" if isinstance(x, str) else "true/false" if isinstance(x, bool) else type(x).__name__
        return f"{name} is {x!r}, {kind}; it must be {want}"
    if not math.isfinite(x) or not lo <= x <= hi:
        return f"{name} is {fmt(x)}; it must be {want}"
    return None


def fmt(x: float) -> str:
    """A number as a person reads it in a message: ``-1``, ``2.5``, ``1e+07``, ``inf`` (never ``np.float64(-1.0)``)."""
    x = float(x)
    if math.isfinite(x) and x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{x:g}"
