"""The aligned crop's pad (DESIGN §4 "Losses"): its default and how it scales with the image, torch-free.

Every aligned crop of the studio (the losses' :mod:`studio.sim.crop`, the renderer-side loss and the retrieval index
of :mod:`studio.imitate`, the keyframes' :func:`studio.targets.keyframes.aligned_crop`, the capture checks of
:mod:`studio.project`) grows a shadow's box by the same pad: given in pixels of a 256-pixel image and scaled with the
image's longer side. Numbers only, so the torch-free footage stage shares the rule with the losses.
"""

from __future__ import annotations

REFERENCE_SIDE = 256  # the image side the pad is given at, pixels
PAD = 5.0  # the default pad around each shadow box, pixels of a REFERENCE_SIDE image (LossConfig.pad)


def pad_pixels(pad: float, height: int, width: int) -> float:
    """The pad in pixels of an ``height × width`` image: ``pad`` pixels at 256, scaled with the longer side."""
    return pad * max(height, width) / REFERENCE_SIDE
