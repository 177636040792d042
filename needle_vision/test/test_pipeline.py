"""The per-pair pipeline: background phase, bad input (defined rejection, never a crash), tracking."""
import numpy as np
import pytest

from vision_shapes import SHAPES, distance_to_curve
from needle_vision.detection.background import BackgroundModel, ContrastThreshold
from needle_vision.pipeline import FrameStatus, StereoConfig, StereoNeedlePipeline
from needle_vision.matching.reconstruction import ReconstructionConfig
from needle_vision.render import NEEDLE_LENGTH, NEEDLE_RADIUS, make_scene, render_background_pair, render_stereo_pair
from needle_vision.matching.tracking import TrackingConfig


@pytest.fixture(scope="module")
def ready(rig, background_frames):
    """A pipeline that has built its background from the session's needle-free frames."""
    pipeline = StereoNeedlePipeline(rig, StereoConfig(background_frames=len(background_frames)), rig.world_from_left)
    statuses = [pipeline.process(0.01 * k, *pair).status for k, pair in enumerate(background_frames)]
    assert statuses == [FrameStatus.BACKGROUND] * len(background_frames)
    return pipeline


def test_measures_after_the_background_frames(ready, renders):
    result = ready.process(1.0, *renders("planar"))
    assert result.status is FrameStatus.MEASURED and result.motion is None
    distance, _ = distance_to_curve(result.measurement.points, SHAPES["planar"])
    assert np.sqrt(np.mean(distance ** 2)) < 1e-4


def test_bootstrapped_background_needs_no_needle_free_frames(rig, renders):
    pipeline = StereoNeedlePipeline(rig, StereoConfig(background_frames=0), rig.world_from_left)
    result = pipeline.process(0.0, *renders("3d"))
    assert result.status is FrameStatus.MEASURED
    distance, _ = distance_to_curve(result.measurement.points, SHAPES["3d"])
    # The closing flattens the background texture near the needle: ~3x the error of averaged frames.
    assert np.sqrt(np.mean(distance ** 2)) < 2e-4


@pytest.mark.parametrize("change, reason", [
    (lambda l, r: (l[:540], r), "left image is 1440x540 but its calibration is 1440x1080"),
    (lambda l, r: (l, r.astype(np.uint16)), "differ in depth"),
    (lambda l, r: (l.astype(np.uint16) * 257, r.astype(np.uint16) * 257), "depth changed"),
    (lambda l, r: (np.dstack([l, l, l]), r), "not single-channel"),
])
def test_unusable_pairs_are_rejected_with_a_reason(ready, renders, change, reason):
    result = ready.process(2.0, *change(*renders("straight")))
    assert result.status is FrameStatus.REJECTED and reason in result.reason


def test_pair_without_needle_is_rejected(ready, background_frames):
    result = ready.process(3.0, *background_frames[0])
    assert result.status is FrameStatus.REJECTED and "no pixel differs" in result.reason


def test_needle_seen_by_one_camera_only_is_rejected(ready, renders, background_frames):
    result = ready.process(4.0, renders("straight")[0], background_frames[0][1])
    assert result.status is FrameStatus.REJECTED


def test_running_background_update_keeps_the_needle_out(rig, background_frames, renders):
    model = BackgroundModel(background_frames[0][0], ContrastThreshold())
    image = renders("straight")[0]
    before = model.image.copy()
    centerline_points = np.array([[621.0, 170.0], [624.0, 918.0]])  # the straight needle in the left image
    model.update(image, centerline_points, 0.5, 8)
    moved = np.abs(model.image - before)
    np.testing.assert_array_equal(moved[540, 618:628], 0)  # the needle's pixels are excluded
    assert np.mean(moved[:, :500]) > 0.5  # elsewhere the model moves towards the frame (noise: ~2.5 DN)


