"""The learning stage's configs: self-exploration data, networks (architecture) and training, each field a flag
of its verb.

Plain dataclasses with no torch import, so the command line builds its flags from them quickly
(``studio.cli.flags``: a field's trailing comment is its help and may end with its range).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from studio.sim.crop_pad import PAD

if TYPE_CHECKING:
    from studio.sim.shadow import Rig


@dataclass(frozen=True)
class SelfModelConfig:
    """Architecture of the self-model."""

    resolution: int = 256  # output image side (a power of two ≥ 16); paper 256, CPU configuration 128
    input: str = "fk"  # "fk": FK joint frames (336 numbers); "theta": the ablation, sin/cos of the raw angles
    hidden: int = 1024  # width of the MLP's hidden layer
    channels: int = 128  # feature channels at 8×8 (paper 128); halved at each upsampling, at least min_channels
    min_channels: int = 16  # narrowest decoder stage
    res_blocks: int = 2  # residual blocks at 8×8
    translation_scale: float = 10.0  # FK positions (metres) are multiplied by this before the MLP

    def __post_init__(self) -> None:
        n = math.log2(self.resolution / 8)
        if self.resolution < 16 or n != int(n):
            raise ValueError(f"resolution must be 8·2^k ≥ 16 (16, 32, 64, 128, 256...), got {self.resolution}")
        if self.input not in ("fk", "theta"):
            raise ValueError(f"input must be 'fk' or 'theta', got {self.input!r}")

    @property
    def upsamplings(self) -> int:
        return int(math.log2(self.resolution / 8))


CPU_CONFIG = SelfModelConfig(resolution=128, hidden=512, channels=64, min_channels=16)  # shipped small model
PAPER_CONFIG = SelfModelConfig()  # 256², 128 channels
PRESETS = {"cpu": CPU_CONFIG, "paper": PAPER_CONFIG}  # architecture presets by name


@dataclass(frozen=True)
class TrainerConfig:
    """How the shared trainer runs; each network's training config extends it with its own fields and defaults."""

    out: str = "runs/model.pt"  # checkpoint file written (and resumed from)
    data: str | None = None  # shard folder made by `collect` (0.7/0.2/0.1 split); unset: pairs rendered on the fly
    steps: int = 6000  # optimiser steps [1, 10000000]
    batch_size: int = 64  # pairs per step (~2 MB each through the 128² self-model and back) [1, 1024]
    lr: float = 2e-3  # peak AdamW learning rate (0, 10]
    weight_decay: float = 1e-4  # AdamW weight decay [0, 10]
    warmup: int = 200  # linear warm-up steps before the cosine decay to lr/50 [0, 10000000]
    eval_every: int = 500  # steps between validation + checkpoint [1, 10000000]
    eval_size: int = 2048  # on-the-fly validation and test set size (shards use their own splits) [1, 20000]
    seed: int = 0  # data and initialisation seed [0, 4294967295]
    device: str | None = None  # "cpu" or "cuda"; unset: CUDA when present
    threads: int | None = None  # torch CPU threads; unset: torch's default [1, 256]
    rig_file: str | None = None  # calibrate-rig's calibration.yaml (or a rig file): on-the-fly shadows through its rig

    def rig(self, resolution: int) -> Rig:
        """The rig of on-the-fly training shadows at ``resolution``: nominal, or measured by ``rig_file``."""
        from studio.sim.rig_file import measured_rig
        from studio.sim.shadow import Rig

        base = Rig(resolution=resolution)
        return measured_rig(self.rig_file, base) if self.rig_file else base

    def __post_init__(self) -> None:
        problems = [
            f"{name} must be {rule}, got {value}"
            for name, value, ok, rule in (
                ("steps", self.steps, self.steps >= 1, "≥ 1"),
                ("batch_size", self.batch_size, self.batch_size >= 1, "≥ 1"),
                ("lr", self.lr, self.lr > 0 and math.isfinite(self.lr), "> 0"),
                ("weight_decay", self.weight_decay, self.weight_decay >= 0, "≥ 0"),
                ("warmup", self.warmup, self.warmup >= 0, "≥ 0"),
                ("eval_every", self.eval_every, self.eval_every >= 1, "≥ 1"),
                ("eval_size", self.eval_size, self.eval_size >= 1, "≥ 1"),
                ("threads", self.threads, self.threads is None or self.threads >= 1, "≥ 1 (or None)"),
            )
            if not ok
        ]
        if problems:
            raise ValueError("; ".join(problems))


