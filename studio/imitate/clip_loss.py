"""CLIP image embeddings of shadow crops, through open_clip, with differentiable preprocessing (DESIGN §4, §6).

What CLIP sees: the shadow as a person in the audience does (display convention), a black shadow on a white
backdrop: ``1 − p`` (``invert=True``) replicated to three channels, resized to the model's input size
(bilinear, antialiased, differentiable) and normalised with the weights' mean/std. Only the image tower is kept,
frozen.

Weights never come from the network. One rule on every face (:func:`find_clip`): the CLIP terms are on when local
weights are given (a checkpoint file) or found in the open_clip / Hugging Face cache, off otherwise, and a line says
which. :func:`load_clip` loads given or cached weights, raising :class:`ClipWeightsError` (which file to provide)
when there are none or they cannot be read. :func:`tiny_clip` builds a small randomly initialised model for tests.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from studio.errors import StudioError
from studio.imitate.clip_files import cache_candidates, missing_message

log = logging.getLogger(__name__)

# A small CLIP (about 0.13 M parameters, 32² input) for tests: random weights only, never a real similarity.
TINY_CLIP_CFG = {
    "embed_dim": 32,
    "vision_cfg": {"image_size": 32, "layers": 2, "width": 64, "patch_size": 8, "head_width": 32},
    "text_cfg": {"context_length": 8, "vocab_size": 64, "width": 32, "heads": 2, "layers": 1},
}
OPENAI_MEAN = (0.48145466, 0.4578275, 0.40821073)  # open_clip.constants.OPENAI_DATASET_MEAN
OPENAI_STD = (0.26862954, 0.26130258, 0.27577711)  # open_clip.constants.OPENAI_DATASET_STD


class ClipWeightsError(StudioError):
    """CLIP weights were asked for but are not on this machine (or cannot be read)."""


class ClipImageEncoder(nn.Module):
    """Frozen CLIP image tower: shadow probabilities ``(B, [1,] S, S)`` in [0, 1] → unit embeddings ``(B, D)``."""

    def __init__(
        self,
        visual: nn.Module,
        image_size: int,
        mean: tuple[float, float, float] = OPENAI_MEAN,
        std: tuple[float, float, float] = OPENAI_STD,
        invert: bool = True,
        name: str = "",
    ) -> None:
        super().__init__()
        self.visual = visual.eval().requires_grad_(False)
        self.image_size = int(image_size)  # side of the square input the tower expects, pixels
        self.invert = invert  # feed 1 − p: black shadow on a white backdrop (display convention)
        self.name = name  # what was loaded, for logs and outputs (model name and weights file)
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> ClipImageEncoder:
        """The tower stays in eval mode (frozen; no dropout)."""
        super().train(mode)
        self.visual.eval()
        return self

    def preprocess(self, shadow: torch.Tensor) -> torch.Tensor:
        """Shadow probabilities ``(B, [1,] S, S)`` → normalised RGB ``(B, 3, image_size, image_size)``."""
        x = shadow if shadow.ndim == 4 else shadow[:, None]
        x = 1.0 - x if self.invert else x
        x = x.expand(-1, 3, -1, -1)
        if x.shape[-2:] != (self.image_size, self.image_size):
            size = (self.image_size, self.image_size)
            x = F.interpolate(x, size=size, mode="bilinear", antialias=True, align_corners=False)
        return (x - self.mean) / self.std

    def forward(self, shadow: torch.Tensor) -> torch.Tensor:
        """Unit embeddings ``(B, D)``, computed on the encoder's device and returned on ``shadow``'s (so CPU renders
        can be scored by a CUDA encoder)."""
        x = self.preprocess(shadow.to(self.mean.device))
        return F.normalize(self.visual(x).float(), dim=-1).to(shadow.device)


def tiny_clip(seed: int = 0, invert: bool = True) -> ClipImageEncoder:
    """A small randomly initialised open_clip model (:data:`TINY_CLIP_CFG`), for tests; builds in milliseconds."""
    from open_clip.model import CLIP, CLIPTextCfg, CLIPVisionCfg

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        cfg = TINY_CLIP_CFG
        model = CLIP(cfg["embed_dim"], CLIPVisionCfg(**cfg["vision_cfg"]), CLIPTextCfg(**cfg["text_cfg"]))
    return ClipImageEncoder(model.visual, cfg["vision_cfg"]["image_size"], invert=invert, name="tiny-random")


def _load_state(model: nn.Module, path: Path) -> None:
    """Load a checkpoint file into ``model``: an open_clip state dict, or an OpenAI TorchScript archive."""
    import open_clip

    try:
        open_clip.load_checkpoint(model, str(path), strict=True, weights_only=True)
        return
    except RuntimeError as e:
        if "TorchScript" not in str(e):
            raise
    state = torch.jit.load(str(path), map_location="cpu").state_dict()
    keys = set(model.state_dict())
    missing = keys - set(state)
    if missing:
        raise RuntimeError(f"TorchScript archive lacks {len(missing)} weights, e.g. {sorted(missing)[:3]}")
    model.load_state_dict({k: v for k, v in state.items() if k in keys}, strict=True)


def load_clip(
    model_name: str = "ViT-B-32",
    weights: str | Path | None = None,
    cache_dir: str | Path | None = None,
    pretrained: str = "openai",
    invert: bool = True,
    device: str | torch.device = "cpu",
) -> ClipImageEncoder:
    """The frozen image tower of open_clip ``model_name`` with local weights only (never a download).

    ``weights``: a checkpoint file (open_clip state dict ``.safetensors``/``.bin``/``.pt``, or OpenAI's TorchScript
    ``.pt``); None: look in the caches for the ``pretrained`` tag (Hugging Face hub cache, ``~/.cache/clip``, or
    ``cache_dir``). ``pretrained`` also sets QuickGELU and the normalisation the weights were trained with.
    Raises :class:`ClipWeightsError` naming the file to provide when none is found or it cannot be loaded.
    """
    import open_clip

    if open_clip.get_model_config(model_name) is None:
        raise ClipWeightsError(f"unknown open_clip model {model_name!r} (e.g. ViT-B-32, ViT-B-16, RN50)")
    if weights is not None:
        path = Path(weights).expanduser()
        if not path.is_file():
            raise ClipWeightsError(missing_message(model_name, pretrained, cache_dir, given=path))
    else:
        path = next((p for p in cache_candidates(model_name, pretrained, cache_dir) if p.is_file()), None)
        if path is None:
            raise ClipWeightsError(missing_message(model_name, pretrained, cache_dir, given=None))
    tag = open_clip.get_pretrained_cfg(model_name, pretrained) or {}
    model = open_clip.create_model(
        model_name, pretrained=None, force_quick_gelu=bool(tag.get("quick_gelu", False)), device="cpu"
    )
    try:
        _load_state(model, path)
    except Exception as e:  # any failure to read the user's file is reported as one clear line
        raise ClipWeightsError(
            f"cannot load CLIP weights for {model_name} from {path} ({type(e).__name__}: {e}); "
            "give an open_clip checkpoint of that model"
        ) from None
    image_size = model.visual.image_size
    image_size = image_size[0] if isinstance(image_size, (tuple, list)) else image_size
    mean, std = tag.get("mean", OPENAI_MEAN), tag.get("std", OPENAI_STD)
    log.info("CLIP %s loaded from %s", model_name, path)
    return ClipImageEncoder(model.visual, image_size, mean, std, invert, name=f"{model_name}:{path}").to(device)


def find_clip(
    weights: str | Path | None = None,
    model_name: str = "ViT-B-32",
    enabled: bool = True,
    device: str | torch.device = "cpu",
    cache_dir: str | Path | None = None,
) -> tuple[ClipImageEncoder | None, str]:
    """The one CLIP rule of every face → ``(encoder or None, one line saying which)``: off when not ``enabled``; on
    with ``weights`` (a checkpoint file; a ClipWeightsError when it is missing or unreadable); else on when the
    weights are in a local cache, off when they are not (never a download, never an error)."""
    if not enabled:
        return None, "CLIP terms off (asked)"
    if weights is None:
        if not any(p.is_file() for p in cache_candidates(model_name, "openai", cache_dir)):
            return None, f"CLIP terms off: no local {model_name} weights given or cached (they are never downloaded)"
    clip = load_clip(model_name, weights=weights, cache_dir=cache_dir, device=device)
    return clip, f"CLIP terms on: {clip.name}"
