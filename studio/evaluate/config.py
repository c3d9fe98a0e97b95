"""The evaluation stage's configs: how Table 1 runs its baselines (torch-free, so ``evaluate`` builds its flags
quickly; the engine: :mod:`studio.evaluate.table1` and :mod:`studio.evaluate.baselines`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class NNConfig:
    """How Nearest Neighbour searches the training images."""

    rank_size: int = 64  # side of the aligned crops every training image is ranked at, pixels
    shortlist: int = 32  # best-ranked images re-scored exactly by the target's ImageLoss (base loss)
    batch: int = 4096  # training crops ranked per batch
    chunk: int = 2048  # training images unpacked and aligned at once while precomputing


@dataclass(frozen=True)
class EvalConfig:
    """How ``evaluate`` runs the baselines (ours is configured by the :class:`~studio.imitate.still.Imitator`)."""

    seed: int = 0  # seed of the Random baseline's draws [0, 4294967295]
    nn: NNConfig = field(default_factory=NNConfig)  # Nearest Neighbour search settings
    score_resolution: int = 0  # render and score every pose at this side, pixels (0: the model's; paper 256) [0, 2048]
    roll: str | float = "auto"  # rows of ours on a rolled mount beside the paper rig's: "auto", degrees, 0 = none

    def __post_init__(self) -> None:
        if self.score_resolution and self.score_resolution < 8:
            raise ValueError(f"score_resolution must be 0 (the model's) or ≥ 8 pixels, got {self.score_resolution}")
        if not (self.roll == "auto" or isinstance(self.roll, (int, float))):
            raise ValueError(f"roll must be 'auto' or degrees, got {self.roll!r}")

    @property
    def roll_rows(self) -> str | None:
        """The name of the rolled rows ("roll auto", "roll 30°"), None when there are none (roll 0)."""
        if self.roll == "auto":
            return "roll auto"
        return f"roll {float(self.roll):g}°" if float(self.roll) else None