@dataclass(frozen=True)
class TrainConfig(TrainerConfig):
    """How ``shadow-studio train`` trains a self-model (the trainer's fields plus the architecture's)."""

    out: str = "runs/selfmodel.pt"  # checkpoint file written (and resumed from)
    model: str = "cpu"  # architecture preset: "cpu" (128², small) or "paper" (256²)
    input: str = "fk"  # "fk" (the paper's model) or "theta" (the ablation: sin/cos of the raw angles)
    resolution: int | None = None  # output resolution instead of the preset's (16, 32, 64, 128, 256...) [16, 1024]

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.model not in PRESETS:
            raise ValueError(f"model must be one of {list(PRESETS)}, got {self.model!r}")
        self.model_config()  # checks input and resolution

    def model_config(self) -> SelfModelConfig:
        base = PRESETS[self.model]
        return replace(base, input=self.input, resolution=self.resolution or base.resolution)


@dataclass(frozen=True)
class InverseConfig:
    """Architecture of the inverse CNN."""

    input_size: int = 64  # side of the aligned shadow crop the CNN sees, pixels (a multiple of 16) [16, 512]
    channels: tuple[int, ...] = (16, 32, 64, 128)  # conv widths; each stage halves the side (stride 2)
    hidden: int = 256  # width of the fully connected layer before the 21 outputs
    pad: float = PAD  # crop padding, pixels of a 256-pixel image (as the losses' LossConfig.pad)

    def __post_init__(self) -> None:
        if self.input_size < 1 or self.input_size % (2 ** len(self.channels)):
            raise ValueError(f"input_size must be a multiple of {2 ** len(self.channels)}, got {self.input_size}")


@dataclass(frozen=True)
class InverseTrainConfig(TrainerConfig):
    """How ``shadow-studio train-inverse`` trains the inverse CNN (the trainer's fields plus its own)."""

    out: str = "runs/inverse.pt"  # checkpoint file written (and resumed from)
    steps: int = 3000  # optimiser steps
    warmup: int = 100  # linear warm-up steps
    eval_size: int = 1024  # on-the-fly validation and test set size (shards use their own splits)
    resolution: int = 128  # rendered shadow side for on-the-fly pairs, pixels (the self-model's) [16, 1024]

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.resolution < 16:
            raise ValueError(f"resolution must be ≥ 16, got {self.resolution}")


@dataclass(frozen=True)
class CollectConfig:
    """What ``shadow-studio collect`` makes."""

    n: int = 20000  # total number of (pose, shadow) pairs [1, 10000000]
    shard_size: int = 5000  # samples per shard file (held in memory while written: 5000 at 1024² is 5 GB) [1, 5000]
    seed: int = 0  # shard k is drawn from the seed sequence (seed, k) [0, 4294967295]
    resolution: int = 256  # shadow image side, pixels [8, 1024]
    window: float = 0.6  # backdrop window side, metres (see studio.sim.shadow.Rig) (0, 100]
    rig_file: str | None = None  # calibrate-rig's calibration.yaml (or a rig file): shadows rendered through its rig

    def __post_init__(self) -> None:
        if self.n < 1 or self.shard_size < 1:
            raise ValueError("--n and --shard-size must be positive")

    @property
    def num_shards(self) -> int:
        return (self.n + self.shard_size - 1) // self.shard_size

    def rig(self) -> Rig:
        """The rig the shards are rendered through: nominal, or measured by ``rig_file`` (a calibrated rig)."""
        from studio.sim.rig_file import measured_rig
        from studio.sim.shadow import Rig

        base = Rig(window=self.window, resolution=self.resolution)
        return measured_rig(self.rig_file, base) if self.rig_file else base
