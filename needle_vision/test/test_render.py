"""The synthetic renderer against geometry computed independently of it."""
import numpy as np
import pytest

from vision_shapes import SHAPES
from needle_vision.render import (NEEDLE_RADIUS, Imaging, needle_coverage, project_points, render_background_pair,
                                  render_stereo_pair, world_from_camera)


@pytest.mark.parametrize("blur", [0.0, 0.5])
def test_needle_coverage_is_centred_on_the_projected_axis_and_as_wide_as_the_tube(rig, blur):
    """Per image row, the coverage-weighted column is the projected centerline and the summed coverage is the
    tube's projected width 2 r f / Z (the straight needle runs along the rows of the left image)."""
    points = SHAPES["straight"]
    camera_points = world_from_camera(rig, "left").inverse().apply(points)
    rows, cols, coverage = needle_coverage(rig.left, camera_points, NEEDLE_RADIUS, blur)
    truth = project_points(rig, points, "left")
    errors, widths, expected = [], [], []
    for row in range(250, 850, 7):
        selected = rows == row
        errors.append((cols[selected] * coverage[selected]).sum() / coverage[selected].sum()
                      - np.interp(row, truth[:, 1], truth[:, 0]))
        widths.append(coverage[selected].sum())
        depth = np.interp(row, truth[:, 1], camera_points[:, 2])
        expected.append(2 * NEEDLE_RADIUS * rig.left.camera_matrix[0, 0] / depth)
    # Exact area coverage samples to an aliasing error of ~0.03 px (see centerline docstring); a 0.5 px blur
    # leaves the Gauss-Hermite quadrature error, ~0.002 px.
    assert np.max(np.abs(errors)) < (0.04 if blur == 0 else 0.005)
    # Width: distortion and the needle's slant change 2 r f / Z by < 3 % over this stretch.
    np.testing.assert_allclose(widths, expected, rtol=0.03)


def test_needle_ends_where_the_centerline_ends(rig):
    points = SHAPES["straight"]
    rows, _, coverage = needle_coverage(rig.left, world_from_camera(rig, "left").inverse().apply(points), NEEDLE_RADIUS)
    truth = project_points(rig, points, "left")
    first, last = sorted((truth[0, 1], truth[-1, 1]))
    # Flat ends: rows more than a pixel beyond an end are empty, rows a pixel inside are fully covered.
    assert not np.any(coverage[(rows < first - 1.0) | (rows > last + 1.0)] > 0)
    inside = [coverage[rows == row].sum() for row in (int(np.ceil(first)) + 1, int(np.floor(last)) - 1)]
    middle = coverage[rows == int((first + last) / 2)].sum()
    np.testing.assert_allclose(inside, middle, rtol=0.02)


def test_background_is_static_textured_and_unevenly_lit(rig, scene):
    first = render_background_pair(rig, np.random.default_rng(1), scene=scene)
    second = render_background_pair(rig, np.random.default_rng(2), scene=scene)
    difference = first[0].astype(float) - second[0].astype(float)
    signal = scene.illumination[0] * scene.background_albedo[0]
    expected_sigma = np.sqrt(2 * (Imaging().read_noise ** 2 + Imaging().shot_gain * signal.mean()) + 2 / 12)
    assert np.std(difference) == pytest.approx(expected_sigma, rel=0.05)  # only sensor noise changes
    assert abs(np.mean(difference)) < 0.05
    light = scene.illumination[0]
    assert light.max() / light.min() > 2.5  # uneven lighting
    assert np.std(scene.background_albedo[0]) > 0.05  # textured


def test_needle_darkens_the_image_only_along_its_projection(rig, scene):
    images = render_stereo_pair(rig, SHAPES["planar"], NEEDLE_RADIUS, np.random.default_rng(1), scene=scene,
                                imaging=Imaging(read_noise=0.0, shot_gain=0.0))
    background = render_background_pair(rig, np.random.default_rng(1), scene=scene,
                                        imaging=Imaging(read_noise=0.0, shot_gain=0.0))
    for k, side in enumerate(("left", "right")):
        changed = np.argwhere(np.abs(images[k].astype(int) - background[k].astype(int)) > 1)[:, ::-1]
        truth = project_points(rig, SHAPES["planar"], side)
        nearest = np.min(np.linalg.norm(changed[:, None, :] - truth[None, :, :], axis=2), axis=1)
        assert nearest.max() < 3.5  # half the tube (1.8 px) + 0.5 px pixel half-diagonal + blur + vertex spacing


