"""Moved to :mod:`needle_common.ros.tf_output`; the stereo node still imports it from here."""
from needle_common.ros.tf_output import TfOutput, transform_stamped

__all__ = ["TfOutput", "transform_stamped"]
