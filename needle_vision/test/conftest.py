"""Shared fixtures of the needle_vision tests: the sample rig, known needle shapes and their renders (made once
per test session), and an independent distance-to-curve measure."""
from __future__ import annotations

import numpy as np
import pytest

from needle_vision.render import NEEDLE_RADIUS, default_rig, make_scene, render_stereo_pair
import vision_shapes
from vision_shapes import SHAPES


@pytest.fixture(scope="session")
def rig():
    return default_rig()


@pytest.fixture(scope="session")
def scene(rig):
    return make_scene(rig, np.random.default_rng(0))


@pytest.fixture(scope="session")
def background_frames(rig, scene):
    return vision_shapes.background_frames(rig, scene)


@pytest.fixture(scope="session")
def backgrounds(background_frames):
    return vision_shapes.models_of_frames(background_frames)


@pytest.fixture(scope="session")
def renders(rig, scene):
    """Stereo pair of each shape, rendered on first use and kept for the session."""
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def get(name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in cache:
            cache[name] = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(7), scene=scene)
        return cache[name]
    return get
