"""The classical segmentation's two steps (:mod:`studio.targets.segment` describes the method): the first frame
from a box (:func:`first_from_box`) and frame-to-frame propagation (:class:`Tracker`), on frames kept at the work
resolution (:class:`WorkFrames`). Every array here is at the work resolution ``(h, w)``; masks are uint8 {0, 1}.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

import studio.targets.segment_cues as cues
from studio.targets.segment_config import DIS_PRESETS, SegmentConfig

log = logging.getLogger(__name__)


class WorkFrames:
    """The frames at the work resolution (RGB, grey, colour-cell indices; the last few cached) and their flow."""

    def __init__(self, frames: np.ndarray, cfg: SegmentConfig):
        n, h, w = frames.shape[:3]
        self.scale = min(1.0, cfg.work_size / max(h, w))  # never upsampled
        self.size = (max(8, round(w * self.scale)), max(8, round(h * self.scale)))  # (w, h)
        self.frames, self.cfg = frames, cfg
        self.dis = cv2.DISOpticalFlow_create(DIS_PRESETS[cfg.flow_preset])
        self._cache: dict[int, tuple] = {}

    def __getitem__(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rgb (h, w, 3), grey (h, w), colour index (h, w)) of frame t."""
        if t not in self._cache:
            if len(self._cache) > 8:
                self._cache.pop(min(self._cache))
            rgb = cv2.resize(self.frames[t], self.size, interpolation=cv2.INTER_AREA)
            grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            self._cache[t] = (rgb, grey, cues.colour_index(rgb, self.cfg.colour_bins))
        return self._cache[t]

    def flow(self, a: int, b: int) -> np.ndarray:
        """Dense flow (h, w, 2) px from frame a to frame b (pixel p of a sits at p + flow in b)."""
        return self.dis.calc(self[a][1], self[b][1], None)


def _lab(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)


def first_from_box(work: WorkFrames, box: tuple[int, int, int, int], cfg: SegmentConfig) -> np.ndarray:
    """Frame 0's mask (h, w) {0, 1} at work size from a box in source pixels."""
    s = work.scale
    w, h = work.size
    x, y = min(int(box[0] * s), w - 2), min(int(box[1] * s), h - 2)
    bw, bh = max(2, min(round(box[2] * s), w - x)), max(2, min(round(box[3] * s), h - y))
    inside = np.zeros((h, w), bool)
    inside[y : y + bh, x : x + bw] = True
    gaps = [g for g in cfg.first_gaps if g < len(work.frames)]
    evidence = np.zeros((h, w), np.float32)
    start, moved = inside.copy(), False  # moved: the motion cue found the object apart from the background
    if gaps:
        z = cues.box_motion([(work.flow(0, g), work.flow(g, 0)) for g in gaps], (x, y, bw, bh))
        known = ~np.isnan(z)
        z = np.nan_to_num(z, nan=0.0)
        levels = np.clip(z[inside & known] * 50, 0, 255).astype(np.uint8)
        if levels.size > 16:
            otsu, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            level = max(otsu / 50, 1.0)
            moving = (z > level) & inside
            share = moving[inside].mean()
            if 0.1 < share < 0.95:  # something in the box moves apart from the background, and not all of it
                evidence = np.clip(
                    np.log(np.maximum(z, 1e-3) / level) * cfg.first_motion_scale,
                    -cfg.first_motion_clip,
                    cfg.first_motion_clip,
                ).astype(np.float32)
                evidence[~known] = 0
                start, moved = moving, True
    size = float(np.sqrt(inside.sum()))
    m = max(4, int(0.2 * size))
    roi = (slice(max(0, y - m), min(h, y + bh + m)), slice(max(0, x - m), min(w, x + bw + m)))
    if not moved and cfg.first_grabcut_iterations > 0:  # no motion cue: the box and colours alone
        cut = _grabcut(work[0][0], (x, y, bw, bh), cfg.first_grabcut_iterations)
        if cut.any():
            log.info("first frame from the box by GrabCut (nothing in the box moves apart from the background)")
            return cues.keep_components(cut, None, cfg.min_component_share)
    return _first_cut(work, inside, start, evidence, roi, size, cfg)


