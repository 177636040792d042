"""Per-pair stereo measurement of the needle with its state (seed 000, Sec. III-A): background models, the
reconstruction of each synchronised pair, and optional tracking. Shared by the node and the offline command.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace
from enum import Enum

import cv2
import numpy as np

from needle_vision.detection.background import BackgroundModel, ContrastThreshold, downsample
from needle_vision.streams.base_pose import BasePoseStore
from needle_vision.calibration.rig import StereoRig
from needle_vision.detection.centerline import CenterlineConfig, ImageCenterline, NoNeedleError, extract_centerline
from needle_vision.matching.correspondence import MatchError, MatchingConfig
from needle_vision.matching.reconstruction import (ImplausibleError, NeedleMeasurement, ReconstructionConfig,
                                                   Triangulation, order_and_resample, triangulate_centerline)
from needle_vision.calibration.rectification import Rectification
from needle_vision.matching.tracking import CenterlineMotion, CenterlineTracker, TrackingConfig
from needle_common.transforms import RigidTransform


@dataclass(frozen=True)
class StereoConfig:
    """Everything the measurement needs besides the rig (the node's parameters, grouped).

    ``background_frames``: the first pairs, assumed needle-free, averaged into the background (0: bootstrap
    from the first pair by erasing the needle morphologically); ``background_learning_rate``: running update of
    the background away from the needle after each measurement (0: static); ``tracking``: None disables it.
    """

    threshold: ContrastThreshold = ContrastThreshold()
    centerline: CenterlineConfig = CenterlineConfig()
    matching: MatchingConfig = MatchingConfig()
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    background_frames: int = 10
    background_learning_rate: float = 0.0
    tracking: TrackingConfig | None = None
    auto_polarity: bool = True  # decide dark/bright needle from the first frame that shows it (else threshold's)


def _largest_component(mask: np.ndarray) -> int:
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return int(stats[1:, cv2.CC_STAT_AREA].max()) if count > 1 else 0


def detect_polarity(darkening: np.ndarray, brightening: np.ndarray, background: np.ndarray,
                    threshold: ContrastThreshold) -> int:
    """+1 (dark needle) when the largest connected structure darker than the background by more than the
    threshold is twice the largest brighter one, -1 (bright) for the converse, 0 when neither dominates.
    ``darkening``/``brightening``: how much darker/brighter than the background each pixel is [DN]; all three
    images at the coarse scale (downsampled by ``threshold.downsample``)."""
    limit = np.maximum(threshold.relative * background, threshold.absolute)
    darker, brighter = (_largest_component(excess > limit) for excess in (darkening, brightening))
    if darker >= 2 * brighter and darker > 0:
        return 1
    if brighter >= 2 * darker and brighter > 0:
        return -1
    return 0


class FrameStatus(Enum):
    BACKGROUND = "used to build the background model"
    MEASURED = "needle measured"
    REJECTED = "rejected"


@dataclass(frozen=True)
class FrameResult:
    """Outcome of one pair: status, the measurement and motion when measured, the reason when rejected, and
    what told the base from the tip (``ordering``: "base pose", "continuity" or "base point")."""

    status: FrameStatus
    measurement: NeedleMeasurement | None = None
    motion: CenterlineMotion | None = None
    reason: str = ""
    ordering: str = ""


@dataclass(frozen=True)
class PairMeasurement:
    """The part of a pair's measurement that does not depend on earlier pairs (:meth:`StereoNeedlePipeline.measure`):
    the image centerlines and the triangulation, or why the pair is rejected (kind, reason)."""

    centerlines: tuple[ImageCenterline, ImageCenterline] | None = None
    triangulation: Triangulation | None = None
    rejection: tuple[str, str] = ("", "")


class StereoNeedlePipeline:
    """Measures the needle in synchronised pairs of raw grey images (uint8 or uint16) of ``rig``.

    Immutable model: rig, rectification, config, ``output_from_left`` (pose of the left optical frame in the
    output frame). Mutable state: background models, background frames collected so far, the tracker, the last
    measured base and ``rejections``, counted by reason kind.

    Base and tip: the end nearer to the base pose of ``base_poses`` at the pair's stamp (fresh poses only), else
    nearer to the previous frame's base (temporal continuity), else nearer to ``reconstruction.base_point``.
    """

    def __init__(self, rig: StereoRig, config: StereoConfig = StereoConfig(),
                 output_from_left: RigidTransform = RigidTransform(), base_poses: BasePoseStore | None = None):
        self.rig = rig
        self.config = config
        self.output_from_left = output_from_left
        self.rectification = Rectification.from_rig(rig)
        self.backgrounds: tuple[BackgroundModel, BackgroundModel] | None = None
        self._background_frames: list[tuple[np.ndarray, np.ndarray]] = []
        self._dtype: np.dtype | None = None
        self.tracker = CenterlineTracker(config.tracking) if config.tracking else None
        self.last_base: np.ndarray | None = None
        self.base_poses = base_poses
        self.polarity = 0 if config.auto_polarity else config.threshold.polarity  # 0: not decided yet
        self.rejections: Counter[str] = Counter()

    def _reject(self, kind: str, reason: str) -> FrameResult:
        self.rejections[kind] += 1
        return FrameResult(FrameStatus.REJECTED, reason=reason)

    def _check(self, left: np.ndarray, right: np.ndarray) -> str:
        """Why the pair cannot be used, or ''."""
        for side, image, camera in (("left", left, self.rig.left), ("right", right, self.rig.right)):
            if image.ndim != 2:
                return f"{side} image is not single-channel"
            if image.shape != (camera.height, camera.width):
                return (f"{side} image is {image.shape[1]}x{image.shape[0]} but its calibration is "
                        f"{camera.width}x{camera.height}")
        if left.dtype != right.dtype:
            return f"left and right images differ in depth ({left.dtype} vs {right.dtype})"
        if self._dtype is not None and left.dtype != self._dtype:
            return f"image depth changed from {self._dtype} to {left.dtype} (the background model is {self._dtype})"
        return ""

    def process(self, stamp: float, left: np.ndarray, right: np.ndarray) -> FrameResult:
        """Use one synchronised pair (stamp [s]) for the background or measure the needle in it."""
        problem = self._check(left, right)
        if problem:
            return self._reject("bad input", problem)
        self._dtype = left.dtype
        config = self.config
        threshold = replace(config.threshold, polarity=self.polarity or 1)
        if self.backgrounds is None and config.background_frames > 0:
            self._background_frames.append((left.copy(), right.copy()))
            if len(self._background_frames) == config.background_frames:
                self.backgrounds = tuple(BackgroundModel.from_frames([pair[k] for pair in self._background_frames],
                                                                     threshold) for k in range(2))
                self._background_frames.clear()
            return FrameResult(FrameStatus.BACKGROUND)
        backgrounds = self.backgrounds
        if not self.polarity:
            if backgrounds is None:  # thin dark structures filled by a closing, thin bright ones by an opening
                image = left.astype(np.float32)
                size = 2 * config.centerline.profile_half_width + 1
                kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
                polarity = detect_polarity(*(downsample(excess, threshold.downsample) for excess in (
                    cv2.morphologyEx(image, cv2.MORPH_CLOSE, kernel) - image,
                    image - cv2.morphologyEx(image, cv2.MORPH_OPEN, kernel), image)), threshold)
            else:  # the coarse brightening is minus the coarse darkening (area averages commute with the sign exactly)
                coarse = downsample(backgrounds[0].image - left, threshold.downsample)  # float32 (promoted)
                polarity = detect_polarity(coarse, -coarse, backgrounds[0].coarse, threshold)
            if not polarity:
                return self._reject("no needle", "neither a dark nor a bright needle stands out (polarity auto)")
            threshold = replace(threshold, polarity=polarity)
            if backgrounds is None:  # bootstrapped from this pair: kept
                self.polarity = polarity
            else:  # kept only once a needle is measured with it (not on empty frames)
                backgrounds = tuple(background.with_polarity(polarity) for background in backgrounds)
        if backgrounds is None:
            backgrounds = self.backgrounds = tuple(BackgroundModel.from_needle_frame(
                image, threshold, config.centerline.profile_half_width) for image in (left, right))
        return self._complete(stamp, left, right, self._measure(left, right, backgrounds), threshold, backgrounds)

    @property
    def settled(self) -> bool:
        """Whether pairs can be measured independently of each other (:meth:`measure` on any thread, then
        :meth:`complete` in order): backgrounds built, polarity decided, no running background update."""
        return self.backgrounds is not None and self.polarity != 0 and self.config.background_learning_rate == 0

    def measure(self, left: np.ndarray, right: np.ndarray) -> PairMeasurement:
        """The part of :meth:`process` that does not depend on earlier pairs; the pipeline must be ``settled``.
        Thread-safe: reads the pipeline's immutable model only."""
        problem = self._check(left, right)
        return PairMeasurement(rejection=("bad input", problem)) if problem else self._measure(left, right,
                                                                                                self.backgrounds)

    def complete(self, stamp: float, left: np.ndarray, right: np.ndarray, pair: PairMeasurement) -> FrameResult:
        """:meth:`process` of a settled pipeline given the pair's :meth:`measure`: ordering, state, tracking
        (pairs in order)."""
        if pair.rejection[0] == "bad input":
            return self._reject(*pair.rejection)
        self._dtype = left.dtype
        threshold = replace(self.config.threshold, polarity=self.polarity)
        return self._complete(stamp, left, right, pair, threshold, self.backgrounds)

    def _measure(self, left: np.ndarray, right: np.ndarray,
                 backgrounds: tuple[BackgroundModel, BackgroundModel]) -> PairMeasurement:
        config = self.config
        try:
            centerlines = tuple(extract_centerline(image, background, config.centerline)
                                for image, background in zip((left, right), backgrounds))
            return PairMeasurement(centerlines, triangulate_centerline(*centerlines, self.rectification,
                                                                       config.matching, config.reconstruction,
                                                                       self.output_from_left))
        except (NoNeedleError, MatchError) as error:  # ImplausibleError is a MatchError
            kind = {NoNeedleError: "no needle", ImplausibleError: "implausible"}.get(type(error), "no stereo match")
            return PairMeasurement(rejection=(kind, str(error)))

    def _complete(self, stamp: float, left: np.ndarray, right: np.ndarray, pair: PairMeasurement,
                  threshold: ContrastThreshold, backgrounds: tuple[BackgroundModel, BackgroundModel]) -> FrameResult:
        """Order base to tip (base pose, else continuity, else base point), then update the state."""
        config = self.config
        if pair.rejection[0]:
            return self._reject(*pair.rejection)
        base = self.base_poses.base_at(stamp) if self.base_poses is not None else None
        ordering = "base pose" if base is not None else "continuity" if self.last_base is not None else "base point"
        try:
            measurement = order_and_resample(pair.triangulation, self.rectification, config.reconstruction,
                                             self.output_from_left, self.last_base if base is None else base)
        except ImplausibleError as error:
            return self._reject("implausible", str(error))
        self.last_base = measurement.points[0]
        self.polarity, self.backgrounds = threshold.polarity, backgrounds
        if config.background_learning_rate > 0:
            for image, background, centerline in zip((left, right), self.backgrounds, pair.centerlines):
                background.update(image, centerline.points, config.background_learning_rate,
                                  2 * config.centerline.profile_half_width)
        motion = self.tracker.update(stamp, measurement.arc_length, measurement.points) if self.tracker else None
        return FrameResult(FrameStatus.MEASURED, measurement, motion, ordering=ordering)


def compile_kernels() -> float:
    """Compile, or load from numba's cache, the measurement's kernels on one rendered pair (uint8 and uint16,
    writable and read-only, ordered either way, and with the curve fit); returns the seconds it took. Run by the node
    before it subscribes and by the install step, so that the first real pairs do not wait for compilation."""
    import time

    from needle_vision.render import NEEDLE_RADIUS, default_rig, make_scene, render_background_pair, render_stereo_pair

    start = time.perf_counter()
    rig = default_rig()
    scene = make_scene(rig, np.random.default_rng(0))
    arc = np.linspace(0.0, 0.27, 271)
    bent = np.column_stack([arc, np.zeros_like(arc), -0.2 * arc ** 2])
    background = render_background_pair(rig, np.random.default_rng(1), scene=scene)
    needle = render_stereo_pair(rig, bent, NEEDLE_RADIUS, np.random.default_rng(2), scene=scene)
    for scale, dtype in ((1, np.uint8), (256, np.uint16)):
        pipeline = StereoNeedlePipeline(rig, StereoConfig(background_frames=1))
        pipeline.process(0.0, *(np.asarray(image, dtype) * scale for image in background))
        images = [np.asarray(image, dtype) * scale for image in needle]
        measured = pipeline.process(1.0, *images).measurement
        for image in images:  # a bag's images are read-only views of the file: kernels typed for those too
            image.setflags(write=False)
        pipeline.last_base = measured.points[-1]  # and ordered the other way round (reversed arrays)
        pipeline.process(2.0, *images)
    fitted = StereoNeedlePipeline(rig, StereoConfig(background_frames=1,
                                                    reconstruction=ReconstructionConfig(curve_fit=True)))
    fitted.process(0.0, *background)  # the curve fit's kernels (reconstruction.curve_fit)
    fitted.process(1.0, *needle)
    return time.perf_counter() - start
