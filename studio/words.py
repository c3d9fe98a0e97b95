"""Counts in words that agree with the number, the one way every message of the studio writes them (the CLI, the
engine's reports and errors, the notebook's panels): ``1 keyframe``, ``3 keyframes``, never ``keyframe(s)``.

    count(3, "keyframe")   # '3 keyframes'
    plural("collides", 2)  # 'collide' (a verb agrees too)
"""

from __future__ import annotations

IRREGULAR = {"was": "were", "is": "are", "it": "them", "collides": "collide", "belongs": "belong"}  # not word + "s"


def plural(word: str, n: int) -> str:
    """``word`` for one, its plural for any other count (``keyframe`` → ``keyframes``, ``was`` → ``were``)."""
    if n == 1:
        return word
    if word in IRREGULAR:
        return IRREGULAR[word]
    return word + ("es" if word.endswith(("s", "x", "ch", "sh")) else "s")


def count(n: int, word: str) -> str:
    """``1 keyframe``, ``0 keyframes``, ``200,000 poses``: the number and the word that agrees with it."""
    return f"{n:,} {plural(word, n)}"
