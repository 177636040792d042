"""Synthetic stereo images of a needle for tests, benchmarks and sample bags (rig of seed 000, Sec. III-A).

A known 3D centerline is drawn as a tube of the needle's radius into both cameras of a calibrated, verged,
distorted rig. Each pixel's needle coverage is the exact area fraction of the pixel square covered by the
locally straight projected band (a box filter: anti-aliased edges with the response of a 100 % fill-factor
sensor), so the projected centerline is known to well below 0.01 px. The scene has a textured background
under uneven illumination (vignetting, a ramp and a spot light; a factor ~3 between dark and bright parts) and
the lens blurs slightly and the sensor adds read and shot noise before quantisation (:class:`Imaging`).

Use :func:`default_rig` for a rig like the paper's (two 1440x1080 cameras, 150 mm baseline, toed in to meet
0.5 m away, barrel distortion), :func:`make_scene` for the static scene, then :func:`render_stereo_pair` per
frame and :func:`render_background_pair` for needle-free frames. World frame (REP 103): the needle base
(clamp point A) at the origin, the undeformed needle along +x, gravity along -z; the cameras look at the
needle from +y.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from needle_vision.calibration.rig import CameraCalibration, StereoRig
from needle_vision.detection.curves import resample
from needle_vision.streams.image_codec import gray_to_encoding
from needle_common.transforms import RigidTransform, look_at_rotation

#: The paper's needle: radius [m] and length [m] (seed 000, Sec. III-A).
NEEDLE_RADIUS = 0.635e-3
NEEDLE_LENGTH = 0.27


def default_rig() -> StereoRig:
    """A rig like seed 000's: 1440x1080 cameras 150 mm apart, toed in (~8.5° each) to meet at the needle's
    middle 0.5 m away, with barrel distortion and small mounting errors (so nothing is parallel).

    The baseline (left -> right camera) points along world -z: the cameras are stacked, so the needle (along
    +x, rows of the image from base at the top to the tip at the bottom) crosses the epipolar lines.
    """
    look_at = np.array([0.135, 0.0, -0.04])
    midpoint = look_at + np.array([0.0, 0.5, 0.0])
    baseline_direction = np.array([0.0, 0.0, -1.0])
    centres = {"left": midpoint - 0.075 * baseline_direction, "right": midpoint + 0.075 * baseline_direction}
    mounting_error = {"left": np.radians([0.35, -0.2, 0.5]), "right": np.radians([-0.25, 0.3, -0.4])}
    poses = {side: RigidTransform(look_at_rotation(look_at - centres[side], baseline_direction)
                                  @ Rotation.from_rotvec(mounting_error[side]).as_matrix(), centres[side])
             for side in centres}
    left = CameraCalibration(1440, 1080, [[1402.5, 0, 726.3], [0, 1401.8, 533.9], [0, 0, 1]],
                             [-0.118, 0.092, 4e-4, -3e-4, -0.021], camera_name="left")
    right = CameraCalibration(1440, 1080, [[1398.7, 0, 712.8], [0, 1399.4, 546.2], [0, 0, 1]],
                              [-0.111, 0.084, -2e-4, 5e-4, -0.017], camera_name="right")
    right_from_left = poses["right"].inverse().compose(poses["left"])
    return StereoRig(left, right, right_from_left.rotation, right_from_left.translation, poses["left"])


def world_from_camera(rig: StereoRig, side: str) -> RigidTransform:
    """Pose of camera ``side`` ('left'/'right') in the world frame."""
    return rig.world_from_left if side == "left" else rig.world_from_left.compose(rig.left_from_right)


def _project(camera: CameraCalibration, points_camera: np.ndarray) -> np.ndarray:
    """Raw (distorted) pixel coordinates ``(n, 2)`` of points in the camera's optical frame."""
    pixels, _ = cv2.projectPoints(points_camera.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                  camera.camera_matrix, camera.distortion)
    return pixels.reshape(-1, 2)