def _grabcut(rgb: np.ndarray, box: tuple[int, int, int, int], iterations: int) -> np.ndarray:
    """OpenCV's GrabCut (Gaussian-mixture colour models re-learnt by graph cuts) from a box (x, y, w, h): the mask
    (h, w) {0, 1} of its definite and probable foreground. From a box alone it beat the colour-histogram rounds of
    :func:`_first_cut` on every clip and box of ``bench_segment.py`` (first-frame J 0.44 → 0.62, mean of ten)."""
    h, w = rgb.shape[:2]
    x, y, bw, bh = box
    if bw >= w - 1 and bh >= h - 1:  # GrabCut needs some background outside the box
        return np.zeros((h, w), np.uint8)
    labels = np.zeros((h, w), np.uint8)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)  # its k-means start: the same answer every run
    cv2.grabCut(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), labels, (x, y, bw, bh), bgd, fgd, iterations,
                cv2.GC_INIT_WITH_RECT)  # fmt: skip
    return ((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)).astype(np.uint8)


def _first_cut(work, inside, start, evidence, roi, size, cfg: SegmentConfig) -> np.ndarray:
    """Colour re-learning + graph cut rounds inside the box from the ``start`` mask with extra ``evidence``."""
    rgb, _, index = work[0]
    h, w = inside.shape
    lab = _lab(rgb[roi])
    cur = start.astype(np.uint8)
    for _ in range(cfg.first_iterations):
        fg, bg = cues.colour_hist(index, cur > 0, cfg.colour_bins), cues.colour_hist(index, cur == 0, cfg.colour_bins)
        unary = cfg.colour_weight * cues.colour_llr(index, fg, bg, cfg.colour_clip) + evidence
        if cfg.local_weight > 0:
            unary += cfg.local_weight * _local(rgb, cur, size, cfg)
        unary[~inside] = -cues.HARD
        cut = np.zeros((h, w), np.uint8)
        cut[roi] = cues.graph_cut(unary[roi], lab, cfg.smoothness)
        cut = cues.keep_components(cut, None, cfg.min_component_share)
        if not cut.any():
            break
        cur = cut
    return cur


def _local(rgb: np.ndarray, guess: np.ndarray, size: float, cfg: SegmentConfig) -> np.ndarray:
    return cues.local_colour_llr(
        rgb,
        guess,
        size,
        cfg.local_cell,
        cfg.local_bins,
        cfg.local_blur,
        cfg.local_eps,
        cfg.colour_clip,
        cfg.local_guard,
    )


