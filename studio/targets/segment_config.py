"""How raw colour footage is segmented (:mod:`studio.targets.segment`): the settings of the classical method and
of the optional Segment Anything adapter, on their own so that every module of the segmentation reads them without
importing the others."""

from __future__ import annotations

from dataclasses import dataclass

import cv2

DIS_PRESETS = {  # SegmentConfig.flow_preset → OpenCV's DIS optical-flow preset
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


@dataclass(frozen=True)
class SegmentConfig:
    """How footage is segmented (defaults measured on four DAVIS sequences, the same for all of them)."""

    method: str = "auto"  # "auto" (Segment Anything when its package and sam_checkpoint exist, else classical),
    # "classical", or "sam" (an error that says what is missing when it cannot run)
    work_size: int = 400  # longest side (px) frames are segmented at (smaller ones as they are); masks upsampled back
    flow_preset: str = "medium"  # DIS optical-flow preset: "ultrafast", "fast" or "medium"
    first_gaps: tuple[int, ...] = (1, 2, 3)  # later frames whose flow from frame 0 gives the box's motion cue
    first_iterations: int = 4  # colour re-learning + graph-cut rounds for the first frame from a box
    first_motion_scale: float = 2.0  # first-frame motion evidence = scale · log(residual / Otsu level) …
    first_motion_clip: float = 3.0  # … clipped to ± this
    first_grabcut_iterations: int = 5  # nothing in the box moves apart (a static shot): GrabCut rounds from the box
    # (0: the colour rounds above alone)
    smoothness: float = 2.0  # graph-cut weight of the contrast-sensitive Potts term (per neighbour pair)
    colour_bins: int = 16  # global colour histograms: bins per RGB channel
    colour_weight: float = 1.0  # weight of the global colour evidence
    colour_clip: float = 5.0  # global and local colour evidence clipped to ± this (log-likelihood ratio)
    fg_anchor: float = 0.5  # object colour model: this share from the first frame, the rest from recent frames
    bg_anchor: float = 0.5  # background model: this share running (from past frames), the rest from this frame
    model_update: float = 0.3  # running colour models: weight of each new frame's colours
    bg_ring: float = 0.3  # background colours are sampled in a band this × size wide around the object
    local_weight: float = 1.0  # weight of the bilateral-grid (local) colour evidence
    local_cell: float = 0.15  # its spatial cell, × size (at least 4 px)
    local_bins: int = 8  # its colour bins per channel
    local_blur: tuple[float, float] = (1.0, 0.7)  # its Gaussian blur in cells: (space, colour)
    local_guard: float = 0.04  # its samples leave out a band this × size wide on each side of the guess's edge
    local_eps: float = 0.05  # added to both blurred counts before their ratio (how fast it trusts few samples)
    shape_weight: float = 1.0  # weight of the warped previous mask (shape prior)
    shape_sigma: float = 0.1  # shape prior = signed distance to the warped mask / (this × size) …
    shape_clip: float = 3.0  # … clipped to ± this
    far: float = 0.6  # pixels farther than this × size from the warped mask are definite background
    roi_margin: float = 0.4  # the graph cut covers the warped mask's box grown by this × size on each side
    motion_weight: float = 1.0  # weight of the motion evidence (times its measured reliability); 0 = no motion
    motion_noise: float = 0.3  # smallest flow residual σ (px at work size)
    motion_clip: float = 4.0  # motion evidence clipped to ± this
    motion_fp: tuple[float, float] = (0.25, 0.45)  # motion off as its false-object share outside rises over these
    min_component_share: float = 0.05  # pieces smaller than this share of the largest are dropped
    size_memory: float = 1.0  # a shrunken mask (partly hidden) is segmented with room for this × the remembered size
    size_decay: float = 0.99  # the remembered size (√area) shrinks by this factor a frame while the mask is smaller
    search_frames: int = 30  # after the mask vanishes (hidden), look for the object again for this many frames
    redetect_level: float = 1.0  # … among pixels whose colour evidence (log-likelihood ratio) is above this …
    redetect_share: float = 0.1  # … taking a piece of at least this share of the remembered area
    redetect_keep: float = 0.2  # … with every other piece of at least this share of the best piece's evidence
    redetect_below: float = 0.15  # a mask below this share of the remembered area is looked for again as well
    sam_checkpoint: str | None = None  # a local Segment Anything checkpoint (.pth for segment_anything, .pt sam2)
    sam_model: str = ""  # segment_anything model type ("vit_b", …) or sam2 config; "" = from the file name
    sam_device: str = "auto"  # torch device for Segment Anything ("auto" = cuda when available, else cpu)
    sam_box_grow: float = 0.1  # SAM 1: each frame's box prompt, the previous mask's box grown by this share per side
    sam_image_size: int = 0  # SAM 2: the model's input side, px (0: the checkpoint's own; smaller is faster on a CPU)

    def __post_init__(self) -> None:
        if self.method not in ("auto", "classical", "sam"):
            raise ValueError(f"method must be 'auto', 'classical' or 'sam', not {self.method!r}")
        if self.flow_preset not in DIS_PRESETS:
            raise ValueError(f"flow_preset must be one of {sorted(DIS_PRESETS)}, not {self.flow_preset!r}")
        if self.work_size < 32 or self.first_iterations < 1 or self.colour_bins < 2 or self.local_bins < 2:
            raise ValueError("work_size must be ≥ 32, first_iterations ≥ 1, colour_bins and local_bins ≥ 2")
        if self.first_grabcut_iterations < 0:
            raise ValueError("first_grabcut_iterations must be ≥ 0 (0: the colour rounds alone)")