def test_tracking_gives_the_velocity_of_a_moving_needle(rig, scene, background_frames):
    pipeline = StereoNeedlePipeline(rig, StereoConfig(background_frames=len(background_frames),
                                                      tracking=TrackingConfig(window=5, max_gap=0.05)),
                                    rig.world_from_left)
    for pair in background_frames:
        pipeline.process(0.0, *pair)
    velocity = np.array([0.0, 0.0, -0.2])  # the whole needle falls at 0.2 m/s
    for k in range(5):
        t = 0.1 + k / 220.0
        pair = render_stereo_pair(rig, SHAPES["straight"] + velocity * t, NEEDLE_RADIUS,
                                  np.random.default_rng(k), scene=scene)
        result = pipeline.process(t, *pair)
    assert result.status is FrameStatus.MEASURED
    mean = result.motion.velocity.mean(axis=0)
    # Across the needle (y, z): position noise ~0.04 mm per frame over 18 ms, averaged over the needle.
    np.testing.assert_allclose(mean[1:], velocity[1:], atol=0.01)
    # Along it (x) samples are identified by arc length from the detected base end, whose detection jitters by
    # ~0.1 mm: tangential velocity is ~5x noisier (see needle_vision.matching.tracking).
    assert abs(mean[0]) < 0.05
    assert result.motion.velocity.shape == result.measurement.points.shape


@pytest.mark.parametrize("seed", range(3))
def test_random_noise_frames_give_no_needle(ready, rig, seed):
    rng = np.random.default_rng(seed)
    shape = (rig.left.height, rig.left.width)
    before = sum(ready.rejections.values())
    result = ready.process(10.0 + seed, *(rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(2)))
    assert result.status is FrameStatus.REJECTED and result.measurement is None
    assert sum(ready.rejections.values()) == before + 1


def test_blank_frames_give_no_needle_and_are_counted(ready, rig):
    """Black, mid-grey (measured a needle before rejection existed) and white frames."""
    shape = (rig.left.height, rig.left.width)
    before = sum(ready.rejections.values())
    for level in (0, 128, 255):
        result = ready.process(20.0, np.full(shape, level, np.uint8), np.full(shape, level, np.uint8))
        assert result.status is FrameStatus.REJECTED and result.measurement is None, level
    assert sum(ready.rejections.values()) == before + 3


def test_longer_than_the_configured_needle_is_rejected_as_implausible(rig, background_frames, renders):
    config = StereoConfig(background_frames=len(background_frames),
                          reconstruction=ReconstructionConfig(max_length=0.5 * NEEDLE_LENGTH))
    pipeline = StereoNeedlePipeline(rig, config, rig.world_from_left)
    for k, pair in enumerate(background_frames):
        pipeline.process(0.01 * k, *pair)
    result = pipeline.process(1.0, *renders("straight"))
    assert result.status is FrameStatus.REJECTED and result.reason.startswith("implausible: measured needle")
    assert pipeline.rejections == {"implausible": 1}


def test_base_and_tip_keep_their_order_by_temporal_continuity(rig, background_frames, renders):
    """A configured base point nearer the base of the straight needle but nearer the tip of the hook: the
    hook's ends follow the previous frame's base instead (independent truth: the shapes' own base, the origin)."""
    base_point = np.array([0.45 * NEEDLE_LENGTH, 0.0, -0.06])
    straight, hook = SHAPES["straight"], SHAPES["hook"]
    assert np.linalg.norm(straight[0] - base_point) < np.linalg.norm(straight[-1] - base_point)
    assert np.linalg.norm(hook[-1] - base_point) < np.linalg.norm(hook[0] - base_point)  # the premise
    config = StereoConfig(background_frames=len(background_frames),
                          reconstruction=ReconstructionConfig(base_point=base_point))
    pipeline = StereoNeedlePipeline(rig, config, rig.world_from_left)
    for k, pair in enumerate(background_frames):
        pipeline.process(0.01 * k, *pair)
    for stamp, name in ((1.0, "straight"), (1.01, "hook")):
        result = pipeline.process(stamp, *renders(name))
        assert result.status is FrameStatus.MEASURED
        assert np.linalg.norm(result.measurement.points[0]) < 2e-3, name  # base measured at the origin


