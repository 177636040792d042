"""The suite's ``needle_interfaces/NeedleShape`` message object from centerline arrays (the stereo node, the offline
pipeline's stereo stage and the sample bags' shape sensor all publish through it)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from needle_interfaces.msg import NeedleShape
from std_msgs.msg import Header


def needle_shape_msg(header: Header, source: str, points: np.ndarray, tangents: np.ndarray, arc_length: np.ndarray,
                     tip_position: np.ndarray, tip_orientation: np.ndarray,
                     uncertainty: np.ndarray | None = None) -> NeedleShape:
    """A NeedleShape: ``length`` is the last arc length [m], the tip pose's orientation (x, y, z, w)."""
    return NeedleShape(
        header=header,
        source=source,
        points=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points],
        tangents=[Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in tangents],
        arc_length=[float(s) for s in arc_length],
        uncertainty=[] if uncertainty is None else [float(u) for u in uncertainty],
        tip_pose=Pose(position=Point(x=float(tip_position[0]), y=float(tip_position[1]), z=float(tip_position[2])),
                      orientation=Quaternion(x=float(tip_orientation[0]), y=float(tip_orientation[1]),
                                             z=float(tip_orientation[2]), w=float(tip_orientation[3]))),
        length=float(arc_length[-1]) if len(arc_length) else 0.0,
    )
