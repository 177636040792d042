"""The compiled coarse path search (one labelling per image) against a plain formulation of its rule in Python:
components of pixel sets, breadth-first geodesics."""
from collections import deque

import numpy as np
import pytest

from needle_vision.detection.centerline import _coarse_paths


def _components(mask: np.ndarray, link: int) -> list[set[tuple[int, int]]]:
    """Pixel sets of the components (pixels up to ``link`` apart, Chebyshev) in the raster order of their first
    pixel."""
    pixels = {(int(y), int(x)) for y, x in zip(*np.nonzero(mask))}
    components = []
    for seed in sorted(pixels):
        if any(seed in component for component in components):
            continue
        component, queue = {seed}, deque([seed])
        while queue:
            y, x = queue.popleft()
            for q in pixels - component:
                if max(abs(q[0] - y), abs(q[1] - x)) <= link:
                    component.add(q)
                    queue.append(q)
        components.append(component)
    return components


def _geodesic(pixels: set[tuple[int, int]], seed: tuple[int, int]) -> np.ndarray:
    """Longest breadth-first geodesic (two sweeps; neighbours up to 2 apart, in raster order) as (x, y)."""
    start = seed
    for _ in range(2):
        hops, parent, queue, far = {start: 0}, {}, deque([start]), start
        while queue:
            p = queue.popleft()
            if hops[p] > hops[far]:
                far = p
            for dy in range(-2, 3):
                for dx in range(-2, 3):
                    q = (p[0] + dy, p[1] + dx)
                    if q in pixels and q not in hops:
                        hops[q], parent[q] = hops[p] + 1, p
                        queue.append(q)
        start = far
    path = [far]
    while path[-1] in parent:
        path.append(parent[path[-1]])
    return np.array([(x, y) for y, x in path], np.int32).reshape(-1, 2)


def reference_paths(mask: np.ndarray, min_length: int, count: int = 4) -> list[np.ndarray]:
    """Largest component first (pixels up to 2 apart; equal sizes: the first in raster order), its longest
    geodesic; then the components not within 3 pixels of a used one, while the paths are long enough."""
    near, reach = _components(mask, 2), _components(mask, 3)
    paths, used = [], []
    for _ in range(count):
        candidates = [c for c in near if not any(c <= r for r in used)]
        if not candidates:
            break
        best = max(candidates, key=len)  # the first of equal size: raster order of the first pixel
        path = _geodesic(best, min(best))
        if len(path) < 2 or (paths and len(path) < min_length):
            break
        paths.append(path)
        used += [r for r in reach if best <= r]
    return paths


@pytest.mark.parametrize("seed", range(4))
def test_coarse_paths_follow_their_rule(seed):
    rng = np.random.default_rng(seed)
    counts = set()
    for trial in range(150):
        height, width = rng.integers(1, 40, 2)
        mask = ((rng.random((height, width)) < rng.uniform(0.0, 0.3)) * 255).astype(np.uint8)
        if trial % 2:  # a few straight strokes (needle-like) instead of scattered pixels
            mask[:] = 0
            for _ in range(rng.integers(1, 6)):
                y0, y1 = rng.integers(0, height, 2)
                x0, x1 = rng.integers(0, width, 2)
                n = max(abs(y1 - y0), abs(x1 - x0)) + 1
                mask[np.linspace(y0, y1, n).round().astype(int), np.linspace(x0, x1, n).round().astype(int)] = 255
        min_length = int(rng.integers(1, 10))
        expected = reference_paths(mask, min_length)
        found = _coarse_paths(mask, np.empty(mask.shape, np.int32), min_length)
        counts.add(len(expected))
        assert len(found) == len(expected)
        for path, truth in zip(found, expected):
            np.testing.assert_array_equal(path, truth)
    assert {0, 1, 2} <= counts  # empty masks, one path, and linked further paths were all exercised
