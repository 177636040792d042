"""The seed 003 model driven alone through a depth/velocity record (the LuGre tests' data and standalone reference)."""
import numpy as np

from needle_sim_ros.tissue.lugre import ModifiedLuGre


def simulate(model: ModifiedLuGre, depth: np.ndarray, velocity: np.ndarray, dt: float, z0: float = 0.0):
    """Force f_k and state z_k at samples k of a depth/velocity record sampled every dt (z_0 = z0)."""
    depth = np.asarray(depth, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    forces, states = np.empty(depth.size), np.empty(depth.size)
    z = z0
    for k in range(depth.size):
        states[k] = z
        forces[k] = model.force(z, depth[k], velocity[k])
        z = model.step(z, depth[k], velocity[k], dt)
    return forces, states