def test_encodings_hold_the_same_picture(rig, scene):
    mono8 = render_stereo_pair(rig, SHAPES["straight"], NEEDLE_RADIUS, np.random.default_rng(5), scene=scene)[0]
    mono16 = render_stereo_pair(rig, SHAPES["straight"], NEEDLE_RADIUS, np.random.default_rng(5), scene=scene,
                                encoding="mono16")[0]
    bgr8 = render_stereo_pair(rig, SHAPES["straight"], NEEDLE_RADIUS, np.random.default_rng(5), scene=scene,
                              encoding="bgr8")[0]
    assert mono16.dtype == np.uint16 and bgr8.shape == mono8.shape + (3,)
    assert np.max(np.abs(mono16 / 257.0 - mono8)) <= 0.5  # same noise draw, finer quantisation
    np.testing.assert_array_equal(bgr8[..., 1], mono8)


@pytest.mark.parametrize("points, radius, message", [
    (np.zeros((1, 3)), NEEDLE_RADIUS, "n >= 2"),
    (SHAPES["straight"], 0.0, "radius"),
    (SHAPES["straight"] + [0.0, 1.0, 0.0], NEEDLE_RADIUS, "behind"),
])
def test_bad_render_input_is_rejected(rig, scene, points, radius, message):
    with pytest.raises(ValueError, match=message):
        render_stereo_pair(rig, points, radius, np.random.default_rng(0), scene=scene)


def _supersampled_silhouette(polygon: np.ndarray, lo: np.ndarray, shape: tuple[int, int], blur: float,
                             factor: int = 16) -> np.ndarray:
    """Independent reference: the convex silhouette rasterized at ``factor`` samples per pixel and axis, blurred
    by the Gaussian point spread at that resolution, then averaged over each pixel (pixel (0, 0) at ``lo``)."""
    import cv2

    samples = [(np.arange(size * factor) + 0.5) / factor - 0.5 + start for size, start in zip(shape[::-1], lo)]
    x, y = np.meshgrid(*samples)
    sides = [(b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
             for a, b in zip(polygon, np.roll(polygon, -1, axis=0))]
    inside = np.all(np.array(sides) >= 0, axis=0) | np.all(np.array(sides) <= 0, axis=0)
    fine = cv2.GaussianBlur(inside.astype(np.float64), (0, 0), blur * factor, borderType=cv2.BORDER_CONSTANT)
    return fine.reshape(shape[0], factor, shape[1], factor).mean(axis=(1, 3))


@pytest.mark.parametrize("angle", [0.3, 2.0])
@pytest.mark.parametrize("bevel", [1e-3, 2e-3])
def test_bevelled_end_is_the_blurred_wedge(angle, bevel):
    """A straight needle seen side-on at constant depth through the optical axis (no distortion): its silhouette
    is the band of half width f r / Z, the bevel a wedge (straight edge on the side (-d_y, d_x) of the end
    direction d, the other converging on it over f L / Z). The renderer's coverage against a 16x supersampled
    rasterization of that polygon, blurred by the same 0.5 px point spread: max abs difference 0.002-0.004 (the
    supersampling's own error; the flat base the same), before 0.06-0.16 (the band blurred across only, times a
    blurred flat-end cut: the last pixel's contrast halved)."""
    from needle_vision.calibration.rig import CameraCalibration

    focal, depth, blur = 1400.0, 0.5, 0.5
    camera = CameraCalibration(200, 200, [[focal, 0, 100.0], [0, focal, 100.0], [0, 0, 1]], [0, 0, 0, 0, 0])
    direction = np.array([np.cos(angle), np.sin(angle)])
    side = np.array([-direction[1], direction[0]])
    base = np.array([100.0, 100.0]) - 14.0 * direction
    tip = base + 10e-3 * focal / depth * direction
    half_width = NEEDLE_RADIUS * focal / depth
    polygon = np.array([base - half_width * side, base + half_width * side, tip + half_width * side,
                        tip - bevel * focal / depth * direction - half_width * side])
    ends = np.array([np.append((end - 100.0) * depth / focal, depth) for end in (base, tip)])
    rows, cols, coverage = needle_coverage(camera, np.linspace(ends[0], ends[1], 41), NEEDLE_RADIUS, blur,
                                           bevel_length=bevel)
    rendered = np.zeros((200, 200))
    rendered[rows, cols] = coverage
    lo = np.floor(np.minimum(base, tip) - 8).astype(int)
    hi = np.ceil(np.maximum(base, tip) + 8).astype(int)
    reference = _supersampled_silhouette(polygon, lo, (hi[1] - lo[1], hi[0] - lo[0]), blur)
    difference = rendered[lo[1]:hi[1], lo[0]:hi[0]] - reference
    assert np.abs(difference).max() < 0.01
    assert rendered.sum() == pytest.approx(reference.sum(), abs=0.05)  # the wedge's area: f L h / Z less
