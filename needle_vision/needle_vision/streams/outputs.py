"""What the node publishes, as plain data (no ROS): ``sensor_msgs/PointCloud2`` fields and the debug image."""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from needle_vision.detection.background import downsample

#: sensor_msgs/PointField datatype FLOAT32
FLOAT32 = 7


def pointcloud2_fields(points: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """An unorganised little-endian cloud of float32 fields x, y, z, plus for each ``extra`` prefix an
    ``(n, 3)`` array as three fields (e.g. ``{"v": velocity}`` -> vx, vy, vz)."""
    columns = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}
    for prefix, values in (extra or {}).items():
        columns.update({prefix + axis: values[:, k] for k, axis in enumerate("xyz")})
    names = list(columns)
    data = np.column_stack([columns[name] for name in names]).astype("<f4")
    return {"height": 1, "width": len(points), "is_bigendian": False, "is_dense": True,
            "point_step": 4 * len(names), "row_step": 4 * len(names) * len(points),
            "fields": [{"name": name, "offset": 4 * k, "datatype": FLOAT32, "count": 1}
                       for k, name in enumerate(names)],
            "data": data.tobytes()}


def debug_image(left: np.ndarray, right: np.ndarray, left_points: np.ndarray | None,
                right_points: np.ndarray | None, factor: int) -> np.ndarray:
    """Left and right images side by side (bgr8, ``factor``x smaller) with the detected centerlines drawn
    (green; none when detection failed). ``factor`` is a power of two."""
    panels = []
    for image, points in ((left, left_points), (right, right_points)):
        if image.dtype != np.uint8:
            image = (image >> 8).astype(np.uint8)
        panel = cv2.cvtColor(downsample(image, factor), cv2.COLOR_GRAY2BGR)
        if points is not None and len(points) > 1:
            scaled = np.round(((points + 0.5) / factor - 0.5) * 16).astype(np.int32)
            cv2.polylines(panel, [scaled], False, (0, 255, 0), 1, cv2.LINE_AA, shift=4)
        panels.append(panel)
    if panels[0].shape != panels[1].shape:
        height = max(p.shape[0] for p in panels)
        panels = [cv2.copyMakeBorder(p, 0, height - p.shape[0], 0, 0, cv2.BORDER_CONSTANT) for p in panels]
    return np.hstack(panels)
