"""The simulator's TF: ``world -> needle_base`` (the base pose) and ``needle_base -> needle_tip`` (the deformed
needle's tip), both dynamic, stamped with the state's time and sent at the shape rate (REP 105 frame names are
the ``frames.*`` parameters)."""
from __future__ import annotations

import numpy as np
from needle_common.ros.tf_output import TfOutput, transform_stamped
from rclpy.node import Node

from needle_common.transforms import conjugate, multiply, quaternion_matrix
from needle_sim_ros.model.kinematics import BaseMotion


def tip_in_base(base: BaseMotion, tip_position: np.ndarray, tip_orientation: np.ndarray) -> tuple:
    """Tip pose relative to the base frame: p = R_b^T (p_tip - p_b), q = q_b^* q_tip."""
    rotation = quaternion_matrix(np.asarray(base.orientation, dtype=float))
    position = rotation.T @ (np.asarray(tip_position, dtype=float) - base.position)
    return position, multiply(conjugate(np.asarray(base.orientation, dtype=float)),
                              np.asarray(tip_orientation, dtype=float))


class SimulatorTf:
    """Sends the two transforms of a state snapshot (see the module docstring)."""

    def __init__(self, node: Node, world: str, base: str, tip: str) -> None:
        self.output = TfOutput(node)
        self.world, self.base, self.tip = world, base, tip

    def has_subscribers(self) -> bool:
        return self.output.has_subscribers()

    def send(self, stamp, base: BaseMotion | None, tip: tuple) -> None:
        if self.output.backend is None or base is None:
            return
        tip_position, tip_orientation = tip_in_base(base, *tip)
        self.output.send([transform_stamped(stamp, self.world, self.base, base.position, base.orientation),
                          transform_stamped(stamp, self.base, self.tip, tip_position, tip_orientation)])
