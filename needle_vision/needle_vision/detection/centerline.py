"""Sub-pixel needle centerline in one image, ordered along the needle (seed 000, Sec. III-A: binarize,
extract the background, find the needle points).

1. Coarse detection on an area-averaged image (``downsample``x smaller): background subtraction, a threshold
   relative to the local background brightness (binarization robust to uneven lighting), the largest
   component (pixels up to two coarse pixels apart are linked, bridging small gaps) and its longest geodesic
   path, which orders the needle from one end to the other; other components whose ends face its ends (a
   needle cut by an occluder) are joined to it, the hidden stretch between them left without points.
2. Full-resolution refinement: the band around the coarse path is cut into axis-aligned one-pixel slices
   (columns where the needle runs closer to horizontal, rows elsewhere); the centroid of the covered fraction
   (B - I) / (B - N) across each slice is a centerline point (no image interpolation; N the needle's own grey
   level along it). Weak slices (gaps, beyond the ends) are dropped.
3. The ends to sub-pixel from the covered fraction's profile along the needle's end direction
   (:func:`_end_along_profile`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np
from scipy.ndimage import median_filter

from needle_vision.detection.background import BackgroundModel, downsample
from needle_vision.detection.curves import arc_length, moving_average, step_lengths


#: [points] window of the running median that gives each centerline point's local scatter.
NOISE_WINDOW = 61
#: [px] consecutive centerline points farther apart are separated by a hidden stretch (shorter gaps are bridged).
GAP_PX = 40.0
#: [slices] running median of the needle's own intensity along the needle (the covered fraction's denominator).
NEEDLE_LEVEL_WINDOW = 41
#: [thresholds] an end of the coarse detection is followed on where the background lies within this many detection
#: thresholds of the needle's own level, or beyond it (:func:`_grow_faded`): there the needle fades, then reverses.
FADE_FACTOR = 3.0
#: [coarse px] the longest step taken there: across the stretch where the background passes through the needle's
#: level and the needle is not seen at all.
FADE_REACH = 6
#: [coarse px per coarse px of the image's diagonal] the most pixels one end is followed through: a needle's band
#: at most a few pixels wide; more means the background model differs from the image (e.g. one bootstrapped from a
#: needle frame, whose closing flattens the texture).
FADE_MAX_AREA = 3.0
#: [-] how many times the ends are followed on from the new ends (each round crosses one faded stretch).
FADE_ROUNDS = 6
#: [points] the needle's level at a coarse path's end: the median over this many refined points before its last four.
END_LEVEL_POINTS = 10


class NoNeedleError(ValueError):
    """No needle-like structure was found in an image (message says why)."""


@dataclass(frozen=True)
class CenterlineConfig:
    """Sub-pixel extraction settings (names match the node's ``detection.*`` parameters)."""

    profile_half_width: int = 4      # [px] half-length of a slice after re-centering (covers the needle's blur)
    min_profile_fraction: float = 0.75  # [-] the parameter detection.min_profile_fraction (described there)
    min_length_px: float = 40.0      # [px] shorter detections are "no needle"
    local_window: int = 41           # [slices] the contrast reference is the median over this many neighbours
    min_contrast_fraction: float = 0.2  # dropped below this fraction of the needle's median, whatever the neighbours
    max_link_angle_deg: float = 15.0  # components whose facing ends differ less in direction are one needle


@dataclass(frozen=True)
class ImageCenterline:
    """Centerline points ``(n, 2)`` (x, y raw pixels) ordered from one end to the other, their slice contrast (the
    covered fraction summed across the slice), the robust scatter [px] across the curve, and per point: that scatter
    over ``NOISE_WINDOW`` points (``local_noise_px``, at least the slice's own centroid noise) and the lateral
    uncertainty [px] of the points extrapolated towards the ends (``extrapolation_px``, 0 for slices: one error
    shared by the stretch); per end (first, last): how far [px] it was put beyond the middle of its fitted taper
    (``end_taper_px``, 0: flat), the tapered reading of an end placed flat (``taper_candidates``) and the flat
    placement of a tapered end (``flat_ends``), :class:`EndReading` or None."""

    points: np.ndarray
    contrast: np.ndarray
    noise_px: float
    local_noise_px: np.ndarray
    extrapolation_px: np.ndarray
    end_taper_px: np.ndarray = field(default_factory=lambda: np.zeros(2))
    taper_candidates: tuple[EndReading | None, EndReading | None] = (None, None)
    flat_ends: tuple[EndReading | None, EndReading | None] = (None, None)


@dataclass(frozen=True)
class EndReading:
    """The other reading of an end, for the other view to decide (``reconstruction._shared_bevels``): a taper
    candidate (an end placed flat whose covered fraction alone falls slowly) or a tapered end placed flat. It replaces
    the centerline's last ``drop`` points at that end by ``points`` (ordered outward, ending with the end),
    ``half_taper_px`` beyond the middle of its fitted taper (0: flat). ``fall_ratio``: a candidate's covered-fraction
    fall over the side edges' blur (0 for a flat placement); ``extrapolation_px``: as ``ImageCenterline``'s."""

    drop: int
    points: np.ndarray
    half_taper_px: float
    fall_ratio: float
    extrapolation_px: np.ndarray


def with_end_reading(centerline: ImageCenterline, end: int, reading: EndReading) -> ImageCenterline:
    """``centerline`` with its ``end`` (0: first, 1: last) replaced by ``reading`` (its taper candidate or flat end;
    the new points get the contrast and local noise of the last point kept); that end has no other reading left."""
    keep = len(centerline.points) - reading.drop
    count = len(reading.points)
    step = -1 if end == 0 else 1  # ordered towards the end
    points, contrast, noise, extrapolation = (values[::step] for values in (
        centerline.points, centerline.contrast, centerline.local_noise_px, centerline.extrapolation_px))
    points = np.vstack([points[:keep], reading.points])[::step]
    contrast, noise = (np.concatenate([values[:keep], np.full(count, values[keep - 1])])[::step]
                       for values in (contrast, noise))
    extrapolation = np.concatenate([extrapolation[:keep], reading.extrapolation_px])[::step]
    tapers = centerline.end_taper_px.copy()
    tapers[end] = reading.half_taper_px
    candidates, flat = (tuple(None if k == end else other for k, other in enumerate(readings))
                        for readings in (centerline.taper_candidates, centerline.flat_ends))
    return replace(centerline, points=points, contrast=contrast, local_noise_px=noise, extrapolation_px=extrapolation,
                   end_taper_px=tapers, taper_candidates=candidates, flat_ends=flat)


@numba.njit(cache=True, nogil=True)
def _flood(start, ys, xs, mask, index, link, hops, parent, queue):  # pragma: no cover - compiled
    """Breadth-first search from pixel ``start`` (``hops[start]`` set, unvisited pixels -1) over the pixels
    ``(ys, xs)`` (non-zero in ``mask``, numbered by ``index``) linked up to ``link`` pixels apart (Chebyshev):
    fills ``hops`` and ``parent`` of the pixels reached, ``queue`` in the order reached; returns their count."""
    height, width = mask.shape
    head, tail = 0, 1
    queue[0] = start
    while head < tail:
        p = queue[head]
        head += 1
        for dy in range(-link, link + 1):
            for dx in range(-link, link + 1):
                y, x = ys[p] + dy, xs[p] + dx
                if 0 <= y < height and 0 <= x < width and mask[y, x]:
                    q = index[y, x]
                    if hops[q] < 0:
                        hops[q] = hops[p] + 1
                        parent[q] = p
                        queue[tail] = q
                        tail += 1
    return tail


@numba.njit(cache=True, nogil=True)
def _components(ys, xs, mask, index, link, label, hops, parent, queue):  # pragma: no cover - compiled
    """Components of the pixels ``(ys, xs)`` (:func:`_flood`) numbered in the raster order of their first pixel:
    ``label`` per pixel is filled in; returns each component's first pixel and size."""
    hops[:] = -1
    seeds = np.empty(len(ys), np.int32)
    sizes = np.empty(len(ys), np.int32)
    current = 0
    for seed in range(len(ys)):
        if hops[seed] >= 0:
            continue
        hops[seed] = 0
        size = _flood(seed, ys, xs, mask, index, link, hops, parent, queue)
        label[queue[:size]] = current
        seeds[current], sizes[current] = seed, size
        current += 1
    return seeds[:current], sizes[:current]


@numba.njit(cache=True, nogil=True)
def _geodesic(seed, ys, xs, mask, index, link, hops, parent, queue):  # pragma: no cover - compiled
    """Longest BFS geodesic (two sweeps) of the component of pixel ``seed``: the path (k, 2) as (x, y)."""
    far = seed
    for _ in range(2):
        hops[:] = -1
        hops[far] = 0
        k = _flood(far, ys, xs, mask, index, link, hops, parent, queue) - 1
        while k > 0 and hops[queue[k - 1]] == hops[queue[k]]:  # the first pixel reached at the largest hop count
            k -= 1
        far = queue[k]
    length = hops[far] + 1
    path = np.empty((length, 2), np.int32)
    p = far
    for k in range(length):
        path[k, 0] = xs[p]
        path[k, 1] = ys[p]
        p = parent[p]
    return path


@numba.njit(cache=True, nogil=True)
def _coarse_path_kernel(mask, index, min_length, count):  # pragma: no cover - compiled
    """Longest geodesic paths of the largest components of the non-zero pixels of ``mask`` (pixels linked up to
    2 apart, Chebyshev; equal sizes: the first in raster order), largest first; after each path, the components
    within 3 pixels of it (linked up to 3 apart) are no longer candidates. Stops at ``count`` paths, at a path
    shorter than 2 points, or at a later one shorter than ``min_length``. ``index`` is an int32 scratch array of
    the mask's shape. Returns the paths' points (x, y) one after the other and their lengths."""
    height, width = mask.shape
    ys = np.empty(height * width, np.int32)  # only the first ``total`` entries are touched
    xs = np.empty(height * width, np.int32)
    total = 0
    for y in range(height):
        for x in range(width):
            if mask[y, x]:
                index[y, x] = total
                ys[total] = y
                xs[total] = x
                total += 1
    ys, xs = ys[:total], xs[:total]
    queue = np.empty(total, np.int32)
    hops = np.empty(total, np.int32)
    parent = np.empty(total, np.int32)
    label = np.empty(total, np.int32)
    seeds, sizes = _components(ys, xs, mask, index, 2, label, hops, parent, queue)
    group = np.empty(total, np.int32)
    _components(ys, xs, mask, index, 3, group, hops, parent, queue)
    erased = np.zeros(total, np.bool_)
    points = np.empty((count * total, 2), np.int32)
    lengths = np.zeros(count, np.int64)
    used, found = 0, 0
    for k in range(count):
        best, best_size = -1, 0
        for c in range(len(seeds)):
            if sizes[c] > best_size and not erased[group[seeds[c]]]:
                best, best_size = c, sizes[c]
        if best < 0:
            break
        path = _geodesic(seeds[best], ys, xs, mask, index, 2, hops, parent, queue)
        if len(path) < 2 or (k > 0 and len(path) < min_length):
            break
        points[used:used + len(path)] = path
        used += len(path)
        lengths[k] = len(path)
        found += 1
        erased[group[seeds[best]]] = True
    return points[:used].copy(), lengths[:found]


@numba.njit(cache=True, nogil=True)
def _grow_faded(coarse, background, mask, seed, level, polarity, relative, absolute):  # pragma: no cover - compiled
    """Where the needle fades into a background at its own ``level`` N (and beyond it, where it shows reversed): the
    coarse pixels reached from ``seed`` (x, y) through pixels up to ``FADE_REACH`` apart (Chebyshev; bridged by a
    straight line where farther than 2: where the background passes through N the needle is not seen at all) whose
    background lies within ``FADE_FACTOR`` detection thresholds (``max(relative * B, absolute)``) of N or beyond it,
    and that are ``mask``ed or differ from the background by at least ``absolute`` either way (the background is
    static: there only the needle changes the image, of either polarity). Returns those not in ``mask`` (uint8, 255)
    and their count."""
    height, width = mask.shape
    grown = np.zeros((height, width), np.uint8)
    visited = np.zeros((height, width), np.bool_)
    queue = np.empty((height * width, 2), np.int32)
    head, tail, count = 0, 0, 0
    if 0 <= seed[1] < height and 0 <= seed[0] < width:
        visited[seed[1], seed[0]] = True
        queue[0, 0], queue[0, 1] = seed[1], seed[0]
        tail = 1
    while head < tail:
        y0, x0 = queue[head, 0], queue[head, 1]
        head += 1
        for y in range(max(y0 - FADE_REACH, 0), min(y0 + FADE_REACH + 1, height)):
            for x in range(max(x0 - FADE_REACH, 0), min(x0 + FADE_REACH + 1, width)):
                if visited[y, x]:
                    continue
                b = background[y, x]
                if polarity * (b - level) >= FADE_FACTOR * max(relative * b, absolute):
                    continue
                if mask[y, x] or abs(b - float(coarse[y, x])) >= absolute:
                    visited[y, x] = True
                    queue[tail, 0], queue[tail, 1] = y, x
                    tail += 1
                    steps = max(abs(y - y0), abs(x - x0))
                    for k in range(1, steps + 1):  # the pixel, and the straight bridge to it from farther than 2
                        if k == steps or steps > 2:
                            yk, xk = y0 + (y - y0) * k // steps, x0 + (x - x0) * k // steps
                            if not mask[yk, xk] and not grown[yk, xk]:
                                grown[yk, xk] = 255
                                count += 1
    return grown, count


@numba.njit(cache=True, nogil=True)
def _refine_path(image, background, polarity, path):  # pragma: no cover - compiled
    """Centroid of the subtracted grey levels in the 3x3 neighbourhood of each coarse path pixel (of the opposite
    polarity where the pixel itself differs the other way: a needle followed where it shows reversed)."""
    height, width = image.shape
    out = np.empty((path.shape[0], 2))
    for k in range(path.shape[0]):
        sign = polarity if polarity * (background[path[k, 1], path[k, 0]] - image[path[k, 1], path[k, 0]]) >= 0 \
            else -polarity
        sw, sx, sy = 0.0, 0.0, 0.0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                y, x = path[k, 1] + dy, path[k, 0] + dx
                if 0 <= y < height and 0 <= x < width:
                    w = sign * (background[y, x] - image[y, x])
                    if w > 0:
                        sw, sx, sy = sw + w, sx + w * x, sy + w * y
        if sw > 0:
            out[k, 0], out[k, 1] = sx / sw, sy / sw
        else:
            out[k, 0], out[k, 1] = path[k, 0], path[k, 1]
    return out


@numba.njit(cache=True, nogil=True)
def _slice_centroids(image, background, polarity, along_rows, fixed, predicted, half_width, needle,
                     with_noise):  # pragma: no cover - compiled
    """Centroid across each one-pixel slice: slice k is row ``fixed[k]`` (along_rows) or column ``fixed[k]``,
    spanning ``round(predicted[k]) ± half_width``, weighted by the relative contrast (B - I) / B or, given the
    needle's own intensity ``needle[k]`` (N, non-empty), the covered fraction (B - I) / (B - N). Returns (centroid,
    contrast: the weights' sum, 0 where the slice leaves the image; the centroid's noise per unit of image noise
    [px/DN], inf unless ``with_noise``: sqrt(sum((c - centroid)^2 / d^2)) / contrast, d the weight's denominator)."""
    height, width = image.shape
    n = fixed.shape[0]
    centroid = np.empty(n)
    contrast = np.zeros(n)
    noise = np.full(n, np.inf)
    for k in range(n):
        centre = int(np.floor(predicted[k] + 0.5))
        f = fixed[k]
        limit = width if along_rows[k] else height
        if centre - half_width < 0 or centre + half_width >= limit or f < 0 \
                or f >= (height if along_rows[k] else width):
            centroid[k] = predicted[k]
            continue
        covered = needle.shape[0] > 0
        sw, sc, s0, s1, s2 = 0.0, 0.0, 0.0, 0.0, 0.0
        for c in range(centre - half_width, centre + half_width + 1):
            b, v = (background[f, c], image[f, c]) if along_rows[k] else (background[c, f], image[c, f])
            d = max(polarity * (b - needle[k]) if covered else b, 1.0)
            w = polarity * (b - v) / d
            sw, sc = sw + w, sc + w * c
            if with_noise:
                q = 1.0 / (d * d)
                s0, s1, s2 = s0 + q, s1 + q * c, s2 + q * c * c
        contrast[k] = sw
        centroid[k] = sc / sw if sw > 0 else predicted[k]
        if with_noise and sw > 0:
            m = centroid[k]
            noise[k] = np.sqrt(max(s2 - 2.0 * m * s1 + m * m * s0, 0.0)) / sw
    return centroid, contrast, noise


@numba.njit(cache=True, nogil=True)
def _needle_levels(image, polarity, along_rows, fixed, centroid, contrast, window):  # pragma: no cover - compiled
    """The needle's own intensity N at each slice: the grey level at its centroid, a running median over ``window``
    of the slices with at least half the median contrast (the others take their nearest such slice's). Empty when
    fewer than ``window`` slices qualify."""
    n = centroid.shape[0]
    height, width = image.shape
    strong = contrast > 0.5 * np.median(contrast[contrast > 0]) if np.any(contrast > 0) else contrast > 0
    selected = np.flatnonzero(strong)
    if selected.shape[0] < window:
        return np.zeros(0)
    levels = np.empty(selected.shape[0])
    for j in range(selected.shape[0]):
        k = selected[j]
        c = min(max(int(np.floor(centroid[k] + 0.5)), 0), (width if along_rows[k] else height) - 1)
        levels[j] = image[fixed[k], c] if along_rows[k] else image[c, fixed[k]]
    levels = _running_median(levels, window, True)
    out = np.empty(n)
    j = 0
    for k in range(n):
        while j + 1 < selected.shape[0] and abs(selected[j + 1] - k) <= abs(selected[j] - k):
            j += 1
        out[k] = levels[j]
    return out


@numba.njit(cache=True, nogil=True)
def _slices_along(path):  # pragma: no cover - compiled
    """One-pixel slices across the polyline ``path`` (full-res x, y), in path order: (along_rows, fixed, predicted,
    obliquity). Each segment is cut by the integer columns (closer to horizontal) or rows it spans, half-open; where
    the slicing direction switches, one pixel early. ``obliquity``: cosine between the slice's index axis and the
    segment (a straight band's contrast along a slice scales with 1/it)."""
    total = 0
    for k in range(path.shape[0] - 1):
        total += int(abs(path[k + 1, 0] - path[k, 0]) + abs(path[k + 1, 1] - path[k, 1])) + 3
    along_rows = np.empty(total, np.bool_)
    fixed = np.empty(total, np.int32)
    predicted = np.empty(total)
    obliquity = np.empty(total)
    n = 0
    previous_rows = False
    for k in range(path.shape[0] - 1):
        dx, dy = path[k + 1, 0] - path[k, 0], path[k + 1, 1] - path[k, 1]
        rows = abs(dy) > abs(dx)
        a = 1 if rows else 0  # the axis the slices are indexed along
        start, stop = path[k, a], path[k + 1, a]
        if stop == start:
            continue
        step = 1 if stop > start else -1
        first = int(np.ceil(start)) if step > 0 else int(np.floor(start))
        if k > 0 and rows != previous_rows:
            first -= step
        last = int(np.ceil(stop)) if step > 0 else int(np.floor(stop))  # exclusive
        cosine = abs(stop - start) / np.sqrt(dx * dx + dy * dy)
        for f in range(first, last, step):
            t = (f - start) / (stop - start)
            along_rows[n] = rows
            fixed[n] = f
            predicted[n] = path[k, 1 - a] + t * (path[k + 1, 1 - a] - path[k, 1 - a])
            obliquity[n] = cosine
            n += 1
        previous_rows = rows
    return along_rows[:n], fixed[:n], predicted[:n], obliquity[:n]


@numba.njit(cache=True, nogil=True)
def _extended(values, j, mirror):  # pragma: no cover - compiled
    """``values[j]`` for any ``j``, extended beyond the ends by reflection about the end samples (``mirror``)
    or by repeating them (scipy.ndimage's 'mirror' and 'nearest' modes)."""
    n = values.shape[0]
    if not mirror or n == 1:
        return values[min(max(j, 0), n - 1)]
    period = 2 * (n - 1)
    j = abs(j) % period
    return values[period - j if j >= n else j]


@numba.njit(cache=True, nogil=True)
def _running_median(values, size, mirror):  # pragma: no cover - compiled
    """scipy.ndimage.median_filter of 1D ``values`` over ``size`` samples (modes as :func:`_extended`): a sorted
    window updated one sample in and one out, O(size) per sample."""
    n = values.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    start = -(size // 2)
    window = np.empty(size)
    for k in range(size):
        window[k] = _extended(values, start + k, mirror)
    window.sort()
    out[0] = window[size // 2]
    for i in range(1, n):
        leaving, entering = _extended(values, start + i - 1, mirror), _extended(values, start + i - 1 + size, mirror)
        k = np.searchsorted(window, leaving)  # the leaving value's slot, refilled by shifting towards the entering
        while k > 0 and window[k - 1] > entering:
            window[k] = window[k - 1]
            k -= 1
        while k < size - 1 and window[k + 1] < entering:
            window[k] = window[k + 1]
            k += 1
        window[k] = entering
        out[i] = window[size // 2]
    return out


#: An end whose contrast profile falls over more than this many times the blur of the needle's side edges is
#: tapered (a bevel seen side-on), in both profiles (:func:`_falls_slowly`; measurements: docs/stereo_history.md).
TAPER_FACTOR = 1.15
#: ... and by more than this many times the profile's relative scatter along the needle.
TAPER_SIGNIFICANCE = 5.0
#: An end placed flat whose covered fraction alone falls slowly is a taper candidate (:class:`EndReading`), a strong
#: one where its spread exceeds this many times the blur.
CANDIDATE_TAPER_FACTOR = 1.34
#: The end's lateral extrapolation takes a cubic term when its coefficient exceeds this many white-noise standard
#: errors and the end lies within ``CUBIC_REACH`` of the fitted span beyond it.
CURVATURE_RAMP_SIGNIFICANCE = 5.0
CUBIC_REACH = 0.25


@numba.njit(cache=True, nogil=True)
def _crossing(s, profile, level, start):  # pragma: no cover - compiled
    """First ``s`` beyond ``start`` where ``profile`` falls below ``level`` (linear interpolation); NaN if none."""
    for k in range(s.shape[0]):
        if s[k] > start and profile[k] < level:
            if k == 0:
                return np.nan
            return s[k - 1] + (s[k] - s[k - 1]) * (profile[k - 1] - level) / (profile[k - 1] - profile[k])
    return np.nan


@numba.njit(cache=True, nogil=True)
def _edge_spread(cross, u):  # pragma: no cover - compiled
    """Distance between the 25 % and 75 % points of the needle's side edges in its cross profile ``cross``
    (samples at ``u``): the blurred step's width. NaN when the profile has no clear peak inside."""
    peak = int(np.argmax(cross))
    if cross[peak] <= 0 or peak == 0 or peak == len(u) - 1:
        return np.nan
    total = 0.0
    for step in (1, -1):  # right edge, left edge (outwards from the peak)
        distance, values = np.abs(u[peak::step] - u[peak]), cross[peak::step]
        inner = _crossing(distance, values, 0.75 * cross[peak], -1.0)
        outer = _crossing(distance, values, 0.25 * cross[peak], -1.0)
        if np.isnan(inner) or np.isnan(outer):
            return np.nan
        total += outer - inner
    return total / 2


@numba.njit(cache=True, nogil=True)
def _phi(z):  # pragma: no cover - compiled
    """Standard normal (cumulative distribution, density) at ``z``."""
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0))), math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


@numba.njit(cache=True, nogil=True)
def _tapered_step(s, centre, taper, sigma):  # pragma: no cover - compiled
    """Fraction of the contrast left at ``s`` by an end whose width falls linearly to nothing over ``taper``
    (centred at ``centre``) through a Gaussian blur ``sigma``: the mean of Phi((x - s) / sigma) over the taper x,
    closed form (G(z) = z Phi(z) + phi(z) integrates Phi); and its derivatives by the centre and the taper."""
    taper = max(taper, 1e-3)
    value, d_centre, d_taper = np.empty(s.shape[0]), np.empty(s.shape[0]), np.empty(s.shape[0])
    for k in range(s.shape[0]):
        outer, inner = (centre + 0.5 * taper - s[k]) / sigma, (centre - 0.5 * taper - s[k]) / sigma
        big_phi_outer, phi_outer = _phi(outer)
        big_phi_inner, phi_inner = _phi(inner)
        value[k] = sigma / taper * (outer * big_phi_outer + phi_outer - inner * big_phi_inner - phi_inner)
        d_centre[k] = (big_phi_outer - big_phi_inner) / taper
        d_taper[k] = (0.5 * (big_phi_outer + big_phi_inner) - value[k]) / taper
    return value, d_centre, d_taper


@numba.njit(cache=True, nogil=True)
def _side_blur(u, cross):  # pragma: no cover - compiled
    """Gaussian blur sigma of the needle's side edges, and the band's centre, half width and contrast: Gauss-Newton
    fit of a blurred band to its cross profile ``cross`` at ``u`` from the profile's peak, area and a 0.6 px blur
    (the last estimate where the fit is singular, e.g. a flat profile)."""
    peak = int(np.argmax(cross))
    parameters = np.array([cross[peak], u[peak], 0.5 * np.sum(cross) * (u[1] - u[0]) / max(cross[peak], 1e-9), 0.6])
    for _ in range(4):
        contrast, centre, half_width, sigma = parameters
        normal = np.zeros((4, 4))
        gradient = np.zeros(4)
        row = np.empty(4)
        for k in range(u.shape[0]):
            rising, falling = (u[k] - centre + half_width) / sigma, (u[k] - centre - half_width) / sigma
            big_phi_rising, phi_rising = _phi(rising)
            big_phi_falling, phi_falling = _phi(falling)
            row[0] = big_phi_rising - big_phi_falling
            row[1] = contrast * (phi_falling - phi_rising) / sigma
            row[2] = contrast * (phi_rising + phi_falling) / sigma
            row[3] = contrast * (phi_falling * falling - phi_rising * rising) / sigma
            residual = cross[k] - contrast * row[0]
            for i in range(4):
                gradient[i] += residual * row[i]
                for j in range(4):
                    normal[i, j] += row[i] * row[j]
        if not abs(np.linalg.det(normal)) > 1e-12 * np.trace(normal) ** 4:  # no band in the profile (or NaN)
            break
        parameters += np.linalg.solve(normal, gradient)
        parameters[2] = max(parameters[2], 0.1)
        parameters[3] = min(max(parameters[3], 0.2), 3.0)
    return parameters[3], parameters[1], parameters[2], parameters[0]


@numba.njit(cache=True, nogil=True)
def _taper_fit(s, profile, centre, taper, sigma):  # pragma: no cover - compiled
    """Least-squares centre and length of the taper of a normalised end ``profile`` (1 inside, 0 beyond)
    sampled at ``s`` (:func:`_tapered_step`, blur ``sigma`` known), from a first guess: Gauss-Newton steps."""
    for _ in range(6):
        model, d_centre, d_taper = _tapered_step(s, centre, taper, sigma)
        residual = profile - model
        a, b, c = np.sum(d_centre * d_centre), np.sum(d_centre * d_taper), np.sum(d_taper * d_taper)
        r0, r1 = np.sum(d_centre * residual), np.sum(d_taper * residual)
        determinant = a * c - b * b
        if determinant <= 0:
            break
        centre += (c * r0 - b * r1) / determinant
        taper = max(taper + (a * r1 - b * r0) / determinant, 0.0)
    return centre, taper


@numba.njit(cache=True, nogil=True)
def _principal_direction(points):  # pragma: no cover - compiled
    """Unit direction of the least-squares line through ``(n, 2)`` points (the covariance's major axis, closed
    form), pointing from the first point to the last; and the points' mean."""
    centre = np.array([points[:, 0].mean(), points[:, 1].mean()])
    a, b, c = 0.0, 0.0, 0.0
    for k in range(points.shape[0]):
        dx, dy = points[k, 0] - centre[0], points[k, 1] - centre[1]
        a, b, c = a + dx * dx, b + dx * dy, c + dy * dy
    major = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    direction = np.array([b, major - a]) if a >= c else np.array([major - c, b])
    norm = np.sqrt(direction[0] ** 2 + direction[1] ** 2)
    direction = np.array([1.0, 0.0]) if norm == 0 else direction / norm
    forward = direction[0] * (points[-1, 0] - points[0, 0]) + direction[1] * (points[-1, 1] - points[0, 1])
    return direction * np.sign(forward), centre


@numba.njit(cache=True, nogil=True)
def _contrast_scale(b, polarity, needle):  # pragma: no cover - compiled
    """The contrast's denominator at background ``b``: B (at least 1) for the relative contrast (B - I) / B, or, given
    the needle's own intensity ``needle`` > 0, B - N for the covered fraction (at least |B - N| / 4 and 1)."""
    return max(b, 1.0) if needle <= 0 else max(polarity * (b - needle), 0.25 * abs(b - needle), 1.0)


@numba.njit(cache=True, nogil=True)
def _contrast_grid(image, background, polarity, centre, direction, s, u, shift,
                   needle):  # pragma: no cover - compiled
    """The contrast interpolated bilinearly on the grid ``centre + s direction + (u + shift(s)) normal`` (``shift``
    per ``s``: the grid bent along the needle): relative to the background, (B - I) / B (signed by ``polarity``),
    or, given the needle's own intensity ``needle`` > 0, the covered fraction (B - I) / (B - N) (its denominator at
    least |B - N| / 4 and 1)."""
    normal = np.array([-direction[1], direction[0]])
    height, width = image.shape
    grid = np.empty((s.shape[0], u.shape[0]))
    for i in range(s.shape[0]):
        for j in range(u.shape[0]):
            x = centre[0] + s[i] * direction[0] + (u[j] + shift[i]) * normal[0]
            y = centre[1] + s[i] * direction[1] + (u[j] + shift[i]) * normal[1]
            x0, y0 = min(int(x), width - 2), min(int(y), height - 2)
            fx, fy = x - x0, y - y0
            value = 0.0
            for dy in range(2):
                for dx in range(2):
                    b = float(background[y0 + dy, x0 + dx])
                    weight = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
                    scale = _contrast_scale(b, polarity, needle)
                    value += weight * polarity * (b - image[y0 + dy, x0 + dx]) / scale
            grid[i, j] = value
    return grid


@numba.njit(cache=True, nogil=True)
def _column_medians(rows):  # pragma: no cover - compiled
    """Median of each column of ``rows``."""
    out = np.empty(rows.shape[1])
    for j in range(rows.shape[1]):
        out[j] = np.median(rows[:, j])
    return out


@numba.njit(cache=True, nogil=True)
def _band_centroids(image, background, polarity, points, rows, half_band,
                    needle):  # pragma: no cover - compiled
    """The centerline points ``(n, 2)`` re-measured over the needle's blurred band only: the centroid of the contrast
    (:func:`_contrast_grid`'s) across the row (``rows``) or column through each point within ``half_band`` px of it
    (edge pixels weighted by their overlap), re-centred once; a point whose window leaves the image is kept."""
    height, width = image.shape
    out = points.copy()
    a = 0 if rows else 1  # the coordinate measured across the slice
    limit = width if rows else height
    for k in range(points.shape[0]):
        f = int(np.floor(points[k, 1 - a] + 0.5))
        centre = points[k, a]
        if f < 0 or f >= (height if rows else width) or centre - half_band - 1 < 0 \
                or centre + half_band + 2 > limit - 1:
            continue
        for _ in range(2):
            sw, sc = 0.0, 0.0
            for c in range(int(np.floor(centre - half_band - 0.5)), int(np.ceil(centre + half_band + 0.5)) + 1):
                window = min(max(half_band + 0.5 - abs(c - centre), 0.0), 1.0)
                b, v = (background[f, c], image[f, c]) if rows else (background[c, f], image[c, f])
                scale = _contrast_scale(b, polarity, needle)
                w = window * polarity * (b - v) / scale
                sw, sc = sw + w, sc + w * c
            if sw <= 0:
                break
            centre = sc / sw
        out[k, a] = centre
        out[k, 1 - a] = f
    return out


@numba.njit(cache=True, nogil=True)
def _falls_slowly(profile, level, inside, spread, blur):  # pragma: no cover - compiled
    """Whether an end ``profile`` (median ``level`` over the ``inside`` rows) falls from 75 % to 25 % over
    ``spread`` > ``TAPER_FACTOR`` times the side edges' ``blur`` and clearly more than the profile's relative scatter
    (``TAPER_SIGNIFICANCE``): a taper."""
    scatter = 1.4826 * np.median(np.abs(profile[inside] - level)) / level
    return not np.isnan(blur) and spread > blur * max(TAPER_FACTOR, 1 + TAPER_SIGNIFICANCE * scatter)


@numba.njit(cache=True, nogil=True)
def _profile_crossings(s, grid, band, inside, start):  # pragma: no cover - compiled
    """The end profile (``grid`` summed over the ``band`` columns, 3-point averaged), its median level over the
    ``inside`` rows and its 75 %, 50 % and 25 % crossings beyond ``start``; whether all three were found."""
    profile = moving_average(grid[:, band].sum(axis=1).reshape(-1, 1), 3)[:, 0]
    level = np.median(profile[inside])
    first = _crossing(s, profile, 0.75 * level, start)
    end = _crossing(s, profile, 0.5 * level, start)
    last = _crossing(s, profile, 0.25 * level, start)
    return profile, level, first, end, last, level > 0 and not (np.isnan(first) or np.isnan(end) or np.isnan(last))


@numba.njit(cache=True, nogil=True)
def _end_along_profile(image, background, polarity, points, half_width, step=0.25):  # pragma: no cover - compiled
    """The needle's end to sub-pixel, ``points`` ordered towards it (about one pixel apart).

    A line fitted to the points 8-30 from the end gives the direction of the end profile: the covered fraction
    integrated across the needle's blurred band, on a grid bent along the needle. The end is where the profile falls
    to half its level; a bevel seen side-on (:data:`TAPER_FACTOR`) is fitted a blurred linear taper and the end put
    half its length beyond its middle. Returns the end's (points kept, new points ending with the end, half taper
    [px]), the other reading's (:class:`EndReading`: points it drops, its points, half taper, fall ratio) and each
    one's lateral uncertainty [px] (:func:`_placed_end`); kept (drop) is -1 where the profile leaves the image or
    does not fall (where there is no other reading)."""
    none = (-1, np.zeros((0, 2)), 0.0, -1, np.zeros((0, 2)), 0.0, 0.0, np.zeros(0), np.zeros(0))
    n = points.shape[0]
    if n < 100:
        return none
    for k in range(n - 99, n):
        if np.sqrt((points[k, 0] - points[k - 1, 0]) ** 2 + (points[k, 1] - points[k - 1, 1]) ** 2) > GAP_PX:
            return none
    direction, centre = _principal_direction(points[n - 30:n - 8])
    normal = np.array([-direction[1], direction[0]])
    along = (points[:, 0] - centre[0]) * direction[0] + (points[:, 1] - centre[1]) * direction[1]
    # The profile's grid is bent along the needle: each row shifted by a quadratic fit of the points' lateral offset.
    aside = (points[:, 0] - centre[0]) * normal[0] + (points[:, 1] - centre[1]) * normal[1]
    bend = np.empty((52, 3))
    for k in range(52):
        t = along[n - 60 + k]
        bend[k, 0], bend[k, 1], bend[k, 2] = t * t, t, 1.0
    bend_coefficients = np.linalg.lstsq(bend, np.ascontiguousarray(aside[n - 60:n - 8]))[0]
    # The profile runs 2 half widths beyond the last slice; 6 when it does not fall within that, if its end then lies
    # beyond the last slice (a fall before it is a faint stretch).
    for reach in (2.0 * half_width, 6.0 * half_width):
        s = np.arange(along[n - 30], along[n - 1] + reach, step)
        u = np.arange(-half_width - 1.0, half_width + 1.5, 0.5)
        shift = (bend_coefficients[0] * s + bend_coefficients[1]) * s + bend_coefficients[2]
        height, width = image.shape
        for i in range(s.shape[0]):  # each row's extremes are at its ends
            for corner_u in (u[0], u[-1]):
                x = centre[0] + s[i] * direction[0] + (corner_u + shift[i]) * normal[0]
                y = centre[1] + s[i] * direction[1] + (corner_u + shift[i]) * normal[1]
                if x < 0 or y < 0 or x > width - 1 or y > height - 1:
                    return none
        grid = _contrast_grid(image, background, polarity, centre, direction, s, u, shift, 0.0)
        inside = s <= along[n - 9]
        cross = _column_medians(grid[inside])
        # The profile sums the contrast over the needle's band and its blurred edges (2 sigma) only.
        side_sigma, band_centre, band_half_width, band_contrast = _side_blur(u, cross)
        band = np.abs(u - band_centre) <= band_half_width + 2 * side_sigma
        if np.count_nonzero(band) < 3:
            band[:] = True
        profile, level, first, end, last, found = _profile_crossings(s, grid, band, inside, along[n - 9])
        if found and (reach == 2.0 * half_width or end > along[n - 1]):
            break
        if reach > 2.0 * half_width:
            return none
    blur = _edge_spread(cross, u)
    spread = last - first
    tapered = _falls_slowly(profile, level, inside, spread, blur)
    # N from the band's fitted contrast over the harmonic mean of B: the covered fraction locates the end; tapered
    # where both profiles fall slowly, a candidate taper where the covered fraction's only does.
    needle = 0.0
    candidate = False
    if band_contrast > 0.0 and 1.0 - polarity * band_contrast > 0.0:
        inverse = 0.0
        for i in range(s.shape[0]):
            for j in range(u.shape[0]):
                if inside[i] and band[j]:
                    x = centre[0] + s[i] * direction[0] + (u[j] + shift[i]) * normal[0]
                    y = centre[1] + s[i] * direction[1] + (u[j] + shift[i]) * normal[1]
                    inverse += 1.0 / max(float(background[int(y + 0.5), int(x + 0.5)]), 1.0)
        needle = (1.0 - polarity * band_contrast) * np.count_nonzero(inside) * np.count_nonzero(band) / inverse
        covered = _contrast_grid(image, background, polarity, centre, direction, s, u, shift, needle)
        covered_profile, covered_level, covered_first, covered_end, covered_last, covered_found = _profile_crossings(
            s, covered, band, inside, along[n - 9])
        if covered_found:
            profile, level, end, spread = covered_profile, covered_level, covered_end, covered_last - covered_first
            covered_tapered = _falls_slowly(profile, level, inside, spread, blur)
            candidate = covered_tapered and not tapered
            tapered = tapered and covered_tapered
    # The blur along the profile: the side edges' (the same point spread and pixel area), plus the moving average's.
    sigma = np.sqrt(side_sigma ** 2 + 2 * step ** 2 / 3)
    half_taper = 0.0
    flat_end = candidate_end = end
    candidate_half_taper = 0.0
    if (tapered or candidate) and spread > blur:
        window = (s >= end - 2 * (spread + blur)) & (s <= end + 2 * (spread + blur))
        middle, taper = _taper_fit(s[window], profile[window] / level, end, 2 * np.sqrt(spread ** 2 - blur ** 2),
                                   sigma)
        candidate_half_taper = 0.5 * taper
        candidate_end = middle + candidate_half_taper
        if tapered:
            end, half_taper = candidate_end, candidate_half_taper
    if not end <= s[-1]:  # placed beyond the profile read (a taper fitted to a profile that does not end)
        return none
    kept, out, uncertainty = _placed_end(image, background, polarity, points, along, centre, direction, normal, end,
                                         half_taper, half_width, band_half_width, side_sigma, needle)
    if kept < 0:
        return none
    # The other reading: a tapered end placed flat, or a candidate's taper.
    other_end, other_half_taper = (flat_end, 0.0) if tapered else (candidate_end, candidate_half_taper)
    if tapered or candidate_half_taper > 0.0:
        other_kept, other_out, other_uncertainty = _placed_end(image, background, polarity, points, along, centre,
                                                               direction, normal, other_end, other_half_taper,
                                                               half_width, band_half_width, side_sigma, needle)
        if other_kept >= 0 and (tapered or other_kept <= kept):
            # It drops the end's new points and the slices it does not keep, and takes back those it keeps beyond.
            return (kept, out, half_taper, len(out) + kept - min(kept, other_kept),
                    np.vstack((points[kept:other_kept], other_out)), other_half_taper,
                    0.0 if tapered else spread / blur, uncertainty,
                    np.concatenate((np.zeros(max(other_kept - kept, 0)), other_uncertainty)))
    return kept, out, half_taper, -1, np.zeros((0, 2)), 0.0, 0.0, uncertainty, np.zeros(0)


@numba.njit(cache=True, nogil=True)
def _placed_end(image, background, polarity, points, along, centre, direction, normal, end, half_taper, half_width,
                band_half_width, side_sigma, needle):  # pragma: no cover - compiled
    """The points towards the ``end`` (:func:`_end_along_profile`: ``along`` the line through ``centre`` in
    ``direction``, ``half_taper`` beyond the middle of its taper): (number of ``points`` kept, the new points
    ending with the end, their lateral uncertainty [px]: where the quadratic and cubic fits to the slices disagree);
    kept is -1 where too few points are left before the taper."""
    # The slices within the taper (centroids pulled aside by the bevel) and within half_width + 1 of the end (cut
    # obliquely) are replaced.
    kept = int(np.searchsorted(along, end - 2 * half_taper - half_width - 1))
    if kept < 80 or end <= along[kept - 1]:
        return -1, np.zeros((0, 2)), np.zeros(0)
    # Quadratic lateral offset against the distance along the line (centred abscissa), fitted to the slices'
    # centroids over the needle's blurred band only.
    rows = abs(direction[1]) > abs(direction[0])
    half_band = min(max(band_half_width + 2 * side_sigma, 1.0), half_width) / max(abs(direction[1 if rows else 0]),
                                                                                   0.5)
    fit = _band_centroids(image, background, polarity, points[kept - 80:kept], rows, min(half_band, half_width),
                           needle)
    abscissa = (fit[:, 0] - centre[0]) * direction[0] + (fit[:, 1] - centre[1]) * direction[1]
    offset = abscissa.mean()
    lateral = (fit[:, 0] - centre[0]) * normal[0] + (fit[:, 1] - centre[1]) * normal[1]
    design = np.empty((80, 4))
    for k in range(80):
        t = abscissa[k] - offset
        design[k, 0], design[k, 1], design[k, 2], design[k, 3] = t * t * t, t * t, t, 1.0
    cubic = np.linalg.lstsq(design, lateral)[0]
    residual = lateral - design @ cubic
    variance = (residual @ residual) / 76.0 * np.linalg.inv(design.T @ design)[0, 0]
    quadratic = np.zeros(4)
    quadratic[1:] = np.linalg.lstsq(np.ascontiguousarray(design[:, 1:]), lateral)[0]
    coefficients = quadratic if end - along[kept - 1] > CUBIC_REACH * (along[kept - 1] - along[kept - 80]) \
        or cubic[0] * cubic[0] <= CURVATURE_RAMP_SIGNIFICANCE ** 2 * variance else cubic
    # Evenly spaced points at the slices' own spacing up to the end (the 3D smoothing's first pass fits by index).
    spacing = (along[kept - 1] - along[kept - 21]) / 20
    count = max(int(round((end - along[kept - 1]) / max(spacing, 0.5))), 1)
    steps = along[kept - 1] + (end - along[kept - 1]) * np.arange(1, count + 1) / count
    out = np.empty((steps.shape[0], 2))
    uncertainty = np.empty(steps.shape[0])
    for k in range(steps.shape[0]):
        t = steps[k] - offset
        shift = ((coefficients[0] * t + coefficients[1]) * t + coefficients[2]) * t + coefficients[3]
        out[k, 0] = centre[0] + steps[k] * direction[0] + shift * normal[0]
        out[k, 1] = centre[1] + steps[k] * direction[1] + shift * normal[1]
        uncertainty[k] = abs((((cubic[0] - quadratic[0]) * t + cubic[1] - quadratic[1]) * t + cubic[2] - quadratic[2])
                             * t + cubic[3] - quadratic[3])
    return kept, out, uncertainty


@numba.njit(cache=True, nogil=True)
def _scatter(points, first, count):  # pragma: no cover - compiled
    """Robust scatter [px] across the curve of the ``count`` slice centroids from ``first`` on (residuals to a
    9-point moving average): the median, and the running median over ``NOISE_WINDOW`` points interpolated to
    all points (the first and last full windows' at the ends); 0 for 9 points or fewer."""
    n = points.shape[0]
    if count <= 9:
        return 0.0, np.zeros(n)
    smooth = moving_average(points, 9)
    residual = np.empty(count)
    for k in range(count):
        dx, dy = points[first + k, 0] - smooth[first + k, 0], points[first + k, 1] - smooth[first + k, 1]
        residual[k] = np.sqrt(dx * dx + dy * dy) * 1.4826 * np.sqrt(9 / 8)
    window = min(NOISE_WINDOW, count)
    local = _running_median(residual, window, False)
    local[:window // 2] = np.median(residual[:window])
    local[count - window // 2:] = np.median(residual[count - window:])
    return np.median(residual), np.interp(np.arange(n) * 1.0, np.arange(first, first + count) * 1.0, local)


@numba.njit(cache=True, nogil=True)
def _reversed_slices(background, polarity, along_rows, fixed, predicted, half_width,
                     fade_level):  # pragma: no cover - compiled
    """The slices whose mean background over ``predicted ± half_width`` lies beyond the needle's own level
    ``fade_level`` (brighter than a bright needle, darker than a dark one): there the needle shows reversed. None
    when ``fade_level`` is 0 (no faded end was followed)."""
    height, width = background.shape
    n = fixed.shape[0]
    out = np.zeros(n, np.bool_)
    if fade_level <= 0:
        return out
    for k in range(n):
        centre = int(np.floor(predicted[k] + 0.5))
        limit = width if along_rows[k] else height
        f = fixed[k]
        if f < 0 or f >= (height if along_rows[k] else width):
            continue
        total, count = 0.0, 0
        for c in range(max(centre - half_width, 0), min(centre + half_width + 1, limit)):
            total += background[f, c] if along_rows[k] else background[c, f]
            count += 1
        out[k] = count > 0 and polarity * (total / count - fade_level) < 0
    return out


@numba.njit(cache=True, nogil=True)
def _slice_points(image, background, polarity, path, half_width, wide, min_contrast_fraction,
                  min_profile_fraction, fade_level):  # pragma: no cover - compiled
    """The centerline points of the one-pixel slices across ``path`` (:func:`_slices_along`; ``wide`` slices, then
    ``half_width`` ones around their centroids), in path order, with their contrast, centroid noise per unit of image
    noise, contrast per unit of needle width, and two selections: ``keep`` (at least ``min_contrast_fraction`` of the
    median width contrast, centroid within the first pass, cut to the first and last ``full`` slice) and ``full``
    (also ``min_profile_fraction`` of it); ``keep`` is empty when fewer than 3 slices have contrast or are full. Last,
    the slices where the needle shows reversed (:func:`_reversed_slices` at the needle's level ``fade_level``)."""
    along_rows, fixed, predicted, obliquity = _slices_along(path)
    flipped = _reversed_slices(background, polarity, along_rows, fixed, predicted, wide, fade_level)
    relative = np.zeros(0)
    centroid, contrast, noise = _slice_centroids(image, background, polarity, along_rows, fixed, predicted, wide,
                                                 relative, False)
    centroid, contrast, noise = _slice_centroids(image, background, polarity, along_rows, fixed, centroid, half_width,
                                                 relative, True)
    needle = _needle_levels(image, polarity, along_rows, fixed, centroid, contrast, NEEDLE_LEVEL_WINDOW)
    if needle.shape[0] > 0:
        centroid, contrast, noise = _slice_centroids(image, background, polarity, along_rows, fixed, centroid,
                                                     half_width, needle, True)
    n = contrast.shape[0]
    points = np.empty((n, 2))
    for k in range(n):
        points[k, 0], points[k, 1] = (centroid[k], fixed[k]) if along_rows[k] else (fixed[k], centroid[k])
    width_contrast = contrast * obliquity
    none = np.zeros(0, np.bool_)
    strong = contrast > 0
    if np.count_nonzero(strong) < 3:
        return points, contrast, noise, width_contrast, none, none, flipped
    level = np.median(width_contrast[strong])
    keep = (width_contrast >= min_contrast_fraction * level) & (np.abs(centroid - predicted) <= wide)
    full = keep & (width_contrast >= min_profile_fraction * level)
    ends = np.flatnonzero(full)
    if len(ends) < 3:
        return points, contrast, noise, width_contrast, none, none, flipped
    keep[:ends[0]] = False
    keep[ends[-1] + 1:] = False
    return points, contrast, noise, width_contrast, keep, full, flipped


@numba.njit(cache=True, nogil=True)
def _kept_slices(points, keep, full, width_contrast, local, min_profile_fraction,
                 half_width):  # pragma: no cover - compiled
    """Indices of the slices kept (:func:`_slice_points`' ``keep`` that are ``full`` or have ``min_profile_fraction`` of
    the ``local`` median width contrast), less those within ``half_width`` (+1 after) of a hidden stretch (kept points
    more than GAP_PX apart): there the slices may be cut by the occluder's edge (centroid biased)."""
    selected = np.flatnonzero(keep)
    for j in range(selected.shape[0]):
        k = selected[j]
        keep[k] = full[k] | (width_contrast[k] >= min_profile_fraction * local[j])
    kept = np.flatnonzero(keep)
    edges = np.flatnonzero(step_lengths(points[kept]) > GAP_PX)
    for edge in edges:
        keep[kept[max(edge - half_width, 0):edge + half_width + 2]] = False
    return np.flatnonzero(keep)


def _with_ends(points: np.ndarray, per_slice: np.ndarray, cut: int, first: tuple, last: tuple
               ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The centerline with its last points at each end replaced by the points towards the sub-pixel end
    (``first``, ``last``: :func:`_end_along_profile` of ``points[:cut][::-1]`` and ``points[cut:]``: kept count, or -1
    to keep the end as it is, and new points), with the ``per_slice`` values (rows) of the nearest slice kept; and
    how many points come before and from the slices."""
    lo = cut - first[0] if first[0] >= 0 else 0
    hi = cut + last[0] if last[0] >= 0 else len(points)
    head = first[1][::-1] if first[0] >= 0 else np.zeros((0, 2))
    tail = last[1] if last[0] >= 0 else np.zeros((0, 2))
    return (np.vstack([head, points[lo:hi], tail]),
            np.concatenate([np.repeat(per_slice[lo:lo + 1], len(head), axis=0), per_slice[lo:hi],
                            np.repeat(per_slice[hi - 1:hi], len(tail), axis=0)]),
            len(head), hi - lo)


def _coarse_paths(mask: np.ndarray, scratch: np.ndarray, min_length: int, count: int = 4) -> list[np.ndarray]:
    """The longest geodesic path of the largest linked component of ``mask``, then of the next largest ones
    (up to ``count``, at least ``min_length`` coarse pixels long) away from the components already used."""
    points, lengths = _coarse_path_kernel(mask, scratch, min_length, count)
    bounds = np.cumsum(lengths).tolist()
    return [points[start:stop] for start, stop in zip([0] + bounds, bounds)]


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    """z component of the cross product of two 2D vectors."""
    return float(a[0] * b[1] - a[1] * b[0])


def _end_tangent(path: np.ndarray) -> np.ndarray:
    """Unit direction out of the last point of ``path`` (from the point 4 before it)."""
    tangent = path[-1] - path[max(-5, -len(path))]
    return tangent / max(np.linalg.norm(tangent), 1e-9)


def _join(first: np.ndarray, second: np.ndarray, max_angle_deg: float, margin: float) -> np.ndarray | None:
    """The two paths as one, through the gap between ends that face each other: end directions within
    ``max_angle_deg`` (antiparallel) and each end within ``margin`` + 15 % of the gap of the other's tangent
    line; the closest such pair of ends. None when no ends face each other."""
    best, best_gap = None, np.inf
    for a in (first, first[::-1]):
        for b in (second, second[::-1]):
            gap = b[0] - a[-1]
            distance = np.linalg.norm(gap)
            tangent_a, tangent_b = _end_tangent(a), _end_tangent(b[::-1])
            if distance >= best_gap or tangent_a @ -tangent_b < np.cos(np.radians(max_angle_deg)):
                continue
            lateral = max(abs(_cross(tangent_a, gap)), abs(_cross(tangent_b, gap)))
            if gap @ tangent_a > 0 and lateral <= margin + 0.15 * distance:
                best, best_gap = np.vstack([a, b]), distance
    return best


def _link_components(paths: list[np.ndarray], max_angle_deg: float, margin: float) -> np.ndarray:
    """The first path extended by the others whose ends face its ends (a needle cut by an occluder)."""
    path, others = paths[0], list(paths[1:])
    while others:
        joined = [_join(path, other, max_angle_deg, margin) for other in others]
        linked = [k for k, candidate in enumerate(joined) if candidate is not None]
        if not linked:
            break
        path = joined[linked[0]]
        others.pop(linked[0])
    return path


@numba.njit(cache=True, nogil=True)
def _end_level(image, background, path, polarity):  # pragma: no cover - compiled
    """The needle's own grey level near the end of ``path`` (full-resolution points ordered towards it, 4 px apart):
    the median over ``END_LEVEL_POINTS`` points before the last four of the grey level of the pixel that differs most
    from the background among the 5x5 around each, in the needle's ``polarity`` (0: either way, where it may show
    reversed); 0 when the path is too short."""
    height, width = image.shape
    first = max(path.shape[0] - 4 - END_LEVEL_POINTS, 0)
    levels = np.empty(max(path.shape[0] - 4 - first, 0))
    count = 0
    for k in range(first, path.shape[0] - 4):
        cx, cy = int(np.floor(path[k, 0] + 0.5)), int(np.floor(path[k, 1] + 0.5))
        best, level = -np.inf, 0.0
        for y in range(max(cy - 2, 0), min(cy + 3, height)):
            for x in range(max(cx - 2, 0), min(cx + 3, width)):
                excess = background[y, x] - float(image[y, x])
                score = polarity * excess if polarity != 0 else abs(excess)
                if score > best:
                    best, level = score, float(image[y, x])
        if best > -np.inf:
            levels[count] = level
            count += 1
    return np.median(levels[:count]) if count > 0 else 0.0


def _coarse_needle_path(image: np.ndarray, coarse: np.ndarray, mask: np.ndarray, background: BackgroundModel,
                        config: CenterlineConfig) -> np.ndarray:
    """The needle's path (full-resolution points) from the coarse ``mask``: its largest component's, linked with the
    components whose ends face its ends (:func:`_link_components`)."""
    factor, polarity = background.threshold.downsample, float(background.threshold.polarity)
    paths = _coarse_paths(mask, background.coarse_scratch, int(config.min_length_px / factor))
    if not paths:
        raise NoNeedleError("no pixel differs enough from the background")
    # Refined (:func:`_refine_path`), in full-resolution coordinates (of the coarse pixel centres), 3-point smoothed.
    paths = [moving_average((_refine_path(coarse, background.coarse, polarity, path) + 0.5) * factor - 0.5, 3)
             for path in paths]
    length = arc_length(paths[0])[-1]
    if length < config.min_length_px:
        raise NoNeedleError(f"largest foreground structure is {length:.0f} px long "
                            f"(< {config.min_length_px:.0f} px): no needle")
    # Components whose ends face each other are one needle with a hidden stretch between them: sliced through
    # (the slices in the gap have no contrast and are dropped).
    return _link_components(paths, config.max_link_angle_deg, 2.0 * factor)


def _followed_fades(image: np.ndarray, coarse: np.ndarray, mask: np.ndarray, background: BackgroundModel,
                    config: CenterlineConfig, path: np.ndarray) -> tuple[np.ndarray, float]:
    """The path with its ends followed where the needle fades into a background at its own level and beyond it, where
    it shows reversed (:func:`_grow_faded`, from each end at the needle's level there; again from the new ends, up to
    ``FADE_ROUNDS`` times), and that level (the mean over the detected ends followed; 0 where none was: the path as it
    is)."""
    threshold = background.threshold
    factor, polarity = threshold.downsample, float(threshold.polarity)
    levels: list[float] = []
    for round_ in range(FADE_ROUNDS):
        grown = np.zeros_like(mask)
        for ordered in (path[::-1], path):
            # The detected ends show the needle's polarity; the ends followed to may lie where it shows reversed.
            level = _end_level(image, background.image, ordered, polarity if round_ == 0 else 0.0)
            if level <= 0:
                continue
            seed = np.round((ordered[-1] + 0.5) / factor - 0.5).astype(np.int64)
            pixels, count = _grow_faded(coarse, background.coarse, mask, seed, level, polarity, threshold.relative,
                                        threshold.absolute)
            if count > FADE_MAX_AREA * np.hypot(*mask.shape):  # not a needle's band: the background model is off
                continue
            if count:
                grown |= pixels
                if round_ == 0:  # the ends of the needle as detected: its level where it fades
                    levels.append(level)
        if not grown.any():
            break
        mask = mask | grown
        path = _coarse_needle_path(image, coarse, mask, background, config)
    return path, float(np.mean(levels)) if levels else 0.0


def extract_centerline(image: np.ndarray, background: BackgroundModel, config: CenterlineConfig = CenterlineConfig()
                       ) -> ImageCenterline:
    """The needle's sub-pixel centerline in ``image`` (uint8/uint16 grey, same size as the background)."""
    if image.shape != background.shape:
        raise ValueError(f"image size {image.shape[::-1]} differs from the background's {background.shape[::-1]}")
    threshold = background.threshold
    factor, polarity = threshold.downsample, float(threshold.polarity)
    coarse = downsample(image, factor)
    mask = background.coarse_foreground(coarse)
    path = _coarse_needle_path(image, coarse, mask, background, config)
    path, fade_level = _followed_fades(image, coarse, mask, background, config, path)
    # Extend both ends along the end tangents so that the tips are sliced too (empty slices are dropped).
    ends = []
    for end, inner in ((path[0], path[min(2, len(path) - 1)]), (path[-1], path[max(-3, -len(path))])):
        direction = (end - inner) / max(np.linalg.norm(end - inner), 1e-9)
        ends.append(end + np.outer([2.0 * factor, factor], direction))
    path = np.vstack([ends[0], path, ends[1][::-1]])

    wide = config.profile_half_width + factor // 2  # first pass: the coarse path is good to ~factor/2 px
    points, contrast, slice_noise, width_contrast, keep, full, flipped = _slice_points(
        image, background.image, polarity, path, config.profile_half_width, wide, config.min_contrast_fraction,
        config.min_profile_fraction, fade_level)
    if len(keep) == 0:
        raise NoNeedleError("the needle's slices have no contrast")
    # Where the needle shows reversed it is linked through, not measured: the covered fraction's denominator B - N
    # passes through zero at the stretch's edges, and N there is only known from beyond them (measured, the stretch
    # broke the uncertainty's promise: 97.0 % within 3 sigma and 6.3 sigma on the hard band, docs/stereo_history.md).
    keep &= ~flipped
    # A slice is compared with the median of its neighbours above a floor (a faded stretch is followed), compiled
    # where the window reflects at most once (scipy's repeated reflection otherwise).
    window, widths = config.local_window, width_contrast[keep]
    local = median_filter(widths, size=window, mode="mirror") if window > len(widths) else _running_median(
        np.ascontiguousarray(widths, dtype=float), window, True)
    kept = _kept_slices(points, keep, full, width_contrast, local, config.min_profile_fraction,
                        config.profile_half_width)
    if len(kept) < 3:
        raise NoNeedleError("too few centerline points with enough contrast")
    points = points[kept]
    cut = len(points) // 2
    first, last = (_end_along_profile(image, background.image, polarity, np.ascontiguousarray(part),
                                      config.profile_half_width) for part in (points[:cut][::-1], points[cut:]))
    points, per_slice, head, slices = _with_ends(points, np.column_stack([contrast[kept], slice_noise[kept]]), cut,
                                                 first, last)
    contrast_kept, slice_noise = per_slice[:, 0], per_slice[:, 1]
    if len(points) < 3 or arc_length(points)[-1] < config.min_length_px:
        raise NoNeedleError("too few centerline points with enough contrast")
    # Scatter of the slice centroids, at least the slice's own centroid noise scaled so that the median slice's is
    # the measured scatter (a slice where the contrast fades errs more than its neighbours' median shows).
    noise, local = _scatter(points, head, slices)
    local = np.maximum(local, noise * slice_noise / np.median(slice_noise[head:head + slices]))
    extrapolation = np.concatenate([first[7][::-1], np.zeros(slices), last[7]])  # empty where an end is kept as it is
    # Each end's other reading: a taper candidate (tapered) or the flat placement of a tapered end (flat).
    candidates, flat = (tuple(None if end[3] < 0 or (end[5] == 0.0) != placed_flat else EndReading(*end[3:7], end[8])
                              for end in (first, last)) for placed_flat in (False, True))
    return ImageCenterline(points, contrast_kept, noise, local, extrapolation, np.array([first[2], last[2]]),
                           candidates, flat)