class Tracker:
    """Frame-to-frame propagation with running colour models (step 2 of the module docstring)."""

    def __init__(self, work: WorkFrames, first: np.ndarray, cfg: SegmentConfig):
        self.work, self.cfg = work, cfg
        index = work[0][2]
        size = float(np.sqrt(max(first.sum(), 1)))
        self.fg0 = cues.colour_hist(index, first > 0, cfg.colour_bins)
        self.fg_run = self.fg0.copy()
        self.bg_run = cues.colour_hist(index, cues.ring(first, max(2, int(cfg.bg_ring * size))), cfg.colour_bins)
        self.lost = False
        self.size_ref = size  # the object's remembered size (√area): follows growth at once, shrinking slowly
        self.last = first.copy()  # the last mask that was not empty (where to look again when the object is lost)
        self.missing = 0  # frames since the mask was last not empty

    def _redetect(self, t: int) -> np.ndarray:
        """Look for the lost object in frame ``t`` near where it was last seen: the pixels whose colour says object
        (the object's and the background's colour models), the pieces of them inside the last mask's box grown by
        the remembered size with at least ``redetect_keep`` × the evidence of the best piece (an object of several
        colours comes back in several pieces); empty when none is at least ``redetect_share`` of the
        remembered area."""
        cfg = self.cfg
        _, _, index = self.work[t]
        fg = cfg.fg_anchor * self.fg0 + (1 - cfg.fg_anchor) * self.fg_run
        llr = cues.colour_llr(index, fg, self.bg_run, cfg.colour_clip)
        h, w = llr.shape
        ys, xs = np.nonzero(self.last)
        r = int(self.size_ref)
        window = np.zeros((h, w), bool)
        window[max(0, ys.min() - r) : ys.max() + r + 1, max(0, xs.min() - r) : xs.max() + r + 1] = True
        cand = ((llr > cfg.redetect_level) & window).astype(np.uint8)
        cand = cv2.morphologyEx(cand, cv2.MORPH_OPEN, cues.disk(max(1, int(0.03 * self.size_ref))))
        n, labels = cv2.connectedComponents(cand, connectivity=8)
        if n < 2:
            return np.zeros((h, w), np.uint8)
        scores = np.bincount(labels.ravel(), weights=llr.ravel(), minlength=n)
        scores[0] = 0.0
        piece = (scores[labels] >= cfg.redetect_keep * scores.max()).astype(np.uint8)  # the best piece and its peers
        if piece.sum() < cfg.redetect_share * self.size_ref**2:
            return np.zeros((h, w), np.uint8)
        log.info("segmentation found the object again at frame %d", t)
        return piece

    def step(self, t: int, prev: np.ndarray) -> np.ndarray:
        cfg, work = self.cfg, self.work
        w, h = work.size
        flow = work.flow(t, t - 1)  # where each pixel of frame t was in frame t-1
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float32)
        warped = cv2.remap(prev.astype(np.float32), gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_LINEAR)
        guess = (warped > 0.5).astype(np.uint8)
        if guess.sum() < 10:  # lost (hidden, or shrunk away): look again where it was last seen, for a while
            self.missing += 1
            if self.missing > cfg.search_frames or self.last.sum() < 10:
                if not self.lost:
                    log.warning("segmentation lost the object at frame %d (it left the frame or shrank away)", t)
                    self.lost = True
                return np.zeros_like(guess)
            guess = self._redetect(t)
            if guess.sum() < 10:
                return guess
        elif cfg.search_frames and guess.sum() < cfg.redetect_below * self.size_ref**2:  # all but lost: look too
            found = self._redetect(t)
            if found.sum() > guess.sum():
                guess = guess | found
        # a mask smaller than the object was (partly hidden) is given room to grow back to the size remembered
        size = max(float(np.sqrt(guess.sum())), cfg.size_memory * self.size_ref)
        m = max(4, int(cfg.roi_margin * size))
        ys, xs = np.nonzero(guess)
        y0, y1, x0, x1 = max(0, ys.min() - m), min(h, ys.max() + m + 1), max(0, xs.min() - m), min(w, xs.max() + m + 1)
        roi = (slice(y0, y1), slice(x0, x1))
        g = guess[roi]
        d_in = cv2.distanceTransform(g, cv2.DIST_L2, 3)
        d_out = cv2.distanceTransform(1 - g, cv2.DIST_L2, 3)
        unary = cfg.shape_weight * np.clip((d_in - d_out) / (cfg.shape_sigma * size), -cfg.shape_clip, cfg.shape_clip)
        rgb, _, index = work[t]
        width = max(2, int(cfg.bg_ring * size))
        here = cues.colour_hist(index[roi], cues.ring(g, width), cfg.colour_bins)
        bg = cfg.bg_anchor * self.bg_run + (1 - cfg.bg_anchor) * here / max(here.sum(), 1) * self.bg_run.sum()
        fg = cfg.fg_anchor * self.fg0 + (1 - cfg.fg_anchor) * self.fg_run
        unary += cfg.colour_weight * cues.colour_llr(index[roi], fg, bg, cfg.colour_clip)
        if cfg.local_weight > 0:
            unary += cfg.local_weight * _local(rgb[roi], g, size, cfg)
        if cfg.motion_weight > 0:
            llr, reliability = cues.motion_llr(
                flow, guess, size, cfg.motion_noise, cfg.motion_clip, cfg.motion_fp[0], cfg.motion_fp[1]
            )
            if llr is not None and reliability > 0:
                unary += cfg.motion_weight * reliability * llr[roi]
        unary[d_out > cfg.far * size] = -cues.HARD
        new = np.zeros((h, w), np.uint8)
        new[roi] = cues.graph_cut(unary, _lab(rgb[roi]), cfg.smoothness)
        new = cues.keep_components(new, guess, cfg.min_component_share)
        if new.any():
            self.missing, self.last, self.lost = 0, new, False
            self.size_ref = max(float(np.sqrt(new.sum())), self.size_ref * cfg.size_decay)
        if new.sum() > 0.3 * prev.sum():  # a mask that collapsed does not teach the colour models
            core = cv2.erode(new, cues.disk(max(1, int(0.03 * size)))) > 0
            u = cfg.model_update
            self.fg_run = (1 - u) * self.fg_run + u * cues.colour_hist(index, core, cfg.colour_bins) / max(
                core.sum(), 1
            ) * self.fg0.sum()
            band = cues.ring(new, width)
            self.bg_run = (1 - u) * self.bg_run + u * cues.colour_hist(index, band, cfg.colour_bins) / max(
                band.sum(), 1
            ) * self.bg_run.sum()
        return new
