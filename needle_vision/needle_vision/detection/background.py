"""Background model and subtraction (seed 000, Sec. III-A: "their background is extracted").

The model is the static scene seen by one camera: the mean of needle-free frames, optionally kept up to date
with a running average of the pixels away from the detected needle. It also bootstraps from a single frame
that shows the needle: a grey-level closing (dark needle) or opening (bright needle) wider than the needle
removes it. Subtracting the model, rather than thresholding raw grey levels, makes the detection robust to
uneven lighting; the coarse threshold is also relative to the local background brightness.
"""
from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, replace
from typing import Iterable

import cv2
import numpy as np


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Area-average by ``factor`` (1, 2, 4 or 8) in steps of two (OpenCV's fast path; ~0.1 ms at 1440x1080)."""
    while factor > 1:
        image = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)
        factor //= 2
    return image


@dataclass(frozen=True)
class ContrastThreshold:
    """A pixel is needle at the coarse level when ``polarity * (background - image)`` exceeds
    ``max(relative * background, absolute)`` [DN, image scale]; polarity +1 for a dark needle, -1 bright."""

    polarity: int = 1
    relative: float = 0.1
    absolute: float = 6.0
    downsample: int = 4


class BackgroundModel:
    """Per-camera background (float32, full resolution) and its coarse copy and threshold for detection."""

    def __init__(self, image: np.ndarray, threshold: ContrastThreshold):
        if image.ndim != 2:
            raise ValueError("background image must be single-channel")
        self.threshold = threshold
        self.image = np.array(image, dtype=np.float32)  # a copy: update() changes it in place
        self._refresh_coarse()

    def _refresh_coarse(self) -> None:
        self.coarse = downsample(self.image, self.threshold.downsample)
        self._set_limit()
        self._scratch = threading.local()

    def _set_limit(self) -> None:
        contrast = np.maximum(self.threshold.relative * self.coarse, self.threshold.absolute)
        # Grey level a coarse pixel must pass (below it for a dark needle, above for a bright one).
        self._coarse_limit = (self.coarse - self.threshold.polarity * contrast).astype(np.float32)

    def with_polarity(self, polarity: int) -> BackgroundModel:
        """This background for a needle of ``polarity`` (+1 dark, -1 bright), to replace this model: the image is
        shared, not copied (the new model's :meth:`update` changes this one's too), the coarse copy kept."""
        model = copy.copy(self)
        model.threshold = replace(self.threshold, polarity=polarity)
        model._set_limit()
        return model

    @property
    def coarse_scratch(self) -> np.ndarray:
        """Work space of the coarse path search (int32, coarse size), one per thread: pairs may be measured
        concurrently with the same model."""
        scratch = getattr(self._scratch, "index", None)
        if scratch is None:
            scratch = self._scratch.index = np.empty(self.coarse.shape, np.int32)
        return scratch

    def coarse_foreground(self, coarse_image: np.ndarray) -> np.ndarray:
        """Binarized coarse image (uint8, 255 = needle candidate): contrast to the background above
        ``max(relative * background, absolute)``."""
        comparison = cv2.CMP_LT if self.threshold.polarity > 0 else cv2.CMP_GT
        return cv2.compare(coarse_image.astype(np.float32), self._coarse_limit, comparison)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape

    @classmethod
    def from_frames(cls, frames: Iterable[np.ndarray], threshold: ContrastThreshold) -> "BackgroundModel":
        """Mean of needle-free frames."""
        frames = list(frames)
        if not frames:
            raise ValueError("no background frames")
        total = np.zeros(frames[0].shape, np.float32)  # exact sums of up to 65536 8-bit frames
        for frame in frames:
            if frame.shape != total.shape:
                raise ValueError(f"background frames differ in size: {frame.shape} vs {total.shape}")
            if frame.dtype in (np.uint8, np.uint16):
                cv2.accumulate(frame, total)  # the same float32 sums, ~1.5x faster (and without the GIL)
            else:
                total += frame
        total /= len(frames)
        return cls(total, threshold)

    @classmethod
    def from_median(cls, frames: Iterable[np.ndarray], threshold: ContrastThreshold) -> "BackgroundModel":
        """Per-pixel median of frames spread over a sequence in which the needle moves: each pixel shows the
        background in more than half of them, so the needle drops out (it does not where it stands still)."""
        frames = list(frames)
        if not frames:
            raise ValueError("no background frames")
        if any(frame.shape != frames[0].shape for frame in frames):
            raise ValueError("background frames differ in size")
        return cls(np.median(np.stack(frames), axis=0), threshold)

    @classmethod
    def from_needle_frame(cls, frame: np.ndarray, threshold: ContrastThreshold,
                          needle_width_px: int) -> "BackgroundModel":
        """Bootstrap from one frame showing the needle: a closing (dark needle) or opening (bright needle)
        with a square wider than the needle erases it. Texture finer than the square is flattened too, so a
        model from needle-free frames is more accurate."""
        size = 2 * int(needle_width_px) + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (size, size))
        operation = cv2.MORPH_CLOSE if threshold.polarity > 0 else cv2.MORPH_OPEN
        return cls(cv2.morphologyEx(frame, operation, kernel), threshold)

    def update(self, frame: np.ndarray, needle_points: np.ndarray, learning_rate: float,
               exclusion_radius_px: int) -> None:
        """Running average ``B <- (1 - rate) B + rate * frame`` except within ``exclusion_radius_px`` of the
        detected needle points ``(n, 2)`` (x, y pixels). Costs ~2 ms per 1440x1080 frame."""
        mask = np.full(self.image.shape, 255, np.uint8)
        if len(needle_points):
            cv2.polylines(mask, [np.round(needle_points).astype(np.int32)], False, 0, 2 * exclusion_radius_px + 1)
        cv2.accumulateWeighted(frame.astype(np.float32), self.image, learning_rate, mask)
        self._refresh_coarse()
