"""Moved to :mod:`needle_common.transforms`; the stereo node still imports it from here."""
from needle_common.transforms import quaternions_from_x_axes as quaternion_from_x_axis

__all__ = ["quaternion_from_x_axis"]
