"""Known needle centerlines for the vision tests, an independent distance-to-curve measure, occluded or faded
renders and the "no invented points" check."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from needle_vision.calibration.rig import StereoRig
from needle_vision.detection.background import BackgroundModel, ContrastThreshold
from needle_vision.matching.reconstruction import UNMEASURED, NeedleMeasurement
from needle_vision.render import NEEDLE_LENGTH, Scene, project_points, render_background_pair

SAMPLES = 1081  # 0.25 mm along the needle: the polyline is the true curve to ~1e-8 m for these curvatures


def bright_scene(scene: Scene) -> Scene:
    """The bright polarity of the tests and benches: a needle of albedo 0.9 on ``scene``'s background at 0.3x its
    albedo."""
    return Scene(scene.illumination, tuple(0.3 * albedo for albedo in scene.background_albedo), 0.9)


def background_frames(rig: StereoRig, scene: Scene) -> list[tuple[np.ndarray, np.ndarray]]:
    """Eight needle-free pairs of ``scene`` (the default background model averages ten; eight keep the noise of
    the model at a third of a frame's)."""
    return [render_background_pair(rig, np.random.default_rng(100 + k), scene=scene) for k in range(8)]


def background_models(rig: StereoRig, scene: Scene, threshold: ContrastThreshold = ContrastThreshold()
                      ) -> tuple[BackgroundModel, BackgroundModel]:
    """Both cameras' background models from :func:`background_frames` of ``scene``."""
    return models_of_frames(background_frames(rig, scene), threshold)


def models_of_frames(frames: list[tuple[np.ndarray, np.ndarray]], threshold: ContrastThreshold = ContrastThreshold()
                     ) -> tuple[BackgroundModel, BackgroundModel]:
    """Both cameras' background models from needle-free ``frames`` (left, right) pairs."""
    return tuple(BackgroundModel.from_frames([pair[k] for pair in frames], threshold) for k in range(2))


def centerline_from_angles(pitch, yaw=lambda xi: 0.0 * xi, length: float = NEEDLE_LENGTH) -> np.ndarray:
    """An inextensible centerline from the base (origin) along +x, bent by pitch (about -y, towards +z) and
    yaw (about z) angles given as functions of the normalised arc length xi in [0, 1]."""
    xi = np.linspace(0.0, 1.0, SAMPLES)
    p, y = pitch(xi), yaw(xi)
    tangent = np.column_stack([np.cos(p) * np.cos(y), np.cos(p) * np.sin(y), np.sin(p)])
    steps = 0.5 * (tangent[1:] + tangent[:-1]) * length / (SAMPLES - 1)  # trapezoid rule
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def _planar_deflection(tip_deflection: float) -> np.ndarray:
    """Cantilever-like bend (slope profile of a tip-loaded beam, 2xi - xi²) with the given downward tip
    deflection [m]."""
    shape = lambda angle: centerline_from_angles(lambda xi: -angle * (2 * xi - xi ** 2))
    angle = brentq(lambda a: -shape(a)[-1, 2] - tip_deflection, 0.0, 1.5)
    return shape(angle)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


SHAPES = {
    "straight": centerline_from_angles(lambda xi: 0.0 * xi),
    "planar": _planar_deflection(0.15),
    # Out of the cameras' viewing plane: towards the cameras (+y) and down, 3D curvature.
    "3d": centerline_from_angles(lambda xi: -0.5 * (2 * xi - xi ** 2), lambda xi: 0.45 * np.sin(np.pi * xi / 1.6)),
    # Straight, a 90° bend, then a 54 mm tail hanging along -z: along the rig's baseline, i.e. parallel to the
    # epipolar lines in both images (depth there is only given by continuity and the tip).
    "hook": centerline_from_angles(lambda xi: -np.pi / 2 * _smoothstep((xi - 0.5) / 0.3)),
    # An S bent out of the image plane: towards the cameras, then away (depth +-45 mm), and down.
    "s_curve": centerline_from_angles(lambda xi: -0.3 * (2 * xi - xi ** 2), lambda xi: 0.5 * np.sin(2 * np.pi * xi)),
    # A 40 mm stretch (45-60 % of the length) pointing towards the rig, 18 deg off the viewing rays: seen
    # nearly end-on, ~3x foreshortened.
    "end_on": centerline_from_angles(
        lambda xi: -0.3 * (2 * xi - xi ** 2),
        lambda xi: 1.26 * (_smoothstep((xi - 0.35) / 0.1) - _smoothstep((xi - 0.6) / 0.1))),
}


def distance_to_curve(points: np.ndarray, curve: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each point to the polyline ``curve`` and the arc length of its closest point (brute force
    over all segments: independent of the code under test)."""
    start, direction = curve[:-1], np.diff(curve, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(direction, axis=1))])
    offset = points[:, None, :] - start[None]
    t = np.clip(np.einsum("psk,sk->ps", offset, direction) / np.einsum("sk,sk->s", direction, direction), 0, 1)
    distance = np.linalg.norm(offset - t[..., None] * direction[None], axis=2)
    best = np.argmin(distance, axis=1)
    rows = np.arange(len(points))
    return distance[rows, best], arc[best] + t[rows, best] * np.linalg.norm(direction[best], axis=1)


def faded(rig: StereoRig, images: tuple[np.ndarray, np.ndarray], background_pair: tuple[np.ndarray, np.ndarray],
          curve: np.ndarray, start: float, stop: float, keep: float, sides: tuple[str, ...] = ("left", "right")
          ) -> list[np.ndarray]:
    """The pair with the needle's contrast scaled by ``keep`` around the true stretch [start, stop] (fractions
    of the length): pixels within 12 px of its projection are blended towards a needle-free frame (in the
    cameras ``sides``; keep 0: an occluder the colour of the background)."""
    out = []
    stretch = curve[int(start * len(curve)):int(stop * len(curve))]
    for image, background, side in zip(images, background_pair, ("left", "right")):
        if side not in sides:
            out.append(image)
            continue
        pixels = project_points(rig, stretch, side)
        mask = np.zeros(image.shape, bool)
        for x, y in pixels[::4]:
            y0, x0 = int(round(y)), int(round(x))
            mask[max(y0 - 12, 0):y0 + 13, max(x0 - 12, 0):x0 + 13] = True
        blended = background + keep * (image.astype(float) - background)
        out.append(np.where(mask, np.clip(np.round(blended), 0, 255), image).astype(image.dtype))
    return out


def check_not_invented(measurement: NeedleMeasurement, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Measured samples lie within 3x their pixel-noise distance (floored at the 0.1 mm accuracy requirement)
    of the truth; the others are flagged UNMEASURED. Returns (distances, true arc lengths) of the samples."""
    distance, arc = distance_to_curve(measurement.points, truth)
    measured = measurement.measured
    assert np.all(measurement.uncertainty[~measured] == UNMEASURED)
    assert np.all(measurement.uncertainty[measured] > 0)
    assert np.all(distance[measured] <= np.maximum(3 * measurement.uncertainty[measured], 1e-4))
    return distance, arc


def centerline_from_curvature(curvature, torsion, length: float = NEEDLE_LENGTH) -> np.ndarray:
    """An inextensible centerline from the base (origin) along +x with curvature ``curvature(s)`` [1/m] and torsion
    ``torsion(s)`` [1/m] (functions of the arc length s [m]; the Frenet frame integrated with the trapezoid rule,
    first bent towards -z)."""
    s = np.linspace(0.0, length, SAMPLES)
    step = length / (SAMPLES - 1)
    frame = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # tangent, normal, binormal rows
    tangents = [frame[0]]
    for k in range(SAMPLES - 1):
        kappa, tau = 0.5 * (curvature(s[k]) + curvature(s[k + 1])), 0.5 * (torsion(s[k]) + torsion(s[k + 1]))
        generator = np.array([[0.0, kappa, 0.0], [-kappa, 0.0, tau], [0.0, -tau, 0.0]]) * step
        frame = _expm3(generator) @ frame
        tangents.append(frame[0])
    tangents = np.array(tangents)
    return np.vstack([np.zeros(3), np.cumsum(0.5 * (tangents[1:] + tangents[:-1]) * step, axis=0)])


def _expm3(generator: np.ndarray) -> np.ndarray:
    """exp of a 3x3 skew matrix (Rodrigues)."""
    omega = np.array([generator[1, 2], -generator[0, 2], generator[0, 1]])
    angle = np.linalg.norm(omega)
    if angle < 1e-15:
        return np.eye(3) + generator
    unit = generator / angle
    return np.eye(3) + np.sin(angle) * unit + (1 - np.cos(angle)) * unit @ unit


def _turning_plane(turn_deg: float = 100.0, bent: float = 0.2) -> np.ndarray:
    """Bent over its first ``bent`` m (curvature fading out over the last 20 mm of it) with the bending plane
    turning ``turn_deg`` (constant torsion), then straight; the curvature is chosen so that the straight tail is
    square to the base direction, and the curve is rotated about x until the tail points along -z: parallel to
    the rig's baseline, along the epipolar lines in both images."""
    tau = np.radians(turn_deg) / bent
    fade = lambda s: np.clip((bent - s) / 0.02, 0.0, 1.0)  # noqa: E731
    shape = lambda kappa: centerline_from_curvature(lambda s: kappa * fade(s), lambda s: tau * (s < bent))  # noqa
    tail = lambda curve: (curve[-1] - curve[-41]) / np.linalg.norm(curve[-1] - curve[-41])  # noqa: E731
    kappa = brentq(lambda k: tail(shape(k))[0], 2.0, 20.0)
    curve = shape(kappa)
    _, b, c = tail(curve)
    angle = np.arctan2(b, c) - np.pi  # rotation about x taking (b, c) to (0, -1)
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]])
    return curve @ rotation.T


