"""Velocity and acceleration of the measured centerline across frames (seed 000, Sec. III-A: the needle's
state "is defined by the position, velocity and acceleration of the point cloud").

Samples are identified across frames by their arc length from the base (the needle is inextensible and its base end is
seen). Over the last ``window`` frames a quadratic in time is fitted by least squares to each sample's position; its
first and second derivatives at the newest frame are the velocity and acceleration (exact for constant acceleration;
noise averaged, not amplified as by finite differences). The velocity along the needle is noisier than across it.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from needle_vision.detection.curves import interpolate


@dataclass(frozen=True)
class TrackingConfig:
    """``window``: frames in the fit (>= 3); ``max_gap`` [s]: a longer gap between frames restarts tracking."""

    window: int = 5
    max_gap: float = 0.05


@dataclass(frozen=True)
class CenterlineMotion:
    """Velocity [m/s] and acceleration [m/s²] ``(k, 3)`` of the newest measurement's samples."""

    velocity: np.ndarray
    acceleration: np.ndarray


class CenterlineTracker:
    """Keeps the last frames' centerlines; :meth:`update` returns the motion once ``window`` frames exist."""

    def __init__(self, config: TrackingConfig = TrackingConfig()):
        if config.window < 3:
            raise ValueError("tracking window must hold at least 3 frames")
        self.config = config
        self._frames: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=config.window)

    def update(self, stamp: float, arc_length: np.ndarray, points: np.ndarray) -> CenterlineMotion | None:
        """Add a measurement (samples ``points (k, 3)`` at ``arc_length (k,)``); None until the window is full.
        An older-or-equal stamp or a gap above ``max_gap`` restarts the window."""
        if self._frames and not (0 < stamp - self._frames[-1][0] <= self.config.max_gap):
            self._frames.clear()
        self._frames.append((stamp, np.asarray(arc_length, float), np.asarray(points, float)))
        if len(self._frames) < self.config.window:
            return None
        lag = np.array([frame[0] - stamp for frame in self._frames])
        # Every frame's centerline at the newest arc lengths (clamped at the tip of shorter frames).
        positions = np.stack([interpolate(frame[1], frame[2], arc_length) for frame in self._frames])
        design = np.column_stack([np.ones_like(lag), lag, lag ** 2])
        coefficients, *_ = np.linalg.lstsq(design, positions.reshape(len(lag), -1), rcond=None)
        shape = np.shape(points)
        return CenterlineMotion(coefficients[1].reshape(shape), 2 * coefficients[2].reshape(shape))