def project_points(rig: StereoRig, points_world: np.ndarray, side: str) -> np.ndarray:
    """Raw (distorted) pixel coordinates ``(n, 2)`` of world points in camera ``side``."""
    camera = rig.left if side == "left" else rig.right
    return _project(camera, world_from_camera(rig, side).inverse().apply(np.asarray(points_world, dtype=float)))


@dataclass(frozen=True)
class Scene:
    """Static appearance seen by each camera: illumination [DN for albedo 1] and background albedo images
    (float32, image size), and the needle's albedo (dark steel against a bright background by default)."""

    illumination: tuple[np.ndarray, np.ndarray]
    background_albedo: tuple[np.ndarray, np.ndarray]
    needle_albedo: float = 0.12


@dataclass(frozen=True)
class Imaging:
    """Lens and sensor: the needle is seen through a Gaussian point spread of ``blur_sigma_px`` before pixel
    integration (a sharp lens near f/4: 0.5 px; 0 gives the bare pixel-area response; the background
    texture is smooth enough not to need it), then per-pixel noise [DN, 8-bit scale] of variance
    ``read_noise² + shot_gain * signal``, then quantisation."""

    blur_sigma_px: float = 0.5
    read_noise: float = 1.5
    shot_gain: float = 0.05


def _smooth_noise(rng: np.random.Generator, size: tuple[int, int], sigma: float) -> np.ndarray:
    """Gaussian-correlated noise of unit standard deviation with correlation length ``sigma`` [px]."""
    width, height = size
    factor = max(1, int(sigma // 2))  # blur a smaller field and enlarge it: same statistics, much faster
    field = rng.standard_normal((height // factor + 2, width // factor + 2)).astype(np.float32)
    field = cv2.GaussianBlur(field, (0, 0), sigma / factor)
    field = cv2.resize(field, (width + 2 * factor, height + 2 * factor), interpolation=cv2.INTER_CUBIC)
    field = field[factor:factor + height, factor:factor + width]
    return (field - field.mean()) / field.std()


def make_scene(rig: StereoRig, rng: np.random.Generator, *, brightness: float = 235.0,
               needle_albedo: float = 0.12, texture_contrast: float = 0.08, edge_contrast: float = 0.0,
               edge_width_px: float = 15.0) -> Scene:
    """A textured, unevenly lit background for each camera (see the module docstring). ``edge_contrast`` > 0
    adds a brightness ramp: the albedo falls by that fraction from the right to the left of a vertical edge
    through the image centre, over ~``edge_width_px`` (a tanh profile)."""
    illumination, albedo = [], []
    for camera in (rig.left, rig.right):
        width, height = camera.image_size
        y, x = np.mgrid[0:height, 0:width].astype(np.float32)
        u, v = (x - width / 2) / (width / 2), (y - height / 2) / (height / 2)
        angle, spot = rng.uniform(0, 2 * np.pi), rng.uniform(-0.6, 0.6, 2)
        ramp = 0.5 * (1 + np.cos(angle) * u * 0.8 + np.sin(angle) * v * 0.8)
        light = (1 - 0.3 * (u ** 2 + v ** 2)) * (0.45 + 0.4 * ramp) \
            + 0.25 * np.exp(-((u - spot[0]) ** 2 + (v - spot[1]) ** 2) / 0.15)
        illumination.append((brightness * light / light.max()).astype(np.float32))
        texture = 0.72 + texture_contrast * _smooth_noise(rng, (width, height), 4.0) \
            + texture_contrast * _smooth_noise(rng, (width, height), 30.0)
        ramp = 1 - 0.5 * edge_contrast * (1 - np.tanh((x - width / 2) / edge_width_px))
        albedo.append((np.clip(texture, 0.45, 0.95) * ramp).astype(np.float32))
    return Scene(tuple(illumination), tuple(albedo), needle_albedo)


_GAUSS_HERMITE = (lambda nodes, weights: (nodes, weights / weights.sum()))(*np.polynomial.hermite_e.hermegauss(12))


def _box_filtered_step(z: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """P(Z <= z) for Z = a*U1 + b*U2, U_i ~ U(-1/2, 1/2), a >= b >= 0: the fraction of a unit pixel whose
    signed distance to a straight edge (normal with |components| a, b) is below ``z``."""
    half_sum, half_diff = (a + b) / 2, (a - b) / 2
    safe_ab = np.maximum(2 * a * b, 1e-12)
    low = (z + half_sum) ** 2 / safe_ab
    high = 1 - (half_sum - z) ** 2 / safe_ab
    middle = 0.5 + z / a
    return np.where(z <= -half_sum, 0.0, np.where(z >= half_sum, 1.0,
                    np.where(z < -half_diff, low, np.where(z > half_diff, high, middle))))


def _blurred_step(z: np.ndarray, normal: np.ndarray, blur_sigma: float) -> np.ndarray:
    """Response of unit pixels at signed distance ``z`` inside a straight edge of unit ``normal`` (``(n, 2)`` or one
    for all): the area fraction inside, averaged over a Gaussian point spread of ``blur_sigma`` [px] (Gauss-Hermite
    quadrature; the exact area fraction when ``blur_sigma`` is 0)."""
    normal = np.abs(np.broadcast_to(normal, (len(z), 2)))
    a, b = normal.max(axis=1), normal.min(axis=1)
    nodes, weights = _GAUSS_HERMITE if blur_sigma > 0 else (np.zeros(1), np.ones(1))
    return sum(w * _box_filtered_step(z - blur_sigma * g, a, b) for g, w in zip(nodes, weights))


def _polygon_square_area(polygon: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Area of a polygon ``(k, 2)`` within the unit squares centred at ``centres`` ``(n, 2)`` (exact; Green's
    theorem: the area is the boundary integral of the x extent clamped to the square, over y within it)."""
    x0, x1 = centres[:, 0] - 0.5, centres[:, 0] + 0.5
    y0, y1 = centres[:, 1] - 0.5, centres[:, 1] + 0.5

    def clamped_integral(x: np.ndarray) -> np.ndarray:  # integral of clamp(s, x0, x1) - x0 from x0 to x
        inside = np.clip(x, x0, x1) - x0
        return 0.5 * inside ** 2 + (x1 - x0) * np.maximum(x - x1, 0.0)

    area = np.zeros(len(centres))
    for (xa, ya), (xb, yb) in zip(polygon, np.roll(polygon, -1, axis=0)):
        if ya == yb:
            continue
        low, high = np.clip(min(ya, yb), y0, y1), np.clip(max(ya, yb), y0, y1)
        slope = (xb - xa) / (yb - ya)
        x_low, x_high = xa + (low - ya) * slope, xa + (high - ya) * slope
        if abs(slope) < 1e-9:
            integral = (np.clip(x_low, x0, x1) - x0) * (high - low)
        else:
            integral = (clamped_integral(x_high) - clamped_integral(x_low)) / slope
        area += np.sign(yb - ya) * integral
    return np.abs(area)


def _polygon_coverage(pixels: np.ndarray, polygon: np.ndarray, blur_sigma: float, axis: np.ndarray) -> np.ndarray:
    """Response of unit pixels centred at ``pixels`` to a polygon: its area fraction within each pixel, averaged
    over an isotropic Gaussian point spread of ``blur_sigma`` [px] (2D Gauss-Hermite quadrature on the unit
    ``axis`` and its normal: across a band along ``axis`` the nodes are :func:`_blurred_step`'s)."""
    if blur_sigma <= 0:
        return _polygon_square_area(polygon, pixels)
    nodes, weights = _GAUSS_HERMITE
    normal = np.array([-axis[1], axis[0]])
    return sum(wa * wn * _polygon_square_area(polygon, pixels + blur_sigma * (ga * axis + gn * normal))
               for ga, wa in zip(nodes, weights) for gn, wn in zip(nodes, weights))


def _disc(centre: np.ndarray, normal: np.ndarray, radius: float, count: int = 64) -> np.ndarray:
    """``count`` points ``(count, 3)`` on the circle of ``radius`` about ``centre`` square to ``normal``."""
    normal = normal / np.linalg.norm(normal)
    first = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    second = np.cross(normal, first)
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)[:, None]
    return centre + radius * (np.cos(angle) * first + np.sin(angle) * second)


def _half_plane(polygon: np.ndarray, point: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """The part of a convex ``polygon`` ``(k, 2)`` on the ``outward`` side of the line through ``point`` square to
    it (Sutherland-Hodgman)."""
    side = (polygon - point) @ outward
    kept = []
    for k in range(len(polygon)):
        following = (k + 1) % len(polygon)
        if side[k] >= 0:
            kept.append(polygon[k])
        if (side[k] >= 0) != (side[following] >= 0):
            t = side[k] / (side[k] - side[following])
            kept.append(polygon[k] + t * (polygon[following] - polygon[k]))
    return np.array(kept).reshape(-1, 2)


def needle_coverage(camera: CameraCalibration, points_camera: np.ndarray, radius: float, blur_sigma_px: float = 0.0,
                    max_spacing_px: float = 0.5, bevel_length: float = 0.0, end_caps: bool = False
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel response to a tube (flat ends) around a centerline given in the camera's optical frame: the
    covered fraction of each pixel's area, through a Gaussian point spread of ``blur_sigma_px``.
    ``bevel_length`` > 0 [m]: the last end is bevelled as seen side-on: its silhouette is a wedge, one edge
    straight up to the tip (the bevel's point, on the side of the image normal (-d_y, d_x) of the end direction
    d), the other converging on it linearly from ``bevel_length`` before the tip; the wedge's exact area coverage
    is blurred by the point spread in both directions (along the needle too). ``end_caps``: each flat end also
    shows the half of its end disc (radius ``radius``, square to the end's tangent) that its projection puts
    beyond the flat cut: an ellipse of half axis ~``radius * |cos|`` (the angle between the tangent and the viewing
    ray) along the needle, nothing seen side-on, a whole disc seen end-on.

    Returns ``(rows, cols, coverage)`` of the pixels the tube touches. The centerline is resampled so that its
    projection has vertices at most ``max_spacing_px`` apart; the local half-width is the projected distance
    of the silhouette lines (``±radius`` across the viewing ray), which includes perspective and distortion.
    """
    points_camera = np.asarray(points_camera, dtype=float)
    project = partial(_project, camera)
    length_px = np.linalg.norm(np.diff(project(points_camera), axis=0), axis=1).sum()
    points = resample(points_camera, max(2, int(np.ceil(length_px / max_spacing_px)) + 1))
    centres = project(points)
    tangent = np.gradient(points, axis=0)
    lateral = np.cross(tangent, points)
    lateral_norm = np.linalg.norm(lateral, axis=1, keepdims=True)
    lateral = np.where(lateral_norm > 1e-12, lateral / np.maximum(lateral_norm, 1e-12), [1.0, 0.0, 0.0])
    half_width = 0.5 * np.linalg.norm(project(points + radius * lateral) - project(points - radius * lateral), axis=1)

    # Candidate pixels: a thick polyline around the projected centerline, within the image.
    margin = int(np.ceil(half_width.max() + 2 + 4 * blur_sigma_px))
    lo = np.maximum(np.floor(centres.min(axis=0)).astype(int) - margin, 0)
    hi = np.minimum(np.ceil(centres.max(axis=0)).astype(int) + margin + 1, [camera.width, camera.height])
    if np.any(hi <= lo):
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0)
    mask = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
    cv2.polylines(mask, [np.round((centres - lo) * 16).astype(np.int32)], False, 255, 2 * margin + 1,
                  lineType=cv2.LINE_8, shift=4)
    rows, cols = np.nonzero(mask)
    pixels = np.column_stack([cols + lo[0], rows + lo[1]]).astype(float)

    # Extend the band straight by a few pixels beyond both ends and measure the distance to it; a flat end then
    # multiplies by the covered fraction along the axis, a bevel subtracts the band beyond its wedge.
    end_tangents = [t / np.linalg.norm(t) for t in (centres[0] - centres[1], centres[-1] - centres[-2])]
    extended = np.vstack([centres[0] + 3 * end_tangents[0], centres, centres[-1] + 3 * end_tangents[1]])
    extended_half_width = np.concatenate([half_width[:1], half_width, half_width[-1:]])

    # Closest point on the projected polyline (nearest vertex, then its two segments).
    _, nearest = cKDTree(extended).query(pixels)
    best_distance = np.full(len(pixels), np.inf)
    best = np.zeros((len(pixels), 4))  # normal x, normal y, half-width at the closest point, signed distance
    for first in (nearest - 1, nearest):
        first = np.clip(first, 0, len(extended) - 2)
        start, direction = extended[first], extended[first + 1] - extended[first]
        length = np.maximum(np.linalg.norm(direction, axis=1), 1e-12)
        t = np.clip(np.einsum("ij,ij->i", pixels - start, direction) / length ** 2, 0.0, 1.0)
        offset = pixels - (start + t[:, None] * direction)
        distance = np.linalg.norm(offset, axis=1)
        normal = np.column_stack([-direction[:, 1], direction[:, 0]]) / length[:, None]
        better = distance < best_distance
        best_distance = np.where(better, distance, best_distance)
        best[better] = np.column_stack([normal, (1 - t) * extended_half_width[first]
                                        + t * extended_half_width[first + 1],
                                        np.einsum("ij,ij->i", offset, normal)])[better]
    # A band of half-width w at signed distance d: the edge at w - d less the one at -w - d.
    coverage = (_blurred_step(best[:, 2] - best[:, 3], best[:, :2], blur_sigma_px)
                - _blurred_step(-best[:, 2] - best[:, 3], best[:, :2], blur_sigma_px))
    ends = list(zip(centres[[0, -1]], end_tangents))[:1 if bevel_length > 0 else 2]  # a bevel: the last end below
    for (end, outward), point, inward in zip(ends, points[[0, -1]], (points[1] - points[0], points[-2] - points[-1])):
        near = np.linalg.norm(pixels - end, axis=1) < half_width.max() + 5 + 4 * blur_sigma_px  # + extension
        coverage[near] *= _blurred_step(-(pixels[near] - end) @ outward, outward, blur_sigma_px)
        if end_caps:
            cap = _half_plane(project(_disc(point, inward, radius)), end, outward)
            if len(cap) >= 3:
                coverage[near] += _polygon_coverage(pixels[near], cap, blur_sigma_px, outward)
    if bevel_length > 0:
        # Subtract the band beyond the wedge: from the bevel's start on the far edge to the point on the near
        # edge, then straight on. Pixels whose quadrature samples all lie past the tip (``reach``: the pixel's
        # half diagonal and the outermost node) lose the whole band; those before the bevel none of it.
        from_tip = np.linalg.norm(points - points[-1], axis=1)
        start = min(np.searchsorted(-from_tip, -bevel_length), len(points) - 1)  # first vertex within the bevel
        before = max(start - 1, 0)
        fraction = np.clip((from_tip[before] - bevel_length) / max(from_tip[before] - from_tip[start], 1e-12), 0, 1)
        bevel_start = project(points[before] + fraction * (points[start] - points[before]))[0]
        start_half_width = half_width[before] + fraction * (half_width[start] - half_width[before])
        tip, outward = centres[-1], end_tangents[1]
        side = np.array([-outward[1], outward[0]])  # the straight edge's side
        reach = np.sqrt(0.5) + (_GAUSS_HERMITE[0].max() * blur_sigma_px if blur_sigma_px > 0 else 0.0)
        removed = np.array([bevel_start - start_half_width * side, tip + half_width[-1] * side,
                            tip + (half_width[-1] * side + (2 * reach + 1) * outward),
                            tip - (half_width[-1] * side - (2 * reach + 1) * outward)])
        along = (pixels - tip) @ outward
        near = np.linalg.norm(pixels - tip, axis=1) < np.linalg.norm(tip - bevel_start) + 2 * margin + reach
        coverage[near & (along > reach)] = 0.0
        wedge = near & (along <= reach) & (along >= (bevel_start - tip) @ outward - reach)
        coverage[wedge] -= _polygon_coverage(pixels[wedge], removed, blur_sigma_px, outward)
    keep = coverage > 0
    return rows[keep] + lo[1], cols[keep] + lo[0], coverage[keep]


def noise_sigma(signal: np.ndarray, imaging: Imaging) -> np.ndarray:
    """Per-pixel standard deviation [DN] of the sensor noise on a noise-free ``signal`` (before quantisation)."""
    return np.sqrt(imaging.read_noise ** 2 + imaging.shot_gain * np.maximum(signal, 0))


def _expose(signal: np.ndarray, rng: np.random.Generator, imaging: Imaging, encoding: str) -> np.ndarray:
    noisy = signal + noise_sigma(signal, imaging) * rng.standard_normal(signal.shape, dtype=np.float32)
    return gray_to_encoding(noisy, encoding)


def render_background_pair(rig: StereoRig, rng: np.random.Generator, *, scene: Scene | None = None,
                           imaging: Imaging = Imaging(), encoding: str = "mono8"
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Needle-free frames (for the background model). ``scene`` defaults to ``make_scene(rig, rng(0))``."""
    scene = scene or make_scene(rig, np.random.default_rng(0))
    return tuple(_expose(scene.illumination[k] * scene.background_albedo[k], rng, imaging, encoding)
                 for k in range(2))


def render_signal(rig: StereoRig, centerline_points_world: np.ndarray, radius: float, *, scene: Scene | None = None,
                  imaging: Imaging = Imaging(), bevel_length: float = 0.0, end_caps: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free left and right images [DN, float32] of :func:`render_stereo_pair` (the signal its sensor
    noise and quantisation are applied to); the arguments are its."""
    points = np.asarray(centerline_points_world, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2 or not np.all(np.isfinite(points)):
        raise ValueError("centerline_points_world must be a finite (n >= 2, 3) array")
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    scene = scene or make_scene(rig, np.random.default_rng(0))
    signals = []
    for k, (side, camera) in enumerate((("left", rig.left), ("right", rig.right))):
        albedo = scene.background_albedo[k].copy()
        points_camera = world_from_camera(rig, side).inverse().apply(points)
        if np.any(points_camera[:, 2] <= radius):
            raise ValueError(f"part of the needle is behind the {side} camera")
        rows, cols, coverage = needle_coverage(camera, points_camera, radius, imaging.blur_sigma_px,
                                               bevel_length=bevel_length, end_caps=end_caps)
        albedo[rows, cols] = (1 - coverage) * albedo[rows, cols] + coverage * scene.needle_albedo
        signals.append(scene.illumination[k] * albedo)
    return signals[0], signals[1]


def render_stereo_pair(rig: StereoRig, centerline_points_world: np.ndarray, radius: float,
                       rng: np.random.Generator, *, scene: Scene | None = None,
                       imaging: Imaging = Imaging(), encoding: str = "mono8", bevel_length: float = 0.0,
                       end_caps: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Left and right images of a tube of ``radius`` [m] around ``centerline_points_world`` ``(n, 3)`` [m].

    The centerline is taken as the polyline through the points (give them densely, e.g. every 0.5 mm).
    ``encoding``: mono8, mono16, bgr8 or rgb8. ``scene`` defaults to ``make_scene(rig, rng(0))`` (make it once
    and pass it when rendering many frames: it costs ~0.1 s). ``bevel_length`` [m]: the last point's end
    bevelled over that length (see :func:`needle_coverage`; 0: cut flat); ``end_caps``: the flat ends show their end
    discs (see there). The noise-free images: :func:`render_signal`.
    """
    signals = render_signal(rig, centerline_points_world, radius, scene=scene, imaging=imaging,
                            bevel_length=bevel_length, end_caps=end_caps)
    return _expose(signals[0], rng, imaging, encoding), _expose(signals[1], rng, imaging, encoding)
