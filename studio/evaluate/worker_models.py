"""What an evaluation worker loads (:mod:`studio.evaluate.table1_task`, :mod:`studio.evaluate.table2_task`): the
self-model and CLIP, named by paths and settings so that the recipe travels to another process or machine."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["ModelRecipe"]


@dataclass(frozen=True)
class ModelRecipe:
    """The self-model and CLIP a worker loads, once."""

    model: str  # self-model checkpoint (on a cluster: a path every machine sees)
    device: str | None = None  # torch device (None: CUDA when present)
    threads: int = 1  # torch CPU threads per worker (0: torch's default) [0, 256]
    clip_weights: str | None = None  # CLIP weights, as the command line's --clip-weights (None: found or off)
    clip_model: str = "ViT-B-32"  # CLIP architecture
    use_clip: bool = True  # False: the CLIP terms off (--no-clip)

    def load(self) -> tuple[Any, Any]:
        """``(self-model, CLIP encoder or None)``, with torch set to ``threads`` in this process."""
        from studio.imitate.clip_loss import find_clip
        from studio.learn.selfmodel import load_selfmodel
        from studio.learn.threads import set_torch_threads

        if self.threads:
            set_torch_threads(self.threads)
        model, _ = load_selfmodel(Path(self.model), device=self.device)
        clip, _ = find_clip(self.clip_weights, self.clip_model, enabled=self.use_clip,
                            device=next(model.parameters()).device)  # fmt: skip
        return model, clip