#: Shapes along the epipolar lines of the rig (its baseline runs along world z: a stretch along z projects onto the
#: epipolar lines in both images, its depth seen only through the curve's continuity and the ends).
EPIPOLAR_SHAPES = {
    # Curls down until the last 54 mm hang along -z (the tangent within 10 deg of the baseline over ~70 mm).
    "curl_down": centerline_from_angles(lambda xi: -np.pi / 2 * _smoothstep(xi / 0.8),
                                        lambda xi: 0.25 * np.sin(np.pi * xi)),
    # Curls up and towards the cameras until the tip points along +z.
    "curl_up": centerline_from_angles(lambda xi: np.pi / 2 * _smoothstep((xi - 0.1) / 0.75) ** 0.7,
                                      lambda xi: 0.4 * np.sin(np.pi * xi)),
    # An S whose middle (~60 mm) runs along -z, out of the image plane (depth +-30 mm).
    "s_epipolar": centerline_from_angles(lambda xi: -np.pi / 2 * np.sin(np.pi * xi) ** 2,
                                         lambda xi: 0.3 * np.sin(2 * np.pi * xi)),
    # A 3D curve whose bending plane turns 100 deg over its first 200 mm; its last 70 mm run along -z.
    "turning_plane": _turning_plane(),
}

#: Shapes along the epipolar lines that are elastic-rod equilibria of the seed 000 needle (the simulator's static solve
#: under its weight and a tip load; made by the suite's test/rod_equilibria.py, stored in data/): `rod_curl_down`
#: curls down until its last ~100 mm hang along -z, `rod_curl_up` curls up towards the cameras until its tip points
#: along +z (its last ~35 mm within 10 deg), `rod_s` is an S whose middle ~120 mm run within 10 deg of -z. The older
#: EPIPOLAR_SHAPES are smoothstep curvature profiles, not equilibria (the turning plane's bend fades out inside its
#: unseen stretch).
ROD_EPIPOLAR_SHAPES = {
    path.stem: np.load(path) for path in sorted((Path(__file__).parent / "data").glob("rod_*.npy"))}
