"""Where CLIP weights are on this machine, without torch or open_clip (the notebook's Weights panel asks when the studio
opens, and every run without local weights asks where they would be): the published sources of the studio's default
CLIP, the cache paths a checkpoint could be at, and what to provide when there is none. The weights themselves are
loaded by :mod:`studio.imitate.clip_loss`; they never come from the network.
"""

from __future__ import annotations

import os
from pathlib import Path

# Where the studio's default CLIP is published (open_clip's pretrained table), read without importing open_clip: every
# run without local weights asks where they would be, and importing open_clip costs 0.7 s beyond what torch loads
# anyway (torchvision). Held equal to open_clip's own table by tests/test_losses.py; other models ask open_clip.
KNOWN_SOURCES = {
    ("ViT-B-32", "openai"): {
        "hf_hub": "timm/vit_base_patch32_clip_224.openai/",
        "url": "https://openaipublic.azureedge.net/clip/models/40d365715913c9da98579312b702a82c18be219cc2a73407c4526f58"
        "eba950af/ViT-B-32.pt",
    },
}


def pretrained_sources(model_name: str, pretrained: str) -> dict:
    """Where ``model_name``/``pretrained`` is published: open_clip's pretrained config (``hf_hub``, ``url``, …), from
    :data:`KNOWN_SOURCES` when it is there (no open_clip import), else from open_clip ({} for an unknown pair)."""
    known = KNOWN_SOURCES.get((model_name, pretrained))
    if known is not None:
        return dict(known)
    import open_clip

    return open_clip.get_pretrained_cfg(model_name, pretrained) or {}


def cache_candidates(model_name: str, pretrained: str, cache_dir: str | Path | None = None) -> list[Path]:
    """Where a cached checkpoint of ``model_name``/``pretrained`` could be (existing or not), best first."""
    cfg = pretrained_sources(model_name, pretrained)
    out: list[Path] = []
    hub = cfg.get("hf_hub", "")
    if hub:
        from huggingface_hub import try_to_load_from_cache

        repo, filename = os.path.split(hub)  # "org/model/" → default file names, as open_clip does
        names = [filename] if filename else []
        names += ["open_clip_model.safetensors", "open_clip_pytorch_model.bin"]
        for name in dict.fromkeys(names):
            found = try_to_load_from_cache(repo, name, cache_dir=str(cache_dir) if cache_dir else None)
            if isinstance(found, str):
                out.append(Path(found))
    url = cfg.get("url", "")
    if url:
        out.append(Path(cache_dir or Path.home() / ".cache" / "clip") / os.path.basename(url))
    return out


def missing_message(model_name: str, pretrained: str, cache_dir: str | Path | None, given: Path | None) -> str:
    """What to provide when CLIP weights are missing (``given``: the file the artist gave, None: none was given)."""
    from huggingface_hub import constants

    cfg = pretrained_sources(model_name, pretrained)
    hub = cfg.get("hf_hub", "").rstrip("/")
    where = f"open_clip_model.safetensors from https://huggingface.co/{hub}" if hub else "an open_clip checkpoint"
    if given is not None:
        problem = f"CLIP weights file not found: {given}"
    else:
        places = [str(Path(cache_dir or constants.HF_HUB_CACHE) / ("models--" + hub.replace("/", "--")))] if hub else []
        places += [str(p) for p in cache_candidates(model_name, pretrained, cache_dir)]
        problem = (
            f"CLIP weights for {model_name} ({pretrained}) are not on this machine (looked in {', '.join(places)}); "
            "they are never downloaded"
        )
    return f"{problem}. Get {where} on a machine with internet and give that file as the CLIP weights"