@pytest.mark.parametrize("albedo, polarity", [(None, 1), (1.0, -1)])
@pytest.mark.parametrize("frames", [4, 0])
def test_polarity_is_detected_automatically(rig, albedo, polarity, frames):
    """A dark needle on the default scene, a shiny (bright, contrast ~0.3) one: measured without being told,
    with averaged and with bootstrapped backgrounds."""
    scene = make_scene(rig, np.random.default_rng(4), **({} if albedo is None else {"needle_albedo": albedo}))
    pipeline = StereoNeedlePipeline(rig, StereoConfig(background_frames=frames), rig.world_from_left)
    assert pipeline.config.auto_polarity
    for k in range(frames):
        pipeline.process(0.01 * k, *render_background_pair(rig, np.random.default_rng(k), scene=scene))
    result = pipeline.process(1.0, *render_stereo_pair(rig, SHAPES["planar"], NEEDLE_RADIUS,
                                                       np.random.default_rng(9), scene=scene))
    assert pipeline.polarity == polarity
    if frames == 0 and albedo is not None:
        # Decided, but the shiny needle's low contrast on a background bootstrapped from the same frame scatters
        # the centerline (1.5 px): rejected as low-confidence whatever the polarity setting (known limitation).
        assert result.status is FrameStatus.REJECTED and "scatters" in result.reason
        return
    assert result.status is FrameStatus.MEASURED, result.reason
    distance, _ = distance_to_curve(result.measurement.points, SHAPES["planar"])
    # A third of the dark needle's contrast, or a background bootstrapped from this frame: 0.1-0.3 mm.
    assert np.sqrt(np.mean(distance ** 2)) < 0.35e-3


@pytest.mark.parametrize("seed", range(3))
def test_polarity_from_the_coarse_difference_is_detect_polaritys(seed):
    """The pipeline decides the polarity on its averaged background from one downsampled difference and the
    background's kept coarse image: the same bits as three downsamplings of the full images."""
    from needle_vision.detection.background import downsample
    from needle_vision.pipeline import detect_polarity

    rng = np.random.default_rng(seed)
    background = rng.uniform(20.0, 230.0, (216, 288)).astype(np.float32)
    image = (background - rng.normal(0.0, 8.0, background.shape)).astype(np.float32)
    image[100:104, 20:260] -= 60.0 * (1 - 2 * (seed % 2))  # a dark or a bright needle
    threshold = ContrastThreshold()
    difference = background - image
    coarse = downsample(difference, threshold.downsample)
    assert np.array_equal(downsample(-difference, threshold.downsample), -coarse)
    assert np.array_equal(BackgroundModel(background, threshold).coarse, downsample(background, threshold.downsample))
    expected = detect_polarity(*(downsample(image, threshold.downsample) for image in (difference, -difference,
                                                                                        background)), threshold)
    assert expected == (1 if seed % 2 == 0 else -1)
    assert detect_polarity(coarse, -coarse, BackgroundModel(background, threshold).coarse, threshold) == expected


@pytest.mark.parametrize("polarity", [1, -1])
def test_background_for_another_polarity_is_the_model_built_for_it(polarity):
    """A model switched to the polarity the pipeline decided: the image shared (not copied) and the coarse copy kept,
    the threshold and foreground those of a model built for that polarity. The pipeline's coarse difference of an 8-
    or 16-bit image from it is float32 without converting the image first (the same bits)."""
    from needle_vision.detection.background import downsample

    rng = np.random.default_rng(5)
    background = rng.uniform(20.0, 230.0, (216, 288)).astype(np.float32)
    model = BackgroundModel(background, ContrastThreshold(polarity=-polarity))
    switched = model.with_polarity(polarity)
    built = BackgroundModel(background, ContrastThreshold(polarity=polarity))
    assert switched.threshold == built.threshold and model.threshold.polarity == -polarity
    assert switched.image is model.image and switched.coarse is model.coarse
    image = background + rng.normal(0.0, 20.0, background.shape).astype(np.float32)
    coarse = downsample(image, built.threshold.downsample)
    assert np.array_equal(switched.coarse_foreground(coarse), built.coarse_foreground(coarse))
    assert not np.array_equal(switched.coarse_foreground(coarse), model.coarse_foreground(coarse))
    for raw in (np.clip(image, 0, 255).astype(np.uint8), (np.clip(image, 0, 255) * 257).astype(np.uint16)):
        difference = switched.image - raw
        assert difference.dtype == np.float32 and np.array_equal(difference, switched.image - raw.astype(np.float32))
