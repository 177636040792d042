"""Shared fixtures of the needle_vision tests: the sample rig, known needle shapes and their renders (made once
per test session), and an independent distance-to-curve measure."""
from __future__ import annotations

import os

import numpy as np
import pytest
from scipy.optimize import brentq

from needle_vision.background import BackgroundModel, ContrastThreshold
from needle_vision.render import NEEDLE_LENGTH, NEEDLE_RADIUS, default_rig, make_scene, render_background_pair, \
    render_stereo_pair

SAMPLES = 1081  # 0.25 mm along the needle: the polyline is the true curve to ~1e-8 m for these curvatures


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


@pytest.fixture(scope="session")
def rig():
    return default_rig()


@pytest.fixture(scope="session")
def scene(rig):
    return make_scene(rig, np.random.default_rng(0))


@pytest.fixture(scope="session")
def background_frames(rig, scene):
    """Eight needle-free pairs (the default background model averages ten; eight keep the noise of the
    model at a third of a frame's)."""
    return [render_background_pair(rig, np.random.default_rng(100 + k), scene=scene) for k in range(8)]


@pytest.fixture(scope="session")
def backgrounds(background_frames):
    threshold = ContrastThreshold()
    return tuple(BackgroundModel.from_frames([pair[k] for pair in background_frames], threshold) for k in range(2))


@pytest.fixture(scope="session")
def renders(rig, scene):
    """Stereo pair of each shape, rendered on first use and kept for the session."""
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def get(name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in cache:
            cache[name] = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(7), scene=scene)
        return cache[name]
    return get


@pytest.fixture(scope="session")
def ros_env() -> dict:
    """Environment for a node in a child process: a ROS domain of this test process only (from the pid, so that
    parallel runs do not see each other), discovery on this host only."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(101 + os.getpid() % 100)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    os.environ.update({key: env[key] for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    return env
